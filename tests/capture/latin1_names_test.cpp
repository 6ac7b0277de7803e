// SPDX-License-Identifier: Apache-2.0
// A real capture on lavapipe of a program whose pApplicationName and pEngineName are Latin-1
// (tests/apps/latin1_names_app.cpp): the layer writes the names as UTF-8 (each bad byte as
// U+FFFD) in the trace and in its debug JSON, and `clastrace info --json` and `replay --json`
// read the trace.
#include "layer_launch_test.h"

#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

namespace {

using nlohmann::json;
using namespace clastrace::layer_launch;

const std::string R = "\xEF\xBF\xBD";  // U+FFFD

class Latin1Names : public LayerLaunchTest {
protected:
    Latin1Names() : LayerLaunchTest("clastrace_latin1_names") {}

    // clastrace COMMAND --json on the trace, without the layer; stdout parsed.
    json tool(const std::string& command, const std::string& trace, int expectedExit) {
        ProcessResult r =
            run(std::string(CLASTRACE_CLI) + " " + command + " --json " + quote(trace), {}, false);
        EXPECT_EQ(r.exitCode, expectedExit) << command << ": " << r.err;
        try {
            return json::parse(r.out);
        } catch (const json::exception& e) {
            ADD_FAILURE() << command << ": " << e.what() << "\n" << r.out << r.err;
            return json();
        }
    }
};

TEST_F(Latin1Names, TheTraceHoldsTheNamesAsUtf8AndTheToolsReadIt) {
    const std::string trace = (dir / "latin1.clt").string();
    ProcessResult r = run(CLASTRACE_LATIN1_APP, {{"CLASTRACE_OUTPUT", trace}});
    ASSERT_EQ(r.exitCode, 0) << r.err;

    // The trace itself holds UTF-8 (the tools below would repair what it did not).
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace, &error);
    ASSERT_TRUE(reader) << error.message;
    const auto* capture = reader->header()->capture();
    ASSERT_TRUE(capture && capture->application_name() && capture->engine_name());
    EXPECT_EQ(capture->application_name()->str(), "caf" + R);
    EXPECT_EQ(capture->engine_name()->str(), "moteur " + R + "t" + R);

    const json info = tool("info", trace, 0);
    EXPECT_EQ(info["header"]["capture"]["application_name"], "caf" + R);
    EXPECT_EQ(info["header"]["capture"]["engine_name"], "moteur " + R + "t" + R);
    EXPECT_EQ(info["records"]["by_kind"]["QueueSubmit"], 1);

    const json replay = tool("replay", trace, 0);
    EXPECT_EQ(replay["trace"], trace);
    EXPECT_EQ(replay["counts"]["submissions"], 1);
}

TEST_F(Latin1Names, TheDebugJsonHoldsTheNamesAsUtf8) {
    const std::string debugJson = (dir / "capture.json").string();
    ProcessResult r = run(CLASTRACE_LATIN1_APP, {{"CLASTRACE_DEBUG_JSON", debugJson}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const json capture = json::parse(readText(debugJson));
    ASSERT_TRUE(capture["devices"].is_array());
    ASSERT_FALSE(capture["devices"].empty());
    EXPECT_EQ(capture["devices"][0]["applicationName"], "caf" + R);
}

}  // namespace
