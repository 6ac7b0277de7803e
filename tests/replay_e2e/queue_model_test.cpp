// SPDX-License-Identifier: Apache-2.0
// What the replay models of queues and command buffers beyond barriers: semaphore signal
// stage masks (vkQueueSubmit2), command pool resets, command buffers submitted with nothing
// recorded.
#include "catalogue_replay.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <unistd.h>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;

constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kQueueA = 0x9001, kQueueB = 0x9002, kPool = 0x9900;

std::string temp_path(const std::string& name) { return temp_trace_path("queue_model", name); }

template <class Scene>
replay::ReplayReport replay_scene(const std::string& name, Scene scene) {
    return replay_catalogue_scene(temp_path(name), scene);
}

ClusterCommand second_build() {
    ClusterCommand c = triangle_clusters(Destinations::kImplicit);
    c.info.dstImplicitData = kDst2;  // only the scratch is shared with the first build
    c.info.dstAddressesArray.deviceAddress = kOut + 0x400;
    c.info.dstSizesArray.deviceAddress = kSizes + 0x400;
    return c;
}

// Queue A builds and signals with `stages`; queue B waits (all stages) and reuses the scratch.
replay::ReplayReport scratch_across_queues(uint64_t stages, uint8_t submit_version) {
    return replay_scene("signal_" + std::to_string(stages) + "_v" + std::to_string(submit_version) +
                            ".clt",
                        [&](TraceScript& t) {
                            triangle_clusters(Destinations::kImplicit).emit(t);
                            t.submit(kQueueA, {}, {{0x5e1, 0, stages}}, 0, submit_version);
                            second_build().emit(t);
                            t.submit(kQueueB, {{0x5e1, 0, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT}},
                                     {}, 0, submit_version);
                        });
}

TEST(QueueModel, NarrowSignalStageMaskLeavesTheBuildUnordered) {
    const replay::ReplayReport r = scratch_across_queues(VK_PIPELINE_STAGE_2_COPY_BIT, 2);
    ASSERT_EQ(r.hazards.size(), 1u) << replay::format_text(r);
    EXPECT_EQ(r.hazards[0].hazard, replay::HazardClass::kWriteAfterWrite);
    EXPECT_TRUE(r.hazards[0].later.field.starts_with("scratchData (the "))
        << r.hazards[0].later.field;
    EXPECT_EQ(r.hazards[0].fix.kind, replay::FixKind::kSemaphore);
    EXPECT_EQ(r.hazards[0].prior.command.submission, 0u);
    EXPECT_EQ(r.hazards[0].later.command.submission, 1u);
}

TEST(QueueModel, SignalStageMaskThatHoldsTheBuildOrAllCommandsOrdersIt) {
    EXPECT_TRUE(scratch_across_queues(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, 2).clean());
    EXPECT_TRUE(scratch_across_queues(kBuild, 2).clean());
    // vkQueueSubmit signals are ALL_COMMANDS by the spec, whatever mask the record holds.
    EXPECT_TRUE(scratch_across_queues(VK_PIPELINE_STAGE_2_COPY_BIT, 1).clean());
}

TEST(QueueModel, PoolResetClearsItsBuffersSubmittingOneAgainIsReported) {
    auto scene = [](bool rerecord) {
        return [rerecord](TraceScript& t) {
            t.begin(0xcb01);
            triangle_clusters(Destinations::kImplicit).emit(t);
            t.submit(kQueueA, {}, {}, 0xf1);
            t.wait_fence(0xf1);
            t.reset(0xcb01, kPool);  // vkResetCommandBuffer of a buffer of kPool: membership known
            t.begin(0xcb01);
            triangle_clusters(Destinations::kImplicit).emit(t);
            t.submit(kQueueA, {}, {}, 0xf2);
            t.wait_fence(0xf2);
            t.reset(0, kPool);  // vkResetCommandPool
            if (rerecord) {
                t.begin(0xcb01);
                triangle_clusters(Destinations::kImplicit).emit(t);
                t.submit(kQueueA, {}, {}, 0xf3);
            } else {
                t.resubmit(kQueueA, 0xcb01, 0xf3);
            }
            t.wait_fence(0xf3);
        };
    };
    replay::ReplayReport r = replay_scene("pool_reset.clt", scene(false));
    ASSERT_EQ(r.findings.size(), 1u) << replay::format_text(r);
    EXPECT_EQ(r.findings[0].rule, "CLASTRACE-replay-command-buffer-not-recorded");
    EXPECT_EQ(r.findings[0].where.submission, 2u);
    EXPECT_EQ(r.findings[0].where.command_buffer_handle, 0xcb01u);
    EXPECT_EQ(r.counts.cluster_commands, 2u);  // the reset buffer's old build is not replayed
    r = replay_scene("pool_rerecorded.clt", scene(true));
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
    EXPECT_EQ(r.counts.cluster_commands, 3u);
}

TEST(QueueModel, PoolResetOfUnknownMembershipIsNotedAndOldCommandsReplay) {
    const replay::ReplayReport r = replay_scene("pool_unknown.clt", [](TraceScript& t) {
        t.begin(0xcb01);
        triangle_clusters(Destinations::kImplicit).emit(t);
        t.submit(kQueueA, {}, {}, 0xf1);
        t.wait_fence(0xf1);
        t.reset(0, kPool);
        t.resubmit(kQueueA, 0xcb01, 0xf2);
        t.wait_fence(0xf2);
        t.reset(0, kPool);  // every frame: noted once
    });
    EXPECT_TRUE(r.findings.empty()) << replay::format_text(r);
    EXPECT_EQ(r.counts.cluster_commands, 2u);
    ASSERT_EQ(r.not_replayed.size(), 1u);
    EXPECT_EQ(std::string(r.not_replayed[0].where.name), "vkResetCommandPool");
    EXPECT_NE(r.not_replayed[0].reason.find("0x9900"), std::string::npos)
        << r.not_replayed[0].reason;
}

TEST(QueueModel, OneTimeBufferSubmittedTwiceIsReported) {
    const replay::ReplayReport r = replay_scene("one_time.clt", [](TraceScript& t) {
        t.begin(0xcb01, VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT);
        triangle_clusters(Destinations::kImplicit).emit(t);
        t.submit(kQueueA, {}, {}, 0xf1);
        t.wait_fence(0xf1);
        t.resubmit(kQueueA, 0xcb01, 0xf2);
        t.wait_fence(0xf2);
    });
    ASSERT_EQ(r.findings.size(), 1u) << replay::format_text(r);
    EXPECT_EQ(r.findings[0].rule, "CLASTRACE-replay-command-buffer-not-recorded");
    EXPECT_EQ(r.counts.cluster_commands, 1u);
}

}  // namespace
