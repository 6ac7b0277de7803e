// SPDX-License-Identifier: Apache-2.0
#include "clastrace/testsupport/test_driver.h"

#include <cstdlib>
#include <filesystem>

namespace clastrace::testsupport {

namespace {

std::string environment_value(const char* name) {
    const char* v = std::getenv(name);
    return v ? v : "";
}

std::string shell_word(const std::string& s) {
    std::string q = "'";
    for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return q + "'";
}

}  // namespace

bool TestDriver::installed() const { return std::filesystem::exists(driver_files); }

std::map<std::string, std::string> TestDriver::environment() const {
    std::map<std::string, std::string> env{{"VK_DRIVER_FILES", driver_files}};
    if (!library_path.empty()) {
        const std::string inherited = environment_value("LD_LIBRARY_PATH");
        env["LD_LIBRARY_PATH"] = library_path + (inherited.empty() ? "" : ":" + inherited);
    }
    return env;
}

std::string TestDriver::environment_words() const {
    std::string words;
    for (const auto& [name, value] : environment()) words += " " + name + "=" + shell_word(value);
    return words;
}

void TestDriver::select_in_this_process() const {
    setenv("VK_DRIVER_FILES", driver_files.c_str(), 1);
    unsetenv("VK_ICD_FILENAMES");  // older loaders' name; it would win over VK_DRIVER_FILES
}

std::string TestDriver::missing_message() const {
    if (driver_files == kSystemLavapipe)
        return "lavapipe is not installed (scripts/deps.sh installs it)";
    return "the test driver " + driver_files +
           " does not exist (CLASTRACE_TEST_DRIVER_FILES; scripts/lavapipe_rt.sh unpacks "
           "lavapipe 25)";
}

TestDriver test_driver() {
    const std::string files = environment_value("CLASTRACE_TEST_DRIVER_FILES");
    if (files.empty()) return {kSystemLavapipe, ""};
    return {files, environment_value("CLASTRACE_TEST_DRIVER_LIBRARY_PATH")};
}

std::optional<TestDriver> ray_tracing_driver() {
    TestDriver d{environment_value("CLASTRACE_RT_DRIVER_FILES"),
                 environment_value("CLASTRACE_RT_DRIVER_LIBRARY_PATH")};
    if (d.driver_files.empty()) {
        // Where scripts/lavapipe_rt.sh unpacks it, as configured (CLASTRACE_RT_DRIVER_DIR).
        const std::filesystem::path dir = CLASTRACE_RT_DRIVER_DIR;
        d = {(dir / "lvp_icd.json").string(), (dir / "root/usr/lib/x86_64-linux-gnu").string()};
    }
    if (!d.installed()) return std::nullopt;
    return d;
}

}  // namespace clastrace::testsupport
