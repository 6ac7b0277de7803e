// SPDX-License-Identifier: Apache-2.0
// Tests that run programs as applications run them: on the test driver (lavapipe unless
// CLASTRACE_TEST_DRIVER_FILES names another: clastrace/testsupport/test_driver.h) through the
// Vulkan loader, with
// the capture layer found through VK_ADD_LAYER_PATH (or without it), each test in a directory of
// its own that is kept when the test fails.
#pragma once

#include <clastrace/testsupport/test_driver.h>
#include <gtest/gtest.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace clastrace::layer_launch {

inline constexpr const char* kCaptureLayer = "VK_LAYER_CLASTRACE_capture";
inline constexpr const char* kValidationLayerManifest =
    "/usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json";
inline constexpr const char* kCaptureOverValidation =
    "VK_LAYER_CLASTRACE_capture:VK_LAYER_KHRONOS_validation";

struct ProcessResult {
    int exitCode = -1;  // -signal when it was killed by one (where the runner can tell)
    std::string out, err;
};

std::string readText(const std::filesystem::path& path);
// `s` as one shell word.
std::string quote(const std::string& s);
size_t count(const std::string& text, const std::string& needle);
std::string hexOf(const std::vector<uint8_t>& bytes);

class LayerLaunchTest : public ::testing::Test {
public:
    std::filesystem::path dir;  // the test's own directory; also XDG_RUNTIME_DIR of what it runs

protected:
    explicit LayerLaunchTest(std::string directoryPrefix)
        : directoryPrefix_(std::move(directoryPrefix)) {}
    void SetUp() override;  // skips the test when the test driver is not installed
    void TearDown() override;

    // "env -u ... NAME=VALUE ...": every layer setting and loader variable of the caller cleared,
    // the test driver the only driver, `layers` enabled from the build tree's manifest (none when empty),
    // `env` on top.
    std::string cleanEnvironment(std::map<std::string, std::string> env,
                                 const std::string& layers) const;
    // Runs the shell command `command` (at most 120 s) in that environment; its output goes to
    // dir/stdout.txt and dir/stderr.txt and comes back in the result.
    ProcessResult run(const std::string& command, std::map<std::string, std::string> env,
                      bool withLayer = true);
    // The Khronos validation layer beneath the capture layer (so it sees what the driver sees),
    // with synchronization validation and its errors and warnings logged: writes
    // dir/vk_layer_settings.txt and returns the environment entries that load both layers.
    // Callers skip the test when kValidationLayerManifest does not exist.
    std::map<std::string, std::string> synchronizationValidation() const;

private:
    std::string directoryPrefix_;
};

// A LayerLaunchTest on the ray-tracing driver (lavapipe 25: clastrace/testsupport/test_driver.h);
// skips when it is not unpacked.
class RayTracingLaunchTest : public LayerLaunchTest {
protected:
    using LayerLaunchTest::LayerLaunchTest;
    void SetUp() override;

    // `command` (a program and its arguments, as shell words) on the driver, without the layer.
    ProcessResult runOnDriver(const std::string& command);
    // `clastrace capture OPTIONS -o TRACE --layer-path <the build tree's manifest> -- COMMAND` on
    // the driver.
    ProcessResult captureOnDriver(const std::filesystem::path& trace, const std::string& command,
                                  const std::string& options = "");

    std::optional<testsupport::TestDriver> driver;
};

}  // namespace clastrace::layer_launch
