// SPDX-License-Identifier: Apache-2.0
// Names that are not UTF-8 through the built `clastrace` program: a Latin-1 trace file name, and
// a trace from an older or foreign writer whose application, engine and device names and ray
// check labels are Latin-1. Every JSON document and HTML page it prints or writes stays valid
// UTF-8 (each bad byte read as U+FFFD), and the exit code is that of the same trace with good names.
#include "shell_run.h"
#include "trace_test_support.h"
#include "unrepaired_trace.h"

#include <clastrace/traces/utf8_text.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>

namespace clastrace::traces::testing {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

const std::string R = "\xEF\xBF\xBD";  // U+FFFD

using ProgramRun = ShellRun;  // output: stdout only

// `path` as one shell word (single quotes; the bytes inside pass as they are).
std::string word(const std::string& path) { return "'" + path + "'"; }

ProgramRun run(const std::string& args) {
    return run_shell(std::string(CLASTRACE_BIN) + " " + args + " 2>/dev/null");
}

// Runs `command` on `trace` and parses its stdout, failing the test if it is not UTF-8 JSON.
json run_json(const std::string& command, const std::string& trace, int* exit_code) {
    ProgramRun r = run(command + " " + word(trace));
    *exit_code = r.exit_code;
    EXPECT_TRUE(is_valid_utf8(r.output)) << command << " printed bytes that are not UTF-8";
    try {
        return json::parse(r.output);
    } catch (const json::exception& e) {
        ADD_FAILURE() << command << " on " << trace << " (exit " << r.exit_code << "): " << e.what()
                      << "\n"
                      << r.output;
        return json();
    }
}

// The string at `key` of an object, "" for anything else (a run that printed no JSON).
std::string text_at(const json& j, const char* key) {
    return j.is_object() && j.contains(key) && j[key].is_string() ? j[key].get<std::string>() : "";
}

// `analyze --html` into `page`, returning the exit code and the page.
std::pair<int, std::string> run_html(const std::string& trace, const fs::path& page) {
    fs::remove(page);
    const int exit_code =
        run("analyze --html " + word(page.string()) + " " + word(trace)).exit_code;
    const std::vector<uint8_t> bytes = read_file(page.string());
    return {exit_code, std::string(bytes.begin(), bytes.end())};
}

class Utf8Cli : public ::testing::Test {
protected:
    void SetUp() override {
        const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
        dir = fs::temp_directory_path() / "clastrace-utf8-cli" / info->name();
        fs::remove_all(dir);
        fs::create_directories(dir);
    }
    fs::path dir;
};

TEST_F(Utf8Cli, LatinOneTraceFileNameReadsAsReplacementCharacterInEveryDocument) {
    const std::string good = (dir / "cafe.clt").string();
    const std::string latin1 = (dir / "caf\xE9.clt").string();
    const std::string shown = (dir / ("caf" + R + ".clt")).string();
    fs::copy_file(CLASTRACE_SAMPLE, good);
    fs::copy_file(CLASTRACE_SAMPLE, latin1);

    struct Document {
        const char* command;
        const char* file_field;
    };
    for (const Document& d : {Document{"info --json", "file"}, Document{"replay --json", "trace"},
                              Document{"analyze --json", "trace"}}) {
        SCOPED_TRACE(d.command);
        int good_exit = -1, latin1_exit = -1;
        const json expected = run_json(d.command, good, &good_exit);
        const json j = run_json(d.command, latin1, &latin1_exit);
        EXPECT_EQ(latin1_exit, good_exit);
        EXPECT_EQ(text_at(expected, d.file_field), good);
        EXPECT_EQ(text_at(j, d.file_field), shown);
    }

    const auto [good_exit, good_page] = run_html(good, dir / "good.html");
    const auto [latin1_exit, page] = run_html(latin1, dir / "latin1.html");
    EXPECT_EQ(latin1_exit, good_exit);
    EXPECT_NE(good_page.find("cafe.clt"), std::string::npos);
    EXPECT_TRUE(is_valid_utf8(page));
    EXPECT_NE(page.find("caf" + R + ".clt"), std::string::npos);
}

// The JSON error object of a trace that cannot be opened names the file too.
TEST_F(Utf8Cli, ErrorObjectsNameALatinOneFileInUtf8) {
    const std::string missing = (dir / "absent\xE9.clt").string();
    for (const char* command : {"info --json", "replay --json"}) {
        SCOPED_TRACE(command);
        int exit_code = -1;
        const json j = run_json(command, missing, &exit_code);
        EXPECT_EQ(exit_code, 2);
        EXPECT_TRUE(j.is_object() && j.contains("error"));
        EXPECT_EQ(text_at(j, std::string(command).starts_with("info") ? "file" : "trace"),
                  (dir / ("absent" + R + ".clt")).string());
    }
}

// The real NV capture (it has ray checks) rewritten with other names, once as UTF-8 and once as
// Latin-1, bypassing the writer's repair.
class ForeignNames : public Utf8Cli {
protected:
    void write_with_names(const std::string& path, const std::string& e_acute) {
        TraceError e;
        auto reader = TraceReader::open(CLASTRACE_NV_SAMPLE, &e);
        ASSERT_TRUE(reader) << e.message;
        fbs::TraceHeaderT header;
        reader->header()->UnPackTo(&header);
        ASSERT_TRUE(header.device && header.capture);
        header.capture->application_name = "caf" + e_acute;
        header.capture->engine_name = "moteur " + e_acute;
        header.device->name = "GPU " + e_acute;
        ReadResult read = read_all(CLASTRACE_NV_SAMPLE);
        ASSERT_EQ(read.damage_count, 0u);
        size_t checks = 0;
        for (fbs::RecordT& r : read.records)
            if (fbs::RayQueryCheckT* c = r.body.AsRayQueryCheck())
                c->label = "rayons " + e_acute + std::to_string(checks++);
        ASSERT_GT(checks, 0u);
        write_unrepaired_trace(path, header, read.records);
    }
};

TEST_F(ForeignNames, LatinOneNamesAndLabelsReadAsReplacementCharacters) {
    const std::string good = (dir / "utf8_names.clt").string();
    const std::string latin1 = (dir / "latin1_names.clt").string();
    ASSERT_NO_FATAL_FAILURE(write_with_names(good, "\xC3\xA9"));
    ASSERT_NO_FATAL_FAILURE(write_with_names(latin1, "\xE9"));

    int good_exit = -1, latin1_exit = -1;
    json expected = run_json("info --json", good, &good_exit);
    json j = run_json("info --json", latin1, &latin1_exit);
    EXPECT_EQ(good_exit, 0);
    EXPECT_EQ(latin1_exit, good_exit);
    EXPECT_EQ(expected["header"]["capture"]["application_name"], "caf\xC3\xA9");
    EXPECT_EQ(j["header"]["capture"]["application_name"], "caf" + R);
    EXPECT_EQ(j["header"]["capture"]["engine_name"], "moteur " + R);
    EXPECT_EQ(j["header"]["device"]["name"], "GPU " + R);

    expected = run_json("replay --json", good, &good_exit);
    j = run_json("replay --json", latin1, &latin1_exit);
    EXPECT_EQ(latin1_exit, good_exit);
    EXPECT_EQ(expected["device"], "GPU \xC3\xA9");
    EXPECT_EQ(j["device"], "GPU " + R);
    ASSERT_TRUE(j["ray_checks"].is_array());
    ASSERT_FALSE(j["ray_checks"].empty());
    EXPECT_EQ(j["ray_checks"].size(), expected["ray_checks"].size());
    for (size_t i = 0; i < j["ray_checks"].size(); ++i) {
        EXPECT_EQ(j["ray_checks"][i]["label"], "rayons " + R + std::to_string(i));
        EXPECT_EQ(j["ray_checks"][i]["agree_hit"], expected["ray_checks"][i]["agree_hit"]);
    }

    run_json("analyze --json", good, &good_exit);
    run_json("analyze --json", latin1, &latin1_exit);
    EXPECT_EQ(latin1_exit, good_exit);
    const auto [good_html_exit, good_page] = run_html(good, dir / "good.html");
    const auto [latin1_html_exit, page] = run_html(latin1, dir / "latin1.html");
    EXPECT_EQ(latin1_html_exit, good_html_exit);
    EXPECT_TRUE(is_valid_utf8(page));
}

}  // namespace
}  // namespace clastrace::traces::testing
