// SPDX-License-Identifier: Apache-2.0
#include <gtest/gtest.h>

#include "address_owners.h"

namespace clastrace::analyze {
namespace {

TEST(AddressOwners, PaintingOverReportsEachPreviousOwnerOnce) {
    AddressOwners owners;
    std::vector<OwnerOverlap> taken;
    owners.paint(100, 100, {1, RegionRole::kScratch, 0}, taken);  // [100,200)
    owners.paint(300, 50, {2, RegionRole::kSrcInfos, 0}, taken);  // [300,350)
    EXPECT_TRUE(taken.empty());
    owners.paint(150, 175, {3, RegionRole::kImplicitData, 1}, taken);  // [150,325)
    ASSERT_EQ(taken.size(), 2u);
    EXPECT_EQ(taken[0].previous.region, 1u);
    EXPECT_EQ(taken[0].base, 150u);
    EXPECT_EQ(taken[0].size, 50u);
    EXPECT_EQ(taken[1].previous.region, 2u);
    EXPECT_EQ(taken[1].base, 300u);
    EXPECT_EQ(taken[1].size, 25u);
    // [100,150) of 1, [150,325) of 3, [325,350) of 2.
    EXPECT_EQ(owners.spans(), 3u);

    taken.clear();
    owners.paint(120, 10, {1, RegionRole::kScratch, 0}, taken);  // same owner: no overlap
    EXPECT_TRUE(taken.empty());
    EXPECT_EQ(owners.spans(), 3u);                               // split and rejoined
    owners.paint(120, 10, {1, RegionRole::kScratch, 2}, taken);  // same region, later command
    EXPECT_TRUE(taken.empty());
    EXPECT_EQ(owners.spans(), 5u);  // bytes 120..130 now last used by command 2
}

TEST(AddressOwners, InnerPaintSplitsASpanInThree) {
    AddressOwners owners;
    std::vector<OwnerOverlap> taken;
    owners.paint(0, 1000, {1, RegionRole::kImplicitData, 0}, taken);
    owners.paint(400, 100, {2, RegionRole::kScratch, 1}, taken);
    ASSERT_EQ(taken.size(), 1u);
    EXPECT_EQ(taken[0].size, 100u);
    EXPECT_EQ(owners.spans(), 3u);
    taken.clear();
    owners.paint(0, 1000, {3, RegionRole::kScratch, 2}, taken);
    ASSERT_EQ(taken.size(), 3u);
    uint64_t bytes = 0;
    for (const auto& t : taken) bytes += t.size;
    EXPECT_EQ(bytes, 1000u);
    EXPECT_EQ(owners.spans(), 1u);
}

TEST(AddressOwners, HandlesTheTopOfTheAddressSpace) {
    AddressOwners owners;
    std::vector<OwnerOverlap> taken;
    owners.paint(UINT64_MAX - 10, 10, {1, RegionRole::kScratch, 0}, taken);
    owners.paint(UINT64_MAX - 5, 5, {2, RegionRole::kScratch, 1}, taken);
    ASSERT_EQ(taken.size(), 1u);
    EXPECT_EQ(taken[0].base, UINT64_MAX - 5);
    EXPECT_EQ(taken[0].size, 5u);
}

}  // namespace
}  // namespace clastrace::analyze
