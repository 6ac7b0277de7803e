// SPDX-License-Identifier: Apache-2.0
// CLASTRACE_DEBUG_ASSERT with the checks on (this target defines CLASTRACE_DEBUG_LEVEL=1).
#include <clastrace/common/debug_assert.h>

#include <gtest/gtest.h>

namespace {

static_assert(CLASTRACE_DEBUG_LEVEL == 1, "common_tests compiles the checks in");

TEST(DebugAssert, HoldingConditionIsEvaluatedOnceAndPasses) {
    int evaluations = 0;
    CLASTRACE_DEBUG_ASSERT(++evaluations == 1);
    EXPECT_EQ(evaluations, 1);
}

TEST(DebugAssertDeathTest, BrokenConditionPrintsFileLineAndConditionThenAborts) {
    const int segments_end = 8, next_begin = 4;
    EXPECT_DEATH(CLASTRACE_DEBUG_ASSERT(segments_end <= next_begin),
                 "debug_assert_test\\.cpp:[0-9]+: invariant broken: segments_end <= next_begin");
}

}  // namespace
