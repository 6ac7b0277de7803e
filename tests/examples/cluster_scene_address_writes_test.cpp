// SPDX-License-Identifier: Apache-2.0
// examples/cluster_scene --compute-infos under the capture layer on lavapipe: a compute shader
// writes the cluster builds' src infos and count through buffer device addresses (push
// constants, no descriptor). In cheap mode (CLASTRACE_DEVICE_ADDRESS_WRITES, the default) the
// dispatch is recorded as a possible writer of all device-address memory: with the barrier
// dispatch-to-sizes the replay is clean; without it the replay reports a possible
// READ-AFTER-WRITE naming the dispatch, the build and its src-info region. With the mode off the
// missing barrier goes unseen. In exact mode the layer compares memory around the dispatch and
// replay reports the missing barrier as a certain hazard on the bytes the shader wrote.
#include "layer_launch_test.h"

#include <clastrace/replay/hazard_report.h>
#include <clastrace/replay/replay_report.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <filesystem>
#include <set>
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
    // `staged`: CLASTRACE_FORCE_STAGING=1, the path for memory the host cannot map (its served
    // builds log scratch findings on lavapipe, so stderr is not checked there).
    clastrace::replay::ReplayReport capture_and_replay(const std::string& extra,
                                                       const std::string& mode,
                                                       TracedDispatches* traced,
                                                       bool staged = false) {
        const fs::path trace = dir / "scene.clt";
        std::map<std::string, std::string> env{{"CLASTRACE_OUTPUT", trace.string()}};
        if (!mode.empty()) env["CLASTRACE_DEVICE_ADDRESS_WRITES"] = mode;
        if (staged) env["CLASTRACE_FORCE_STAGING"] = "1";
        ProcessResult r = run(std::string(CLUSTER_SCENE_APP) +
                                  " --compute-infos --max-clusters 6 --json " + extra,
                              env);
        EXPECT_EQ(r.exitCode, 0) << r.err;
        if (!staged) {
            EXPECT_EQ(r.err, "");
        }
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

// Exact mode: the layer pauses around the marked dispatch and compares memory; the trace says
// which bytes it changed (DeviceAddressWrites), and replay takes them as certain writes.
struct ExactWrites {
    uint32_t records = 0;
    uint64_t compared_bytes = 0;
    std::vector<std::pair<uint64_t, uint64_t>> ranges;  // [begin, end) of each write
    std::vector<uint32_t> commands;                     // the dispatches' command indices
};

ExactWrites read_exact_writes(const fs::path& trace) {
    ExactWrites e;
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    EXPECT_TRUE(reader) << error.message;
    if (!reader) return e;
    clastrace::traces::RecordView view;
    bool submitted = false;
    while (reader->next(&view)) {
        submitted |= view.kind == RecordBody::QueueSubmit;
        const auto* w = view.record->body_as_DeviceAddressWrites();
        if (!w) continue;
        EXPECT_FALSE(submitted) << "written ahead of the QueueSubmit that runs the dispatch";
        ++e.records;
        e.commands.push_back(w->command_index());
        e.compared_bytes += w->compared_bytes();
        if (w->writes())
            for (const auto* s : *w->writes())
                e.ranges.emplace_back(s->address(), s->address() + s->size());
    }
    return e;
}

bool inside(const std::pair<uint64_t, uint64_t>& range, uint64_t begin, uint64_t end) {
    return range.first >= begin && range.second <= end;
}

class ExactWithoutTheBarrier : public ComputeWrittenInfos,
                               public ::testing::WithParamInterface<bool> {};

// Mapped memory, and (staged) the copies the pauses make of memory the host cannot map.
TEST_P(ExactWithoutTheBarrier, ACertainHazardOnTheWrittenInfos) {
    TracedDispatches traced;
    const auto report =
        capture_and_replay("--skip-barrier dispatch-to-sizes", "exact", &traced, GetParam());
    ASSERT_EQ(traced.marked, 1u);
    ASSERT_LT(traced.infos_begin, traced.infos_end);
    const ExactWrites exact = read_exact_writes(dir / "scene.clt");
    ASSERT_EQ(exact.records, 1u);
    EXPECT_GT(exact.compared_bytes, 0u);
    // What the shader wrote: the infos and their count, nothing else.
    ASSERT_FALSE(exact.ranges.empty());
    for (const auto& r : exact.ranges)
        EXPECT_TRUE(inside(r, traced.infos_begin, traced.infos_end) ||
                    inside(r, traced.count_address, traced.count_address + 4))
            << std::hex << r.first << ".." << r.second;
    EXPECT_TRUE(report.findings.empty()) << describe(report);
    bool infos = false, count = false;
    for (const auto& h : report.hazards) {
        EXPECT_FALSE(h.possible()) << h.format();  // exact mode reports nothing possible
        EXPECT_EQ(h.hazard, clastrace::replay::HazardClass::kReadAfterWrite) << h.format();
        EXPECT_EQ(std::string(h.prior.command.name), "vkCmdDispatch") << h.format();
        if (std::string(h.later.command.name) != "vkCmdBuildClusterAccelerationStructureIndirectNV")
            continue;
        if (h.later.field.find("srcInfosArray") != std::string::npos &&
            h.overlap.begin >= traced.infos_begin && h.overlap.end <= traced.infos_end) {
            infos = true;
            EXPECT_EQ(h.format().rfind("SYNC-HAZARD-READ-AFTER-WRITE: ", 0), 0u) << h.format();
            EXPECT_EQ(h.fix.src_stages, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT) << h.format();
        }
        count |= h.later.field.find("srcInfosCount") != std::string::npos &&
                 h.overlap.begin <= traced.count_address && traced.count_address < h.overlap.end;
    }
    EXPECT_TRUE(infos) << describe(report);
    EXPECT_TRUE(count) << describe(report);
}

INSTANTIATE_TEST_SUITE_P(MappedOrStaged, ExactWithoutTheBarrier, ::testing::Bool(),
                         [](const auto& info) { return info.param ? "Staged" : "Mapped"; });

// With the barrier exact mode is clean: none of cheap mode's false reports (the vertex reads and
// later copies that the whole-address-space write met).
TEST_F(ComputeWrittenInfos, ExactWithTheBarrierIsClean) {
    TracedDispatches traced;
    const auto report = capture_and_replay("", "exact", &traced);
    EXPECT_EQ(traced.marked, 1u);
    EXPECT_EQ(read_exact_writes(dir / "scene.clt").records, 1u);
    EXPECT_TRUE(report.clean()) << describe(report);
    EXPECT_TRUE(report.hazards.empty()) << describe(report);
}

// A second marked dispatch writes into a buffer nothing reads, with no barrier after it: exact
// mode reports nothing; cheap mode takes it for a writer of everything the builds read.
TEST_F(ComputeWrittenInfos, ExactDispatchWritingElsewhereRaisesNothing) {
    TracedDispatches traced;
    const auto report = capture_and_replay("--compute-elsewhere", "exact", &traced);
    EXPECT_EQ(traced.marked, 2u);
    const ExactWrites exact = read_exact_writes(dir / "scene.clt");
    ASSERT_EQ(exact.records, 2u);
    EXPECT_TRUE(report.clean()) << describe(report);
    // Cheap mode (the same commands, so the same indices) reports the second dispatch.
    const uint32_t elsewhere = std::max(exact.commands[0], exact.commands[1]);
    TracedDispatches cheap_traced;
    const auto cheap = capture_and_replay("--compute-elsewhere", "cheap", &cheap_traced);
    std::set<uint32_t> possible_writers;  // command indices of the dispatches reported
    for (const auto& h : cheap.hazards)
        if (h.possible() && std::string(h.prior.command.name) == "vkCmdDispatch")
            possible_writers.insert(h.prior.command.command);
    EXPECT_EQ(possible_writers.count(elsewhere), 1u) << describe(cheap);
}

TEST_F(ComputeWrittenInfos, ListBarriersNamesTheDispatchBarrier) {
    ProcessResult r =
        run(std::string(CLUSTER_SCENE_APP) + " --list-barriers --compute-infos", {}, false);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("dispatch-to-sizes"), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find("copy-to-sizes"), std::string::npos) << r.out;
}

}  // namespace
