// SPDX-License-Identifier: Apache-2.0
// CLASTRACE_DEBUG_ASSERT at level 0, as Release and RelWithDebInfo builds compile it: the
// condition is never evaluated, so a broken one neither aborts nor has side effects.
#undef CLASTRACE_DEBUG_LEVEL
#define CLASTRACE_DEBUG_LEVEL 0
#include <clastrace/common/debug_assert.h>

#include <gtest/gtest.h>

namespace {

TEST(DebugAssertOff, ConditionIsNotEvaluated) {
    int evaluations = 0;
    CLASTRACE_DEBUG_ASSERT(++evaluations == 99);
    EXPECT_EQ(evaluations, 0);
}

}  // namespace
