// SPDX-License-Identifier: Apache-2.0
// Binary semaphores in a replayed trace (format 1.2 records): a successful
// vkAcquireNextImageKHR is the presentation engine's signal of its semaphore, so the frame's
// submission that waits on it is no longer an unsatisfied wait; and a binary semaphore
// signalled again while its captured signal is still unconsumed is reported as
// VUID-vkQueueSubmit-pSignalSemaphores-00067 (vkQueueSubmit) or
// VUID-vkQueueSubmit2-semaphore-03868 (vkQueueSubmit2). Each rule has a broken and a valid twin.
#include "trace_files.h"
#include "trace_script.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace {

using namespace clastrace;
using namespace clastrace::test;

constexpr uint64_t kQueue = 0x9e;
constexpr uint64_t kTarget = 0xb1;
constexpr uint64_t kImageAvailable = 0x5a;
constexpr uint64_t kRenderDone = 0x5d;
constexpr uint64_t kFrameDone = 0xf1;
constexpr uint64_t kTransfer = VK_PIPELINE_STAGE_2_TRANSFER_BIT;
constexpr const char* kSubmitVuid = "VUID-vkQueueSubmit-pSignalSemaphores-00067";
constexpr const char* kSubmit2Vuid = "VUID-vkQueueSubmit2-semaphore-03868";

std::vector<const replay::ReplayFinding*> findings_of(const replay::ReplayReport& r,
                                                      const std::string& rule) {
    std::vector<const replay::ReplayFinding*> out;
    for (const replay::ReplayFinding& f : r.findings)
        if (f.rule == rule) out.push_back(&f);
    return out;
}

class SemaphoreSignals : public ::testing::Test {
protected:
    std::string path;
    void SetUp() override {
        path = temp_trace_path("semaphore_signals",
                               ::testing::UnitTest::GetInstance()->current_test_info()->name());
    }
    void TearDown() override { discard_trace(path); }
};

// present_frames_app's loop: acquire -> fill, wait on the acquire, signal render-done -> present.
void write_frames(const std::string& path, int frames, bool with_acquires) {
    TraceScript s(path);
    s.buffer(kTarget, 0x10000, 0x100, VK_BUFFER_USAGE_TRANSFER_DST_BIT);
    for (int f = 0; f < frames; ++f) {
        if (with_acquires) s.acquire(kImageAvailable);
        s.fill(kTarget, 0, 0x100, uint32_t(f));
        s.submit(kQueue, {{kImageAvailable, 0, kTransfer}}, {{kRenderDone, 0}}, kFrameDone, 1);
        s.present(kQueue, {kRenderDone}, uint64_t(f));
        s.wait_fence(kFrameDone);
    }
    s.finish();
}

TEST_F(SemaphoreSignals, WithoutAcquireRecordsEveryFramesWaitIsUnsatisfied) {
    write_frames(path, 3, false);
    const replay::ReplayReport r = replay_file(path);
    EXPECT_EQ(r.counts.unsatisfied_semaphore_waits, 3u);
    EXPECT_EQ(r.counts.acquires, 0u);
    EXPECT_EQ(r.counts.presents, 3u);
    EXPECT_TRUE(findings_of(r, kSubmitVuid).empty());
}

TEST_F(SemaphoreSignals, AnAcquireSatisfiesTheWaitOnItsSemaphore) {
    write_frames(path, 3, true);
    const replay::ReplayReport r = replay_file(path);
    EXPECT_EQ(r.counts.unsatisfied_semaphore_waits, 0u);
    EXPECT_EQ(r.counts.acquires, 3u);
    EXPECT_EQ(r.counts.presents, 3u);
    EXPECT_EQ(r.counts.submissions, 3u);
    EXPECT_TRUE(r.findings.empty()) << r.findings[0].format();
    EXPECT_TRUE(r.hazards.empty());
}

TEST_F(SemaphoreSignals, AFailedAcquireSignalsNothing) {
    TraceScript s(path);
    s.buffer(kTarget, 0x10000, 0x100, VK_BUFFER_USAGE_TRANSFER_DST_BIT);
    s.acquire(kImageAvailable, 0, VK_TIMEOUT);
    s.fill(kTarget, 0, 0x100, 1);
    s.submit(kQueue, {{kImageAvailable, 0, kTransfer}}, {}, 0, 1);
    s.finish();
    const replay::ReplayReport r = replay_file(path);
    EXPECT_EQ(r.counts.acquires, 1u);
    EXPECT_EQ(r.counts.unsatisfied_semaphore_waits, 1u);
}

TEST_F(SemaphoreSignals, HazardCountsAreLeftOutWithNoHazards) {
    write_frames(path, 2, false);
    replay::ReplayOptions options;
    options.check_hazards = false;
    const replay::ReplayReport r = replay_file(path, options);
    EXPECT_EQ(r.counts.unsatisfied_semaphore_waits, 0u);  // not counted
    EXPECT_EQ(r.counts.presents, 2u);
}

// Broken: submission 1 signals render-done again while submission 0's signal is unconsumed.
// Valid twin: a present (or a submission) waits on it in between.
void write_double_signal(const std::string& path, uint8_t version, int consumer) {
    TraceScript s(path);
    s.buffer(kTarget, 0x10000, 0x100, VK_BUFFER_USAGE_TRANSFER_DST_BIT);
    s.fill(kTarget, 0, 0x100, 1);
    s.submit(kQueue, {}, {{kRenderDone, 0}}, 0, version);
    if (consumer == 1) s.present(kQueue, {kRenderDone});
    if (consumer == 2) {
        s.fill(kTarget, 0, 0x100, 2);
        s.submit(kQueue, {{kRenderDone, 0, kTransfer}}, {}, 0, version);
    }
    s.fill(kTarget, 0, 0x100, 3);
    s.next_command_buffer();
    s.fill(kTarget, 0, 0x100, 4);
    s.submit(kQueue, {}, {{0x77, 0}, {kRenderDone, 0}}, 0, version);
    s.finish();
}

TEST_F(SemaphoreSignals, SignalledAgainBeforeAnyWaitIsReportedForQueueSubmit) {
    write_double_signal(path, 1, 0);
    const replay::ReplayReport r = replay_file(path);
    const auto found = findings_of(r, kSubmitVuid);
    ASSERT_EQ(found.size(), 1u);
    EXPECT_EQ(found[0]->where.submission, 1u);
    EXPECT_STREQ(found[0]->where.name, "vkQueueSubmit");
    EXPECT_NE(found[0]->message.find("pSubmits[0].pSignalSemaphores[1]"), std::string::npos)
        << found[0]->message;
    EXPECT_NE(found[0]->message.find("submission 0 batch 0"), std::string::npos)
        << found[0]->message;
    EXPECT_TRUE(findings_of(r, kSubmit2Vuid).empty());
}

TEST_F(SemaphoreSignals, SignalledAgainBeforeAnyWaitIsReportedForQueueSubmit2) {
    write_double_signal(path, 2, 0);
    const replay::ReplayReport r = replay_file(path);
    const auto found = findings_of(r, kSubmit2Vuid);
    ASSERT_EQ(found.size(), 1u);
    EXPECT_EQ(found[0]->where.submission, 1u);
    EXPECT_STREQ(found[0]->where.name, "vkQueueSubmit2");
    EXPECT_NE(found[0]->message.find("pSubmits[0].pSignalSemaphoreInfos[1]"), std::string::npos)
        << found[0]->message;
    EXPECT_TRUE(findings_of(r, kSubmitVuid).empty());
}

TEST_F(SemaphoreSignals, APresentInBetweenConsumesTheSignal) {
    write_double_signal(path, 1, 1);
    const replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(findings_of(r, kSubmitVuid).empty());
    EXPECT_EQ(r.counts.presents, 1u);
}

TEST_F(SemaphoreSignals, ASubmissionWaitInBetweenConsumesTheSignal) {
    write_double_signal(path, 2, 2);
    const replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(findings_of(r, kSubmit2Vuid).empty());
    EXPECT_EQ(r.counts.unsatisfied_semaphore_waits, 0u);
}

TEST_F(SemaphoreSignals, ASignalAfterAnUnconsumedAcquireIsReported) {
    TraceScript s(path);
    s.buffer(kTarget, 0x10000, 0x100, VK_BUFFER_USAGE_TRANSFER_DST_BIT);
    s.acquire(kImageAvailable);
    s.fill(kTarget, 0, 0x100, 1);
    s.submit(kQueue, {}, {{kImageAvailable, 0}}, 0, 1);  // the acquire's signal was never waited on
    s.finish();
    const replay::ReplayReport r = replay_file(path);
    const auto found = findings_of(r, kSubmitVuid);
    ASSERT_EQ(found.size(), 1u);
    EXPECT_NE(found[0]->message.find("vkAcquireNextImageKHR"), std::string::npos)
        << found[0]->message;
}

// An acquire given a semaphore still signalled: VUID-vkAcquireNextImageKHR-semaphore-01286, or
// VUID-VkAcquireNextImageInfoKHR-semaphore-01288 for vkAcquireNextImage2KHR (deviceMask set),
// whatever the call returned. Valid twin: the frame's submission waits on it in between.
void write_double_acquire(const std::string& path, uint32_t device_mask, bool wait_between,
                          int32_t second_result) {
    TraceScript s(path);
    s.buffer(kTarget, 0x10000, 0x100, VK_BUFFER_USAGE_TRANSFER_DST_BIT);
    s.acquire(kImageAvailable, 0, VK_SUCCESS, device_mask);
    s.fill(kTarget, 0, 0x100, 1);
    s.submit(kQueue,
             wait_between ? std::vector<SemaphoreUse>{{kImageAvailable, 0, kTransfer}}
                          : std::vector<SemaphoreUse>{},
             {}, 0, 1);
    s.acquire(kImageAvailable, 0, second_result, device_mask);
    s.finish();
}

TEST_F(SemaphoreSignals, AnAcquireOfAStillSignalledSemaphoreIsReported) {
    write_double_acquire(path, 0, false, VK_SUCCESS);
    replay::ReplayReport r = replay_file(path);
    auto found = findings_of(r, "VUID-vkAcquireNextImageKHR-semaphore-01286");
    ASSERT_EQ(found.size(), 1u);
    EXPECT_EQ(found[0]->where.submission, 1u);  // before the next submission
    EXPECT_STREQ(found[0]->where.name, "vkAcquireNextImageKHR");
    EXPECT_EQ(r.findings.size(), 1u);

    write_double_acquire(path, 1, false, VK_TIMEOUT);
    r = replay_file(path);
    found = findings_of(r, "VUID-VkAcquireNextImageInfoKHR-semaphore-01288");
    ASSERT_EQ(found.size(), 1u);
    EXPECT_STREQ(found[0]->where.name, "vkAcquireNextImage2KHR");
    EXPECT_NE(found[0]->message.find("vkAcquireNextImage2KHR (swapchain"), std::string::npos)
        << found[0]->message;
}

TEST_F(SemaphoreSignals, AnAcquireAfterTheWaitIsValid) {
    for (uint32_t device_mask : {0u, 1u}) {
        write_double_acquire(path, device_mask, true, VK_SUCCESS);
        const replay::ReplayReport r = replay_file(path);
        EXPECT_TRUE(r.findings.empty()) << r.findings[0].format();
        EXPECT_EQ(r.counts.acquires, 2u);
    }
}

// Semaphores whose earlier signal the trace does not hold, and timeline signals, are left alone.
TEST_F(SemaphoreSignals, UnknownAndTimelineSemaphoresAreNotReported) {
    TraceScript s(path);
    s.buffer(kTarget, 0x10000, 0x100, VK_BUFFER_USAGE_TRANSFER_DST_BIT);
    s.fill(kTarget, 0, 0x100, 1);
    s.submit(kQueue, {{0x99, 0, kTransfer}}, {{0x99, 0}, {0x72, 5}}, 0,
             2);  // 0x99: signalled outside the trace
    s.fill(kTarget, 0, 0x100, 2);
    s.submit(kQueue, {}, {{0x72, 5}}, 0, 2);  // a timeline value twice is a different rule
    s.finish();
    const replay::ReplayReport r = replay_file(path);
    EXPECT_TRUE(findings_of(r, kSubmit2Vuid).empty());
}

}  // namespace
