// SPDX-License-Identifier: Apache-2.0
#include <gtest/gtest.h>

#include "clastrace/analyze/value_distribution.h"

namespace clastrace::analyze {
namespace {

TEST(ValueDistribution, EmptyHasZeroes) {
    ValueDistribution d;
    EXPECT_EQ(d.count(), 0u);
    EXPECT_EQ(d.min(), 0u);
    EXPECT_EQ(d.max(), 0u);
    EXPECT_EQ(d.median(), 0u);
    EXPECT_TRUE(d.median_exact());
}

TEST(ValueDistribution, OddCountMedianIsMiddleValue) {
    ValueDistribution d;
    for (uint64_t v : {1400u, 900u, 1000u, 1200u, 1000u}) d.add(v);
    EXPECT_EQ(d.count(), 5u);
    EXPECT_EQ(d.sum(), 5500u);
    EXPECT_EQ(d.min(), 900u);
    EXPECT_EQ(d.max(), 1400u);
    EXPECT_EQ(d.median(), 1000u);
}

TEST(ValueDistribution, EvenCountMedianIsLowerMiddle) {
    ValueDistribution d;
    for (uint64_t v : {10u, 40u, 20u, 30u}) d.add(v);
    EXPECT_EQ(d.median(), 20u);  // rank ceil(4/2) = 2
}

TEST(ValueDistribution, Log2BinsHoldPowerOfTwoRanges) {
    ValueDistribution d;
    d.add(0);
    d.add(1);
    d.add(2);
    d.add(3);
    d.add(1023);
    d.add(1024);
    d.add(UINT64_MAX);
    const auto& b = d.log2_bins();
    EXPECT_EQ(b[0], 1u);   // 0
    EXPECT_EQ(b[1], 1u);   // 1
    EXPECT_EQ(b[2], 2u);   // 2..3
    EXPECT_EQ(b[10], 1u);  // 512..1023
    EXPECT_EQ(b[11], 1u);  // 1024..2047
    EXPECT_EQ(b[64], 1u);  // top bin
    EXPECT_EQ(ValueDistribution::bin_low(11), 1024u);
}

TEST(ValueDistribution, SumSaturatesInsteadOfWrapping) {
    ValueDistribution d;
    d.add(UINT64_MAX);
    d.add(5);
    EXPECT_EQ(d.sum(), UINT64_MAX);
    d.add(UINT64_MAX / 2, 4);  // value * times overflows
    EXPECT_EQ(d.sum(), UINT64_MAX);
    EXPECT_EQ(d.count(), 6u);
}

TEST(ValueDistribution, StaysExactUpToTheDistinctLimit) {
    ValueDistribution d;
    for (uint64_t v = 1; v <= ValueDistribution::kMaxDistinct; ++v) d.add(v * 16);
    EXPECT_TRUE(d.median_exact());
    EXPECT_EQ(d.median(), (ValueDistribution::kMaxDistinct / 2) * 16);
}

TEST(ValueDistribution, FoldsPastTheLimitWithinOnePart128) {
    ValueDistribution d;
    const uint64_t n = 100001;  // odd: the median is value 50001 * 37
    for (uint64_t v = 1; v <= n; ++v) d.add(v * 37);
    EXPECT_FALSE(d.median_exact());
    const double exact = 50001.0 * 37.0;
    EXPECT_LE(static_cast<double>(d.median()), exact);
    EXPECT_GE(static_cast<double>(d.median()), exact * (1.0 - 1.0 / 64));
    EXPECT_EQ(d.min(), 37u);
    EXPECT_EQ(d.max(), n * 37);
    EXPECT_EQ(d.count(), n);
}

}  // namespace
}  // namespace clastrace::analyze
