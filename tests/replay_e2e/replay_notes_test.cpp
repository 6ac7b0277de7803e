// SPDX-License-Identifier: Apache-2.0
// Limits are notes, not findings: a correct application's trace (the H100 capture of
// nv_ray_tracing, which deserializes the driver's own blob) exits 0 with its notes listed apart;
// a trace with a real hazard still exits 1, its notes listed beside the hazard.
#include "catalogue_replay.h"

#include <clastrace/replay/replay_report.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <set>
#include <string>
#include <sys/wait.h>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;

const std::set<std::string> kSampleLimits = {"CLASTRACE-replay-nv-opaque-object",
                                             "CLASTRACE-serialized-blob-from-another-driver"};

int run_cli(const std::string& args, std::string* out) {
    const std::string out_path = temp_trace_path("replay_notes", "cli.out");
    const std::string cmd =
        std::string(CLASTRACE_BIN) + " " + args + " > " + out_path + " 2>/dev/null";
    const int status = std::system(cmd.c_str());
    std::ifstream in(out_path);
    out->assign(std::istreambuf_iterator<char>(in), {});
    std::remove(out_path.c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// Every entry of a JSON `notes` array has the documented fields and types (docs/replay.md).
void expect_note_shape(const nlohmann::json& notes) {
    ASSERT_TRUE(notes.is_array());
    for (const nlohmann::json& n : notes) {
        ASSERT_TRUE(n.is_object()) << n;
        EXPECT_EQ(n.size(), 5u) << n;
        EXPECT_TRUE(n["rule"].is_string()) << n;
        EXPECT_TRUE(replay::is_replay_limit(n["rule"].get<std::string>())) << n;
        EXPECT_TRUE(n["message"].is_string() && !n["message"].get<std::string>().empty()) << n;
        EXPECT_TRUE(n["op_index"].is_number_integer()) << n;
        EXPECT_TRUE(n["address"].is_string()) << n;
        EXPECT_EQ(n["address"].get<std::string>().rfind("0x", 0), 0u) << n;
        const nlohmann::json& w = n["where"];
        ASSERT_TRUE(w.is_object()) << n;
        for (const char* key : {"sequence", "submission", "command_buffer", "command"})
            EXPECT_TRUE(w[key].is_number_unsigned()) << key << " in " << n;
        EXPECT_TRUE(w["command_buffer_handle"].is_string()) << n;
        EXPECT_TRUE(w["name"].is_string()) << n;
    }
}

TEST(ReplayNotes, LimitsAreNamedByRule) {
    for (const std::string& rule : kSampleLimits) EXPECT_TRUE(replay::is_replay_limit(rule));
    EXPECT_TRUE(replay::is_replay_limit("CLASTRACE-replay-memory-budget"));
    EXPECT_TRUE(replay::is_replay_limit("CLASTRACE-findings-truncated"));
    // Broken rules and damage stay findings.
    EXPECT_FALSE(
        replay::is_replay_limit("VUID-VkCopyMemoryToAccelerationStructureInfoKHR-dst-03746"));
    EXPECT_FALSE(replay::is_replay_limit("CLASTRACE-deserialize-handle-names-no-created-object"));
    EXPECT_FALSE(replay::is_replay_limit("CLASTRACE-replay-output-differs"));
    EXPECT_FALSE(replay::is_replay_limit("CLASTRACE-replay-restatement-out-of-order"));
    EXPECT_FALSE(replay::is_replay_limit("CLASTRACE-memory-fault"));
}

TEST(ReplayNotes, CorrectH100TraceExitsZeroWithItsNotes) {
    std::string out;
    EXPECT_EQ(run_cli(std::string("replay ") + CLASTRACE_NV_SAMPLE, &out), 0) << out;
    const size_t notes = out.find("\nNotes (limits of this replay, not findings):\n");
    ASSERT_NE(notes, std::string::npos) << out;
    for (const std::string& rule : kSampleLimits) {
        // Listed under Notes, never as a finding line of its own.
        EXPECT_NE(out.find("  " + rule + ": ", notes), std::string::npos) << out;
        EXPECT_NE(out.rfind(rule + ": ", 0), 0u) << out;
    }
    EXPECT_NE(out.find("result: clean"), std::string::npos) << out;

    ASSERT_EQ(run_cli(std::string("replay --json ") + CLASTRACE_NV_SAMPLE, &out), 0) << out;
    const nlohmann::json j = nlohmann::json::parse(out);
    EXPECT_EQ(j["clean"], true);
    EXPECT_TRUE(j["findings"].empty()) << j["findings"];
    EXPECT_EQ(j["notes_over_cap"], 0);
    expect_note_shape(j["notes"]);
    std::set<std::string> rules;
    for (const nlohmann::json& n : j["notes"]) {
        rules.insert(n["rule"].get<std::string>());
        EXPECT_EQ(n["where"]["name"], "vkCmdCopyMemoryToAccelerationStructureKHR") << n;
    }
    EXPECT_EQ(rules, kSampleLimits);
}

TEST(ReplayNotes, AnalyzeOfTheH100TraceExitsZeroAndSaysWhy) {
    std::string out;
    ASSERT_EQ(run_cli(std::string("analyze --json ") + CLASTRACE_NV_SAMPLE, &out), 0) << out;
    const nlohmann::json j = nlohmann::json::parse(out);
    bool limits = false;
    for (const nlohmann::json& n : j["notes"]) {
        const std::string text = n.get<std::string>();
        if (text.find("limit(s) of its own, not findings") == std::string::npos) continue;
        limits = true;
        for (const std::string& rule : kSampleLimits)
            EXPECT_NE(text.find(rule + " x1"), std::string::npos) << text;
    }
    EXPECT_TRUE(limits) << j["notes"];
}

TEST(ReplayNotes, HazardStillExitsOneWithTheNotesBeside) {
    // A build writes the CLAS at kDst; a deserialization of a foreign blob overwrites it with
    // no barrier: one hazard (a finding) and the blob's notes (not findings).
    const std::string path = temp_trace_path("replay_notes", "hazard.clt");
    {
        TraceScript t(path, device());
        add_buffers(t);
        t.acceleration_structure(0xa5001, kDstBuffer, 0, 0x1000);
        triangle_clusters(Destinations::kExplicit).emit(t);
        std::vector<uint8_t> blob(0x100, 0x5a);
        const uint64_t header[3] = {0x100, 0x800, 0};
        std::memcpy(blob.data() + 32, header, sizeof header);
        t.deserialize(kStaging, 0xa5001, blob);
        t.finish();
    }
    std::string out;
    EXPECT_EQ(run_cli("replay " + path, &out), 1) << out;
    EXPECT_EQ(out.rfind("SYNC-HAZARD-", 0), 0u) << out;
    EXPECT_NE(out.find("\nNotes (limits of this replay, not findings):\n"), std::string::npos)
        << out;
    ASSERT_EQ(run_cli("replay --json " + path, &out), 1) << out;
    const nlohmann::json j = nlohmann::json::parse(out);
    EXPECT_EQ(j["clean"], false);
    EXPECT_EQ(j["hazards"]["hazards"].size(), 1u) << j["hazards"];
    EXPECT_TRUE(j["findings"].empty()) << j["findings"];
    EXPECT_FALSE(j["notes"].empty());
    expect_note_shape(j["notes"]);
    discard_trace(path);
}

}  // namespace
