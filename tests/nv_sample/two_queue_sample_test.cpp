// SPDX-License-Identifier: Apache-2.0
// traces/samples/h100_cluster_scene_two_queues.clt: examples/cluster_scene --threads 2 under the
// capture layer on an H100 (driver 580), which lacks VK_NV_cluster_acceleration_structure: the
// layer served it. Two threads recorded two command buffers and submitted them to two queues
// of one family (lavapipe, our CI driver, has only one queue, so this is the two-queue case of
// the capture tests). Nothing may be lost: every build of both command buffers is in the
// trace, and the replay reproduces every output the application's device held.
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <map>
#include <set>

namespace {

using namespace clastrace;

TEST(TwoQueueSample, BothQueuesAndEveryBuildOfBothCommandBuffersAreRecorded) {
    traces::TraceError error;
    auto reader = traces::TraceReader::open(CLASTRACE_TWO_QUEUE_SAMPLE, &error);
    ASSERT_TRUE(reader) << error.message;
    std::set<uint64_t> queues;
    std::set<uint32_t> queue_indices;
    std::map<uint64_t, int> builds_by_command_buffer, copies_by_command_buffer, submitted;
    traces::RecordView view;
    while (reader->next(&view)) {
        const fbs::Record& r = *view.record;
        switch (view.kind) {
        case fbs::RecordBody::QueueSubmit: {
            const auto* s = r.body_as_QueueSubmit();
            queues.insert(s->queue());
            queue_indices.insert(s->queue_index());
            if (s->batches())
                for (const auto* b : *s->batches())
                    if (b->command_buffers())
                        for (uint64_t cb : *b->command_buffers()) ++submitted[cb];
            break;
        }
        case fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect:
            ++builds_by_command_buffer[r.body_as_CmdBuildClusterAccelerationStructureIndirect()
                                           ->command_buffer()];
            break;
        case fbs::RecordBody::CmdCopyBuffer:
            ++copies_by_command_buffer[r.body_as_CmdCopyBuffer()->command_buffer()];
            break;
        default: break;
        }
    }
    EXPECT_EQ(reader->damage_count(), 0u);
    EXPECT_EQ(queues.size(), 2u);
    EXPECT_EQ(queue_indices, (std::set<uint32_t>{0, 1}));
    ASSERT_EQ(submitted.size(), 2u);
    for (const auto& [cb, times] : submitted) {
        EXPECT_EQ(times, 1);
        EXPECT_EQ(builds_by_command_buffer[cb], 8)
            << "command buffer " << cb;  // every op type, as on lavapipe
        EXPECT_EQ(copies_by_command_buffer[cb], 5) << "command buffer " << cb;
    }
}

TEST(TwoQueueSample, ReplayReproducesEveryOutputWithoutHazard) {
    traces::TraceError error;
    auto reader = traces::TraceReader::open(CLASTRACE_TWO_QUEUE_SAMPLE, &error);
    ASSERT_TRUE(reader) << error.message;
    const replay::ReplayReport r = replay::replay_trace(*reader, CLASTRACE_TWO_QUEUE_SAMPLE, {});
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
    EXPECT_TRUE(r.engine_trace);  // served: the outputs are the engine's bytes
    EXPECT_EQ(r.counts.submissions, 2u);
    EXPECT_EQ(r.counts.cluster_commands, 16u);
    EXPECT_EQ(r.counts.outputs_compared, 442u);
}

}  // namespace
