// SPDX-License-Identifier: Apache-2.0
// Sparse memory (vkQueueBindSparse) in a hand-built trace: the CI driver (lavapipe, Mesa 22.3)
// has no sparseBinding, so no capture of a real sparse bind runs here. A sparse buffer holds a
// cluster build's implicit destination; its pages are bound to the memory that a plain buffer
// (kDstBuffer) is bound to, so a copy reading that buffer reads the bytes the build wrote
// through another address. Without a barrier that is a hazard, with one it is clean; a build
// into a page with no memory bound is a finding.
#include "catalogue_replay.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <string>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;
using replay::HazardClass;

constexpr uint64_t kSparseBuffer = 0xd001;
constexpr uint64_t kSparseAddress = 0x50000000;  // the sparse buffer's own device addresses
constexpr uint64_t kSparseSize = 0x20000;
constexpr uint64_t kPage = 0x10000;
constexpr uint64_t kMemory = 0x1001;                 // the catalogue's memory (kDst in it)
constexpr uint64_t kDstMemoryOffset = kDst - kBase;  // where kDstBuffer is bound
constexpr uint64_t kQueue = 0x7001, kBindDone = 0x8001;
constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kAsWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
constexpr uint64_t kCopy = VK_PIPELINE_STAGE_2_COPY_BIT;
constexpr uint64_t kTransferRead = VK_ACCESS_2_TRANSFER_READ_BIT;

enum class Binding { kWhole, kSecondPageOnly };
enum class Barrier { kNone, kGlobal, kOnSparseBuffer };

// The sparse buffer bound over kDstBuffer's memory; the build writes its implicit destination
// through the sparse buffer, the copy reads kDstBuffer (the alias), with or without a barrier.
void write_scene(TraceScript& t, Binding binding, Barrier barrier) {
    t.sparse_buffer(kSparseBuffer, kSparseSize,
                    VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT |
                        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR);
    std::vector<VkSparseMemoryBind> binds;
    if (binding == Binding::kWhole)
        binds.push_back({0, kSparseSize, VkDeviceMemory(kMemory), kDstMemoryOffset, 0});
    else
        binds.push_back({kPage, kPage, VkDeviceMemory(kMemory), kDstMemoryOffset + kPage, 0});
    t.bind_sparse(kQueue, kSparseBuffer, kSparseAddress, binds, kBindDone);
    ClusterCommand c = triangle_clusters(Destinations::kImplicit);
    c.info.dstImplicitData = kSparseAddress;
    c.emit(t);
    if (barrier == Barrier::kGlobal) t.barrier(kBuild, kAsWrite, kCopy, kTransferRead);
    // A buffer barrier naming the sparse buffer covers the memory bound under it.
    if (barrier == Barrier::kOnSparseBuffer)
        t.buffer_barrier(kSparseBuffer, 0, VK_WHOLE_SIZE, kBuild, kAsWrite, kCopy, kTransferRead);
    t.copy(kDstBuffer, 0, kStagingBuffer, 0, 256);
    t.submit(kQueue, {{kBindDone, 0, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT}});
}

replay::ReplayReport replay_scene(const std::string& name, Binding binding, Barrier barrier) {
    return replay_catalogue_scene(temp_trace_path("sparse_memory", name + ".clt"),
                                  [&](TraceScript& t) { write_scene(t, binding, barrier); });
}

bool has_finding(const replay::ReplayReport& r, const std::string& rule) {
    return std::any_of(r.findings.begin(), r.findings.end(),
                       [&](const replay::ReplayFinding& f) { return f.rule == rule; });
}

TEST(SparseMemory, CopyThroughAnAliasOfTheBuildsSparseDestinationIsAHazard) {
    const replay::ReplayReport r = replay_scene("no_barrier", Binding::kWhole, Barrier::kNone);
    ASSERT_EQ(r.hazards.size(), 1u);
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_EQ(h.hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(std::string(h.prior.command.name),
              "vkCmdBuildClusterAccelerationStructureIndirectNV");
    EXPECT_EQ(std::string(h.later.command.name), "vkCmdCopyBuffer");
    // The bytes are named where the memory is: kDstBuffer's addresses.
    EXPECT_EQ(h.overlap.begin, kDst);
    EXPECT_FALSE(has_finding(r, "CLASTRACE-sparse-unbound-access"));
}

TEST(SparseMemory, BarrierBetweenBuildAndAliasCopyIsClean) {
    const replay::ReplayReport r = replay_scene("barrier", Binding::kWhole, Barrier::kGlobal);
    EXPECT_TRUE(r.hazards.empty()) << (r.hazards.empty() ? "" : r.hazards[0].format());
    EXPECT_FALSE(has_finding(r, "CLASTRACE-sparse-unbound-access"));
}

TEST(SparseMemory, BufferBarrierOnTheSparseBufferCoversTheAliasedMemory) {
    const replay::ReplayReport r =
        replay_scene("buffer_barrier", Binding::kWhole, Barrier::kOnSparseBuffer);
    EXPECT_TRUE(r.hazards.empty()) << (r.hazards.empty() ? "" : r.hazards[0].format());
}

TEST(SparseMemory, BuildIntoAnUnboundPageIsAFinding) {
    const replay::ReplayReport r =
        replay_scene("unbound", Binding::kSecondPageOnly, Barrier::kGlobal);
    auto f = std::find_if(r.findings.begin(), r.findings.end(), [](const replay::ReplayFinding& f) {
        return f.rule == "CLASTRACE-sparse-unbound-access";
    });
    ASSERT_NE(f, r.findings.end());
    EXPECT_EQ(f->address, kSparseAddress);
    EXPECT_NE(f->message.find("sparse buffer 0xd001"), std::string::npos) << f->message;
    EXPECT_NE(f->message.find("writes bytes [0, "), std::string::npos) << f->message;
    EXPECT_EQ(std::string(f->where.name), "vkCmdBuildClusterAccelerationStructureIndirectNV");
}

}  // namespace
