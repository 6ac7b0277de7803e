// SPDX-License-Identifier: Apache-2.0
// SharedPauseTracker: when a submission whose pause events another queue may still use can
// start. Lavapipe has one queue, so the layer's two-queue path is checked here on the state
// alone: the queue of the earlier execution, its pauses handled or not, its last release
// reset or not.
#include "clastrace/capture/shared_pause_tracker.h"

#include <gtest/gtest.h>

#include <set>

namespace {

using clastrace::capture::SharedPauseTracker;

constexpr uint64_t kQueueA = 0xa, kQueueB = 0xb;
constexpr uint64_t kRelease1 = 0xe1, kRelease2 = 0xe2, kOther = 0xe9;

// The event states a test sets: a release in `set` reads SET, every other RESET.
struct Events {
    std::set<uint64_t> set;
    SharedPauseTracker::ReleaseIsReset isReset() const {
        return [this](uint64_t e) { return set.count(e) == 0; };
    }
};

TEST(SharedPauseTracker, SecondQueueWaitsUntilEveryPauseIsHandledAndReset) {
    SharedPauseTracker t;
    Events events;
    // Execution on queue A: two pauses.
    t.expected(kQueueA, kRelease1);
    t.expected(kQueueA, kRelease2);
    const std::vector<uint64_t> both{kRelease1, kRelease2};
    EXPECT_TRUE(t.busy_elsewhere(kQueueB, both, events.isReset()));
    EXPECT_FALSE(t.busy_elsewhere(kQueueA, both,
                                  events.isReset()));  // one queue: its order keeps them apart
    EXPECT_FALSE(
        t.busy_elsewhere(kQueueB, {kOther}, events.isReset()));  // other events: no conflict

    t.released(kQueueA, kRelease1);
    events.set.insert(kRelease1);
    EXPECT_TRUE(t.busy_elsewhere(kQueueB, both, events.isReset()));  // second pause still to come
    events.set.erase(kRelease1);
    t.released(kQueueA, kRelease2);
    events.set.insert(kRelease2);
    // Every pause handled, but queue A has not reset the last release: a new execution would
    // pass its wait on it unobserved.
    EXPECT_TRUE(t.busy_elsewhere(kQueueB, both, events.isReset()));
    events.set.erase(kRelease2);
    EXPECT_FALSE(t.busy_elsewhere(kQueueB, both, events.isReset()));
    EXPECT_TRUE(t.empty());
}

TEST(SharedPauseTracker, TwoPendingExecutionsOnOneQueueBothCount) {
    SharedPauseTracker t;
    Events events;
    t.expected(kQueueA, kRelease1);
    t.expected(kQueueA, kRelease1);  // the command buffer listed twice
    t.released(kQueueA, kRelease1);
    EXPECT_TRUE(t.busy_elsewhere(kQueueB, {kRelease1},
                                 events.isReset()));  // reset seen, one execution left
    t.released(kQueueA, kRelease1);
    EXPECT_FALSE(t.busy_elsewhere(kQueueB, {kRelease1}, events.isReset()));
}

TEST(SharedPauseTracker, BothOtherQueuesMustFinish) {
    SharedPauseTracker t;
    Events events;
    t.expected(kQueueA, kRelease1);
    t.expected(kQueueB, kRelease1);
    constexpr uint64_t kQueueC = 0xc;
    t.released(kQueueA, kRelease1);
    EXPECT_TRUE(t.busy_elsewhere(kQueueC, {kRelease1}, events.isReset()));  // B still pending
    t.released(kQueueB, kRelease1);
    EXPECT_FALSE(t.busy_elsewhere(kQueueC, {kRelease1}, events.isReset()));
}

TEST(SharedPauseTracker, ResetCommandBufferForgetsItsEvents) {
    SharedPauseTracker t;
    Events events;
    t.expected(kQueueA, kRelease1);
    t.forget(kRelease1);
    EXPECT_FALSE(t.busy_elsewhere(kQueueB, {kRelease1}, events.isReset()));
    EXPECT_TRUE(t.empty());
}

TEST(SharedPauseTracker, ReleaseOfUnknownEventIsIgnored) {
    SharedPauseTracker t;
    Events events;
    t.released(kQueueA, kRelease1);
    EXPECT_TRUE(t.empty());
    EXPECT_FALSE(t.busy_elsewhere(kQueueB, {kRelease1}, events.isReset()));
}

}  // namespace
