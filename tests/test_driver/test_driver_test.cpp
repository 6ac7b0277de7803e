// SPDX-License-Identifier: Apache-2.0
// The tests' driver comes from the environment at test time, the system's lavapipe by default;
// a private driver's library path goes before the inherited LD_LIBRARY_PATH.
#include <clastrace/testsupport/test_driver.h>

#include <gtest/gtest.h>

#include <cstdlib>
#include <map>
#include <string>

namespace {

using clastrace::testsupport::kSystemLavapipe;
using clastrace::testsupport::test_driver;
using clastrace::testsupport::TestDriver;

// Sets or clears variables for one test and puts back what the process had.
class ScopedEnvironment {
public:
    void set(const char* name, const char* value) {
        if (!saved_.count(name)) {
            const char* old = std::getenv(name);
            saved_[name] = old ? std::optional<std::string>(old) : std::nullopt;
        }
        if (value)
            setenv(name, value, 1);
        else
            unsetenv(name);
    }
    ~ScopedEnvironment() {
        for (const auto& [name, value] : saved_)
            if (value)
                setenv(name.c_str(), value->c_str(), 1);
            else
                unsetenv(name.c_str());
    }

private:
    std::map<std::string, std::optional<std::string>> saved_;
};

TEST(TestDriver, IsTheSystemLavapipeWhenNothingNamesAnother) {
    ScopedEnvironment env;
    env.set("CLASTRACE_TEST_DRIVER_FILES", nullptr);
    env.set("CLASTRACE_TEST_DRIVER_LIBRARY_PATH", "/ignored/without/files");
    env.set("LD_LIBRARY_PATH", "/inherited");
    const TestDriver d = test_driver();
    EXPECT_EQ(d.driver_files, kSystemLavapipe);
    EXPECT_EQ(d.library_path, "");
    EXPECT_EQ(d.environment(),
              (std::map<std::string, std::string>{{"VK_DRIVER_FILES", kSystemLavapipe}}));
    EXPECT_EQ(d.missing_message(), "lavapipe is not installed (scripts/deps.sh installs it)");
}

TEST(TestDriver, IsWhatTheEnvironmentNamesWithItsLibrariesFirst) {
    ScopedEnvironment env;
    env.set("CLASTRACE_TEST_DRIVER_FILES", "/opt/lvp 25/lvp_icd.json");
    env.set("CLASTRACE_TEST_DRIVER_LIBRARY_PATH", "/opt/lvp 25/lib");
    env.set("LD_LIBRARY_PATH", "/inherited");
    const TestDriver d = test_driver();
    EXPECT_EQ(d.driver_files, "/opt/lvp 25/lvp_icd.json");
    EXPECT_FALSE(d.installed());
    EXPECT_EQ(d.environment(),
              (std::map<std::string, std::string>{{"LD_LIBRARY_PATH", "/opt/lvp 25/lib:/inherited"},
                                                  {"VK_DRIVER_FILES",
                                                   "/opt/lvp 25/lvp_icd.json"}}));
    // One shell word per value, whatever the path holds.
    EXPECT_EQ(d.environment_words(),
              " LD_LIBRARY_PATH='/opt/lvp 25/lib:/inherited' "
              "VK_DRIVER_FILES='/opt/lvp 25/lvp_icd.json'");
    EXPECT_NE(d.missing_message().find("/opt/lvp 25/lvp_icd.json does not exist"),
              std::string::npos)
        << d.missing_message();
}

TEST(TestDriver, LeavesLdLibraryPathAloneWithoutALibraryPath) {
    ScopedEnvironment env;
    env.set("CLASTRACE_TEST_DRIVER_FILES", "/x/icd.json");
    env.set("CLASTRACE_TEST_DRIVER_LIBRARY_PATH", nullptr);
    env.set("LD_LIBRARY_PATH", nullptr);
    EXPECT_EQ(test_driver().environment(),
              (std::map<std::string, std::string>{{"VK_DRIVER_FILES", "/x/icd.json"}}));
    env.set("CLASTRACE_TEST_DRIVER_LIBRARY_PATH", "/x/lib");
    EXPECT_EQ(test_driver().environment().at("LD_LIBRARY_PATH"), "/x/lib");  // no trailing ':'
}

TEST(TestDriver, SelectsItselfForThisProcessOverTheOlderVariable) {
    ScopedEnvironment env;
    env.set("VK_ICD_FILENAMES", "/old/icd.json");
    env.set("VK_DRIVER_FILES", nullptr);
    TestDriver{"/x/icd.json", ""}.select_in_this_process();
    EXPECT_STREQ(std::getenv("VK_DRIVER_FILES"), "/x/icd.json");
    EXPECT_EQ(std::getenv("VK_ICD_FILENAMES"), nullptr);
}

}  // namespace
