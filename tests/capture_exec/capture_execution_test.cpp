// SPDX-License-Identifier: Apache-2.0
// The capture layer on lavapipe (serving the cluster extension) through the loader, then the
// replay of its trace: a cluster build recorded in a secondary command buffer and executed
// twice by one primary (each execution captured at its own pause, with its own count), and a
// simultaneous-use command buffer listed twice in one submission (each execution replayed
// with its own snapshots). The served outputs must be reproduced by the replay.
#include "layer_launch_test.h"
#include <clastrace/engine/execution_record.h>
#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/testsupport/test_driver.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using clastrace::fbs::RecordBody;
using clastrace::layer_launch::quote;
using clastrace::layer_launch::readText;

struct ClusterRuns : clastrace::replay::ReplayObserver {
    std::vector<uint32_t> opCounts;
    std::vector<clastrace::replay::ReplayLocation> where;
    void on_command(const clastrace::replay::ReplayedCommand& c) override {
        if (!c.execution ||
            c.record->body_type() != RecordBody::CmdBuildClusterAccelerationStructureIndirect)
            return;
        opCounts.push_back(c.execution->op_count);
        where.push_back(c.where);
    }
};

std::string describe(const clastrace::replay::ReplayReport& r) {
    std::string s;
    for (const auto& h : r.hazards) s += h.format() + "\n";
    for (const auto& f : r.findings) s += f.format() + "\n";
    return s;
}

class CaptureExecution : public ::testing::Test {
protected:
    fs::path dir;
    const clastrace::testsupport::TestDriver driver = clastrace::testsupport::test_driver();

    void SetUp() override {
        if (!driver.installed()) GTEST_SKIP() << driver.missing_message();
        const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
        dir = fs::temp_directory_path() /
              ("clastrace_exec_" + std::to_string(getpid()) + "_" + info->name());
        fs::remove_all(dir);
        fs::create_directories(dir);
    }
    void TearDown() override {
        if (!HasFailure() && !dir.empty()) fs::remove_all(dir);
    }

    // Runs the frames app with `args` under the layer, capturing to `trace`; returns its exit code.
    // `twoQueues`: the test layer below gives lavapipe's family a second queue.
    int capture(const std::string& args, const fs::path& trace, bool twoQueues = false,
                const std::string& extraEnv = "") {
        std::string line =
            "env -u VK_INSTANCE_LAYERS -u VK_ADD_LAYER_PATH -u VK_ICD_FILENAMES -u CLASTRACE_SERVE "
            "-u CLASTRACE_CAPTURE -u CLASTRACE_SUBMIT_RANGE -u CLASTRACE_DEBUG_JSON -u "
            "CLASTRACE_FORCE_STAGING "
            "-u CLASTRACE_SHARED_WAIT_MS";
        const std::string layerPath =
            std::string(CLASTRACE_LAYER_MANIFEST_DIR) +
            (twoQueues ? std::string(":") + CLASTRACE_TWO_QUEUE_MANIFEST_DIR : "");
        const std::string layers =
            twoQueues ? "VK_LAYER_CLASTRACE_capture:VK_LAYER_CLASTRACE_test_two_queues"
                      : "VK_LAYER_CLASTRACE_capture";
        line += driver.environment_words() + " XDG_RUNTIME_DIR=" + quote(dir.string()) +
                " VK_ADD_LAYER_PATH=" + quote(layerPath) + " VK_INSTANCE_LAYERS=" + layers + " " +
                extraEnv + " CLASTRACE_LOG=error CLASTRACE_OUTPUT=" + quote(trace.string());
        line += std::string(" ") + CLASTRACE_FRAMES_APP + " " + args + " >" +
                quote((dir / "stdout.txt").string()) + " 2>" + quote((dir / "stderr.txt").string());
        const int status = std::system(line.c_str());
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    }

    static clastrace::replay::ReplayReport replay(const fs::path& trace, ClusterRuns* runs) {
        clastrace::traces::TraceError e;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &e);
        EXPECT_TRUE(reader) << e.message;
        if (!reader) return {};
        EXPECT_EQ(reader->version_minor(), clastrace::traces::TraceReader::current_version_minor());
        clastrace::replay::ReplayOptions options;
        options.observer = runs;
        return clastrace::replay::replay_trace(*reader, trace.string(), options);
    }

    // Record kinds and CommandBufferBegin (handle, level, restatement) in file order.
    struct Begins {
        std::vector<std::tuple<uint64_t, uint32_t, uint32_t>> begins;
        size_t executes = 0, submits = 0;
    };
    static Begins begins(const fs::path& trace) {
        Begins b;
        clastrace::traces::TraceError e;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &e);
        if (!reader) return b;
        clastrace::traces::RecordView view;
        while (reader->next(&view)) {
            if (const auto* begin = view.record->body_as_CommandBufferBegin())
                b.begins.emplace_back(begin->command_buffer(), begin->level(),
                                      begin->restatement());
            b.executes += view.kind == RecordBody::CmdExecuteCommands;
            b.submits += view.kind == RecordBody::QueueSubmit;
        }
        return b;
    }
};

// One primary: copy srcInfosArray, execute the secondary (count 1), copy the count (2),
// execute it again. Both executions pause inside the secondary; the trace restates the
// secondary for its second execution, and the replay reproduces the served outputs.
TEST_F(CaptureExecution, ClusterBuildInSecondaryIsCapturedPerExecutionAndReplays) {
    const fs::path trace = dir / "secondary.clt";
    ASSERT_EQ(capture("secondary " + quote((dir / "out.json").string()), trace), 0)
        << readText(dir / "stderr.txt");
    EXPECT_EQ(readText(dir / "stderr.txt"), "");
    // Both clusters were built by the second execution: two non-zero sizes.
    const std::string out = readText(dir / "out.json");
    EXPECT_EQ(out.find("\"dstSizes\": \"00000000"), std::string::npos) << out;
    EXPECT_EQ(out.find("00000000\", \"counts\""), std::string::npos) << out;

    Begins b = begins(trace);
    ASSERT_EQ(b.begins.size(), 3u);
    const uint64_t secondary = std::get<0>(b.begins[0]);
    EXPECT_EQ(std::get<1>(b.begins[0]), 1u);  // secondary, recording
    EXPECT_EQ(std::get<2>(b.begins[0]), 0u);
    EXPECT_EQ(std::get<0>(b.begins[1]), secondary);  // its restatement for the second execution
    EXPECT_EQ(std::get<2>(b.begins[1]), 1u);
    EXPECT_EQ(std::get<1>(b.begins[2]), 0u);  // the primary
    EXPECT_EQ(b.executes, 2u);
    EXPECT_EQ(b.submits, 1u);

    ClusterRuns runs;
    clastrace::replay::ReplayReport r = replay(trace, &runs);
    EXPECT_EQ(runs.opCounts, (std::vector<uint32_t>{1, 2}));
    ASSERT_EQ(runs.where.size(), 2u);
    for (uint32_t e = 0; e < 2; ++e) {
        EXPECT_EQ(runs.where[e].secondary_handle, secondary);
        EXPECT_EQ(runs.where[e].command, 1u + 2 * e);  // the vkCmdExecuteCommands of the primary
        EXPECT_EQ(runs.where[e].secondary_command, 1u);
    }
    EXPECT_TRUE(r.findings.empty()) << describe(r);  // outputs reproduced byte for byte
    EXPECT_TRUE(r.hazards.empty()) << describe(r);
    EXPECT_GT(r.counts.snapshots_applied, 0u);
}

// Without the secondary's barrier, the primary's copies (srcInfosArray, then the count) are
// read by the build in the secondary unordered: a read-after-write for each execution, whose
// later command is named inside the secondary.
TEST_F(CaptureExecution, SkippedBarrierInSecondaryIsTheHazard) {
    const fs::path trace = dir / "secondary_skip.clt";
    ASSERT_EQ(capture("secondary " + quote((dir / "out.json").string()) + " --skip-barrier", trace),
              0)
        << readText(dir / "stderr.txt");
    ClusterRuns runs;
    clastrace::replay::ReplayReport r = replay(trace, &runs);
    EXPECT_EQ(runs.opCounts, (std::vector<uint32_t>{1, 2}));
    ASSERT_EQ(r.hazards.size(), 2u) << describe(r);
    const char* fields[] = {"srcInfosArray", "srcInfosCount"};
    for (size_t i = 0; i < 2; ++i) {
        const auto& h = r.hazards[i];
        EXPECT_EQ(h.hazard, clastrace::replay::HazardClass::kReadAfterWrite) << h.format();
        EXPECT_STREQ(h.prior.command.name, "vkCmdCopyBuffer");
        EXPECT_EQ(h.prior.command.secondary_handle, 0u);
        EXPECT_EQ(h.prior.command.command, 2 * i);
        EXPECT_NE(h.later.command.secondary_handle, 0u);
        EXPECT_EQ(h.later.command.command, 1 + 2 * i);
        EXPECT_NE(h.later.field.find(fields[i]), std::string::npos) << h.format();
    }
}

// The served engine's finding on the build inside the secondary becomes a CaptureFinding per
// execution naming the secondary, the command's index in it, the primary and the execute.
TEST_F(CaptureExecution, CaptureFindingInSecondaryNamesThePrimary) {
    const fs::path trace = dir / "secondary_bad.clt";
    ASSERT_EQ(capture("secondary " + quote((dir / "out.json").string()) + " --bad-cluster-id",
                      trace),
              0)
        << readText(dir / "stderr.txt");
    Begins b = begins(trace);
    ASSERT_EQ(b.begins.size(), 3u);
    const uint64_t secondary = std::get<0>(b.begins[0]), primary = std::get<0>(b.begins[2]);
    clastrace::traces::TraceError e;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &e);
    ASSERT_TRUE(reader) << e.message;
    std::vector<std::tuple<uint64_t, uint32_t, uint64_t, uint32_t, uint32_t>> findings;
    clastrace::traces::RecordView view;
    while (reader->next(&view))
        if (const auto* f = view.record->body_as_CaptureFinding())
            if (f->rule() && f->rule()->str().find("clusterID") != std::string::npos)
                findings.emplace_back(f->command_buffer(), f->command_index(),
                                      f->primary_command_buffer(), f->execute_command_index(),
                                      f->op_index());
    using F = std::tuple<uint64_t, uint32_t, uint64_t, uint32_t, uint32_t>;
    EXPECT_EQ(findings, (std::vector<F>{F{secondary, 1u, primary, 1u, 0u},
                                        F{secondary, 1u, primary, 3u, 0u}}));
    // The replay finds the same rule at the same places.
    clastrace::replay::ReplayReport r = replay(trace, nullptr);
    std::vector<std::tuple<uint64_t, uint32_t, uint64_t, uint32_t>> replayed;
    for (const auto& f : r.findings)
        if (f.rule.find("clusterID") != std::string::npos)
            replayed.emplace_back(f.where.command_buffer_handle, f.where.command,
                                  f.where.secondary_handle, f.where.secondary_command);
    using R = std::tuple<uint64_t, uint32_t, uint64_t, uint32_t>;
    EXPECT_EQ(replayed,
              (std::vector<R>{R{primary, 1u, secondary, 1u}, R{primary, 3u, secondary, 1u}}))
        << describe(r);
}

// Queue handles of the QueueSubmit records and the rules of the CaptureFindings, in file order.
struct Submissions {
    std::vector<uint64_t> queues;
    std::vector<std::string> rules;
};
Submissions submissionsOf(const fs::path& trace) {
    Submissions s;
    clastrace::traces::TraceError e;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &e);
    if (!reader) return s;
    clastrace::traces::RecordView view;
    while (reader->next(&view)) {
        if (const auto* q = view.record->body_as_QueueSubmit()) s.queues.push_back(q->queue());
        if (const auto* f = view.record->body_as_CaptureFinding())
            s.rules.push_back(f->rule() ? f->rule()->str() : "");
    }
    return s;
}

// One simultaneous-use command buffer submitted to queue 0 and at once to queue 1 (a second
// queue the test layer below adds). The second submission is admitted only once the first
// execution has passed its pause, so each execution is captured at its own pause: the count
// read is 1 on queue 0 and 2 on queue 1 (without the admission the worker could take the first
// execution's pause for the second queue's, and swap them).
TEST_F(CaptureExecution, SimultaneousUseOnTwoQueuesIsCapturedPerQueue) {
    const fs::path trace = dir / "two_queues.clt";
    ASSERT_EQ(capture("twoqueues " + quote((dir / "out.json").string()), trace, true), 0)
        << readText(dir / "stderr.txt");
    EXPECT_EQ(readText(dir / "stderr.txt"), "");
    Submissions s = submissionsOf(trace);
    ASSERT_EQ(s.queues.size(), 2u);
    EXPECT_NE(s.queues[0], s.queues[1]);
    EXPECT_TRUE(s.rules.empty());
    ClusterRuns runs;
    clastrace::replay::ReplayReport r = replay(trace, &runs);
    EXPECT_EQ(runs.opCounts, (std::vector<uint32_t>{1, 2}));
    ASSERT_EQ(runs.where.size(), 2u);
    EXPECT_EQ(runs.where[0].submission, 0u);
    EXPECT_EQ(runs.where[1].submission, 1u);
    EXPECT_TRUE(r.findings.empty()) << describe(r);
}

// The first execution waits on an event the host sets only after both submissions returned:
// the admission of the second cannot wait for it, gives up after CLASTRACE_SHARED_WAIT_MS,
// says so once on stderr and in the trace, and the application runs to the end.
TEST_F(CaptureExecution, SimultaneousUseOnTwoQueuesThatCannotWaitIsReported) {
    const fs::path trace = dir / "two_queues_held.clt";
    ASSERT_EQ(capture("twoqueues " + quote((dir / "out.json").string()) + " --hold-first", trace,
                      true, "CLASTRACE_SHARED_WAIT_MS=200"),
              0)
        << readText(dir / "stderr.txt");
    EXPECT_NE(readText(dir / "stderr.txt").find("still running on another queue after 200 ms"),
              std::string::npos)
        << readText(dir / "stderr.txt");
    Submissions s = submissionsOf(trace);
    ASSERT_EQ(s.queues.size(), 2u);
    EXPECT_EQ(s.rules, (std::vector<std::string>{"CLASTRACE-capture-concurrent-execution"}));
}

// A simultaneous-use command buffer listed twice in one submission, then submitted twice more:
// the replay runs each execution with the count its capture saw (1, then 2 for the others).
TEST_F(CaptureExecution, CommandBufferListedTwiceReplaysEachExecution) {
    const fs::path trace = dir / "simultaneous.clt";
    ASSERT_EQ(capture("simultaneous " + quote((dir / "out.json").string()), trace), 0)
        << readText(dir / "stderr.txt");
    Begins b = begins(trace);
    ASSERT_EQ(b.begins.size(), 4u);
    EXPECT_EQ(std::get<2>(b.begins[0]), 0u);
    EXPECT_EQ(std::get<2>(b.begins[1]), 1u);  // the second listing in the first submission
    EXPECT_EQ(std::get<2>(b.begins[2]), 0u);
    EXPECT_EQ(std::get<2>(b.begins[3]), 0u);
    ClusterRuns runs;
    clastrace::replay::ReplayReport r = replay(trace, &runs);
    EXPECT_EQ(runs.opCounts, (std::vector<uint32_t>{1, 2, 2, 2}));
    EXPECT_TRUE(r.findings.empty()) << describe(r);
}

}  // namespace
