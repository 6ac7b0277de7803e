// SPDX-License-Identifier: Apache-2.0
// The Vulkan driver the tests run on, named in one place. Tests that start Vulkan programs give
// them this driver's environment; the choice is the caller's environment at test time:
//   CLASTRACE_TEST_DRIVER_FILES         the ICD manifest (VK_DRIVER_FILES) of every Vulkan test;
//                                       unset: the system's lavapipe (kSystemLavapipe)
//   CLASTRACE_TEST_DRIVER_LIBRARY_PATH  folders put before LD_LIBRARY_PATH of what runs on it
//                                       (a privately unpacked driver's libraries)
// Tests that need ray tracing (ctest label `rt-driver`) run on ray_tracing_driver() instead:
// Mesa 25.0.7's lavapipe that scripts/lavapipe_rt.sh unpacks (CLASTRACE_RT_DRIVER_DIR at
// configure time), or CLASTRACE_RT_DRIVER_FILES / CLASTRACE_RT_DRIVER_LIBRARY_PATH at test time.
#pragma once

#include <map>
#include <optional>
#include <string>

namespace clastrace::testsupport {

inline constexpr const char* kSystemLavapipe = "/usr/share/vulkan/icd.d/lvp_icd.x86_64.json";

struct TestDriver {
    std::string driver_files;  // the ICD manifest, for VK_DRIVER_FILES
    std::string library_path;  // before LD_LIBRARY_PATH; empty when the system's paths do

    bool installed() const;  // the manifest exists
    // VK_DRIVER_FILES and, with a library path, LD_LIBRARY_PATH (the caller's appended) for the
    // environment of a program started on this driver.
    std::map<std::string, std::string> environment() const;
    // The same as " NAME=VALUE" words for an `env ...` command line, each value quoted.
    std::string environment_words() const;
    // Makes the Vulkan loader of this process pick this driver (VK_DRIVER_FILES). The library
    // path cannot change for a running process: ctest gives it through LD_LIBRARY_PATH when set.
    void select_in_this_process() const;
    // "lavapipe is not installed ..." or "the test driver ... does not exist ...": why the tests
    // that need it skip.
    std::string missing_message() const;
};

// The driver of every Vulkan test (see above).
TestDriver test_driver();
// The ray-tracing driver, when it is unpacked; nullopt otherwise (tests skip with
// kNoRayTracingDriver).
std::optional<TestDriver> ray_tracing_driver();

inline constexpr const char* kNoRayTracingDriver =
    "needs lavapipe 25 (ray tracing), which is not unpacked: run scripts/lavapipe_rt.sh "
    "(scripts/deps.sh --tests runs it), or set CLASTRACE_RT_DRIVER_FILES";

}  // namespace clastrace::testsupport
