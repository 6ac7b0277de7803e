// SPDX-License-Identifier: Apache-2.0
// Runs the built `clastrace` program on good, damaged and unreadable traces and checks
// its exit codes (0 intact, 1 damage, 2 usage/unreadable) and what it prints.
#include "shell_run.h"
#include "trace_test_support.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>


namespace clastrace::traces::testing {
namespace {

using ProgramRun = ShellRun;

// Output: stdout and stderr together, or stdout alone (for JSON) without `merge_stderr`.
ProgramRun run(const std::string& args, bool merge_stderr = true) {
    return run_shell(std::string(CLASTRACE_BIN) + " " + args +
                     (merge_stderr ? " 2>&1" : " 2>/dev/null"));
}

const std::string kSample = CLASTRACE_SAMPLE;

TEST(ClastraceCli, HelpOnProgramAndInfo) {
    ProgramRun top = run("--help");
    EXPECT_EQ(top.exit_code, 0);
    EXPECT_NE(top.output.find("info"), std::string::npos) << top.output;
    ProgramRun info = run("info --help");
    EXPECT_EQ(info.exit_code, 0);
    EXPECT_NE(info.output.find("--json"), std::string::npos) << info.output;
    EXPECT_NE(info.output.find("TRACE"), std::string::npos) << info.output;
}

TEST(ClastraceCli, UsageErrorsExitWithTwo) {
    EXPECT_EQ(run("").exit_code, 2);
    EXPECT_EQ(run("info").exit_code, 2);
    EXPECT_EQ(run("info --bogus " + kSample).exit_code, 2);
    EXPECT_EQ(run("nosuchcommand").exit_code, 2);
}

TEST(ClastraceCli, InfoOnTheSampleIsCleanAndComplete) {
    ProgramRun r = run("info " + kSample);
    EXPECT_EQ(r.exit_code, 0) << r.output;
    for (const char* text :
         {"NVIDIA GeForce RTX 4080 (sample)", "maxVerticesPerCluster 256",
          "CmdBuildClusterAccelerationStructureIndirect", "CmdBuildAccelerationStructureNV",
          "QueueSubmit", "dedup ratio", "compression ratio", "damage      none"}) {
        EXPECT_NE(r.output.find(text), std::string::npos) << "missing \"" << text << "\" in\n"
                                                          << r.output;
    }
}

TEST(ClastraceCli, InfoJsonHasTheDocumentedFields) {
    ProgramRun r = run("info --json " + kSample, false);
    ASSERT_EQ(r.exit_code, 0) << r.output;
    nlohmann::json j = nlohmann::json::parse(r.output);
    EXPECT_EQ(j["format_version"]["major"], 1);
    EXPECT_EQ(j["header"]["device"]["vendor_id"], 0x10de);
    EXPECT_EQ(j["header"]["device"]["cluster_properties"]["maxVerticesPerCluster"], 256);
    EXPECT_EQ(j["header"]["device"]["cluster_properties"]["clusterBottomLevelByteAlignment"], 256);
    EXPECT_EQ(j["header"]["device"]["cluster_features"]["enabled"], true);
    EXPECT_EQ(j["header"]["device"]["cluster_features"]["served"],
              false);  // the sample's driver built them
    EXPECT_EQ(j["index"]["present"], true);
    EXPECT_EQ(j["index"]["submissions"], 1);
    EXPECT_EQ(j["records"]["by_kind"]["QueueSubmit"], 1);
    EXPECT_EQ(j["records"]["by_kind"]["CmdBuildClusterAccelerationStructureIndirect"], 1);
    EXPECT_EQ(j["records"]["by_kind"]["DebugLabel"], 0);  // every kind is listed, zero or not
    EXPECT_GT(j["memory"]["bytes_referenced"].get<uint64_t>(),
              j["memory"]["bytes_stored"].get<uint64_t>());
    EXPECT_GT(j["memory"]["dedup_ratio"].get<double>(), 1.0);
    EXPECT_GT(j["chunks"]["raw_bytes"].get<uint64_t>(),
              j["chunks"]["compressed_bytes"].get<uint64_t>());
    EXPECT_EQ(j["damage"]["count"], 0);
    EXPECT_TRUE(j["damage"]["items"].empty());
}

// --vs-zstd (issue 23): the file against plain zstd of its referenced bytes, in text and JSON;
// a trace written with deltas counts them. Without the option the comparison is null.
TEST(ClastraceCli, InfoComparesTheFileWithPlainZstdOnRequest) {
    const std::string path = temp_path("cli_vs_zstd.clt");
    write_frames_trace(path, 12, 8192);
    ProgramRun text = run("info --vs-zstd " + path);
    EXPECT_EQ(text.exit_code, 0) << text.output;
    EXPECT_NE(text.output.find("x plain zstd -3 of the referenced bytes ("), std::string::npos)
        << text.output;
    EXPECT_NE(text.output.find("stored XOR an earlier content of their range"), std::string::npos)
        << text.output;
    ProgramRun json = run("info --json --vs-zstd " + path, false);
    ASSERT_EQ(json.exit_code, 0) << json.output;
    nlohmann::json j = nlohmann::json::parse(json.output);
    const uint64_t zstd_bytes = j["size_vs_zstd"]["zstd_bytes"].get<uint64_t>();
    EXPECT_GT(zstd_bytes, 0u);
    EXPECT_EQ(j["size_vs_zstd"]["file_bytes"], j["file_size"]);
    EXPECT_EQ(j["size_vs_zstd"]["zstd_level"], 3);
    EXPECT_DOUBLE_EQ(j["size_vs_zstd"]["ratio"].get<double>(),
                     double(j["file_size"].get<uint64_t>()) / double(zstd_bytes));
    EXPECT_GT(j["memory"]["contents_delta"].get<uint64_t>(), 0u);
    ProgramRun plain = run("info --json " + path, false);
    ASSERT_EQ(plain.exit_code, 0) << plain.output;
    EXPECT_TRUE(nlohmann::json::parse(plain.output)["size_vs_zstd"].is_null());
}

TEST(ClastraceCli, DamagedTraceExitsWithOneAndNamesTheOffset) {
    std::vector<uint8_t> file = read_file(kSample);
    ASSERT_GT(file.size(), 1000u);
    file[file.size() / 2] ^= 0x04;
    const std::string path = temp_path("flipped.clt");
    write_file(path, file);
    ProgramRun r = run("info " + path);
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_NE(r.output.find("checksum mismatch"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find(path + ": offset "), std::string::npos) << r.output;

    ProgramRun j = run("info --json " + path, false);
    EXPECT_EQ(j.exit_code, 1);
    nlohmann::json doc = nlohmann::json::parse(j.output);
    ASSERT_GE(doc["damage"]["count"].get<int>(), 1);
    EXPECT_EQ(doc["damage"]["items"][0]["code"], "checksum_mismatch");

    file = read_file(kSample);
    file.resize(file.size() - 100);
    const std::string cut = temp_path("cut.clt");
    write_file(cut, file);
    ProgramRun c = run("info " + cut);
    EXPECT_EQ(c.exit_code, 1) << c.output;
    EXPECT_NE(c.output.find("[truncated]"), std::string::npos) << c.output;
}

// A trace whose CmdTraceRays inputs or DeviceAddressWrites writes name contents badly: a wrong
// hash (contents no record defines) or contents shorter than the snapshot says (truncated).
std::string trace_with_bad_snapshot(fbs::RecordBody kind, bool truncated) {
    const std::string path = temp_path(std::string(fbs::EnumNameRecordBody(kind)) +
                                       (truncated ? ".truncated.clt" : ".wrong_hash.clt"));
    TraceError e;
    auto w = TraceWriter::create(path, test_header(), {}, &e);
    EXPECT_TRUE(w) << e.message;
    if (!w) return path;
    std::vector<uint8_t> bytes(32, 0x5a);
    fbs::MemorySnapshot s;
    EXPECT_FALSE(w->snapshot(0xb0, 0, 0xe000, bytes.data(), bytes.size(), &s));
    // Truncated: the contents hold 32 bytes, the snapshot says 64.
    s = fbs::MemorySnapshot(s.buffer(), s.offset(), s.address(), truncated ? 64 : s.size(),
                            truncated ? s.hash() : s.hash() ^ 1);
    fbs::RecordT r;
    if (kind == fbs::RecordBody::CmdTraceRays) {
        fbs::CmdTraceRaysT rays;
        rays.entry_point = "vkCmdTraceRaysIndirectKHR";
        rays.indirect_address = 0xe000;
        rays.inputs = {s};
        r.body.Set(std::move(rays));
    } else {
        fbs::DeviceAddressWritesT writes;
        writes.writes = {s};
        r.body.Set(std::move(writes));
    }
    EXPECT_FALSE(w->append(r));
    EXPECT_FALSE(w->finish());
    return path;
}

TEST(ClastraceCli, BadSnapshotsOfRaysAndAddressWritesExitWithOneAndNameTheRule) {
    for (fbs::RecordBody kind :
         {fbs::RecordBody::CmdTraceRays, fbs::RecordBody::DeviceAddressWrites})
        for (bool truncated : {false, true}) {
            const std::string path = trace_with_bad_snapshot(kind, truncated);
            // info names the reader's rule; replay reports the damage as its finding.
            const std::string code = truncated ? "[content_mismatch]" : "[missing_contents]";
            const std::string what = std::string("(") + fbs::EnumNameRecordBody(kind) +
                                     "): snapshot of address 0x000000000000e000";
            for (const char* command : {"info", "replay"}) {
                ProgramRun r = run(std::string(command) + " " + path);
                SCOPED_TRACE(std::string(command) + " " + path);
                EXPECT_EQ(r.exit_code, 1) << r.output;
                EXPECT_NE(r.output.find(path + ": offset "), std::string::npos) << r.output;
                const std::string rule = command == std::string("info")
                                             ? code
                                             : "CLASTRACE-trace-damaged: " + path + ": offset ";
                EXPECT_NE(r.output.find(rule), std::string::npos) << r.output;
                EXPECT_NE(r.output.find(what), std::string::npos) << r.output;
            }
        }
}

TEST(ClastraceCli, UnreadableInputExitsWithTwo) {
    ProgramRun missing = run("info /nonexistent/trace.clt");
    EXPECT_EQ(missing.exit_code, 2);
    EXPECT_NE(missing.output.find("/nonexistent/trace.clt: offset 0: cannot open"),
              std::string::npos)
        << missing.output;
    const std::string text = temp_path("text.clt");
    write_file(text, std::vector<uint8_t>(100, 'a'));
    ProgramRun not_trace = run("info " + text);
    EXPECT_EQ(not_trace.exit_code, 2);
    EXPECT_NE(not_trace.output.find("not a clastrace trace"), std::string::npos)
        << not_trace.output;
    const std::string empty = temp_path("empty.clt");
    write_file(empty, {});
    ProgramRun e = run("info --json " + empty);
    EXPECT_EQ(e.exit_code, 2);
    EXPECT_NE(e.output.find("empty file"), std::string::npos) << e.output;
}

}  // namespace
}  // namespace clastrace::traces::testing
