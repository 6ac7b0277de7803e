// SPDX-License-Identifier: Apache-2.0
// The ReplayObserver contract (replay_observer.h) as the streaming analysis relies on it: every
// record once, submissions balanced, commands in sequence order inside their submission, a
// cluster build's execution record and engine time present, and each hazard delivered right
// after the command that found it.
#include "analyze_scene.h"

#include <clastrace/engine/execution_record.h>
#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <filesystem>
#include <unistd.h>

namespace clastrace {
namespace {

struct Recorder final : replay::ReplayObserver {
    uint64_t records = 0, begins = 0, ends = 0, commands = 0, executions = 0, hazards = 0;
    uint64_t engine_ns = 0, ops = 0;
    bool open = false, order_ok = true, hazard_ok = true, memory_ok = true;
    int64_t last_sequence = -1;
    replay::ReplayLocation last;
    void on_record(const traces::RecordView&) override { ++records; }
    void on_submission_begin(uint32_t) override {
        order_ok &= !open;
        open = true;
        ++begins;
    }
    void on_command(const replay::ReplayedCommand& c) override {
        order_ok &= open && static_cast<int64_t>(c.where.sequence) > last_sequence;
        last_sequence = static_cast<int64_t>(c.where.sequence);
        last = c.where;
        ++commands;
        memory_ok &= c.memory != nullptr && c.record != nullptr;
        if (c.execution) {
            ++executions;
            engine_ns += c.engine_ns;
            ops += c.execution->ops.size();
            memory_ok &= c.replay_ns >= c.engine_ns;
        }
    }
    void on_hazard(const replay::HazardReport& h) override {
        ++hazards;
        hazard_ok &= h.later.command.submission == last.submission &&
                     h.later.command.command == last.command &&
                     h.later.command.command_buffer == last.command_buffer;
    }
    void on_submission_end(uint32_t) override {
        order_ok &= open;
        open = false;
        ++ends;
    }
};

TEST(ReplayObserverContract, EventsArriveInOrder) {
    const std::string path = (std::filesystem::temp_directory_path() /
                              ("observer_" + std::to_string(::getpid()) + ".clt"))
                                 .string();
    {
        test::AnalyzeSceneWriter w(path, 1.0f);
        test::ClusterBuild a;
        a.triangle_counts = {2, 8, 18};
        w.timestamp(10);
        w.build(a);
        w.timestamp(20);
        test::ClusterBuild b;  // no barrier: B's implicit data on A's scratch is a hazard
        b.triangle_counts = {4, 4};
        b.dst = test::AnalyzeScene::kPool + 0x20000;
        b.scratch = test::AnalyzeScene::kPool + 0x30000;
        b.arrays = test::AnalyzeScene::kArrays + 0x400;
        w.build(b);
        w.nv_build(24, 1000, 512);
        w.submit();
        w.build(a);
        w.submit();
        w.finish();
    }
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    ASSERT_TRUE(reader) << e.message;
    Recorder rec;
    replay::ReplayOptions options;
    options.observer = &rec;
    const replay::ReplayReport r = replay::replay_trace(*reader, path, options);
    std::filesystem::remove(path);

    EXPECT_EQ(rec.records, r.counts.records);
    EXPECT_EQ(rec.begins, 2u);
    EXPECT_EQ(rec.ends, 2u);
    EXPECT_TRUE(rec.order_ok);
    EXPECT_FALSE(rec.open);
    EXPECT_EQ(rec.commands,
              6u);  // 2 timestamps, A, B, the NV build; A again in the second submission
    // Every command the engine ran hands its record over: the cluster builds and the NV build.
    EXPECT_EQ(rec.executions,
              r.counts.cluster_commands + r.counts.nv_builds + r.counts.deserializations);
    EXPECT_EQ(r.counts.nv_builds, 1u);
    EXPECT_EQ(rec.ops, r.counts.cluster_ops + r.counts.nv_builds);  // an NV build is one op
    EXPECT_GT(rec.engine_ns, 0u);
    EXPECT_TRUE(rec.memory_ok);
    EXPECT_GE(rec.hazards, r.hazards.size());  // before replay folds per-op hazards
    EXPECT_GT(rec.hazards, 0u);
    EXPECT_TRUE(rec.hazard_ok);
}

}  // namespace
}  // namespace clastrace
