// SPDX-License-Identifier: Apache-2.0
// Semaphore signal stage masks (vkQueueSubmit2's VkSemaphoreSubmitInfo::stageMask): the
// signal's first synchronization scope holds only the work in those stages, or chained
// into them by earlier barriers; writes outside it are neither ordered nor made available.
#include <gtest/gtest.h>

#include "sync_stream.h"

namespace clastrace::replay::test {
namespace {

constexpr AddressRange kScratch{0x1000, 0x1100};
constexpr AddressRange kInfos{0x2000, 0x2100};
constexpr AddressRange kStaging{0x3000, 0x3100};
constexpr StageMask kAll = VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;

Stream::Build scratch_build() {
    Stream::Build b;
    b.scratch = kScratch;
    return b;
}

// Queue 0 builds (scratch write) and signals with `signal_stages`; queue 1 waits (all
// stages) and builds on the same scratch.
std::vector<HazardReport> scratch_across_queues(StageMask signal_stages) {
    Stream s;
    s.submit(0);
    s.build(scratch_build());
    s.end({{0x5E, 0, signal_stages}});
    s.submit(1, {{0x5E, 0, kAll}});
    s.build(scratch_build());
    s.end();
    return s.hazards();
}

TEST(SyncSignalMask, SignalWithoutTheWritersStageLeavesTheWriteUnordered) {
    const auto bad = scratch_across_queues(kCopy);
    ASSERT_EQ(bad.size(), 1u);
    EXPECT_EQ(bad[0].hazard, HazardClass::kWriteAfterWrite);
    EXPECT_EQ(bad[0].fix.kind, FixKind::kSemaphore);
    EXPECT_EQ(bad[0].prior.queue, 0u);
    EXPECT_EQ(bad[0].later.queue, 1u);
}

TEST(SyncSignalMask, AllCommandsOrTheWritersStageOrdersIt) {
    EXPECT_TRUE(scratch_across_queues(kAll).empty());
    EXPECT_TRUE(scratch_across_queues(kAsBuild).empty());
    // BOTTOM_OF_PIPE as a source stage is ALL_COMMANDS.
    EXPECT_TRUE(scratch_across_queues(VK_PIPELINE_STAGE_2_BOTTOM_OF_PIPE_BIT).empty());
}

// A barrier chaining the build into COPY puts it into a COPY signal's scope; with access
// masks the write is also made available, without them only ordered.
std::vector<HazardReport> chained(AccessMask barrier_src_access) {
    Stream s;
    s.submit(0);
    s.build(scratch_build());
    s.barrier(kAsBuild, barrier_src_access, kCopy, 0);
    s.end({{0x5E, 0, kCopy}});
    s.submit(1, {{0x5E, 0, kAll}});
    s.fill(kScratch);  // overwrites scratch: WAW needs the build's write available
    s.end();
    return s.hazards();
}

TEST(SyncSignalMask, BarrierChainIntoTheSignalStageBringsTheWriteIn) {
    EXPECT_TRUE(chained(kAsWrite).empty());
    const auto bad = chained(0);  // execution only: ordered, not available
    ASSERT_EQ(bad.size(), 1u);
    EXPECT_EQ(bad[0].hazard, HazardClass::kWriteAfterWrite);
}

TEST(SyncSignalMask, NarrowSignalOrdersOnlyItsStagesOfTheSameSubmission) {
    // Queue 0 copies the infos and builds; the COPY signal covers the copy only.
    Stream s;
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);
    s.build(scratch_build());
    s.end({{0x5E, 0, kCopy}});
    s.submit(1, {{0x5E, 0, kAll}});
    Stream::Build reader;
    reader.src_infos = kInfos;
    s.build(reader);           // reads the copied infos: ordered and visible
    s.build(scratch_build());  // reuses scratch: the first build is outside the signal
    s.end();
    ASSERT_EQ(s.hazards().size(), 1u);
    EXPECT_EQ(s.hazards()[0].later.field, "scratchData");
}

// Queue 0 -> queue 1 (full signal, wait at `wait_stage`) -> queue 2 (narrow COPY signal):
// the queue 0 write is in the COPY signal only if queue 1's wait chained it into COPY.
std::vector<HazardReport> relayed(StageMask wait_stage) {
    Stream s;
    s.submit(0);
    s.build(scratch_build());
    s.end({{0x5E, 0, kAll}});
    s.submit(1, {{0x5E, 0, wait_stage}});
    s.fill({0x9000, 0x9010});
    s.end({{0x5F, 0, kCopy}});
    s.submit(2, {{0x5F, 0, kAll}});
    s.build(scratch_build());
    s.end();
    return s.hazards();
}

TEST(SyncSignalMask, RelayedWritesFollowTheMiddleQueuesChain) {
    EXPECT_TRUE(relayed(kAll).empty());
    EXPECT_TRUE(relayed(kCopy).empty());
    const auto bad = relayed(kAsBuild);  // the wait chained the write into AS_BUILD only, not COPY
    ASSERT_EQ(bad.size(), 1u);
    EXPECT_EQ(bad[0].prior.queue, 0u);
    EXPECT_EQ(bad[0].later.queue, 2u);
}

TEST(SyncSignalMask, TimelineSignalsCarryTheirMaskToo) {
    for (StageMask stages : {kCopy, kAll}) {
        Stream s;
        s.submit(0);
        s.build(scratch_build());
        s.end({{0x7E, 5, stages}});
        s.submit(1, {{0x7E, 3, kAll}});  // waits for value 3: satisfied by the signal of 5
        s.build(scratch_build());
        s.end();
        EXPECT_EQ(s.hazards().size(), stages == kCopy ? 1u : 0u);
    }
}

}  // namespace
}  // namespace clastrace::replay::test
