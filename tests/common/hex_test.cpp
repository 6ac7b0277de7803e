// SPDX-License-Identifier: Apache-2.0
// Exact text of the shared hex helpers, at the edges every former copy had to get right.
#include <clastrace/common/hex.h>

#include <gtest/gtest.h>

#include <cstddef>
#include <cstdint>
#include <vector>

namespace clastrace::common {
namespace {

TEST(Hex, NumberHasPrefixLowercaseDigitsAndNoPadding) {
    EXPECT_EQ(hex(0), "0x0");
    EXPECT_EQ(hex(1), "0x1");
    EXPECT_EQ(hex(0xabcdef), "0xabcdef");
    EXPECT_EQ(hex(0x1000), "0x1000");
    EXPECT_EQ(hex(UINT64_MAX), "0xffffffffffffffff");
    EXPECT_EQ(hex(0x8000000000000000ull), "0x8000000000000000");
}

TEST(Hex, MinimumDigitsPadWithZerosAndNeverCut) {
    EXPECT_EQ(hex(0, 16), "0x0000000000000000");
    EXPECT_EQ(hex(0x2a, 16), "0x000000000000002a");
    EXPECT_EQ(hex(UINT64_MAX, 16), "0xffffffffffffffff");
    EXPECT_EQ(hex(0x12345, 4), "0x12345");
    EXPECT_EQ(hex(0xff, 0), "0xff");
    EXPECT_EQ(hex(0, 0), "0x0");
    EXPECT_EQ(hex(0xff, -3), "0xff");
}

TEST(Hex, BytesAreTwoDigitsEachWithoutPrefix) {
    EXPECT_EQ(hex_bytes(std::span<const uint8_t>{}), "");
    const std::vector<uint8_t> bytes{0x00, 0x01, 0x0f, 0x10, 0xab, 0xff};
    EXPECT_EQ(hex_bytes(bytes), "00010f10abff");
    const std::byte raw[] = {std::byte{0xde}, std::byte{0xad}, std::byte{0x00}};
    EXPECT_EQ(hex_bytes(raw), "dead00");
}

}  // namespace
}  // namespace clastrace::common
