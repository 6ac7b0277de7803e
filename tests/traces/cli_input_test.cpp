// SPDX-License-Identifier: Apache-2.0
// `clastrace` on arguments and inputs it must refuse: out-of-range options, a submission the
// trace does not hold, paths that are not regular files (FIFO, pipe, device, directory), and
// traces that cannot be opened under --json. Each is exit 2 with one clear line, never a
// hang, a silent empty run or a 309-digit bound.
#include "shell_run.h"
#include "trace_test_support.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <regex>
#include <sys/stat.h>

namespace clastrace::traces::testing {
namespace {

using ProgramRun = ShellRun;

// `timeout` turns a hang (the FIFO case before its fix) into exit 124 instead of a stuck test.
ProgramRun run(const std::string& args, const std::string& stderr_to = "&1") {
    return run_shell("timeout 20 " + std::string(CLASTRACE_BIN) + " " + args + " 2>" + stderr_to);
}

bool has(const ProgramRun& r, const std::string& text) {
    return r.output.find(text) != std::string::npos;
}

bool has_a_huge_number(const std::string& text) {
    return std::regex_search(text, std::regex("[0-9]{21,}"));
}

const std::string kSample = CLASTRACE_SAMPLE;  // one submission, finished (indexed)
const char* const kCommands[] = {"info", "replay", "analyze"};

TEST(ClastraceCliInput, MaxFindingsZeroIsRefusedWithAReadableRange) {
    ProgramRun r = run("replay --max-findings 0 " + kSample);
    EXPECT_EQ(r.exit_code, 2) << r.output;
    EXPECT_TRUE(has(r, "--max-findings")) << r.output;
    EXPECT_TRUE(has(r, "from 1 to 1000000, not '0'")) << r.output;
    EXPECT_FALSE(has_a_huge_number(r.output)) << r.output;
    EXPECT_EQ(run("replay --max-findings 1000001 " + kSample).exit_code, 2);
    EXPECT_EQ(run("replay --max-findings 1 " + kSample).exit_code, 0);
}

TEST(ClastraceCliInput, MaxRawMibZeroIsRefusedWithAReadableRangeByEveryReader) {
    for (const char* command : kCommands) {
        ProgramRun r = run(std::string(command) + " --max-raw-mib 0 " + kSample);
        EXPECT_EQ(r.exit_code, 2) << command << ": " << r.output;
        EXPECT_TRUE(has(r, "--max-raw-mib")) << r.output;
        EXPECT_TRUE(has(r, "from 1 to 17592186044415, not '0'")) << r.output;
        EXPECT_FALSE(has_a_huge_number(r.output)) << r.output;
        EXPECT_EQ(run(std::string(command) + " --max-raw-mib 4096 " + kSample).exit_code, 0)
            << command;
    }
}

TEST(ClastraceCliInput, NegativeSubmitIsRefusedWithAReadableRange) {
    ProgramRun r = run("replay --submit -1 " + kSample);
    EXPECT_EQ(r.exit_code, 2) << r.output;
    EXPECT_TRUE(has(r, "--submit")) << r.output;
    EXPECT_FALSE(has_a_huge_number(r.output)) << r.output;
}

TEST(ClastraceCliInput, SubmitBeyondTheTraceSaysHowManyItHolds) {
    ProgramRun r = run("replay --submit 999 " + kSample);
    EXPECT_EQ(r.exit_code, 2) << r.output;
    EXPECT_TRUE(has(r, "--submit 999: the trace holds 1 submission (--submit 0)")) << r.output;
    EXPECT_EQ(run("replay --submit 0 " + kSample).exit_code, 0);

    ProgramRun json = run("replay --json --submit 999 " + kSample, "/dev/null");
    EXPECT_EQ(json.exit_code, 2);
    nlohmann::json j = nlohmann::json::parse(json.output);
    EXPECT_EQ(j["trace"], kSample);
    EXPECT_EQ(j["error"]["code"], "invalid_argument");
    EXPECT_NE(j["error"]["message"].get<std::string>().find("holds 1 submission"),
              std::string::npos);
}

// Without its index (trailer cut off) the count comes from the replay itself.
TEST(ClastraceCliInput, SubmitBeyondATraceWithoutIndexSaysHowManyWereRead) {
    const std::string path = temp_path("no_index.clt");
    write_frames_trace(path, 3, 6000);
    std::vector<uint8_t> bytes = read_file(path);
    bytes.resize(bytes.size() - 32);  // the trailer
    write_file(path, bytes);
    ProgramRun r = run("replay --submit 7 " + path);
    EXPECT_EQ(r.exit_code, 2) << r.output;
    EXPECT_TRUE(
        has(r, "--submit 7: the readable part of the trace holds 3 submissions (--submit 0 to 2)"))
        << r.output;
    std::filesystem::remove(path);
}

TEST(ClastraceCliInput, FifoWithoutWriterIsRefusedAtOnce) {
    const std::string fifo = temp_path("trace.fifo");
    std::filesystem::remove(fifo);
    ASSERT_EQ(mkfifo(fifo.c_str(), 0600), 0);
    for (const char* command : kCommands) {
        ProgramRun r = run(std::string(command) + " " + fifo);
        EXPECT_EQ(r.exit_code, 2) << command << ": " << r.output;
        EXPECT_TRUE(
            has(r,
                "not a regular file (a FIFO or pipe): clastrace reads traces from regular files"))
            << command << ": " << r.output;
    }
    std::filesystem::remove(fifo);
}

TEST(ClastraceCliInput, PipeIsRefusedNotCalledEmpty) {
    const ProgramRun r = run_shell("cat " + kSample + " | timeout 20 " +
                                   std::string(CLASTRACE_BIN) + " info /dev/stdin 2>&1");
    const std::string& out = r.output;
    EXPECT_EQ(r.exit_code, 2) << out;
    EXPECT_NE(out.find("not a regular file (a FIFO or pipe)"), std::string::npos) << out;
    EXPECT_EQ(out.find("empty file"), std::string::npos) << out;
}

TEST(ClastraceCliInput, DevZeroAndDirectoriesAreRefused) {
    for (const char* command : kCommands) {
        ProgramRun zero = run(std::string(command) + " /dev/zero");
        EXPECT_EQ(zero.exit_code, 2) << command << ": " << zero.output;
        EXPECT_TRUE(has(zero, "not a regular file (a character device)"))
            << command << ": " << zero.output;
        EXPECT_FALSE(has(zero, "empty file")) << command << ": " << zero.output;
        ProgramRun dir =
            run(std::string(command) + " " + std::filesystem::temp_directory_path().string());
        EXPECT_EQ(dir.exit_code, 2) << command << ": " << dir.output;
        EXPECT_TRUE(has(dir, "not a regular file (a directory)")) << command << ": " << dir.output;
    }
}

TEST(ClastraceCliInput, AnalyzeJsonPrintsAnErrorObjectWhenTheTraceCannotBeOpened) {
    const std::string missing = temp_path("missing.clt");
    ProgramRun r = run("analyze --json " + missing, "/dev/null");
    EXPECT_EQ(r.exit_code, 2);
    nlohmann::json j = nlohmann::json::parse(r.output);  // throws (fails) when nothing was printed
    EXPECT_EQ(j["trace"], missing);
    EXPECT_EQ(j["error"]["code"], "io_error");
    EXPECT_EQ(j["error"]["offset"], 0);
    EXPECT_NE(j["error"]["message"].get<std::string>().find("cannot open"), std::string::npos);

    ProgramRun fifo_kind = run("analyze --json /dev/zero", "/dev/null");
    EXPECT_EQ(fifo_kind.exit_code, 2);
    EXPECT_NE(nlohmann::json::parse(fifo_kind.output)["error"]["message"].get<std::string>().find(
                  "not a regular file"),
              std::string::npos);
}

TEST(ClastraceCliInput, InfoJsonPrintsAnErrorObjectWhenTheTraceCannotBeOpened) {
    ProgramRun r = run("info --json /dev/zero", "/dev/null");
    EXPECT_EQ(r.exit_code, 2);
    nlohmann::json j = nlohmann::json::parse(r.output);
    EXPECT_EQ(j["file"], "/dev/zero");  // info names the trace "file", as its report does
    EXPECT_EQ(j["error"]["code"], "io_error");
}

}  // namespace
}  // namespace clastrace::traces::testing
