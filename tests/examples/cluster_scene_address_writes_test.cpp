// SPDX-License-Identifier: Apache-2.0
// examples/cluster_scene --compute-infos under the capture layer on lavapipe: a compute shader
// writes the cluster builds' src infos and count through buffer device addresses (push
// constants, no descriptor). In cheap mode (CLASTRACE_DEVICE_ADDRESS_WRITES, the default) the
// dispatch is recorded as a possible writer of all device-address memory: with the barrier
// dispatch-to-sizes the replay is clean; without it the replay reports a possible
// READ-AFTER-WRITE naming the dispatch, the build and its src-info region. With the mode off the
// missing barrier goes unseen.
#include "layer_launch_test.h"

#include <clastrace/replay/hazard_report.h>
#include <clastrace/replay/replay_report.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using clastrace::fbs::RecordBody;
using nlohmann::json;
using namespace clastrace::layer_launch;

struct TracedDispatches {
    uint32_t dispatches = 0, marked = 0;
    // The first cluster build's srcInfosArray region and srcInfosCount address.
    uint64_t infos_begin = 0, infos_end = 0, count_address = 0;
};

TracedDispatches read_dispatches(const fs::path& trace) {
    TracedDispatches t;
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    EXPECT_TRUE(reader) << error.message;
    if (!reader) return t;
    clastrace::traces::RecordView view;
    while (reader->next(&view)) {
        if (const auto* d = view.record->body_as_CmdDispatch()) {
            ++t.dispatches;
            t.marked += d->may_write_device_addresses() ? 1 : 0;
        }
        const auto* b = view.record->body_as_CmdBuildClusterAccelerationStructureIndirect();
        if (b && t.infos_end == 0) {
            t.infos_begin = b->src_infos_array()->device_address();
            t.infos_end = t.infos_begin + b->src_infos_array()->size();
            t.count_address = b->src_infos_count();
        }
    }
    return t;
}

class ComputeWrittenInfos : public LayerLaunchTest {
public:
    ComputeWrittenInfos() : LayerLaunchTest("clastrace_address_writes") {}

    // The sample under the layer with its infos written by compute; returns the replay.
    clastrace::replay::ReplayReport capture_and_replay(const std::string& extra,
                                                       const std::string& mode,
                                                       TracedDispatches* traced) {
        const fs::path trace = dir / "scene.clt";
        std::map<std::string, std::string> env{{"CLASTRACE_OUTPUT", trace.string()}};
        if (!mode.empty()) env["CLASTRACE_DEVICE_ADDRESS_WRITES"] = mode;
        ProcessResult r = run(std::string(CLUSTER_SCENE_APP) +
                                  " --compute-infos --max-clusters 6 --json " + extra,
                              env);
        EXPECT_EQ(r.exitCode, 0) << r.err;
        EXPECT_EQ(r.err, "");
        *traced = read_dispatches(trace);
        clastrace::traces::TraceError error;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
        if (!reader) {
            ADD_FAILURE() << error.message;
            return {};
        }
        return clastrace::replay::replay_trace(*reader, trace.string());
    }
};

std::string describe(const clastrace::replay::ReplayReport& report) {
    return clastrace::replay::format_text(report);
}

// With the barrier nothing certain and nothing on the bytes the dispatch wrote. What remains is
// cheap mode's false reports, all READ-AFTER-WRITE: the barrier's second scope is the build's
// INDIRECT_COMMAND_READ | ACCELERATION_STRUCTURE_READ, so the build's vertex/index reads
// (SHADER_READ) and the later copies' reads are not ordered after the whole-address-space
// possible write (docs/benchmarks.md counts them). The builds' scratch and destination writes
// raise nothing: possible writes meet reads only (docs/replay.md, "Possible hazards").
TEST_F(ComputeWrittenInfos, WithTheBarrierNothingOnTheBytesTheDispatchWrote) {
    TracedDispatches traced;
    const auto report = capture_and_replay("", "", &traced);
    EXPECT_EQ(traced.dispatches, 1u);
    EXPECT_EQ(traced.marked, 1u);  // the shader uses PhysicalStorageBuffer pointers
    EXPECT_TRUE(report.findings.empty()) << describe(report);
    for (const auto& h : report.hazards) {
        EXPECT_TRUE(h.possible()) << h.format();
        EXPECT_EQ(h.hazard, clastrace::replay::HazardClass::kReadAfterWrite) << h.format();
        const bool on_infos =
            h.overlap.begin < traced.infos_end && traced.infos_begin < h.overlap.end;
        const bool on_count =
            h.overlap.begin <= traced.count_address && traced.count_address < h.overlap.end;
        EXPECT_FALSE(on_infos || on_count) << h.format();
    }
}

TEST_F(ComputeWrittenInfos, WithoutTheBarrierAPossibleHazardNamesDispatchBuildAndSrcInfos) {
    TracedDispatches traced;
    const auto report = capture_and_replay("--skip-barrier dispatch-to-sizes", "", &traced);
    ASSERT_EQ(traced.marked, 1u);
    ASSERT_LT(traced.infos_begin, traced.infos_end);
    EXPECT_TRUE(report.findings.empty()) << describe(report);
    EXPECT_FALSE(report.clean());
    bool infos = false, count = false;
    for (const auto& h : report.hazards) {
        EXPECT_TRUE(h.possible()) << h.format();  // nothing certain: only the shader wrote
        if (h.hazard != clastrace::replay::HazardClass::kReadAfterWrite) continue;
        if (std::string(h.prior.command.name) != "vkCmdDispatch") continue;
        if (std::string(h.later.command.name) != "vkCmdBuildClusterAccelerationStructureIndirectNV")
            continue;
        if (h.later.field.find("srcInfosArray") != std::string::npos &&
            h.overlap.begin >= traced.infos_begin && h.overlap.end <= traced.infos_end) {
            infos = true;
            EXPECT_EQ(h.format().rfind("POSSIBLE-SYNC-HAZARD-READ-AFTER-WRITE: ", 0), 0u)
                << h.format();
            EXPECT_EQ(h.fix.src_stages, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT) << h.format();
        }
        count |= h.later.field.find("srcInfosCount") != std::string::npos &&
                 h.overlap.begin <= traced.count_address && traced.count_address < h.overlap.end;
    }
    EXPECT_TRUE(infos) << describe(report);
    EXPECT_TRUE(count) << describe(report);
}

// Off: the shader is not scanned, the dispatch not marked, and the missing barrier unseen.
TEST_F(ComputeWrittenInfos, OffModeMarksNothingAndMissesTheHazard) {
    TracedDispatches traced;
    const auto report = capture_and_replay("--skip-barrier dispatch-to-sizes", "off", &traced);
    EXPECT_EQ(traced.dispatches, 1u);
    EXPECT_EQ(traced.marked, 0u);
    EXPECT_TRUE(report.hazards.empty()) << describe(report);
}

TEST_F(ComputeWrittenInfos, ExactModeIsRejectedByName) {
    TracedDispatches traced;
    const fs::path trace = dir / "scene.clt";
    ProcessResult r =
        run(std::string(CLUSTER_SCENE_APP) + " --compute-infos --max-clusters 2",
            {{"CLASTRACE_OUTPUT", trace.string()}, {"CLASTRACE_DEVICE_ADDRESS_WRITES", "exact"}});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.err.find("CLASTRACE_DEVICE_ADDRESS_WRITES='exact' is not cheap or off"),
              std::string::npos)
        << r.err;
    EXPECT_EQ(read_dispatches(trace).marked, 1u);  // the default (cheap) is kept
}

TEST_F(ComputeWrittenInfos, ListBarriersNamesTheDispatchBarrier) {
    ProcessResult r =
        run(std::string(CLUSTER_SCENE_APP) + " --list-barriers --compute-infos", {}, false);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("dispatch-to-sizes"), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find("copy-to-sizes"), std::string::npos) << r.out;
}

}  // namespace
