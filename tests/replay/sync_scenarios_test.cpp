// SPDX-License-Identifier: Apache-2.0
// The hazard catalogue: each scenario once with the bug and once correctly synchronized.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "sync_stream.h"

namespace clastrace::replay::test {
namespace {

constexpr AddressRange kInfos{0x1000, 0x1040};
constexpr AddressRange kCount{0x1100, 0x1104};
constexpr AddressRange kScratch{0x2000, 0x3000};
constexpr AddressRange kClas{0x10000, 0x14000};
constexpr AddressRange kAddresses{0x4000, 0x4040};
constexpr AddressRange kSizes{0x4100, 0x4120};
constexpr AddressRange kBlas{0x20000, 0x21000};
constexpr AddressRange kStaging{0x8000, 0x8040};

Stream::Build clas_build(AddressRange scratch = kScratch) {
    Stream::Build b;
    b.src_infos = kInfos;
    b.src_count = kCount;
    b.scratch = scratch;
    b.dst_implicit = kClas;
    b.dst_addresses = kAddresses;
    b.dst_sizes = kSizes;
    return b;
}

Stream::Build blas_build() {
    Stream::Build b;
    b.src_infos = {0x5000, 0x5010};
    b.scratch = {0x6000, 0x6800};
    b.dst_implicit = kBlas;
    b.inputs = {{kClas, "clusterReferences[0]"}};
    return b;
}

const HazardReport& only(const Stream& s) {
    EXPECT_EQ(s.hazards().size(), 1u);
    return s.hazards().front();
}

TEST(SyncScenarios, ScratchReusedByTwoBuildsWithoutBarrier) {
    Stream s;
    s.submit();
    const CommandRef first = s.build(clas_build());
    Stream::Build second = clas_build();
    second.dst_implicit = {0x30000, 0x34000};
    second.dst_addresses = {0x4200, 0x4240};
    second.dst_sizes = {0x4300, 0x4320};
    const CommandRef later = s.build(second);
    s.end();
    // The scratch collides, and so does the shared srcInfos/count only as reads (no hazard).
    ASSERT_EQ(s.hazards().size(), 1u);
    const HazardReport& h = s.hazards()[0];
    EXPECT_EQ(h.hazard, HazardClass::kWriteAfterWrite);
    EXPECT_EQ(h.prior.field, "scratchData");
    EXPECT_EQ(h.later.field, "scratchData");
    EXPECT_EQ(h.prior.command.command, first.command);
    EXPECT_EQ(h.later.command.command, later.command);
    EXPECT_EQ(h.overlap, kScratch);
    EXPECT_EQ(h.fix.kind, FixKind::kPipelineBarrier);
    EXPECT_EQ(h.fix.src_stages, kAsBuild);
    EXPECT_EQ(h.fix.src_access, kAsWrite);
    EXPECT_EQ(h.fix.dst_stages, kAsBuild);
    EXPECT_EQ(h.fix.dst_access, kAsRead | kAsWrite);
}

TEST(SyncScenarios, ScratchReusedWithBarrierIsClean) {
    Stream s;
    s.submit();
    s.build(clas_build());
    s.barrier(kAsBuild, kAsWrite, kAsBuild, kAsRead | kAsWrite);
    Stream::Build second = clas_build();
    second.dst_implicit = {0x30000, 0x34000};
    s.build(second);
    s.end();
    EXPECT_TRUE(s.hazards().empty()) << s.hazards().front().format();
}

TEST(SyncScenarios, ScratchBarrierMissingReadAccessStillHazard) {
    // The spec demands ACCELERATION_STRUCTURE_READ|WRITE for scratch; WRITE alone leaves the read unsynchronized.
    Stream s;
    s.submit();
    s.build(clas_build());
    s.barrier(kAsBuild, kAsWrite, kAsBuild, kAsWrite);
    Stream::Build second = clas_build();
    second.dst_implicit = {0x30000, 0x34000};
    s.build(second);
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.hazard, HazardClass::kWriteAfterWrite);
    EXPECT_EQ(h.later.field, "scratchData");
}

TEST(SyncScenarios, ClasReadByBlasBuildWithoutBarrier) {
    Stream s;
    s.submit();
    const CommandRef clas = s.build(clas_build());
    const CommandRef blas = s.build(blas_build());
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.prior.field, "dstImplicitData");
    EXPECT_EQ(h.later.field, "clusterReferences[0]");
    EXPECT_EQ(h.prior.command.command, clas.command);
    EXPECT_EQ(h.later.command.command, blas.command);
    EXPECT_EQ(h.overlap, kClas);
    EXPECT_EQ(h.fix.dst_access, kAsRead);
}

TEST(SyncScenarios, ClasBarrierWithShaderReadInsteadOfAccelerationStructureRead) {
    Stream s;
    s.submit();
    s.build(clas_build());
    s.barrier(kAsBuild, kAsWrite, kAsBuild, VK_ACCESS_2_SHADER_READ_BIT);
    s.build(blas_build());
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.later.field, "clusterReferences[0]");
}

TEST(SyncScenarios, ClasBarrierCorrect) {
    Stream s;
    s.submit();
    s.build(clas_build());
    s.barrier(kAsBuild, kAsWrite, kAsBuild, kAsRead);
    s.build(blas_build());
    s.end();
    EXPECT_TRUE(s.hazards().empty());
}

TEST(SyncScenarios, TemplateInstantiateAcrossCommandBuffersNeedsBarrier) {
    // A template built in command buffer 0 and instantiated in command buffer 1 of the same submission:
    // command-buffer boundaries order nothing.
    Stream s;
    s.submit();
    Stream::Build tmpl = clas_build();
    s.build(tmpl);
    s.next_command_buffer();
    Stream::Build inst;
    inst.src_infos = {0x7000, 0x7020};
    inst.scratch = {0x9000, 0x9100};
    inst.dst_implicit = {0x40000, 0x41000};
    inst.inputs = {{kClas, "clusterTemplateAddress[0]"}};
    s.build(inst);
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.prior.command.command_buffer, 0u);
    EXPECT_EQ(h.later.command.command_buffer, 1u);
    EXPECT_EQ(h.later.field, "clusterTemplateAddress[0]");
}

TEST(SyncScenarios, SrcInfosCopiedThenReadWithShaderReadBarrier) {
    Stream s;
    s.submit();
    s.copy_buffer(kStaging, kInfos);
    s.barrier(VK_PIPELINE_STAGE_2_TRANSFER_BIT, kTransferWrite, kAsBuild,
              VK_ACCESS_2_SHADER_READ_BIT);
    s.build(clas_build());
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.prior.command.name, std::string("vkCmdCopyBuffer"));
    EXPECT_EQ(h.prior.field, "dstBuffer");
    EXPECT_EQ(h.later.field, "srcInfosArray");
    EXPECT_EQ(h.fix.src_stages, kCopy);
    EXPECT_EQ(h.fix.src_access, kTransferWrite);
    EXPECT_EQ(h.fix.dst_stages, kAsBuild);
    EXPECT_EQ(h.fix.dst_access, kIndirect);
    const std::string text = h.format();
    EXPECT_NE(text.find("SYNC-HAZARD-READ-AFTER-WRITE"), std::string::npos) << text;
    EXPECT_NE(text.find("srcInfosArray [0x1000, 0x1040)"), std::string::npos) << text;
    EXPECT_NE(text.find("ACCELERATION_STRUCTURE_BUILD / INDIRECT_COMMAND_READ"), std::string::npos)
        << text;
    EXPECT_NE(text.find("COPY / TRANSFER_WRITE"), std::string::npos) << text;
    EXPECT_NE(text.find("srcStageMask=VK_PIPELINE_STAGE_2_COPY_BIT, "
                        "srcAccessMask=VK_ACCESS_2_TRANSFER_WRITE_BIT, "
                        "dstStageMask=VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, "
                        "dstAccessMask=VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT"),
              std::string::npos)
        << text;
}

TEST(SyncScenarios, SrcInfosCopiedThenReadWithIndirectBarrierIsClean) {
    Stream s;
    s.submit();
    s.copy_buffer(kStaging, kInfos);
    s.copy_buffer({0x8100, 0x8104}, kCount);
    s.barrier(VK_PIPELINE_STAGE_2_TRANSFER_BIT, kTransferWrite, kAsBuild, kIndirect);
    s.build(clas_build());
    s.end();
    EXPECT_TRUE(s.hazards().empty());
}

TEST(SyncScenarios, CountFilledWithoutBarrier) {
    Stream s;
    s.submit();
    s.fill(kCount);
    s.build(clas_build());
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.later.field, "srcInfosCount");
    EXPECT_EQ(h.prior.command.name, std::string("vkCmdFillBuffer"));
    EXPECT_EQ(h.fix.src_stages, kClear);
}

TEST(SyncScenarios, FillNeedsClearStageNotCopyStage) {
    // vkCmdFillBuffer runs at CLEAR: a barrier from COPY does not cover it, ALL_TRANSFER does.
    Stream bad;
    bad.submit();
    bad.fill(kCount);
    bad.barrier(kCopy, kTransferWrite, kAsBuild, kIndirect);
    bad.build(clas_build());
    bad.end();
    EXPECT_EQ(bad.hazards().size(), 1u);

    Stream good;
    good.submit();
    good.fill(kCount);
    good.barrier(VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT, kTransferWrite, kAsBuild, kIndirect);
    good.build(clas_build());
    good.end();
    EXPECT_TRUE(good.hazards().empty());
}

TEST(SyncScenarios, UpdateBufferThenVertexDataRead) {
    Stream s;
    s.submit();
    s.fill({0xA000, 0xA100}, "vkCmdUpdateBuffer");
    Stream::Build b = clas_build();
    b.inputs = {{{0xA000, 0xA100}, "srcInfosArray[0].vertexBuffer"}};
    s.build(b);
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.prior.command.name, std::string("vkCmdUpdateBuffer"));
    EXPECT_EQ(h.later.field, "srcInfosArray[0].vertexBuffer");
    EXPECT_EQ(h.fix.dst_access, kAsRead);
}

TEST(SyncScenarios, ShaderWrittenInfosNeedIndirectRead) {
    Stream s;
    s.submit();
    s.model.record_access(s.next("vkCmdDispatch"),
                          Stream::write(kInfos.begin, kInfos.end, kCompute,
                                        VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, "binding 0"));
    s.barrier(kCompute, VK_ACCESS_2_SHADER_WRITE_BIT, kAsBuild, VK_ACCESS_2_SHADER_READ_BIT);
    s.build(clas_build());
    s.barrier(kCompute, VK_ACCESS_2_SHADER_WRITE_BIT, kAsBuild, kIndirect);
    s.build(clas_build({0x50000, 0x51000}));
    s.end();
    // Only the first build reads srcInfos too early; the second one is covered by the second barrier.
    // (Its outputs collide with the first build's: those are separate WAW findings.)
    int raw = 0;
    for (const HazardReport& h : s.hazards())
        if (h.hazard == HazardClass::kReadAfterWrite) {
            ++raw;
            EXPECT_EQ(h.later.command.command, 2u);
            EXPECT_EQ(h.prior.field, "binding 0");
        }
    EXPECT_EQ(raw, 1);
}

TEST(SyncScenarios, OutputOverwrittenWithoutBarrier) {
    Stream s;
    s.submit();
    s.build(clas_build());
    s.copy_buffer(kStaging, kAddresses);
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.hazard, HazardClass::kWriteAfterWrite);
    EXPECT_EQ(h.prior.field, "dstAddressesArray");
    EXPECT_EQ(h.later.field, "dstBuffer");
    EXPECT_EQ(h.fix.src_access, kAsWrite);
    EXPECT_EQ(h.fix.dst_access, kTransferWrite);
}

TEST(SyncScenarios, OutputReadByCopyWithoutAndWithBarrier) {
    Stream bad;
    bad.submit();
    bad.build(clas_build());
    bad.copy_buffer(kSizes, {0xB000, 0xB020});
    bad.end();
    const HazardReport& h = only(bad);
    EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.prior.field, "dstSizesArray");
    EXPECT_EQ(h.later.field, "srcBuffer");

    Stream good;
    good.submit();
    good.build(clas_build());
    good.barrier(kAsBuild, kAsWrite, kCopy, kTransferRead);
    good.copy_buffer(kSizes, {0xB000, 0xB020});
    good.end();
    EXPECT_TRUE(good.hazards().empty());
}

TEST(SyncScenarios, WriteAfterReadNeedsOnlyExecutionDependency) {
    Stream bad;
    bad.submit();
    bad.build(clas_build());
    bad.copy_buffer(kStaging, kInfos);
    bad.end();
    const HazardReport& h = only(bad);
    EXPECT_EQ(h.hazard, HazardClass::kWriteAfterRead);
    EXPECT_EQ(h.prior.field, "srcInfosArray");
    EXPECT_EQ(h.fix.src_access, 0u);
    EXPECT_EQ(h.fix.dst_access, 0u);
    EXPECT_EQ(h.fix.src_stages, kAsBuild);
    EXPECT_EQ(h.fix.dst_stages, kCopy);

    Stream good;
    good.submit();
    good.build(clas_build());
    good.barrier(kAsBuild, 0, kCopy, 0);
    good.copy_buffer(kStaging, kInfos);
    good.end();
    EXPECT_TRUE(good.hazards().empty());
}

TEST(SyncScenarios, ExecutionOnlyBarrierDoesNotFixReadAfterWrite) {
    Stream s;
    s.submit();
    s.copy_buffer(kStaging, kInfos);
    s.barrier(kCopy, 0, kAsBuild, 0);
    s.build(clas_build());
    s.end();
    EXPECT_EQ(only(s).hazard, HazardClass::kReadAfterWrite);
}

TEST(SyncScenarios, EventSetAfterWriteAndWaitedOrdersIt) {
    Stream s;
    s.submit();
    s.copy_buffer(kStaging, kInfos);
    const MemoryBarrier b{kCopy, kTransferWrite, kAsBuild, kIndirect};
    const DependencyInfo dep{std::span(&b, 1), {}, 0};
    s.model.set_event(s.next("vkCmdSetEvent2"), 77, dep);
    const uint64_t events[] = {77};
    s.model.wait_events(s.next("vkCmdWaitEvents2"), events, dep);
    s.build(clas_build());
    s.end();
    EXPECT_TRUE(s.hazards().empty());
}

TEST(SyncScenarios, EventSetBeforeWriteDoesNotOrderIt) {
    Stream s;
    s.submit();
    const MemoryBarrier b{kCopy, kTransferWrite, kAsBuild, kIndirect};
    const DependencyInfo dep{std::span(&b, 1), {}, 0};
    s.model.set_event(s.next("vkCmdSetEvent2"), 77, dep);
    s.copy_buffer(kStaging, kInfos);
    const uint64_t events[] = {77};
    s.model.wait_events(s.next("vkCmdWaitEvents2"), events, dep);
    s.build(clas_build());
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.later.field, "srcInfosArray");
}

TEST(SyncScenarios, EventResetAndSetAgainStartsAfresh) {
    // Set, reset, write, set again, wait: the second set's first scope contains the write.
    Stream s;
    s.submit();
    const MemoryBarrier b{kCopy, kTransferWrite, kAsBuild, kIndirect};
    const DependencyInfo dep{std::span(&b, 1), {}, 0};
    s.model.set_event(s.next("vkCmdSetEvent2"), 5, dep);
    s.model.reset_event(s.next("vkCmdResetEvent2"), 5);
    s.copy_buffer(kStaging, kInfos);
    s.model.set_event(s.next("vkCmdSetEvent2"), 5, dep);
    const uint64_t events[] = {5};
    s.model.wait_events(s.next("vkCmdWaitEvents2"), events, dep);
    s.build(clas_build());
    s.end();
    EXPECT_TRUE(s.hazards().empty());
}

TEST(SyncScenarios, EventSetAgainWithNarrowerScopeDropsEarlierMembers) {
    // The copy was in the first set's scope; the event is set again from COMPUTE only, and the wait
    // therefore orders nothing of the copy.
    Stream s;
    s.submit();
    s.copy_buffer(kStaging, kInfos);
    const MemoryBarrier from_copy{kCopy, kTransferWrite, kAsBuild, kIndirect};
    const MemoryBarrier from_compute{kCompute, VK_ACCESS_2_SHADER_WRITE_BIT, kAsBuild, kIndirect};
    s.model.set_event(s.next("vkCmdSetEvent2"), 5, DependencyInfo{std::span(&from_copy, 1), {}, 0});
    s.model.set_event(s.next("vkCmdSetEvent2"), 5,
                      DependencyInfo{std::span(&from_compute, 1), {}, 0});
    const uint64_t events[] = {5};
    s.model.wait_events(s.next("vkCmdWaitEvents2"), events,
                        DependencyInfo{std::span(&from_compute, 1), {}, 0});
    s.build(clas_build());
    s.end();
    EXPECT_EQ(s.hazards().size(), 1u);
}

TEST(SyncScenarios, EventsV1UseTheWaitsAccessMasks) {
    Stream good;
    good.submit();
    good.copy_buffer(kStaging, kInfos);
    good.model.set_event_v1(good.next("vkCmdSetEvent"), 9, VK_PIPELINE_STAGE_TRANSFER_BIT);
    const MemoryBarrier wait =
        memory_barrier_v1(VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                          VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                          VK_ACCESS_INDIRECT_COMMAND_READ_BIT);
    const uint64_t events[] = {9};
    good.model.wait_events(good.next("vkCmdWaitEvents"), events,
                           DependencyInfo{std::span(&wait, 1), {}, 0});
    good.build(clas_build());
    good.end();
    EXPECT_TRUE(good.hazards().empty());

    Stream bad;  // the wait's source access does not include the copy's TRANSFER_WRITE
    bad.submit();
    bad.copy_buffer(kStaging, kInfos);
    bad.model.set_event_v1(bad.next("vkCmdSetEvent"), 9, VK_PIPELINE_STAGE_TRANSFER_BIT);
    const MemoryBarrier wrong =
        memory_barrier_v1(VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
                          VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                          VK_ACCESS_INDIRECT_COMMAND_READ_BIT);
    bad.model.wait_events(bad.next("vkCmdWaitEvents"), events,
                          DependencyInfo{std::span(&wrong, 1), {}, 0});
    bad.build(clas_build());
    bad.end();
    EXPECT_EQ(bad.hazards().size(), 1u);
}

TEST(SyncScenarios, TwoQueuesWithoutSemaphore) {
    Stream s;
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);
    s.end();
    s.submit(1);
    s.build(clas_build());
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.prior.queue, 0u);
    EXPECT_EQ(h.later.queue, 1u);
    EXPECT_EQ(h.fix.kind, FixKind::kSemaphore);
    EXPECT_NE(h.format().find("semaphore"), std::string::npos);
}

TEST(SyncScenarios, TwoQueuesWithSemaphore) {
    Stream s;
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);
    s.end({{0x5E, 0}});
    s.submit(1, {{0x5E, 0, kAsBuild}});
    s.build(clas_build());
    s.end();
    EXPECT_TRUE(s.hazards().empty());
}

TEST(SyncScenarios, CrossQueueWriteAfterReadNeedsSemaphoreBack) {
    auto run = [](bool signal_back) {
        Stream s;
        s.submit(0);
        s.build(clas_build());  // reads srcInfos on the compute queue
        s.end(signal_back ? std::initializer_list<SemaphoreSignal>{{9, 0}}
                          : std::initializer_list<SemaphoreSignal>{});
        if (signal_back)
            s.submit(1, {{9, 0, kCopy}});
        else
            s.submit(1);
        s.copy_buffer(kStaging, kInfos);  // the transfer queue overwrites them
        s.end();
        return s.hazards();
    };
    const auto bad = run(false);
    ASSERT_EQ(bad.size(), 1u);
    EXPECT_EQ(bad[0].hazard, HazardClass::kWriteAfterRead);
    EXPECT_EQ(bad[0].fix.kind, FixKind::kSemaphore);
    EXPECT_EQ(bad[0].prior.queue, 0u);
    EXPECT_EQ(bad[0].later.queue, 1u);
    EXPECT_TRUE(run(true).empty());
}

TEST(SyncScenarios, SemaphoreWaitStageMustCoverTheReader) {
    Stream bad;  // waits at COMPUTE only: the build at ACCELERATION_STRUCTURE_BUILD is not ordered
    bad.submit(0);
    bad.copy_buffer(kStaging, kInfos);
    bad.end({{0x5E, 0}});
    bad.submit(1, {{0x5E, 0, kCompute}});
    bad.build(clas_build());
    bad.end();
    EXPECT_EQ(only(bad).fix.kind, FixKind::kSemaphore);

    Stream
        chained;  // a barrier on the waiting queue chains COMPUTE to the build, with the right access
    chained.submit(0);
    chained.copy_buffer(kStaging, kInfos);
    chained.end({{0x5E, 0}});
    chained.submit(1, {{0x5E, 0, kCompute}});
    chained.barrier(kCompute, 0, kAsBuild, kIndirect);
    chained.build(clas_build());
    chained.end();
    EXPECT_TRUE(chained.hazards().empty());
}

TEST(SyncScenarios, SemaphoreOrdersOnlyWorkBeforeTheSignal) {
    Stream s;
    s.submit(0);
    s.end({{0x5E, 0}});  // signals before the copy is submitted
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);
    s.end();
    s.submit(1, {{0x5E, 0, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT}});
    s.build(clas_build());
    s.end();
    EXPECT_EQ(only(s).fix.kind, FixKind::kSemaphore);
}

TEST(SyncScenarios, SemaphoresChainAcrossThreeQueues) {
    Stream s;
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);
    s.end({{1, 0}});
    s.submit(1, {{1, 0, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT}});
    s.end({{2, 0}});
    s.submit(2, {{2, 0, kAsBuild}});
    s.build(clas_build());
    s.end();
    EXPECT_TRUE(s.hazards().empty());
}

TEST(SyncScenarios, TimelineSemaphoreValues) {
    Stream good;
    good.submit(0);
    good.copy_buffer(kStaging, kInfos);
    good.end({{0x71, 5}});
    good.submit(1, {{0x71, 3, kAsBuild}});  // 5 >= 3: satisfied by the signal of 5
    good.build(clas_build());
    good.end();
    EXPECT_TRUE(good.hazards().empty());
    EXPECT_EQ(good.model.stats().unsatisfied_waits, 0u);

    Stream bad;
    bad.submit(0);
    bad.copy_buffer(kStaging, kInfos);
    bad.end({{0x71, 5}});
    bad.submit(1, {{0x71, 7, kAsBuild}});  // nobody signalled 7 yet
    bad.build(clas_build());
    bad.end();
    EXPECT_EQ(bad.hazards().size(), 1u);
    EXPECT_EQ(bad.model.stats().unsatisfied_waits, 1u);
}

TEST(SyncScenarios, HostSignalledTimelineSatisfiesWaitButOrdersNoDeviceWork) {
    Stream s;
    s.submit(0);
    s.copy_buffer(kStaging, kInfos);
    s.end();
    s.model.host_signal_semaphore(0x72, 1);
    s.submit(1, {{0x72, 1, kAsBuild}});
    s.build(clas_build());
    s.end();
    EXPECT_EQ(s.model.stats().unsatisfied_waits, 0u);
    ASSERT_EQ(s.hazards().size(), 1u);  // the copy on queue 0 is still unordered
    EXPECT_EQ(s.hazards()[0].fix.kind, FixKind::kSemaphore);
}

TEST(SyncScenarios, HostWriteBeforeSubmitIsVisible) {
    Stream s;
    s.model.host_access({0, 0, 0, 0, "memcpy to mapped srcInfos"},
                        Stream::write(kInfos.begin, kInfos.end, 0, 0, "srcInfosArray"));
    s.submit();
    s.build(clas_build());
    s.end();
    EXPECT_TRUE(s.hazards().empty());
}

TEST(SyncScenarios, HostWriteWhileSubmissionInFlight) {
    Stream bad;
    bad.submit();
    bad.build(clas_build());
    bad.end({}, 0xF);
    bad.model.host_access({1, 0, 0, 0, "memcpy to mapped srcInfos"},
                          Stream::write(kInfos.begin, kInfos.end, 0, 0, "srcInfosArray"));
    const HazardReport& h = only(bad);
    EXPECT_EQ(h.hazard, HazardClass::kWriteAfterRead);
    EXPECT_EQ(h.later.queue, kHostQueue);
    EXPECT_EQ(h.fix.kind, FixKind::kHostWait);

    Stream good;
    good.submit();
    good.build(clas_build());
    good.end({}, 0xF);
    good.model.wait_for_fence(0xF);
    good.model.host_access({1, 0, 0, 0, "memcpy to mapped srcInfos"},
                           Stream::write(kInfos.begin, kInfos.end, 0, 0, "srcInfosArray"));
    EXPECT_TRUE(good.hazards().empty());
}

TEST(SyncScenarios, HostReadOfSizesNeedsHostBarrierAndFence) {
    Stream no_barrier;
    no_barrier.submit();
    no_barrier.build(clas_build());
    no_barrier.end({}, 0xF);
    no_barrier.model.wait_for_fence(0xF);
    no_barrier.model.host_access({1, 0, 0, 0, "read mapped sizes"},
                                 Stream::read(kSizes.begin, kSizes.end, 0, 0, "dstSizesArray"));
    const HazardReport& h = only(no_barrier);
    EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.fix.kind, FixKind::kHostWaitAndBarrier);
    EXPECT_EQ(h.fix.dst_stages, VK_PIPELINE_STAGE_2_HOST_BIT);
    EXPECT_EQ(h.fix.dst_access, VK_ACCESS_2_HOST_READ_BIT);

    Stream good;
    good.submit();
    good.build(clas_build());
    good.barrier(kAsBuild, kAsWrite, VK_PIPELINE_STAGE_2_HOST_BIT, VK_ACCESS_2_HOST_READ_BIT);
    good.end({}, 0xF);
    good.model.wait_for_fence(0xF);
    good.model.host_access({1, 0, 0, 0, "read mapped sizes"},
                           Stream::read(kSizes.begin, kSizes.end, 0, 0, "dstSizesArray"));
    EXPECT_TRUE(good.hazards().empty());

    Stream no_wait;
    no_wait.submit();
    no_wait.build(clas_build());
    no_wait.barrier(kAsBuild, kAsWrite, VK_PIPELINE_STAGE_2_HOST_BIT, VK_ACCESS_2_HOST_READ_BIT);
    no_wait.end({}, 0xF);
    no_wait.model.host_access({1, 0, 0, 0, "read mapped sizes"},
                              Stream::read(kSizes.begin, kSizes.end, 0, 0, "dstSizesArray"));
    EXPECT_EQ(only(no_wait).fix.kind, FixKind::kHostWaitAndBarrier);
}

TEST(SyncScenarios, BarrierChainsCompose) {
    Stream
        good;  // COPY -> COMPUTE -> RAY_TRACING -> AS_BUILD, availability in the first, visibility in the last
    good.submit();
    good.copy_buffer(kStaging, kInfos);
    good.barrier(kCopy, kTransferWrite, kCompute, 0);
    good.barrier(kCompute, 0, VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR, 0);
    good.barrier(VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR, 0, kAsBuild, kIndirect);
    good.build(clas_build());
    good.end();
    EXPECT_TRUE(good.hazards().empty());

    Stream broken;  // the middle link starts at FRAGMENT_SHADER, which COMPUTE never reaches
    broken.submit();
    broken.copy_buffer(kStaging, kInfos);
    broken.barrier(kCopy, kTransferWrite, kCompute, 0);
    broken.barrier(VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT, 0,
                   VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR, 0);
    broken.barrier(VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR, 0, kAsBuild, kIndirect);
    broken.build(clas_build());
    broken.end();
    EXPECT_EQ(broken.hazards().size(), 1u);

    Stream
        never_available;  // exec chain complete but no barrier's source access includes the write
    never_available.submit();
    never_available.copy_buffer(kStaging, kInfos);
    never_available.barrier(kCopy, 0, kCompute, 0);
    never_available.barrier(kCompute, VK_ACCESS_2_SHADER_WRITE_BIT, kAsBuild, kIndirect);
    never_available.build(clas_build());
    never_available.end();
    EXPECT_EQ(never_available.hazards().size(), 1u);
}

TEST(SyncScenarios, LogicallyLaterStagesJoinTheChain) {
    // DRAW_INDIRECT as destination covers every stage after it, COMPUTE included.
    Stream s;
    s.submit();
    s.copy_buffer(kStaging, kInfos);
    s.barrier(kCopy, kTransferWrite, VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT, 0);
    s.barrier(kCompute, 0, kAsBuild, kIndirect);
    s.build(clas_build());
    s.end();
    EXPECT_TRUE(s.hazards().empty());
}

TEST(SyncScenarios, BarriersOfOneCommandDoNotChainEachOther) {
    Stream s;
    s.submit();
    s.copy_buffer(kStaging, kInfos);
    const MemoryBarrier two[] = {{kCopy, kTransferWrite, kCompute, 0},
                                 {kCompute, 0, kAsBuild, kIndirect}};
    s.model.pipeline_barrier(s.next("vkCmdPipelineBarrier2"), DependencyInfo{two, {}, 0});
    s.build(clas_build());
    s.end();
    EXPECT_EQ(s.hazards().size(), 1u);
}

TEST(SyncScenarios, BufferBarrierCoversOnlyItsRange) {
    Stream other;  // barrier on unrelated memory
    other.submit();
    other.copy_buffer(kStaging, kInfos);
    other.buffer_barrier({0x9000, 0x9100}, kCopy, kTransferWrite, kAsBuild, kIndirect);
    other.build(clas_build());
    other.end();
    EXPECT_EQ(other.hazards().size(), 1u);

    Stream exact;
    exact.submit();
    exact.copy_buffer(kStaging, kInfos);
    exact.buffer_barrier(kInfos, kCopy, kTransferWrite, kAsBuild, kIndirect);
    exact.build(clas_build());
    exact.end();
    EXPECT_TRUE(exact.hazards().empty());

    Stream half;  // covers the first half: the hazard is exactly the second half
    half.submit();
    half.copy_buffer(kStaging, kInfos);
    half.buffer_barrier({0x1000, 0x1020}, kCopy, kTransferWrite, kAsBuild, kIndirect);
    half.build(clas_build());
    half.end();
    const HazardReport& h = only(half);
    EXPECT_EQ(h.overlap, (AddressRange{0x1020, 0x1040}));

    Stream global;
    global.submit();
    global.copy_buffer(kStaging, kInfos);
    global.barrier(kCopy, kTransferWrite, kAsBuild, kIndirect);
    global.build(clas_build());
    global.end();
    EXPECT_TRUE(global.hazards().empty());
}

TEST(SyncScenarios, V1BarrierMasks) {
    Stream good;
    good.submit();
    good.copy_buffer(kStaging, kInfos);
    const MemoryBarrier b =
        memory_barrier_v1(VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                          VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                          VK_ACCESS_INDIRECT_COMMAND_READ_BIT);
    good.model.pipeline_barrier(good.next("vkCmdPipelineBarrier"),
                                DependencyInfo{std::span(&b, 1), {}, 0});
    good.build(clas_build());
    good.end();
    EXPECT_TRUE(good.hazards().empty());

    // BOTTOM_OF_PIPE -> TOP_OF_PIPE without memory barriers: every stage ordered, nothing made visible.
    Stream exec_only;
    exec_only.submit();
    exec_only.build(clas_build());
    const MemoryBarrier e = execution_barrier_v1(VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT,
                                                 VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT);
    exec_only.model.pipeline_barrier(exec_only.next("vkCmdPipelineBarrier"),
                                     DependencyInfo{std::span(&e, 1), {}, 0});
    exec_only.copy_buffer(kStaging, kInfos);          // WAR on srcInfos: ordered
    exec_only.copy_buffer(kSizes, {0xB000, 0xB020});  // RAW on dstSizesArray: not visible
    exec_only.end();
    const HazardReport& h = only(exec_only);
    EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.prior.field, "dstSizesArray");

    // v1 TOP_OF_PIPE as source is an empty first scope.
    Stream top;
    top.submit();
    top.build(clas_build());
    const MemoryBarrier t =
        execution_barrier_v1(VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT);
    top.model.pipeline_barrier(top.next("vkCmdPipelineBarrier"),
                               DependencyInfo{std::span(&t, 1), {}, 0});
    top.copy_buffer(kStaging, kInfos);
    top.end();
    EXPECT_EQ(only(top).hazard, HazardClass::kWriteAfterRead);
}

TEST(SyncScenarios, PartialOverlapReportsExactRegion) {
    Stream s;
    s.submit();
    s.model.record_access(s.next("vkCmdDispatch"),
                          Stream::write(0x100, 0x140, kCompute,
                                        VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, "binding 1"));
    s.model.record_access(s.next(kBuildName), Stream::read(0x120, 0x180, kAsBuild, kAsRead,
                                                           "srcInfosArray[0].indexBuffer"));
    s.end();
    const HazardReport& h = only(s);
    EXPECT_EQ(h.overlap, (AddressRange{0x120, 0x140}));
    EXPECT_EQ(h.prior.range, (AddressRange{0x100, 0x140}));
    EXPECT_EQ(h.later.range, (AddressRange{0x120, 0x180}));
}

TEST(SyncScenarios, MoveWithOverlappingSourceAndDestination) {
    Stream bad;
    bad.submit();
    const CommandRef c = bad.next(kBuildName);
    bad.model.record_copy(c,
                          Stream::read(0x1000, 0x1400, kAsBuild, kAsRead,
                                       "srcInfosArray[3].srcAccelerationStructure"),
                          Stream::write(0x1200, 0x1600, kAsBuild, kAsWrite,
                                        "dstAddressesArray[3]"));
    bad.end();
    const HazardReport& h = only(bad);
    EXPECT_EQ(h.hazard, HazardClass::kMoveOverlap);
    EXPECT_EQ(h.overlap, (AddressRange{0x1200, 0x1400}));
    EXPECT_EQ(h.fix.kind, FixKind::kDisjointRanges);
    EXPECT_NE(h.format().find("SYNC-HAZARD-MOVE-OVERLAP"), std::string::npos);

    Stream good;
    good.submit();
    good.model.record_copy(good.next(kBuildName),
                           Stream::read(0x1000, 0x1400, kAsBuild, kAsRead,
                                        "srcInfosArray[3].srcAccelerationStructure"),
                           Stream::write(0x1400, 0x1800, kAsBuild, kAsWrite,
                                         "dstAddressesArray[3]"));
    good.end();
    EXPECT_TRUE(good.hazards().empty());
}

TEST(SyncScenarios, DeserializeIntoMemoryStillInUse) {
    auto run = [](bool with_barrier) {
        Stream s;
        s.submit();
        s.build(blas_build());  // reads the CLAS memory
        if (with_barrier)
            s.barrier(kAsBuild, 0, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR, 0);
        s.model.record_deserialize(
            s.next("vkCmdCopyMemoryToAccelerationStructureKHR"),
            Stream::read(0x90000, 0x94000, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR,
                         kTransferRead, "pInfo->src"),
            Stream::write(kClas.begin, kClas.end,
                          VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR, kAsWrite,
                          "pInfo->dst"));
        s.end();
        return s.hazards();
    };
    const auto bad = run(false);
    ASSERT_EQ(bad.size(), 1u);
    EXPECT_EQ(bad[0].hazard, HazardClass::kDeserializeInUse);
    EXPECT_EQ(bad[0].prior.field, "clusterReferences[0]");
    EXPECT_EQ(bad[0].later.field, "pInfo->dst");
    EXPECT_TRUE(run(true).empty());
}

TEST(SyncScenarios, SameCommandDoesNotConflictWithItself) {
    Stream s;
    s.submit();
    const CommandRef c = s.next(kBuildName);
    s.model.record_access(c, Stream::read(0x100, 0x200, kAsBuild, kAsRead, "scratchData"));
    s.model.record_access(c,
                          Stream::write(0x100, 0x200, kAsBuild, kAsRead | kAsWrite, "scratchData"));
    s.end();
    EXPECT_TRUE(s.hazards().empty());
}

TEST(SyncScenarios, SubmissionsOnOneQueueStillNeedBarriers) {
    Stream bad;
    bad.submit();
    bad.copy_buffer(kStaging, kInfos);
    bad.end();
    bad.submit();
    bad.build(clas_build());
    bad.end();
    const HazardReport& h = only(bad);
    EXPECT_EQ(h.prior.command.submission, 0u);
    EXPECT_EQ(h.later.command.submission, 1u);
    EXPECT_EQ(h.fix.kind, FixKind::kPipelineBarrier);

    Stream good;  // a barrier in the next submission covers earlier submissions on the queue
    good.submit();
    good.copy_buffer(kStaging, kInfos);
    good.end();
    good.submit();
    good.barrier(kCopy, kTransferWrite, kAsBuild, kIndirect);
    good.build(clas_build());
    good.end();
    EXPECT_TRUE(good.hazards().empty());
}

TEST(SyncScenarios, DuplicatesAreCountedNotRepeatedAndCapHolds) {
    SyncOptions options;
    options.max_reports = 3;
    Stream s(options);
    s.submit();
    const CommandRef w = s.next("vkCmdDispatch");
    s.model.record_access(w, Stream::write(0, 0x1000, kCompute,
                                           VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, "binding 0"));
    const CommandRef r = s.next(kBuildName);
    // The same read, split into pieces by the same command: one finding.
    for (uint64_t a = 0; a < 0x1000; a += 0x100)
        s.model.record_access(r, Stream::read(a, a + 0x100, kAsBuild, kAsRead, "vertexBuffer"));
    // Ten distinct readers: 3 kept, the rest counted over the cap.
    for (int i = 0; i < 10; ++i)
        s.model.record_access(s.next(kBuildName),
                              Stream::read(0, 0x10, kAsBuild, kAsRead, "vertexBuffer"));
    s.end();
    EXPECT_EQ(s.hazards().size(), 3u);
    EXPECT_EQ(s.model.stats().duplicate_hazards, 15u);
    EXPECT_EQ(s.model.stats().hazards_over_cap, 8u);
    EXPECT_EQ(s.hazards()[0].later.command.command, r.command);
    EXPECT_EQ(s.hazards()[0].overlap, (AddressRange{0, 0x100}));
}

TEST(SyncScenarios, HostWaitsRetireFinishedAccesses) {
    Stream s;
    for (int frame = 0; frame < 50; ++frame) {
        s.submit();
        for (uint64_t i = 0; i < 20; ++i) {
            Stream::Build b = clas_build({0x100000 + i * 0x1000, 0x100000 + i * 0x1000 + 0x800});
            b.dst_implicit = {0x200000 + i * 0x1000, 0x200000 + i * 0x1000 + 0x1000};
            b.dst_addresses = {0x300000 + i * 0x40, 0x300000 + i * 0x40 + 0x40};
            b.dst_sizes = {};
            s.build(b);
        }
        s.barrier(kAsBuild, kAsWrite, VK_PIPELINE_STAGE_2_HOST_BIT, VK_ACCESS_2_HOST_READ_BIT);
        s.end({}, 0xF);
        s.model.wait_for_fence(0xF);
        // Everything finished: fence waits sweep it out once it has doubled, so what is
        // tracked stays within the sweep floor however many frames go by.
        EXPECT_LE(s.model.stats().segments, 1024u) << "frame " << frame;
    }
    EXPECT_TRUE(s.hazards().empty());
    EXPECT_GT(s.model.stats().peak_segments, 0u);
    // An idle wait always sweeps: nothing left to track.
    s.model.device_wait_idle();
    EXPECT_EQ(s.model.stats().segments, 0u);
}

// Fence waits sweep lazily, but a long stream of frames over new addresses each frame still
// keeps only about twice what one sweep leaves.
TEST(SyncScenarios, FenceWaitsKeepSegmentsBoundedOverNewAddresses) {
    Stream s;
    uint64_t peak = 0;
    for (uint64_t frame = 0; frame < 400; ++frame) {
        s.submit();
        for (uint64_t i = 0; i < 20; ++i) {
            const uint64_t base = 0x100000000ull + frame * 0x100000 + i * 0x1000;
            Stream::Build b = clas_build({base, base + 0x800});
            b.dst_implicit = {base + 0x800, base + 0x1000};
            b.dst_addresses = {};
            b.dst_sizes = {};
            s.build(b);
        }
        s.barrier(kAsBuild, kAsWrite, VK_PIPELINE_STAGE_2_HOST_BIT, VK_ACCESS_2_HOST_READ_BIT);
        s.end({}, 0xF);
        s.model.wait_for_fence(0xF);
        peak = std::max<uint64_t>(peak, s.model.stats().segments);
    }
    EXPECT_TRUE(s.hazards().empty());
    EXPECT_LE(peak, 2 * 1024u + 100u);  // 400 frames x ~60 segments would be 24000 without sweeps
}

TEST(SyncScenarios, JsonCarriesClassCommandsFieldsAndFix) {
    Stream s;
    s.submit();
    s.copy_buffer(kStaging, kInfos);
    s.build(clas_build());
    s.end();
    const nlohmann::json j = to_json(s.hazards(), s.model.stats().duplicate_hazards);
    ASSERT_EQ(j["hazards"].size(), 1u);
    const auto& h = j["hazards"][0];
    EXPECT_EQ(h["class"], "READ-AFTER-WRITE");
    EXPECT_EQ(h["prior"]["command"], "vkCmdCopyBuffer");
    EXPECT_EQ(h["later"]["field"], "srcInfosArray");
    EXPECT_EQ(h["later"]["command_index"], 1);
    EXPECT_EQ(h["overlap"][0], "0x1000");
    EXPECT_EQ(h["fix"]["dstAccessMask"], "VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT");
    EXPECT_EQ(j["suppressed"], 0);
}

}  // namespace
}  // namespace clastrace::replay::test

namespace clastrace::replay::test {
namespace {

TEST(SyncEdges, ExtremeAndEmptyRanges) {
    Stream s;
    s.submit();
    const uint64_t top = ~uint64_t(0);
    s.model.record_access(s.next("vkCmdFillBuffer"),
                          Stream::write(top - 16, top, kClear, kTransferWrite, "dstBuffer"));
    s.model.record_access(s.next("vkCmdFillBuffer"),
                          Stream::write(0, 0, kClear, kTransferWrite, "empty"));
    s.model.record_access(s.next("vkCmdFillBuffer"),
                          Stream::write(100, 50, kClear, kTransferWrite, "inverted"));
    s.buffer_barrier({200, 100}, kClear, kTransferWrite, kAsBuild, kAsRead);  // inverted: ignored
    s.model.record_access(s.next(kBuildName),
                          Stream::read(top - 8, top, kAsBuild, kAsRead, "vertexBuffer"));
    s.model.record_access(s.next(kBuildName),
                          Stream::read(0, top, kAsBuild, kAsRead, "everything"));
    s.end();
    ASSERT_EQ(s.hazards().size(), 2u);
    EXPECT_EQ(s.hazards()[0].overlap, (AddressRange{top - 8, top}));
    EXPECT_EQ(s.hazards()[1].overlap, (AddressRange{top - 16, top}));
}

TEST(SyncEdges, WaitsOnThingsNeverSignalled) {
    Stream s;
    s.model.wait_for_fence(12345);         // unknown fence: no effect
    s.model.host_wait_semaphore(777, 3);   // unknown semaphore: no effect
    s.submit(0, {{0xDEAD, 0, kAsBuild}});  // binary semaphore nobody signalled
    s.copy_buffer(kStaging, kInfos);
    const uint64_t never_set[] = {4242};
    const MemoryBarrier b{kCopy, kTransferWrite, kAsBuild, kIndirect};
    s.model.wait_events(s.next("vkCmdWaitEvents2"), never_set,
                        DependencyInfo{std::span(&b, 1), {}, 0});
    s.build(clas_build());
    s.end();
    EXPECT_EQ(s.model.stats().unsatisfied_waits, 1u);
    EXPECT_EQ(s.hazards().size(), 1u);  // the unset event orders nothing
}

TEST(SyncEdges, LogStaysBoundedWithoutHostWaits) {
    // One endless submission with a barrier before every access: the log is compacted as it grows.
    Stream s;
    s.submit();
    std::size_t at_10k = 0;
    for (int i = 0; i < 100000; ++i) {
        s.barrier(i % 3 ? kAsBuild : kCopy, kAsWrite | kTransferWrite, kAsBuild,
                  kAsRead | kAsWrite);
        const uint64_t a = uint64_t(i % 64) * 0x1000;
        s.model.record_access(s.next(kBuildName), Stream::write(a, a + 0x800, kAsBuild,
                                                                kAsRead | kAsWrite, "scratchData"));
        if (i == 10000) at_10k = s.model.memory_bytes();
    }
    s.end();
    EXPECT_TRUE(s.hazards().empty());
    EXPECT_LT(s.model.memory_bytes(), 2 * at_10k + 65536);
}

TEST(SyncEdges, EventSlotsRecycleWhenManyEventsArePending) {
    // 20 events set and none waited: the oldest lose their slot, which is counted, and a wait on one
    // of them then orders nothing (a possible false positive, never a missed hazard).
    Stream s;
    s.submit();
    s.copy_buffer(kStaging, kInfos);
    const MemoryBarrier b{kCopy, kTransferWrite, kAsBuild, kIndirect};
    const DependencyInfo dep{std::span(&b, 1), {}, 0};
    for (uint64_t e = 1; e <= 20; ++e) s.model.set_event(s.next("vkCmdSetEvent2"), e, dep);
    const uint64_t oldest[] = {1};
    s.model.wait_events(s.next("vkCmdWaitEvents2"), oldest, dep);
    s.build(clas_build());
    s.end();
    EXPECT_EQ(s.model.stats().event_slot_reuses, 4u);
    EXPECT_EQ(s.hazards().size(), 1u);
    Stream t;  // the newest event still works
    t.submit();
    t.copy_buffer(kStaging, kInfos);
    for (uint64_t e = 1; e <= 20; ++e) t.model.set_event(t.next("vkCmdSetEvent2"), e, dep);
    const uint64_t newest[] = {20};
    t.model.wait_events(t.next("vkCmdWaitEvents2"), newest, dep);
    t.build(clas_build());
    t.end();
    EXPECT_TRUE(t.hazards().empty());
}

}  // namespace
}  // namespace clastrace::replay::test
