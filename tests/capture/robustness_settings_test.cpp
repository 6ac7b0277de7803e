// SPDX-License-Identifier: Apache-2.0
// The settings of the robustness features: the flush interval and forced staging.
#include "layer_config_env.h"

#include <gtest/gtest.h>

using namespace clastrace::capture;
using clastrace::capture::test::parse;

namespace {

TEST(RobustnessSettings, DefaultsFlushEverySecondWithoutStaging) {
    LayerConfig c = parse({});
    EXPECT_EQ(c.flush_milliseconds, 1000u);
    EXPECT_FALSE(c.force_staging);
}

TEST(RobustnessSettings, ReadsFlushIntervalAndStaging) {
    LayerConfig c = parse({{"CLASTRACE_FLUSH_MS", "0"}, {"CLASTRACE_FORCE_STAGING", "1"}});
    EXPECT_EQ(c.flush_milliseconds, 0u);
    EXPECT_TRUE(c.force_staging);
    EXPECT_TRUE(c.errors.empty());
    EXPECT_EQ(parse({{"CLASTRACE_FLUSH_MS", "3600000"}}).flush_milliseconds, 3600000u);
}

TEST(RobustnessSettings, RejectsBadValuesByNameAndKeepsDefaults) {
    for (const char* bad : {"-1", "3600001", "1e3", "", "99999999999999999999"}) {
        LayerConfig c = parse({{"CLASTRACE_FLUSH_MS", bad}});
        EXPECT_EQ(c.flush_milliseconds, 1000u) << bad;
        ASSERT_EQ(c.errors.size(), 1u) << bad;
        EXPECT_NE(c.errors[0].find(std::string("CLASTRACE_FLUSH_MS='") + bad + "'"),
                  std::string::npos)
            << c.errors[0];
    }
    LayerConfig c = parse({{"CLASTRACE_FORCE_STAGING", "yes please"}});
    EXPECT_FALSE(c.force_staging);
    ASSERT_EQ(c.errors.size(), 1u);
    EXPECT_NE(c.errors[0].find("CLASTRACE_FORCE_STAGING='yes please'"), std::string::npos)
        << c.errors[0];
}

}  // namespace
