// `clastrace capture -o OUT.clt [options] -- APP [ARGS...]`: runs APP with the capture layer
// enabled through the Vulkan loader's environment variables, and reports what it wrote.
#include "commands.h"

#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

namespace clastrace::tools {
namespace {

namespace fs = std::filesystem;

constexpr const char* kLayerName = "VK_LAYER_CLASTRACE_capture";
constexpr const char* kManifestName = "VkLayer_clastrace_capture.json";

struct CaptureOptions {
  std::string output;
  std::string submitRange;
  std::string frames;  // CLASTRACE_FRAME_RANGE
  int zstdLevel = 3;
  std::string serve = "auto";
  bool noCapture = false;
  std::string log = "error";
  std::string layerPath;
  uint32_t rayCheck = 0;  // CLASTRACE_RAY_CHECK: rays per NV top level, 0 = off
  std::string backgroundCpus;  // CLASTRACE_BACKGROUND_CPUS
  std::vector<std::string> command;
};

// The manifest next to this program: the build tree's (tools/../capture/manifest) or the
// installed one (bin/../share/vulkan/explicit_layer.d). Empty: leave it to the loader's search.
std::string findManifestDir() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (ec) return {};
  for (const fs::path& candidate : {self.parent_path().parent_path() / "capture" / "manifest",
                                    self.parent_path().parent_path() / "share" / "vulkan" / "explicit_layer.d"})
    if (fs::exists(candidate / kManifestName, ec)) return candidate.string();
  return {};
}

void prependList(const char* variable, const std::string& value) {
  const char* old = std::getenv(variable);
  std::string joined = value;
  if (old && *old) joined += std::string(":") + old;
  setenv(variable, joined.c_str(), 1);
}

int runCapture(const CaptureOptions& o) {
  if (o.command.empty()) {
    std::fprintf(stderr, "clastrace capture: no application given (put it after --)\n");
    return kExitUsage;
  }
  const fs::path output = fs::absolute(o.output);
  if (!o.noCapture) {
    std::FILE* probe = std::fopen(output.c_str(), "wb");
    if (!probe) {
      std::fprintf(stderr, "clastrace capture: cannot write '%s': %s\n", output.c_str(), std::strerror(errno));
      return kExitUsage;
    }
    std::fclose(probe);
  }
  const std::string manifestDir = o.layerPath.empty() ? findManifestDir() : o.layerPath;
  if (!manifestDir.empty()) prependList("VK_ADD_LAYER_PATH", manifestDir);
  const char* layers = std::getenv("VK_INSTANCE_LAYERS");
  if (!layers || !std::strstr(layers, kLayerName)) prependList("VK_INSTANCE_LAYERS", kLayerName);
  setenv("CLASTRACE_OUTPUT", output.c_str(), 1);
  setenv("CLASTRACE_CAPTURE", o.noCapture ? "0" : "1", 1);
  setenv("CLASTRACE_SERVE", o.serve.c_str(), 1);
  setenv("CLASTRACE_ZSTD_LEVEL", std::to_string(o.zstdLevel).c_str(), 1);
  setenv("CLASTRACE_LOG", o.log.c_str(), 1);
  if (o.rayCheck) setenv("CLASTRACE_RAY_CHECK", std::to_string(o.rayCheck).c_str(), 1);
  if (!o.submitRange.empty()) setenv("CLASTRACE_SUBMIT_RANGE", o.submitRange.c_str(), 1);
  else unsetenv("CLASTRACE_SUBMIT_RANGE");
  if (!o.frames.empty()) setenv("CLASTRACE_FRAME_RANGE", o.frames.c_str(), 1);
  else unsetenv("CLASTRACE_FRAME_RANGE");
  if (!o.backgroundCpus.empty()) setenv("CLASTRACE_BACKGROUND_CPUS", o.backgroundCpus.c_str(), 1);

  std::vector<char*> argv;
  for (const std::string& a : o.command) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  const pid_t child = fork();
  if (child < 0) {
    std::fprintf(stderr, "clastrace capture: fork failed: %s\n", std::strerror(errno));
    return kExitUsage;
  }
  if (child == 0) {
    execvp(argv[0], argv.data());
    std::fprintf(stderr, "clastrace capture: cannot run '%s': %s\n", argv[0], std::strerror(errno));
    _exit(127);
  }
  int status = 0;
  while (waitpid(child, &status, 0) < 0 && errno == EINTR) {
  }
  const int code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  std::error_code ec;
  if (!o.noCapture) {
    const auto size = fs::file_size(output, ec);
    if (ec || size == 0)
      std::fprintf(stderr, "clastrace capture: '%s' was not written (did the application create a Vulkan device?)\n",
                   output.c_str());
    else
      std::fprintf(stderr, "clastrace capture: wrote '%s' (%llu bytes)\n", output.c_str(), (unsigned long long)size);
  }
  return code;  // the application's own exit code
}

// The layer's syntax (capture/src/layer_config.cpp): checked here too, so a typo stops before
// the application runs instead of capturing every frame.
CLI::Validator frameRangeValidator() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        auto number = [](const std::string& t) {
          return !t.empty() && t.size() <= 19 && t.find_first_not_of("0123456789") == std::string::npos;
        };
        const size_t dash = text.find('-');
        const std::string first = text.substr(0, dash);
        const std::string last = dash == std::string::npos ? first : text.substr(dash + 1);
        bool ok = number(first) && (last.empty() || number(last));
        if (ok && !last.empty() && std::stoull(last) < std::stoull(first)) ok = false;
        if (dash == std::string::npos && !number(first)) ok = false;
        return ok ? std::string() : "'" + text + "' is not a frame range: N, A-B (A <= B) or A-";
      },
      "N|A-B|A-");
}

// CLASTRACE_BACKGROUND_CPUS's syntax (capture/src/background_cpus.cpp): spare, app, or CPUs
// and inclusive ranges joined by commas, each CPU below 4096.
CLI::Validator backgroundCpusValidator() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        if (text == "spare" || text == "app") return {};
        auto cpu = [](const std::string& t) {
          return !t.empty() && t.size() <= 4 && t.find_first_not_of("0123456789") == std::string::npos &&
                 std::stoul(t) < 4096;
        };
        bool ok = true;
        size_t at = 0;
        while (ok && at <= text.size()) {
          const size_t comma = std::min(text.find(',', at), text.size());
          const std::string item = text.substr(at, comma - at);
          const size_t dash = item.find('-');
          const std::string first = item.substr(0, dash);
          const std::string last = dash == std::string::npos ? first : item.substr(dash + 1);
          ok = cpu(first) && cpu(last) && std::stoul(last) >= std::stoul(first);
          at = comma + 1;
        }
        return ok ? std::string() : "'" + text + "' is not spare, app or a CPU list such as 6-7,12";
      },
      "spare|app|LIST");
}

}  // namespace

Command register_capture(CLI::App& app) {
  auto options = std::make_shared<CaptureOptions>();
  CLI::App* sub = app.add_subcommand(
      "capture",
      "Run an application with the capture layer and write its cluster builds to a .clt trace.\n"
      "Exit code: the application's (2 when it could not be started or the output is unwritable).");
  sub->add_option("-o,--output", options->output, "trace to write (.clt)")->required();
  sub->add_option("--submit-range", options->submitRange, "queue submissions to capture: N, A-B or A- (0-based)");
  sub->add_option("--frames", options->frames,
                  "frames to capture: N, A-B or A- (0-based; frame N is what is submitted after the N-th "
                  "vkQueuePresentKHR and up to the next). With --submit-range too, a submission is captured only "
                  "when it is in both")
      ->check(frameRangeValidator());
  sub->add_option("--zstd-level", options->zstdLevel,
                  "zstd level of the trace's chunks: 1..22, or a fast level -1..-100 (faster, larger)")
      ->check(CLI::Range(-100, 22) &
              CLI::Validator([](std::string& v) { return std::string(v == "0" ? "0 is not a level" : ""); }, "NOT 0"));
  sub->add_option("--serve", options->serve, "serve VK_NV_cluster_acceleration_structure: auto (when the driver "
                                             "lacks it), on, off")
      ->check(CLI::IsMember({"auto", "on", "off", "0", "1"}));
  sub->add_flag("--no-capture", options->noCapture, "only serve the extension, write nothing");
  sub->add_option("--log", options->log, "layer messages: quiet, error, info, debug")
      ->check(CLI::IsMember({"quiet", "error", "info", "debug"}));
  sub->add_option("--ray-check", options->rayCheck,
                  "after each NV top-level build, trace N rays with the driver and record its hits "
                  "(RayQueryCheck; needs VK_NV_ray_tracing)")
      ->check(CLI::Range(0, 1048576));
  sub->add_option("--background-cpus", options->backgroundCpus,
                  "CPUs for the capture's background threads (trace writing and compression): spare (default: "
                  "the CPUs the application may not run on, if any), app (the application's), or a list such as "
                  "6-7,12")
      ->check(backgroundCpusValidator());
  sub->add_option("--layer-path", options->layerPath, "folder holding VkLayer_clastrace_capture.json");
  sub->add_option("command", options->command, "the application and its arguments (after --)")->required();
  return {sub, [options] {
            CaptureOptions o = *options;
            if (o.serve == "on") o.serve = "1";
            if (o.serve == "off") o.serve = "0";
            return runCapture(o);
          }};
}

}  // namespace clastrace::tools
