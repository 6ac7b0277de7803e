// SPDX-License-Identifier: Apache-2.0
// The rule that keeps or drops cluster commands before a frame range (layer_pre_range_clusters.h,
// capture/README.md "Frame ranges"), on made-up commands and captures: no device needed.
#include "layer_pre_range_clusters.h"

#include <gtest/gtest.h>

#include <cstring>
#include <vector>

namespace {

using clastrace::capture::ClusterBuildCapture;
using clastrace::capture::ClusterBuildCommand;
using clastrace::capture::MemoryRole;
using clastrace::capture::PreRangeClusterCommands;

ClusterBuildCommand command_of(VkClusterAccelerationStructureOpTypeNV type) {
    ClusterBuildCommand c;
    c.parameters.info.input.opType = type;
    c.parameters.info.input.opMode =
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    return c;
}

// A capture whose objects are [begin, begin + size) for each of `objects`.
ClusterBuildCapture capture_of(std::vector<std::pair<uint64_t, size_t>> objects) {
    ClusterBuildCapture c;
    for (auto [begin, size] : objects) {
        clastrace::capture::CapturedRange r{MemoryRole::kDstObject, 0, begin, {}, 0, 0};
        std::memset(r.bytes.fill(size), 0xAB, size);
        c.outputs.push_back(std::move(r));
    }
    return c;
}

constexpr auto kClusters = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
constexpr auto kBottomLevel =
    VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;

// Clusters built at 0x1000 twice: the first build goes once the second covered its objects.
TEST(PreRangeClusterCommands, AnOverwrittenBuildGoes) {
    PreRangeClusterCommands kept;
    kept.note({1, 10, 0}, command_of(kClusters));
    kept.note({2, 20, 0}, command_of(kClusters));
    kept.arrived({1, 10, 0}, capture_of({{0x1000, 256}, {0x1100, 256}}));
    EXPECT_EQ(kept.size(), 2u);
    EXPECT_EQ(kept.arrived_count(), 1u);
    kept.arrived({2, 20, 0}, capture_of({{0x1000, 512}}));
    EXPECT_EQ(kept.size(), 1u);
    EXPECT_EQ(kept.live_objects(), 1u);
    std::vector<PreRangeClusterCommands::Taken> taken = kept.take();
    ASSERT_EQ(taken.size(), 1u);
    EXPECT_EQ(std::get<1>(taken[0].key), 20u);  // the second build stays
    EXPECT_EQ(kept.size(), 0u);
}

// A bottom level built between the two builds read the first one's clusters: the first stays,
// so replay can build what that bottom level read.
TEST(PreRangeClusterCommands, ABuildReadBeforeItWasOverwrittenStays) {
    PreRangeClusterCommands kept;
    kept.note({1, 10, 0}, command_of(kClusters));
    kept.note({2, 11, 0}, command_of(kBottomLevel));
    kept.note({3, 20, 0}, command_of(kClusters));
    kept.arrived({1, 10, 0}, capture_of({{0x1000, 256}}));
    kept.arrived({2, 11, 0}, capture_of({{0x8000, 128}}));
    kept.arrived({3, 20, 0}, capture_of({{0x1000, 256}}));
    EXPECT_EQ(kept.size(), 3u);
    EXPECT_EQ(kept.live_objects(), 2u);  // the bottom level's and the second build's
}

// One byte of overlap ends an object; objects elsewhere do not.
TEST(PreRangeClusterCommands, PartialOverlapEndsAnObjectAndDisjointOnesDoNot) {
    PreRangeClusterCommands kept;
    kept.note({1, 10, 0}, command_of(kClusters));
    kept.note({2, 20, 0}, command_of(kClusters));
    kept.note({3, 30, 0}, command_of(kClusters));
    kept.arrived({1, 10, 0}, capture_of({{0x1000, 256}}));
    kept.arrived({2, 20, 0}, capture_of({{0x2000, 256}}));  // beside it
    EXPECT_EQ(kept.size(), 3u);
    kept.arrived({3, 30, 0}, capture_of({{0x10FF, 1}}));  // its last byte
    EXPECT_EQ(kept.size(), 2u);
}

// Captures may come out of execution order (several queues): a later command's capture coming
// first still ends the older one's objects when that one arrives.
TEST(PreRangeClusterCommands, CapturesOutOfOrderGiveTheSameResult) {
    PreRangeClusterCommands kept;
    kept.note({1, 10, 0}, command_of(kClusters));
    kept.note({2, 20, 0}, command_of(kClusters));
    kept.arrived({2, 20, 0}, capture_of({{0x1000, 256}}));
    EXPECT_EQ(kept.size(), 2u);  // the first one's objects are not known yet: it stays
    kept.arrived({1, 10, 0}, capture_of({{0x1000, 256}}));
    EXPECT_EQ(kept.size(), 1u);
}

// A command whose capture names no object (its sizes unknown) is kept to the end.
TEST(PreRangeClusterCommands, ACommandWithoutObjectsStays) {
    PreRangeClusterCommands kept;
    kept.note({1, 10, 0}, command_of(kClusters));
    kept.note({2, 20, 0}, command_of(kClusters));
    kept.arrived({1, 10, 0}, capture_of({}));
    kept.arrived({2, 20, 0}, capture_of({{0x1000, 256}}));
    EXPECT_EQ(kept.size(), 2u);
    EXPECT_EQ(kept.live_objects(), 2u);  // unknown counts one
}

// Freed memory ends the objects in it, whether their capture came before the free or after;
// objects built in memory allocated after the free do not end.
TEST(PreRangeClusterCommands, FreedMemoryEndsItsObjects) {
    PreRangeClusterCommands kept;
    kept.note({1, 10, 0}, command_of(kClusters));
    kept.note({2, 20, 0}, command_of(kClusters));
    kept.arrived({1, 10, 0}, capture_of({{0x1000, 256}}));
    kept.freed(0x1000, 0x3000);  // holds both commands' objects
    EXPECT_EQ(kept.size(), 1u);  // the first went; the second's capture has not come
    kept.note({3, 30, 0}, command_of(kClusters));  // into memory allocated at the same address
    kept.arrived({2, 20, 0}, capture_of({{0x2000, 256}}));
    kept.arrived({3, 30, 0}, capture_of({{0x1000, 256}}));
    std::vector<PreRangeClusterCommands::Taken> taken = kept.take();
    ASSERT_EQ(taken.size(), 1u);
    EXPECT_EQ(std::get<1>(taken[0].key), 30u);
}

// A bottom level built over the clusters before their memory was freed keeps them, as an
// overwrite does (the rule does not judge whether the bottom level is still usable).
TEST(PreRangeClusterCommands, FreedMemoryReadBeforeTheFreeStays) {
    PreRangeClusterCommands kept;
    kept.note({1, 10, 0}, command_of(kClusters));
    kept.note({2, 11, 0}, command_of(kBottomLevel));
    kept.arrived({1, 10, 0}, capture_of({{0x1000, 256}}));
    kept.arrived({2, 11, 0}, capture_of({{0x8000, 128}}));
    kept.freed(0x1000, 0x2000);
    EXPECT_EQ(kept.size(), 2u);
    EXPECT_EQ(kept.live_objects(), 1u);
}

}  // namespace
