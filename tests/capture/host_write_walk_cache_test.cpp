// SPDX-License-Identifier: Apache-2.0
// The host-write watch's walk cache (capture/src/host_write_walk_cache.h): a kept walk is found
// again only for equal parameters (the application's pointers aside), an unchanged memory map and
// reads that give their bytes again; an INDIRECTED src infos array is never kept.
#include "host_write_walk_cache.h"

#include <gtest/gtest.h>

namespace {

using clastrace::capture::ClusterCommandParameters;
using clastrace::capture::HostWriteWalkCache;

ClusterCommandParameters triangle_build(VkDeviceAddress infos) {
    ClusterCommandParameters p{};
    p.info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    p.info.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    p.info.input.maxAccelerationStructureCount = 4;
    p.info.srcInfosArray = {infos, 48, 4 * 48};
    p.info.srcInfosCount = 0x9000;
    p.has_op_input = true;
    return p;
}

struct Kept {
    HostWriteWalkCache cache;
    std::vector<uint8_t> infos = std::vector<uint8_t>(4 * 48, 1);
    // What the walk's reads give now: the infos as they are.
    bool unchanged(const HostWriteWalkCache::Read& r) const { return r.bytes == infos; }
    const HostWriteWalkCache::Ranges* find(const ClusterCommandParameters& p,
                                           uint64_t changes = 7) {
        return cache.find(p, changes,
                          [this](const HostWriteWalkCache::Read& r) { return unchanged(r); });
    }
};

TEST(HostWriteWalkCache, AResubmittedCommandWhoseReadsHoldTheSameBytesGetsItsRanges) {
    Kept k;
    const ClusterCommandParameters p = triangle_build(0x8000);
    HostWriteWalkCache::Found f;
    f.address = 0xA000;
    f.size = 96;
    k.cache.keep(p, 7, {{0x8000, k.infos}}, {{f}, {}});
    ClusterCommandParameters again = triangle_build(0x8000);
    int chained = 0;
    again.info.pNext = &chained;  // a re-recorded command: other application pointers
    const auto* found = k.find(again);
    ASSERT_NE(found, nullptr);
    ASSERT_EQ(found->found.size(), 1u);
    EXPECT_EQ(found->found[0].address, 0xA000u);
    EXPECT_EQ(found->found[0].size, 96u);
}

TEST(HostWriteWalkCache, ChangedBytesParametersOrMapAreWalkedAgain) {
    Kept k;
    const ClusterCommandParameters p = triangle_build(0x8000);
    k.cache.keep(p, 7, {{0x8000, k.infos}}, {{HostWriteWalkCache::Found{}}, {}});
    EXPECT_EQ(k.find(p, 8), nullptr);                    // a buffer came or went since
    EXPECT_EQ(k.find(triangle_build(0x8100)), nullptr);  // other parameters
    k.infos[5] = 2;                                      // the host or the device wrote the infos
    EXPECT_EQ(k.find(p), nullptr);
    k.infos[5] = 1;
    EXPECT_NE(k.find(p), nullptr);
}

TEST(HostWriteWalkCache, AnIndirectedSrcInfosArrayIsNotKept) {
    ClusterCommandParameters p = triangle_build(0x8000);
    EXPECT_TRUE(HostWriteWalkCache::keepable(p));
    p.info.addressResolutionFlags =
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV;
    EXPECT_FALSE(HostWriteWalkCache::keepable(p));
}

}  // namespace
