// SPDX-License-Identifier: Apache-2.0
// vkQueuePresentKHR in the synchronization model: the presentation engine's wait consumes a
// binary semaphore's signal, so a later wait on it finds no signal instead of a stale one
// (which would order work that nothing orders).
#include <gtest/gtest.h>

#include "sync_stream.h"

namespace clastrace::replay::test {
namespace {

constexpr AddressRange kStaging{0x8000, 0x8040};
constexpr AddressRange kInfos{0x1000, 0x1040};
constexpr uint64_t kRenderDone = 0x5E;

// Queue 0 copies into kInfos and signals kRenderDone; optionally a present waits on it; then
// queue 1 waits on kRenderDone and reads kInfos.
const Stream& run(Stream& s, bool present) {
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);
    s.end({{kRenderDone, 0}});
    if (present) {
        const uint64_t waits[] = {kRenderDone};
        s.model.present_wait(waits);
    }
    s.submit(1, {{kRenderDone, 0, kCopy}});
    s.copy_buffer(kInfos, {0x9000, 0x9040});
    s.end();
    return s;
}

TEST(SyncPresent, PresentConsumesTheBinarySignal) {
    Stream without;
    run(without, false);
    EXPECT_TRUE(without.hazards().empty());  // the signal orders queue 1's read after the copy
    EXPECT_EQ(without.model.stats().unsatisfied_waits, 0u);

    Stream with;
    run(with, true);
    // The present took the signal: queue 1's wait has none, so nothing orders its read.
    EXPECT_EQ(with.model.stats().unsatisfied_waits, 1u);
    ASSERT_EQ(with.hazards().size(), 1u);
    EXPECT_EQ(with.hazards()[0].hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(with.hazards()[0].fix.kind, FixKind::kSemaphore);
}

TEST(SyncPresent, SignalledAgainAfterThePresentOrdersAgain) {
    Stream s;
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);
    s.end({{kRenderDone, 0}});
    const uint64_t waits[] = {kRenderDone};
    s.model.present_wait(waits);
    s.submit(0);  // the next frame signals it again
    s.end({{kRenderDone, 0}});
    s.submit(1, {{kRenderDone, 0, kCopy}});
    s.copy_buffer(kInfos, {0x9000, 0x9040});
    s.end();
    EXPECT_TRUE(s.hazards().empty());
    EXPECT_EQ(s.model.stats().unsatisfied_waits, 0u);
}

TEST(SyncPresent, UnknownAndTimelineSemaphoresAreLeftAlone) {
    Stream s;
    const uint64_t unknown[] = {0xDEAD};  // signalled outside the trace (an earlier frame range)
    s.model.present_wait(unknown);
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);
    s.end({{0x72, 5}});  // timeline value 5
    const uint64_t timeline[] = {0x72};
    s.model.present_wait(timeline);  // presents wait on binary semaphores only: value 5 stays
    s.submit(1, {{0x72, 5, kCopy}});
    s.copy_buffer(kInfos, {0x9000, 0x9040});
    s.end();
    EXPECT_TRUE(s.hazards().empty());
    EXPECT_EQ(s.model.stats().unsatisfied_waits, 0u);
}

}  // namespace
}  // namespace clastrace::replay::test
