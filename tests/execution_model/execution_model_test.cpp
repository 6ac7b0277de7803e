// SPDX-License-Identifier: Apache-2.0
// How the replay executes command buffers (format 1.2): a command buffer listed twice in one
// submission runs each execution with its own restated recording, and a secondary command
// buffer runs inline at its primary's vkCmdExecuteCommands, in the primary's command-buffer
// order (hazards across the boundary are found, a barrier on either side orders them), with
// findings naming primary, secondary and command.
#include "catalogue_scene.h"
#include "trace_script.h"

#include <clastrace/engine/execution_record.h>
#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>
#include <unistd.h>
#include <vector>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;
using replay::HazardClass;

constexpr uint64_t kQueue = 0x9001;
constexpr uint64_t kPrimary = 0xc100, kSecondary = 0x5c01, kOtherSecondary = 0x5c02;
constexpr uint32_t kSimultaneous = VK_COMMAND_BUFFER_USAGE_SIMULTANEOUS_USE_BIT;
constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kCopy = VK_PIPELINE_STAGE_2_COPY_BIT;
constexpr uint64_t kIndirect = VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT;
constexpr uint64_t kTransferWrite = VK_ACCESS_2_TRANSFER_WRITE_BIT;

std::string temp_path(const std::string& name) {
    return (std::filesystem::temp_directory_path() /
            ("execution_model_" + std::to_string(::getpid()) + "_" + name + ".clt"))
        .string();
}

// Every cluster command the engine ran, in execution order, with where it ran.
struct ClusterRuns : replay::ReplayObserver {
    std::vector<uint32_t> op_counts;
    std::vector<replay::ReplayLocation> where;
    void on_command(const replay::ReplayedCommand& c) override {
        if (!c.execution || !c.record ||
            c.record->body_type() != fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect)
            return;
        op_counts.push_back(c.execution->op_count);
        where.push_back(c.where);
    }
};

replay::ReplayReport replay_file(const std::string& path,
                                 replay::ReplayObserver* observer = nullptr) {
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    EXPECT_TRUE(reader) << e.message;
    if (!reader) return {};
    replay::ReplayOptions options;
    options.observer = observer;
    replay::ReplayReport report = replay::replay_trace(*reader, path);
    if (observer) {  // the observer run is a second pass over the same file
        auto again = traces::TraceReader::open(path, &e);
        report = replay::replay_trace(*again, path, options);
    }
    std::remove(path.c_str());
    return report;
}

std::string describe(const replay::ReplayReport& r) {
    std::string s;
    for (const auto& h : r.hazards) s += h.format() + "\n";
    for (const auto& f : r.findings) s += f.format() + "\n";
    return s;
}

// Triangle clusters whose srcInfosCount (at kCount) holds `count`: 2 ops at most.
ClusterCommand counted_build(uint32_t count) {
    ClusterCommand c = triangle_clusters(Destinations::kImplicit, 2);
    c.info.srcInfosCount = kCount;
    c.inputs.push_back({kCount, bytes_of(std::vector<uint32_t>{count})});
    return c;
}

// A trace of the catalogue's buffers and whatever `body` records, written to a fresh path.
template <class Body>
std::string write_trace(const std::string& name, Body body) {
    const std::string path = temp_path(name);
    TraceScript t(path, device());
    add_buffers(t);
    body(t);
    t.finish();
    return path;
}

// Two recordings of one command buffer, each a full barrier then a build: `first`, then a
// build counting 2, the second written as restatement `second_restatement`.
void record_two_executions(TraceScript& t, uint64_t command_buffer, uint32_t level,
                           uint32_t second_restatement, ClusterCommand first) {
    t.begin(command_buffer, kSimultaneous, level, 0);
    t.full_barrier();  // orders each execution after the one before
    first.emit(t);
    t.end();
    t.begin(command_buffer, kSimultaneous, level, second_restatement);
    t.full_barrier();
    counted_build(2).emit(t);
    t.end();
}

// A simultaneous-use secondary executed twice by one vkCmdExecuteCommands (primary command 1
// after a barrier): the recording's build (secondary command 1) has a bad cluster ID and
// counts 1, the restatement's counts 2.
void secondary_executed_twice(TraceScript& t) {
    ClusterCommand bad = counted_build(1);
    edit_info<TriangleInfo>(bad, 0, [](TriangleInfo& i) { i.clusterID = 0xFFFFFFFFu; });
    record_two_executions(t, kSecondary, 1, 1, bad);
    t.begin(kPrimary, 0, 0, 0);
    t.full_barrier();                              // primary command 0
    t.execute_commands({kSecondary, kSecondary});  // primary command 1
    t.end();
    t.submit_listed(kQueue, {kPrimary});
}

// Replays with `options` (no second pass) and removes the file.
replay::ReplayReport replay_file_with(const std::string& path,
                                      const replay::ReplayOptions& options) {
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    EXPECT_TRUE(reader) << e.message;
    replay::ReplayReport report =
        reader ? replay::replay_trace(*reader, path, options) : replay::ReplayReport{};
    std::remove(path.c_str());
    return report;
}

// Writes and replays one of a hazard test's twins: the barriered one (`fixed`) has no hazard,
// the other exactly one, returned for its checks (none when the count is wrong, already
// reported). Neither has findings.
template <class Body>
std::optional<replay::HazardReport> twin_hazard(const std::string& name, bool fixed, Body body) {
    const replay::ReplayReport r = replay_file(write_trace(fixed ? name + "_fixed" : name, body));
    EXPECT_TRUE(r.findings.empty()) << describe(r);
    if (fixed) {
        EXPECT_TRUE(r.hazards.empty()) << describe(r);
        return std::nullopt;
    }
    EXPECT_EQ(r.hazards.size(), 1u) << describe(r);
    if (r.hazards.size() != 1) return std::nullopt;
    return r.hazards[0];
}

// ---- One command buffer, two executions in one submission --------------------------------

// The capture saw the count at 1 in the first execution and at 2 in the second (the
// command buffer rewrites it after the build): each execution must run with its own bytes,
// and a later submission of the same buffer with the recording itself.
TEST(ExecutionModel, CommandBufferListedTwiceRunsEachRestatement) {
    const std::string path = write_trace("twice", [](TraceScript& t) {
        record_two_executions(t, kPrimary, 0, 1, counted_build(1));
        t.submit_listed(kQueue, {kPrimary, kPrimary});
        t.submit_listed(kQueue, {kPrimary});
    });
    ClusterRuns runs;
    replay::ReplayReport r = replay_file(path, &runs);
    EXPECT_EQ(runs.op_counts, (std::vector<uint32_t>{1, 2, 1}));
    ASSERT_EQ(runs.where.size(), 3u);
    EXPECT_EQ(runs.where[0].command_buffer, 0u);
    EXPECT_EQ(runs.where[1].command_buffer, 1u);  // second listing of the same handle
    EXPECT_EQ(runs.where[2].submission, 1u);
    EXPECT_TRUE(r.hazards.empty()) << describe(r);
    EXPECT_TRUE(r.findings.empty()) << describe(r);
}

// Before format 1.2 a capture wrote the two executions as two ordinary recordings: the last
// one wins, for both executions (what old traces replay as; kept for them).
TEST(ExecutionModel, OrdinaryBeginStillReplacesTheRecording) {
    const std::string path = write_trace("replaced", [](TraceScript& t) {
        record_two_executions(t, kPrimary, 0, 0, counted_build(1));
        t.submit_listed(kQueue, {kPrimary, kPrimary});
    });
    ClusterRuns runs;
    replay_file(path, &runs);
    EXPECT_EQ(runs.op_counts, (std::vector<uint32_t>{2, 2}));
}

// A restatement index past the copies written so far is reported and kept as the next copy.
TEST(ExecutionModel, RestatementOutOfOrderIsReported) {
    const std::string path = write_trace("out_of_order", [](TraceScript& t) {
        record_two_executions(t, kPrimary, 0, 7, counted_build(1));
        t.submit_listed(kQueue, {kPrimary, kPrimary, kPrimary});
    });
    ClusterRuns runs;
    replay::ReplayReport r = replay_file(path, &runs);
    EXPECT_EQ(runs.op_counts,
              (std::vector<uint32_t>{1, 2, 1}));  // a third execution has no copy: the recording
    ASSERT_EQ(r.findings.size(), 1u) << describe(r);
    EXPECT_EQ(r.findings[0].rule, "CLASTRACE-replay-restatement-out-of-order");
    EXPECT_NE(r.findings[0].message.find("execution 7"), std::string::npos)
        << r.findings[0].message;
}

// ---- Secondary command buffers --------------------------------------------------------------

// srcInfosArray written by a copy inside a secondary, read by a build in the primary after the
// vkCmdExecuteCommands: without a barrier a read-after-write whose earlier command is named as
// primary > secondary > command; a barrier in the primary after the execute fixes it.
void copy_in_secondary_build_in_primary(TraceScript& t, bool fixed, uint32_t* build_index) {
    const std::vector<uint8_t> infos =
        bytes_of(std::vector<TriangleInfo>{triangle_info(0), triangle_info(1)});
    t.begin(kSecondary, 0, 1, 0);
    t.fill(kScratchBuffer, 0x4000, 16, 0);  // command 0 of the secondary: unrelated
    t.copy(kStagingBuffer, 0, kInfosBuffer, 0, infos.size(), {{kStaging, infos}});
    t.end();
    t.begin(kPrimary, 0, 0, 0);
    t.execute_commands({kSecondary});
    if (fixed) t.barrier(kCopy, kTransferWrite, kBuild, kIndirect);
    *build_index = triangle_clusters(Destinations::kImplicit).emit(t);
    t.end();
    t.submit_listed(kQueue, {kPrimary});
}

TEST(ExecutionModel, HazardFromSecondaryIntoPrimaryIsFound) {
    for (const bool fixed : {false, true}) {
        SCOPED_TRACE(fixed ? "barriered twin" : "missing barrier");
        uint32_t build = 0;
        const std::optional<replay::HazardReport> h =
            twin_hazard("sec_to_pri", fixed, [&](TraceScript& t) {
                copy_in_secondary_build_in_primary(t, fixed, &build);
            });
        if (!h) continue;
        EXPECT_EQ(h->hazard, HazardClass::kReadAfterWrite);
        EXPECT_STREQ(h->prior.command.name, "vkCmdCopyBuffer");
        EXPECT_EQ(h->prior.command.command_buffer_handle, kPrimary);
        EXPECT_EQ(h->prior.command.command, 0u);  // the vkCmdExecuteCommands
        EXPECT_EQ(h->prior.command.secondary_handle, kSecondary);
        EXPECT_EQ(h->prior.command.secondary, 0u);
        EXPECT_EQ(h->prior.command.secondary_command, 1u);
        EXPECT_STREQ(h->later.command.name, "vkCmdBuildClusterAccelerationStructureIndirectNV");
        EXPECT_EQ(h->later.command.secondary_handle, 0u);
        EXPECT_EQ(h->later.command.command, build);
        EXPECT_NE(h->later.field.find("srcInfosArray"), std::string::npos) << h->later.field;
        const std::string text = h->format();
        EXPECT_NE(text.find("secondary 0 (0x5c01), cmd 1"), std::string::npos) << text;
        const std::string json = replay::to_json(*h).dump();
        EXPECT_NE(json.find("\"secondary\""), std::string::npos) << json;
    }
}

// The other way: the primary copies, the build runs in the secondary. The barrier that fixes
// it sits inside the secondary, before its build: command-buffer order runs through both.
TEST(ExecutionModel, HazardFromPrimaryIntoSecondaryIsFound) {
    for (const bool fixed : {false, true}) {
        SCOPED_TRACE(fixed ? "barriered twin" : "missing barrier");
        const std::optional<replay::HazardReport> h =
            twin_hazard("pri_to_sec", fixed, [&](TraceScript& t) {
                const std::vector<uint8_t> infos =
                    bytes_of(std::vector<TriangleInfo>{triangle_info(0), triangle_info(1)});
                t.begin(kSecondary, 0, 1, 0);
                if (fixed) t.barrier(kCopy, kTransferWrite, kBuild, kIndirect);
                triangle_clusters(Destinations::kImplicit).emit(t);
                t.end();
                t.begin(kPrimary, 0, 0, 0);
                t.copy(kStagingBuffer, 0, kInfosBuffer, 0, infos.size(), {{kStaging, infos}});
                t.execute_commands({kSecondary});
                t.end();
                t.submit_listed(kQueue, {kPrimary});
            });
        if (!h) continue;
        EXPECT_EQ(h->hazard, HazardClass::kReadAfterWrite);
        EXPECT_STREQ(h->prior.command.name, "vkCmdCopyBuffer");
        EXPECT_EQ(h->prior.command.secondary_handle, 0u);
        EXPECT_EQ(h->later.command.command, 1u);  // the vkCmdExecuteCommands
        EXPECT_EQ(h->later.command.secondary_handle, kSecondary);
        EXPECT_EQ(h->later.command.secondary_command, 0u);
    }
}

// Scratch shared by builds in two secondaries of one vkCmdExecuteCommands: a write-after-write
// between the secondaries unless the second begins with a barrier.
TEST(ExecutionModel, HazardBetweenTwoSecondariesIsFound) {
    for (const bool fixed : {false, true}) {
        SCOPED_TRACE(fixed ? "barriered twin" : "missing barrier");
        const std::optional<replay::HazardReport> h =
            twin_hazard("sec_sec", fixed, [&](TraceScript& t) {
                t.begin(kSecondary, 0, 1, 0);
                triangle_clusters(Destinations::kImplicit).emit(t);
                t.end();
                t.begin(kOtherSecondary, 0, 1, 0);
                if (fixed)
                    t.barrier(kBuild, VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR, kBuild,
                              VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                                  VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
                ClusterCommand second = triangle_clusters(Destinations::kImplicit);
                second.info.dstImplicitData = kDst2;
                second.info.dstAddressesArray.deviceAddress = kOut + 0x400;
                second.info.dstSizesArray.deviceAddress = kSizes + 0x400;
                second.emit(t);
                t.end();
                t.begin(kPrimary, 0, 0, 0);
                t.execute_commands({kSecondary, kOtherSecondary});
                t.end();
                t.submit_listed(kQueue, {kPrimary});
            });
        if (!h) continue;
        EXPECT_EQ(h->hazard, HazardClass::kWriteAfterWrite);
        EXPECT_EQ(h->prior.command.secondary_handle, kSecondary);
        EXPECT_EQ(h->prior.command.secondary, 0u);
        EXPECT_EQ(h->later.command.secondary_handle, kOtherSecondary);
        EXPECT_EQ(h->later.command.secondary, 1u);
        EXPECT_NE(h->later.field.find("scratchData"), std::string::npos) << h->later.field;
    }
}

// The engine's findings in a secondary name primary, execute command, secondary and command;
// a secondary executed twice runs its restatement the second time (its own snapshots).
TEST(ExecutionModel, SecondaryReExecutionAndFindingLocation) {
    const std::string path = write_trace("sec_findings", secondary_executed_twice);
    ClusterRuns runs;
    replay::ReplayReport r = replay_file(path, &runs);
    EXPECT_EQ(runs.op_counts, (std::vector<uint32_t>{1, 2}));
    ASSERT_EQ(runs.where.size(), 2u);
    EXPECT_EQ(runs.where[1].secondary, 1u);
    EXPECT_TRUE(r.hazards.empty()) << describe(r);
    ASSERT_EQ(r.findings.size(), 1u) << describe(r);
    const replay::ReplayFinding& f = r.findings[0];
    EXPECT_NE(f.rule.find("clusterID"), std::string::npos) << f.rule;
    EXPECT_EQ(f.where.command_buffer_handle, kPrimary);
    EXPECT_EQ(f.where.command, 1u);
    EXPECT_EQ(f.where.secondary_handle, kSecondary);
    EXPECT_EQ(f.where.secondary, 0u);
    EXPECT_EQ(f.where.secondary_command, 1u);
    EXPECT_EQ(f.op_index, 0);
    EXPECT_NE(f.format().find("cmd 1 > secondary 0 (0x5c01), cmd 1"), std::string::npos)
        << f.format();
}

// --ops selects a secondary's commands by their own sequence numbers: the second execution's
// build alone (sequence 5: barrier #0, execute #1, then #2 #3 and #4 #5 for the two executions).
TEST(ExecutionModel, OpsSelectCommandsInsideSecondaries) {
    const std::string path = write_trace("sec_ops", secondary_executed_twice);
    ClusterRuns runs;
    replay::ReplayOptions options;
    options.observer = &runs;
    options.first_command = 5;
    options.last_command = 5;
    const replay::ReplayReport r = replay_file_with(path, options);
    EXPECT_EQ(runs.op_counts, (std::vector<uint32_t>{2}));
    ASSERT_EQ(runs.where.size(), 1u);
    EXPECT_EQ(runs.where[0].sequence, 5u);
    EXPECT_EQ(runs.where[0].secondary, 1u);
    EXPECT_TRUE(r.findings.empty()) << describe(r);  // the bad cluster ID is in the first execution
    EXPECT_EQ(r.counts.skipped_commands, 5u);
}

// A secondary the trace never recorded is named at its execute; a primary handle listed as a
// secondary is reported by the VUID that forbids it, and still runs.
TEST(ExecutionModel, BadSecondariesAreReported) {
    const std::string path = write_trace("sec_bad", [](TraceScript& t) {
        t.begin(kOtherSecondary, 0, 0, 0);  // level 0: a primary
        t.fill(kScratchBuffer, 0, 16, 0);
        t.end();
        t.begin(kPrimary, 0, 0, 0);
        t.execute_commands({kSecondary, kOtherSecondary});
        t.end();
        t.submit_listed(kQueue, {kPrimary});
    });
    replay::ReplayReport r = replay_file(path);
    ASSERT_EQ(r.findings.size(), 2u) << describe(r);
    EXPECT_EQ(r.findings[0].rule, "CLASTRACE-replay-command-buffer-not-recorded");
    EXPECT_EQ(r.findings[0].where.secondary_handle, kSecondary);
    EXPECT_EQ(r.findings[0].where.command_buffer_handle, kPrimary);
    EXPECT_EQ(r.findings[1].rule, "VUID-vkCmdExecuteCommands-pCommandBuffers-00088");
    EXPECT_EQ(r.counts.copies, 1u);  // the fill ran all the same
}

// Hostile execution records: a primary that executes itself, a secondary that executes
// another (nested), an execute listing 100000 unknown handles, a restatement index of
// UINT32_MAX. Each is reported, bounded, and nothing recurses.
TEST(ExecutionModel, HostileExecutionRecordsAreBounded) {
    const std::string path = write_trace("hostile", [](TraceScript& t) {
        t.begin(kOtherSecondary, 0, 1, 0);
        t.fill(kScratchBuffer, 0, 16, 0);
        t.end();
        t.begin(kSecondary, 0, 1, 0);
        t.execute_commands({kOtherSecondary});  // nested
        t.end();
        t.begin(kPrimary, 0, 0, 0);
        t.execute_commands({kPrimary, kSecondary});  // itself, then the nesting secondary
        t.execute_commands(std::vector<uint64_t>(100000, 0xdead));
        t.end();
        t.begin(kPrimary, 0, 0, 0xFFFFFFFFu);  // a restatement with no copies before it
        t.fill(kScratchBuffer, 16, 16, 0);
        t.end();
        t.submit_listed(kQueue, {kPrimary, kPrimary});
    });
    replay::ReplayOptions options;
    options.max_findings = 64;
    const replay::ReplayReport r = replay_file_with(path, options);
    size_t out_of_order = 0, not_primary = 0, not_recorded = 0;
    for (const auto& f : r.findings) {
        out_of_order += f.rule == "CLASTRACE-replay-restatement-out-of-order";
        not_primary += f.rule == "VUID-vkCmdExecuteCommands-pCommandBuffers-00088";
        not_recorded += f.rule == "CLASTRACE-replay-command-buffer-not-recorded";
    }
    EXPECT_EQ(out_of_order, 1u);
    EXPECT_GE(not_primary, 1u);  // the primary listed as its own secondary
    EXPECT_GT(not_recorded, 0u);
    EXPECT_EQ(r.findings.size(), options.max_findings);
    EXPECT_GT(r.findings_over_cap, 100000u);  // both executions list them all
    size_t nested = 0;
    for (const auto& n : r.not_replayed) nested += n.reason.find("nested") != std::string::npos;
    EXPECT_GE(nested, 1u);
    // Executions of the primary count in execution order, nested ones included: the first
    // listing runs the recording, whose self-execution is the second execution (copy 1: the
    // one fill); the second listing is the third and runs the recording again.
    EXPECT_EQ(r.counts.copies, 1u);
}

}  // namespace
