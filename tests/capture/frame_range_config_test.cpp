// SPDX-License-Identifier: Apache-2.0
// CLASTRACE_FRAME_RANGE parsing: the same syntax and errors as CLASTRACE_SUBMIT_RANGE, kept
// apart from it.
#include "layer_config_env.h"

#include <gtest/gtest.h>

using namespace clastrace::capture;
using clastrace::capture::test::parse;

namespace {

TEST(FrameRangeConfig, DefaultIsEveryFrame) {
    LayerConfig c = parse({});
    EXPECT_EQ(c.frame_range.first, 0u);
    EXPECT_EQ(c.frame_range.last, UINT64_MAX);
    EXPECT_TRUE(c.frame_range.contains(0));
    EXPECT_TRUE(c.frame_range.contains(UINT64_MAX));
}

TEST(FrameRangeConfig, SingleClosedAndOpenRanges) {
    LayerConfig single = parse({{"CLASTRACE_FRAME_RANGE", "7"}});
    EXPECT_FALSE(single.frame_range.contains(6));
    EXPECT_TRUE(single.frame_range.contains(7));
    EXPECT_FALSE(single.frame_range.contains(8));

    LayerConfig closed = parse({{"CLASTRACE_FRAME_RANGE", "2-3"}});
    for (uint64_t f = 0; f < 6; ++f)
        EXPECT_EQ(closed.frame_range.contains(f), f == 2 || f == 3) << f;

    LayerConfig open = parse({{"CLASTRACE_FRAME_RANGE", "4-"}});
    EXPECT_FALSE(open.frame_range.contains(3));
    EXPECT_TRUE(open.frame_range.contains(4));
    EXPECT_TRUE(open.frame_range.contains(UINT64_MAX));

    // The extremes of the counter: frame 0 alone, and the largest 19-digit frame number.
    EXPECT_TRUE(parse({{"CLASTRACE_FRAME_RANGE", "0-0"}}).frame_range.contains(0));
    EXPECT_FALSE(parse({{"CLASTRACE_FRAME_RANGE", "0-0"}}).frame_range.contains(1));
    LayerConfig huge = parse({{"CLASTRACE_FRAME_RANGE", "9999999999999999999"}});
    EXPECT_TRUE(huge.errors.empty());
    EXPECT_TRUE(huge.frame_range.contains(9999999999999999999ull));
}

TEST(FrameRangeConfig, IndependentOfTheSubmitRange) {
    LayerConfig c = parse({{"CLASTRACE_FRAME_RANGE", "1-4"}, {"CLASTRACE_SUBMIT_RANGE", "3-"}});
    EXPECT_TRUE(c.errors.empty());
    EXPECT_EQ(c.frame_range.first, 1u);
    EXPECT_EQ(c.frame_range.last, 4u);
    EXPECT_EQ(c.submit_range.first, 3u);
    EXPECT_EQ(c.submit_range.last, UINT64_MAX);
    // A bad frame range leaves a good submission range alone, and the other way round.
    LayerConfig bad = parse({{"CLASTRACE_FRAME_RANGE", "x"}, {"CLASTRACE_SUBMIT_RANGE", "5"}});
    EXPECT_EQ(bad.submit_range.first, 5u);
    ASSERT_EQ(bad.errors.size(), 1u);
    EXPECT_NE(bad.errors[0].find("CLASTRACE_FRAME_RANGE='x'"), std::string::npos);
}

TEST(FrameRangeConfig, BadValuesAreNamedAndTheDefaultKept) {
    for (const char* value : {"", "3-1", "-2", "a", "1-b", "2--3", " 2", "2 ", "1-2-3", "0x10",
                              "99999999999999999999", "18446744073709551616", "-"}) {
        LayerConfig c = parse({{"CLASTRACE_FRAME_RANGE", value}});
        ASSERT_EQ(c.errors.size(), 1u) << "'" << value << "'";
        EXPECT_EQ(c.errors[0],
                  std::string("CLASTRACE_FRAME_RANGE='") + value +
                      "' is not N, A-B (A <= B) or A- (0-based frames); using the default");
        EXPECT_EQ(c.frame_range.first, 0u) << value;
        EXPECT_EQ(c.frame_range.last, UINT64_MAX) << value;
    }
}

}  // namespace
