// SPDX-License-Identifier: Apache-2.0
// The advice naming the application's wait that missed a hazard: a semaphore wait that
// follows the prior access but leaves out the later access's stage, and a host wait on an
// earlier submission's fence before a host write; and a pipeline barrier between the two
// accesses that leaves out a stage, an access or the bytes. No advice where there was no such
// wait or barrier.
#include <gtest/gtest.h>

#include <string>

#include "sync_stream.h"

namespace clastrace::replay::test {
namespace {

constexpr AddressRange kClas{0x1000, 0x1100};
constexpr AddressRange kInfos{0x2000, 0x2100};
constexpr AddressRange kCleared{0x3000, 0x3100};
constexpr uint64_t kSemaphore = 0x5E;

// Submission 0 builds the CLAS; submission 1, waiting on the semaphore at `wait_stages`,
// builds a bottom level reading them.
// `signal_stages`: the signal's stage mask (VkSemaphoreSubmitInfo::stageMask).
std::vector<HazardReport> bottom_level_after_wait(
    StageMask wait_stages, StageMask signal_stages = VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT) {
    Stream s;
    s.submit(0);
    Stream::Build clas;
    clas.dst_implicit = kClas;
    s.build(clas);
    s.end({{kSemaphore, 0, signal_stages}});
    s.submit(0, {{kSemaphore, 0, wait_stages}});
    Stream::Build blas;
    blas.inputs = {{kClas, "srcInfosArray[0].clusterReferences[*]"}};
    s.build(blas);
    s.end();
    return s.hazards();
}

TEST(SyncWaitAdvice, SemaphoreWaitMissingTheLaterStageIsNamed) {
    const auto h = bottom_level_after_wait(kCompute);
    ASSERT_EQ(h.size(), 1u);
    EXPECT_EQ(h[0].hazard, HazardClass::kReadAfterWrite);
    EXPECT_NE(h[0].advice.find("The wait of submission 1 on semaphore 0x5e"), std::string::npos)
        << h[0].advice;
    EXPECT_NE(h[0].advice.find("at COMPUTE_SHADER only: add ACCELERATION_STRUCTURE_BUILD"),
              std::string::npos)
        << h[0].advice;
}

// A signal whose stage mask names the build (a narrow signal) is named the same way when the
// wait misses; a signal whose stage mask leaves the prior build out is named itself.
TEST(SyncWaitAdvice, NarrowSignalsWaitMissingTheLaterStageIsNamed) {
    const auto h = bottom_level_after_wait(kCompute, kAsBuild);
    ASSERT_EQ(h.size(), 1u);
    EXPECT_NE(h[0].advice.find("The wait of submission 1 on semaphore 0x5e follows submission "
                               "0's access, but at COMPUTE_SHADER only"),
              std::string::npos)
        << h[0].advice;
}

TEST(SyncWaitAdvice, SignalLeavingThePriorStageOutIsNamed) {
    const auto h = bottom_level_after_wait(kAsBuild, kCopy);
    ASSERT_EQ(h.size(), 1u);
    EXPECT_EQ(h[0].advice,
              "The signal of semaphore 0x5e by submission 0, which submission 1 waits on, is at "
              "COPY only: add ACCELERATION_STRUCTURE_BUILD to the signal's stage mask "
              "(VkSemaphoreSubmitInfo::stageMask).");
}

TEST(SyncWaitAdvice, SemaphoreWaitAtTheLaterStageOrdersIt) {
    EXPECT_TRUE(bottom_level_after_wait(kAsBuild).empty());
}

// A semaphore signaled before the prior access orders nothing after it: no advice about it.
TEST(SyncWaitAdvice, WaitOnAnEarlierSignalIsNotNamed) {
    Stream s;
    s.submit(0);
    s.fill(kCleared);
    s.end({{kSemaphore, 0, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT}});
    s.submit(0);
    Stream::Build clas;
    clas.dst_implicit = kClas;
    s.build(clas);
    s.end();
    s.submit(0, {{kSemaphore, 0, kCompute}});
    Stream::Build blas;
    blas.inputs = {{kClas, "srcInfosArray[0].clusterReferences[*]"}};
    s.build(blas);
    s.end();
    ASSERT_EQ(s.hazards().size(), 1u);
    EXPECT_TRUE(s.hazards()[0].advice.empty()) << s.hazards()[0].advice;
}

// Frame 0 (fence 0xF0) fills, frame 1 (fence 0xF1) builds from the infos; the host waits on
// `waited` and rewrites the infos.
std::vector<HazardReport> host_rewrite_after_waiting(uint64_t waited) {
    Stream s;
    s.submit(0);
    s.fill(kCleared);
    s.end({}, 0xF0);
    s.submit(0);
    Stream::Build clas;
    clas.src_infos = kInfos;
    s.build(clas);
    s.end({}, 0xF1);
    s.model.wait_for_fence(waited);
    s.model.host_access(CommandRef{s.submission, 0, 0, 0, "host write (mapped memory)"},
                        Stream::write(kInfos.begin, kInfos.end, VK_PIPELINE_STAGE_2_HOST_BIT,
                                      VK_ACCESS_2_HOST_WRITE_BIT, "mapped memory"));
    return s.hazards();
}

TEST(SyncWaitAdvice, HostWaitOnAnEarlierSubmissionsFenceIsNamed) {
    const auto h = host_rewrite_after_waiting(0xF0);
    ASSERT_EQ(h.size(), 1u);
    EXPECT_EQ(h[0].hazard, HazardClass::kWriteAfterRead);
    EXPECT_NE(h[0].advice.find("The host last waited on fence 0xf0, signaled by submission 0, "
                               "which does not include submission 1"),
              std::string::npos)
        << h[0].advice;
}

TEST(SyncWaitAdvice, HostWaitOnTheReadersFenceOrdersTheWrite) {
    EXPECT_TRUE(host_rewrite_after_waiting(0xF1).empty());
}

constexpr AddressRange kStaging{0x4000, 0x4100};

// The staging copy into the infos (cmd 0), `barrier` (cmd 1), then the build reading them
// (cmd 2): the one hazard's advice.
template <class Barrier>
std::string advice_after_copy(Barrier barrier) {
    Stream s;
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);
    barrier(s);
    Stream::Build clas;
    clas.src_infos = kInfos;
    s.build(clas);
    s.end();
    EXPECT_EQ(s.hazards().size(), 1u);
    return s.hazards().empty() ? "" : s.hazards()[0].advice;
}

TEST(SyncBarrierAdvice, BarrierWithoutSourceAccessIsNamed) {
    const std::string advice =
        advice_after_copy([](Stream& s) { s.barrier(kCopy, 0, kAsBuild, kIndirect); });
    EXPECT_NE(advice.find("The barrier between them, vkCmdPipelineBarrier2 (queue 0, submit 0, "
                          "cb 0, cmd 1), misses: its srcAccessMask leaves out TRANSFER_WRITE"),
              std::string::npos)
        << advice;
}

TEST(SyncBarrierAdvice, BarrierToAnotherStageIsNamed) {
    const std::string advice =
        advice_after_copy([](Stream& s) { s.barrier(kCopy, kTransferWrite, kCompute, kIndirect); });
    EXPECT_NE(advice.find("its dstStageMask leaves out ACCELERATION_STRUCTURE_BUILD"),
              std::string::npos)
        << advice;
}

TEST(SyncBarrierAdvice, BarrierToAnotherAccessIsNamed) {
    const std::string advice = advice_after_copy(
        [](Stream& s) { s.barrier(kCopy, kTransferWrite, kAsBuild, VK_ACCESS_2_SHADER_READ_BIT); });
    EXPECT_NE(advice.find("its dstAccessMask leaves out INDIRECT_COMMAND_READ"), std::string::npos)
        << advice;
}

TEST(SyncBarrierAdvice, BufferBarrierOverOtherBytesIsNamed) {
    const std::string advice = advice_after_copy(
        [](Stream& s) { s.buffer_barrier(kStaging, kCopy, kTransferWrite, kAsBuild, kIndirect); });
    EXPECT_NE(advice.find("its buffer range [0x4000, 0x4100) leaves these bytes out"),
              std::string::npos)
        << advice;
}

// A barrier before the copy is not between the two; a full one after a narrow one orders them.
TEST(SyncBarrierAdvice, BarrierBeforeThePriorAccessIsNotNamed) {
    Stream s;
    s.submit(0);
    s.barrier(kCopy, 0, kAsBuild, kIndirect);
    s.copy_buffer(kStaging, kInfos);
    Stream::Build clas;
    clas.src_infos = kInfos;
    s.build(clas);
    s.end();
    ASSERT_EQ(s.hazards().size(), 1u);
    EXPECT_TRUE(s.hazards()[0].advice.empty()) << s.hazards()[0].advice;
}

// vkCmdSetEvent2 whose source half misses the copy, and its wait: the set is named.
TEST(SyncBarrierAdvice, EventSetWithoutTheCopyStageIsNamed) {
    const std::string advice = advice_after_copy([](Stream& s) {
        const MemoryBarrier b{kCompute, VK_ACCESS_2_SHADER_WRITE_BIT, kAsBuild, kIndirect};
        const DependencyInfo dep{std::span(&b, 1), {}, 0};
        const uint64_t event = 0xE1;
        s.model.set_event(s.next("vkCmdSetEvent2"), event, dep);
        s.model.wait_events(s.next("vkCmdWaitEvents2"), std::span(&event, 1), dep);
    });
    EXPECT_NE(advice.find(
                  "The event set between them, vkCmdSetEvent2 (queue 0, submit 0, cb 0, cmd 1), "
                  "misses: its srcStageMask leaves out COPY"),
              std::string::npos)
        << advice;
}

// vkCmdSetEvent2 and vkCmdWaitEvents2 sharing a dependency whose source half is right and whose
// destination misses the build: the wait is named, the set (which misses nothing) is not.
TEST(SyncBarrierAdvice, EventWaitWithoutTheBuildStageIsNamed) {
    const std::string advice = advice_after_copy([](Stream& s) {
        const MemoryBarrier b{kCopy, kTransferWrite, kCompute, VK_ACCESS_2_SHADER_READ_BIT};
        const DependencyInfo dep{std::span(&b, 1), {}, 0};
        const uint64_t event = 0xE2;
        s.model.set_event(s.next("vkCmdSetEvent2"), event, dep);
        s.model.wait_events(s.next("vkCmdWaitEvents2"), std::span(&event, 1), dep);
    });
    EXPECT_NE(advice.find(
                  "The event wait between them, vkCmdWaitEvents2 (queue 0, submit 0, cb 0, "
                  "cmd 2), misses: its dstStageMask leaves out ACCELERATION_STRUCTURE_BUILD"),
              std::string::npos)
        << advice;
}

// vkCmdSetEvent (stages only) and a vkCmdWaitEvents whose srcAccessMask leaves the copy's write
// out: the wait carries the access mask, so the wait is named.
TEST(SyncBarrierAdvice, EventWaitV1WithoutSourceAccessIsNamed) {
    const std::string advice = advice_after_copy([](Stream& s) {
        const uint64_t event = 0xE3;
        s.model.set_event_v1(s.next("vkCmdSetEvent"), event, VK_PIPELINE_STAGE_TRANSFER_BIT);
        const MemoryBarrier b =
            memory_barrier_v1(VK_PIPELINE_STAGE_TRANSFER_BIT, 0,
                              VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                              VK_ACCESS_INDIRECT_COMMAND_READ_BIT);
        s.model.wait_events(s.next("vkCmdWaitEvents"), std::span(&event, 1),
                            DependencyInfo{std::span(&b, 1), {}, 0});
    });
    EXPECT_NE(advice.find("The event wait between them, vkCmdWaitEvents (queue 0, submit 0, cb 0, "
                          "cmd 2), misses: its srcAccessMask leaves out TRANSFER_WRITE"),
              std::string::npos)
        << advice;
}

}  // namespace
}  // namespace clastrace::replay::test
