// SPDX-License-Identifier: Apache-2.0
#include "layer_launch_test.h"

#include <clastrace/common/hex.h>
#include <clastrace/testsupport/test_driver.h>

#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

namespace clastrace::layer_launch {

namespace fs = std::filesystem;

std::string readText(const fs::path& path) {
    std::ifstream in(path);
    std::stringstream text;
    text << in.rdbuf();
    return text.str();
}

std::string quote(const std::string& s) {
    std::string q = "'";
    for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return q + "'";
}

size_t count(const std::string& text, const std::string& needle) {
    size_t n = 0;
    for (size_t at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1))
        ++n;
    return n;
}

std::string hexOf(const std::vector<uint8_t>& bytes) { return clastrace::common::hex_bytes(bytes); }

void LayerLaunchTest::SetUp() {
    const auto driver = clastrace::testsupport::test_driver();
    if (!driver.installed()) GTEST_SKIP() << driver.missing_message();
    // Parameterized tests' names hold '/'.
    std::string name = ::testing::UnitTest::GetInstance()->current_test_info()->name();
    for (char& c : name)
        if (c == '/') c = '_';
    dir = fs::temp_directory_path() /
          (directoryPrefix_ + "_" + std::to_string(getpid()) + "_" + name);
    fs::remove_all(dir);
    fs::create_directories(dir);
}

void LayerLaunchTest::TearDown() {
    if (!HasFailure() && !dir.empty()) fs::remove_all(dir);
}

std::string LayerLaunchTest::cleanEnvironment(std::map<std::string, std::string> env,
                                              const std::string& layers) const {
    std::string line = "env -u VK_INSTANCE_LAYERS -u VK_ADD_LAYER_PATH -u VK_ICD_FILENAMES";
    for (const char* v :
         {"CLASTRACE_OUTPUT", "CLASTRACE_CAPTURE", "CLASTRACE_SERVE", "CLASTRACE_SUBMIT_RANGE",
          "CLASTRACE_ZSTD_LEVEL", "CLASTRACE_LOG", "CLASTRACE_DEBUG_JSON", "CLASTRACE_FLUSH_MS",
          "CLASTRACE_FORCE_STAGING", "CLASTRACE_TIMESTAMPS", "CLASTRACE_RAY_CHECK",
          "CLASTRACE_STATS", "CLASTRACE_SHARED_WAIT_MS", "CLASTRACE_FRAME_RANGE",
          "CLASTRACE_BACKGROUND_CPUS", "CLASTRACE_DEVICE_ADDRESS_WRITES"})
        line += std::string(" -u ") + v;
    for (const auto& [name, value] : clastrace::testsupport::test_driver().environment())
        env[name] = value;
#ifdef CLASTRACE_ASAN_RUNTIME
    // The layer is built with ASan, whose runtime must come first in a process's libraries.
    env.try_emplace("LD_PRELOAD", CLASTRACE_ASAN_RUNTIME);
#endif
    env["XDG_RUNTIME_DIR"] = dir.string();
    env["VK_LOADER_DEBUG"] = "";  // the loader's own warnings are not the programs' output
    if (!layers.empty()) {
        env["VK_ADD_LAYER_PATH"] = CLASTRACE_LAYER_MANIFEST_DIR;
        env["VK_INSTANCE_LAYERS"] = layers;
    }
    for (const auto& [k, v] : env) line += " " + k + "=" + quote(v);
    return line;
}

std::map<std::string, std::string> LayerLaunchTest::synchronizationValidation() const {
    const fs::path settings = dir / "vk_layer_settings.txt";
    std::ofstream(settings) << "khronos_validation.enables = "
                               "VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT\n"
                               "khronos_validation.report_flags = error,warn\n"
                               "khronos_validation.debug_action = VK_DBG_LAYER_ACTION_LOG_MSG\n";
    return {{"VK_ADD_LAYER_PATH", CLASTRACE_LAYER_MANIFEST_DIR},
            {"VK_INSTANCE_LAYERS", kCaptureOverValidation},
            {"VK_LAYER_SETTINGS_PATH", settings.string()}};
}

ProcessResult LayerLaunchTest::run(const std::string& command,
                                   std::map<std::string, std::string> env, bool withLayer) {
    const fs::path out = dir / "stdout.txt", err = dir / "stderr.txt";
    const std::string line = cleanEnvironment(std::move(env), withLayer ? kCaptureLayer : "") +
                             " timeout 120 " + command + " >" + quote(out.string()) + " 2>" +
                             quote(err.string());
    ProcessResult r;
    const int status = std::system(line.c_str());
    r.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.out = readText(out);
    r.err = readText(err);
    return r;
}

void RayTracingLaunchTest::SetUp() {
    LayerLaunchTest::SetUp();
    if (IsSkipped()) return;
    driver = testsupport::ray_tracing_driver();
    if (!driver) GTEST_SKIP() << testsupport::kNoRayTracingDriver;
}

ProcessResult RayTracingLaunchTest::runOnDriver(const std::string& command) {
    return run("env" + driver->environment_words() + " " + command, {}, false);
}

ProcessResult RayTracingLaunchTest::captureOnDriver(const fs::path& trace,
                                                    const std::string& command,
                                                    const std::string& options) {
    return runOnDriver(std::string(CLASTRACE_CLI_PATH) + " capture " + options + " -o " +
                       quote(trace.string()) + " --layer-path " + CLASTRACE_LAYER_MANIFEST_DIR +
                       " -- " + command);
}

}  // namespace clastrace::layer_launch
