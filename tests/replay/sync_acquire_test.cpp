// SPDX-License-Identifier: Apache-2.0
// vkAcquireNextImageKHR in the synchronization model: the presentation engine signals the
// binary semaphore (and fence) from outside every queue. A wait on it is satisfied, and the
// signal consumed, but it orders no device work: nothing a queue did before the acquire is
// made visible by it.
#include <gtest/gtest.h>

#include "sync_stream.h"

namespace clastrace::replay::test {
namespace {

constexpr AddressRange kStaging{0x8000, 0x8040};
constexpr AddressRange kInfos{0x1000, 0x1040};
constexpr uint64_t kImageAvailable = 0x5A;
constexpr uint64_t kAcquireFence = 0xF5;

TEST(SyncAcquire, TheWaitOnTheAcquireSemaphoreIsSatisfied) {
    for (bool acquired : {false, true}) {
        Stream s;
        if (acquired) s.model.acquire_signal(kImageAvailable, 0);
        s.submit(0, {{kImageAvailable, 0, kCopy}});
        s.copy_buffer(kStaging, kInfos);
        s.end();
        EXPECT_EQ(s.model.stats().unsatisfied_waits, acquired ? 0u : 1u);
        // A binary wait consumes the signal: a second wait finds none.
        s.submit(0, {{kImageAvailable, 0, kCopy}});
        s.end();
        EXPECT_EQ(s.model.stats().unsatisfied_waits, acquired ? 1u : 2u);
    }
}

TEST(SyncAcquire, TheAcquireOrdersNoDeviceWork) {
    Stream s;
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);  // queue 0 writes kInfos
    s.end();
    s.model.acquire_signal(kImageAvailable, kAcquireFence);
    s.model.wait_for_fence(kAcquireFence);  // the acquire's fence completes no queue's work
    s.submit(1, {{kImageAvailable, 0, kCopy}});
    s.copy_buffer(kInfos, {0x9000, 0x9040});  // queue 1 reads it
    s.end();
    EXPECT_EQ(s.model.stats().unsatisfied_waits, 0u);
    ASSERT_EQ(s.hazards().size(), 1u);
    EXPECT_EQ(s.hazards()[0].hazard, HazardClass::kReadAfterWrite);
}

}  // namespace
}  // namespace clastrace::replay::test
