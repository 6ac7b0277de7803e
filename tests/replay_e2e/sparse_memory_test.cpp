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

// --- two sparse buffers over one memory, and a rebind -------------------------------------

constexpr uint64_t kSecondSparse = 0xd002;
constexpr uint64_t kSecondAddress = 0x60000000;
constexpr uint64_t kSparseUsage =
    VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT | VK_BUFFER_USAGE_STORAGE_BUFFER_BIT |
    VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR | VK_BUFFER_USAGE_TRANSFER_SRC_BIT;
constexpr uint64_t kDst2MemoryOffset = kDst2 - kBase;

VkSparseMemoryBind whole_at(uint64_t memory_offset) {
    return {0, kSparseSize, VkDeviceMemory(kMemory), memory_offset, 0};
}

// The build writes its destination through the first sparse buffer; the copy reads the second,
// bound over the same memory: the two addresses never meet, the memory does.
TEST(SparseMemory, TwoSparseBuffersOverOneMemoryMeetThere) {
    const replay::ReplayReport r =
        replay_catalogue_scene(temp_trace_path("sparse_memory", "two_buffers.clt"), [](auto& t) {
            t.sparse_buffer(kSparseBuffer, kSparseSize, kSparseUsage);
            t.sparse_buffer(kSecondSparse, kSparseSize, kSparseUsage);
            t.bind_sparse(kQueue, kSparseBuffer, kSparseAddress, {whole_at(kDstMemoryOffset)});
            t.bind_sparse(kQueue, kSecondSparse, kSecondAddress, {whole_at(kDstMemoryOffset)},
                          kBindDone);
            ClusterCommand c = triangle_clusters(Destinations::kImplicit);
            c.info.dstImplicitData = kSparseAddress;
            c.emit(t);
            t.copy(kSecondSparse, 0, kStagingBuffer, 0, 256);
            t.submit(kQueue, {{kBindDone, 0, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT}});
        });
    ASSERT_EQ(r.hazards.size(), 1u);
    EXPECT_EQ(r.hazards[0].hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(std::string(r.hazards[0].prior.command.name),
              "vkCmdBuildClusterAccelerationStructureIndirectNV");
    EXPECT_EQ(std::string(r.hazards[0].later.command.name), "vkCmdCopyBuffer");
    EXPECT_EQ(r.hazards[0].overlap.begin, kDst);
    EXPECT_TRUE(r.findings.empty()) << r.findings[0].format();
}

// The build writes through the sparse buffer in one submission; the next submission reads the
// sparse buffer's first bytes. Rebound in between to other memory, the read reaches that memory
// and meets nothing; not rebound, it reads what the build wrote, with no barrier.
replay::ReplayReport replay_rebind(bool rebind) {
    return replay_catalogue_scene(
        temp_trace_path("sparse_memory", rebind ? "rebind.clt" : "no_rebind.clt"), [&](auto& t) {
            t.sparse_buffer(kSparseBuffer, kSparseSize, kSparseUsage);
            t.bind_sparse(kQueue, kSparseBuffer, kSparseAddress, {whole_at(kDstMemoryOffset)});
            ClusterCommand c = triangle_clusters(Destinations::kImplicit);
            c.info.dstImplicitData = kSparseAddress;
            c.emit(t);
            t.submit(kQueue);
            if (rebind)
                t.bind_sparse(kQueue, kSparseBuffer, kSparseAddress,
                              {{0, kPage, VkDeviceMemory(kMemory), kDst2MemoryOffset, 0}});
            t.copy(kSparseBuffer, 0, kStagingBuffer, 0, 256);
            t.submit(kQueue);
        });
}

TEST(SparseMemory, ReadAfterARebindReachesTheNewMemory) {
    const replay::ReplayReport rebound = replay_rebind(true);
    EXPECT_TRUE(rebound.hazards.empty()) << rebound.hazards[0].format();
    const replay::ReplayReport kept = replay_rebind(false);
    ASSERT_EQ(kept.hazards.size(), 1u);
    EXPECT_EQ(kept.hazards[0].hazard, HazardClass::kReadAfterWrite);
    EXPECT_EQ(kept.hazards[0].overlap.begin, kDst);
}

// --- binds the replay cannot apply: findings naming the record -----------------------------

const replay::ReplayFinding* finding(const replay::ReplayReport& r, const std::string& rule) {
    auto f = std::find_if(r.findings.begin(), r.findings.end(),
                          [&](const replay::ReplayFinding& f) { return f.rule == rule; });
    return f == r.findings.end() ? nullptr : &*f;
}

replay::ReplayReport replay_binds(const std::string& name, uint64_t buffer, uint64_t address,
                                  const std::vector<VkSparseMemoryBind>& binds) {
    return replay_catalogue_scene(temp_trace_path("sparse_memory", name + ".clt"), [&](auto& t) {
        t.sparse_buffer(kSparseBuffer, kSparseSize, kSparseUsage);
        t.sparse_buffer(kSecondSparse, kSparseSize, kSparseUsage);
        t.bind_sparse(kQueue, kSecondSparse, kSecondAddress, {whole_at(kDst2MemoryOffset)});
        t.bind_sparse(kQueue, buffer, address, binds);
    });
}

void expect_damage(const replay::ReplayReport& r, const std::string& rule,
                   const std::string& says) {
    const replay::ReplayFinding* f = finding(r, rule);
    ASSERT_NE(f, nullptr) << rule;
    EXPECT_NE(f->message.find("QueueBindSparse record in chunk "), std::string::npos) << f->message;
    EXPECT_NE(f->message.find(", batch 0"), std::string::npos) << f->message;
    EXPECT_NE(f->message.find(says), std::string::npos) << f->message;
    EXPECT_EQ(std::string(f->where.name), "vkQueueBindSparse");
    EXPECT_FALSE(r.clean());
}

TEST(SparseMemory, BindPastTheBufferEndIsDamageNamingTheBind) {
    const replay::ReplayReport r =
        replay_binds("past_end", kSparseBuffer, kSparseAddress,
                     {whole_at(kDstMemoryOffset),
                      {kSparseSize - kPage, 2 * kPage, VkDeviceMemory(kMemory), 0, 0}});
    expect_damage(r, "CLASTRACE-sparse-bind-damaged",
                  "buffer bind 0 (buffer 0xd001), bind 1: resourceOffset 0x10000 size 0x20000 "
                  "runs past the buffer's 0x20000 bytes");
}

TEST(SparseMemory, HostileSizesAndAnUnknownBufferAreDamage) {
    expect_damage(replay_binds("wrap", kSparseBuffer, kSparseAddress,
                               {{0, kPage, VkDeviceMemory(kMemory), ~uint64_t(0) - 8, 0}}),
                  "CLASTRACE-sparse-bind-damaged", "wraps past 2^64");
    expect_damage(replay_binds("huge", kSparseBuffer, kSparseAddress,
                               {{8, ~uint64_t(0), VkDeviceMemory(kMemory), 0, 0}}),
                  "CLASTRACE-sparse-bind-damaged", "runs past the buffer");
    expect_damage(replay_binds("unknown", 0xdead, kSparseAddress, {whole_at(0)}),
                  "CLASTRACE-sparse-bind-damaged",
                  "(buffer 0xdead): no vkCreateBuffer of this buffer precedes the bind");
}

TEST(SparseMemory, HostileAddressesAreDamage) {
    // Over the second sparse buffer's addresses, and past the end of the address space.
    expect_damage(replay_binds("overlapping_address", kSparseBuffer, kSecondAddress + kPage,
                               {whole_at(kDstMemoryOffset)}),
                  "CLASTRACE-sparse-bind-damaged", "overlap another sparse buffer's");
    expect_damage(replay_binds("address_wraps", kSparseBuffer, ~uint64_t(0) - kPage,
                               {whole_at(kDstMemoryOffset)}),
                  "CLASTRACE-sparse-bind-damaged", "runs past the device address space");
    // A later record giving the placed buffer another address.
    expect_damage(replay_binds("moved", kSecondSparse, kSecondAddress + 0x100000,
                               {whole_at(kDstMemoryOffset)}),
                  "CLASTRACE-sparse-bind-damaged", "differs from 0x60000000");
}

TEST(SparseMemory, ARangeBoundTwiceInOneBatchIsAFinding) {
    const replay::ReplayReport r =
        replay_binds("twice", kSparseBuffer, kSparseAddress,
                     {whole_at(kDstMemoryOffset), {kPage, kPage, VkDeviceMemory(kMemory), 0, 0}});
    expect_damage(r, "CLASTRACE-sparse-bind-overlap",
                  "buffer bind 0 bind 0 and buffer bind 0 bind 1 both bind bytes [0x10000, "
                  "0x20000) of sparse buffer 0xd001");
    // Binds of one range in two batches (two calls) are a rebind, not a fault.
    const replay::ReplayReport rebind =
        replay_binds("twice_apart", kSecondSparse, kSecondAddress, {whole_at(kDstMemoryOffset)});
    EXPECT_EQ(finding(rebind, "CLASTRACE-sparse-bind-overlap"), nullptr);
    EXPECT_EQ(finding(rebind, "CLASTRACE-sparse-bind-damaged"), nullptr);
}

}  // namespace
