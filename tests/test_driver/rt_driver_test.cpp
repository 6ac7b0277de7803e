// SPDX-License-Identifier: Apache-2.0
// The ray-tracing tests' driver (ctest label rt-driver) is what they need: through the Vulkan
// loader, with the environment every rt-driver test gives its programs, vulkaninfo names Mesa
// 25.0.7's lavapipe at Vulkan 1.4 and lists acceleration structures, ray queries, ray-tracing
// pipelines, position fetch and mesh shaders, and sparse binding.
#include <clastrace/testsupport/test_driver.h>

#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>

namespace {

namespace fs = std::filesystem;

std::string vulkaninfo_on(const clastrace::testsupport::TestDriver& driver, const fs::path& dir) {
    const fs::path out = dir / "vulkaninfo.txt";
    const std::string line = "env -u VK_ICD_FILENAMES -u VK_INSTANCE_LAYERS -u VK_ADD_LAYER_PATH" +
                             driver.environment_words() + " XDG_RUNTIME_DIR=" + dir.string() +
                             " vulkaninfo >" + out.string() + " 2>/dev/null";
    if (std::system(line.c_str()) != 0) return "";
    std::ifstream in(out);
    std::stringstream text;
    text << in.rdbuf();
    return text.str();
}

TEST(RayTracingDriver, IsLavapipe25WithRayTracingMeshShadersAndSparseBinding) {
    const auto driver = clastrace::testsupport::ray_tracing_driver();
    if (!driver) GTEST_SKIP() << clastrace::testsupport::kNoRayTracingDriver;
    if (std::system("command -v vulkaninfo >/dev/null 2>&1") != 0)
        GTEST_SKIP() << "vulkaninfo is not installed (scripts/deps.sh --tests installs it)";
    const fs::path dir = fs::temp_directory_path() / ("clastrace_rt_" + std::to_string(getpid()));
    fs::create_directories(dir);
    const std::string info = vulkaninfo_on(*driver, dir);
    fs::remove_all(dir);
    ASSERT_FALSE(info.empty()) << "vulkaninfo failed on " << driver->driver_files;
    for (const char* line : {"driverInfo *= Mesa 25\\.0\\.7", "apiVersion *= 1\\.4\\.305",
                             "sparseBinding *= true", "VK_KHR_acceleration_structure +:",
                             "VK_KHR_ray_query +:", "VK_KHR_ray_tracing_pipeline +:",
                             "VK_KHR_ray_tracing_position_fetch +:", "VK_EXT_mesh_shader +:"})
        EXPECT_TRUE(std::regex_search(info, std::regex(std::string("\\s") + line))) << line;
}

}  // namespace
