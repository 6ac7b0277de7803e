// SPDX-License-Identifier: Apache-2.0
// The path users with a driver that has the extension take (issue 19), end to end on lavapipe:
// examples/cluster_scene under the capture layer with serving off, above the stand-in driver
// (README.md) -> a driver trace -> replay. Each run is paired with the same run served (the
// capture layer's engine as the driver): the driver trace must be replayed as one (sizes
// compared side by side and different from the engine's, addresses translated), and it must
// give exactly the hazards of the served trace, named by class, both commands and both regions.
#include "layer_launch_test.h"

#include <clastrace/replay/hazard_report.h>
#include <clastrace/replay/replay_report.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

namespace {

namespace fs = std::filesystem;
using clastrace::fbs::RecordBody;
using nlohmann::json;

using namespace clastrace::layer_launch;

// A subset of the mesh keeps each run well under a second on lavapipe.
constexpr const char* kSubset = "--max-clusters 6";
constexpr const char* kStandinLayer = "VK_LAYER_CLASTRACE_standin_driver";
constexpr const char* kEngineDriverName = "clastrace engine";

// A hazard as both traces must agree on it: class, then the earlier command and region, then
// the later command and region (commands by the application's labels, "build:clusters").
// Byte ranges are left out on purpose: the driver trace's ranges follow the driver's sizes.
using HazardIdentity = std::tuple<std::string, std::string, std::string, std::string, std::string>;
using HazardSet = std::set<HazardIdentity>;

struct SceneRun {
    json app;  // the application's --json output (its first scene)
    clastrace::replay::ReplayReport report;
    std::string driver;  // the trace header's driver name
    HazardSet hazards;
};

std::string describe(const clastrace::replay::ReplayReport& report) {
    std::string text;
    for (const auto& f : report.findings) text += f.format() + "\n";
    for (const auto& h : report.hazards) text += h.format() + "\n";
    for (const auto& d : report.trace_damage) text += d + "\n";
    return text;
}

std::string describe(const HazardSet& hazards) {
    std::string text;
    for (const auto& [name, prior, prior_field, later, later_field] : hazards)
        text +=
            name + " " + prior + " (" + prior_field + ") -> " + later + " (" + later_field + ")\n";
    return text;
}

// The application's label of each command of `command_buffer`, by the trace's command index;
// "" for the capture layer's own timestamps (the only commands the application did not record).
std::vector<std::string> labels_by_trace_index(const fs::path& trace, uint64_t command_buffer,
                                               const std::vector<std::string>& app_labels) {
    std::vector<std::string> labels;
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    EXPECT_TRUE(reader) << error.message;
    if (!reader) return labels;
    size_t next_app_command = 0;
    clastrace::traces::RecordView view;
    while (reader->next(&view)) {
        const clastrace::fbs::Record* r = view.record;
        uint64_t cb = 0;
        bool own = false;
        switch (view.kind) {
        case RecordBody::GpuTimestamp:
            cb = r->body_as_GpuTimestamp()->command_buffer(), own = true;
            break;
        case RecordBody::CmdBuildClusterAccelerationStructureIndirect:
            cb = r->body_as_CmdBuildClusterAccelerationStructureIndirect()->command_buffer();
            break;
        case RecordBody::CmdCopyBuffer: cb = r->body_as_CmdCopyBuffer()->command_buffer(); break;
        case RecordBody::CmdPipelineBarrier:
            cb = r->body_as_CmdPipelineBarrier()->command_buffer();
            break;
        default: continue;
        }
        if (cb != command_buffer) continue;
        if (own || next_app_command >= app_labels.size())
            labels.emplace_back();
        else
            labels.push_back(app_labels[next_app_command++]);
    }
    EXPECT_EQ(next_app_command, app_labels.size()) << trace << ": not every command was traced";
    return labels;
}

class StandinScene : public LayerLaunchTest {
public:
    StandinScene() : LayerLaunchTest("clastrace_standin_scene") {}

    static std::string scene_command(const std::string& args) {
        return std::string(CLUSTER_SCENE_APP) + " " + args;
    }

    // Served: the capture layer alone on lavapipe offers the extension and builds in its engine.
    SceneRun capture_served(const std::string& args) {
        return capture(dir / "served.clt", args, {}, true);
    }

    // The driver's path: serving off, the stand-in driver below the capture layer.
    SceneRun capture_on_standin(const std::string& args) {
        const std::string manifests =
            std::string(CLASTRACE_LAYER_MANIFEST_DIR) + ":" + CLASTRACE_STANDIN_MANIFEST_DIR;
        return capture(dir / "driver.clt", args,
                       {{"VK_ADD_LAYER_PATH", manifests},
                        {"VK_INSTANCE_LAYERS", std::string(kCaptureLayer) + ":" + kStandinLayer},
                        {"CLASTRACE_SERVE", "0"}},
                       false);
    }

private:
    SceneRun capture(const fs::path& trace, const std::string& args,
                     std::map<std::string, std::string> env, bool with_capture_layer_only) {
        SceneRun run_result;
        env["CLASTRACE_OUTPUT"] = trace.string();
        const ProcessResult r = run(scene_command(args + " --json"), env, with_capture_layer_only);
        EXPECT_EQ(r.exitCode, 0) << trace << ": " << r.err;
        EXPECT_EQ(r.err, "") << trace;  // no layer finding: every build is valid
        if (r.exitCode != 0) return run_result;
        run_result.app = json::parse(r.out)["scenes"][0];

        clastrace::traces::TraceError error;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
        EXPECT_TRUE(reader) << error.message;
        if (!reader) return run_result;
        if (reader->header() && reader->header()->device() &&
            reader->header()->device()->driver_name())
            run_result.driver = reader->header()->device()->driver_name()->str();
        run_result.report = clastrace::replay::replay_trace(*reader, trace.string());
        run_result.hazards = hazard_identities(trace, run_result);
        return run_result;
    }

    static HazardSet hazard_identities(const fs::path& trace, const SceneRun& run_result) {
        const uint64_t command_buffer = run_result.app["commandBuffer"];
        const std::vector<std::string> labels =
            labels_by_trace_index(trace, command_buffer,
                                  run_result.app["commands"].get<std::vector<std::string>>());
        auto label = [&](const clastrace::replay::CommandRef& c) -> std::string {
            if (c.command_buffer_handle != command_buffer || c.command >= labels.size() ||
                labels[c.command].empty())
                return "not the application's: command " + std::to_string(c.command);
            return labels[c.command];
        };
        HazardSet found;
        for (const auto& h : run_result.report.hazards)
            found.insert({clastrace::replay::hazard_class_name(h.hazard), label(h.prior.command),
                          h.prior.field, label(h.later.command), h.later.field});
        return found;
    }
};

// The driver trace is replayed as a driver trace: its sizes are the stand-in's, compared side by
// side with the engine's (never equal: every object the stand-in reports is padded), and the
// objects' addresses are translated to where the engine rebuilt them.
void expect_driver_trace(const SceneRun& driver, const SceneRun& served) {
    EXPECT_EQ(served.driver, kEngineDriverName);
    EXPECT_TRUE(served.report.engine_trace);
    EXPECT_NE(driver.driver, kEngineDriverName);
    EXPECT_NE(driver.driver, "");
    const clastrace::replay::ReplayReport& r = driver.report;
    EXPECT_FALSE(r.engine_trace);
    EXPECT_GT(r.counts.addresses_translated, 0u);
    EXPECT_EQ(r.counts.cluster_commands, served.report.counts.cluster_commands);
    ASSERT_EQ(r.sizes.size(), served.report.sizes.size());
    uint32_t compared = 0;
    for (size_t i = 0; i < r.sizes.size(); ++i) {
        const auto& s = r.sizes[i];
        SCOPED_TRACE("cluster command " + std::to_string(i));
        EXPECT_EQ(s.ops, served.report.sizes[i].ops);
        compared += s.ops_compared;
        if (s.ops_compared == 0) continue;  // a command whose sizes the stand-in leaves alone
        EXPECT_EQ(s.sizes_equal, 0u);
        EXPECT_NE(s.captured_bytes, s.engine_bytes);
    }
    EXPECT_GT(compared, 0u);
    EXPECT_NE(clastrace::replay::format_text(r).find("sizes compared side by side"),
              std::string::npos)
        << clastrace::replay::format_text(r);
}

// --list-barriers names exactly the variants below: a barrier added to the sample must be
// added here.
const std::vector<std::string> kSkippableBarriers = {"copy-to-sizes",
                                                     "sizes-to-clusters",
                                                     "copy-to-templates",
                                                     "clusters-to-templates",
                                                     "templates-to-template-move",
                                                     "template-move-to-address-copy",
                                                     "copy-to-instantiate",
                                                     "template-move-to-instantiate",
                                                     "instantiate-to-indices",
                                                     "indices-to-move",
                                                     "copy-to-blas",
                                                     "move-to-blas"};

TEST_F(StandinScene, EveryBarrierOfTheSampleIsAVariantHere) {
    const ProcessResult r = run(scene_command("--list-barriers"), {}, false);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    std::set<std::string> listed;
    std::istringstream lines(r.out);
    for (std::string line; std::getline(lines, line);)
        listed.insert(line.substr(0, line.find(' ')));
    EXPECT_EQ(listed, std::set<std::string>(kSkippableBarriers.begin(), kSkippableBarriers.end()));
}

TEST_F(StandinScene, CorrectSampleReplaysCleanOnBothPaths) {
    const SceneRun served = capture_served(kSubset);
    const SceneRun driver = capture_on_standin(kSubset);
    ASSERT_FALSE(served.app.is_null());
    ASSERT_FALSE(driver.app.is_null());
    expect_driver_trace(driver, served);
    EXPECT_TRUE(served.report.clean()) << describe(served.report);
    EXPECT_TRUE(driver.report.clean()) << describe(driver.report);
    EXPECT_TRUE(driver.report.not_replayed.empty());

    // As a user runs it: `clastrace replay` exits 0 on both.
    for (const char* trace : {"served.clt", "driver.clt"}) {
        const ProcessResult replayed =
            run(std::string(CLASTRACE_CLI) + " replay " + quote((dir / trace).string()), {}, false);
        EXPECT_EQ(replayed.exitCode, 0) << trace << ": " << replayed.out << replayed.err;
    }
}

class SkippedBarrierOnStandin : public StandinScene,
                                public ::testing::WithParamInterface<std::string> {};

TEST_P(SkippedBarrierOnStandin, DriverTraceGivesTheServedHazards) {
    const std::string args = std::string(kSubset) + " --skip-barrier " + GetParam();
    const SceneRun served = capture_served(args);
    const SceneRun driver = capture_on_standin(args);
    ASSERT_FALSE(served.app.is_null());
    ASSERT_FALSE(driver.app.is_null());
    EXPECT_EQ(driver.app["commands"], served.app["commands"]);
    expect_driver_trace(driver, served);
    EXPECT_TRUE(served.report.findings.empty()) << describe(served.report);
    EXPECT_TRUE(driver.report.findings.empty()) << describe(driver.report);
    EXPECT_TRUE(driver.report.trace_damage.empty()) << describe(driver.report);
    EXPECT_FALSE(served.hazards.empty()) << "leaving out " << GetParam() << " gave no hazard";
    EXPECT_EQ(driver.hazards, served.hazards) << "driver trace:\n"
                                              << describe(driver.hazards) << "served trace:\n"
                                              << describe(served.hazards);
}

INSTANTIATE_TEST_SUITE_P(EachBarrier, SkippedBarrierOnStandin,
                         ::testing::ValuesIn(kSkippableBarriers), [](const auto& info) {
                             std::string n = info.param;
                             for (char& c : n)
                                 if (c == '-') c = '_';
                             return n;
                         });

}  // namespace
