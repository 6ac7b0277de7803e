// SPDX-License-Identifier: Apache-2.0
// `clastrace capture -o OUT.clt [options] -- APP [ARGS...]`: runs APP with the capture layer
// enabled through the Vulkan loader's environment variables, and reports what it wrote.
#include "commands.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include <clastrace/traces/output_file.h>

namespace clastrace::tools {
namespace {

namespace fs = std::filesystem;

constexpr const char* kLayerName = "VK_LAYER_CLASTRACE_capture";
constexpr const char* kManifestName = "VkLayer_clastrace_capture.json";

struct CaptureOptions {
    std::string output;
    std::string submit_range;
    std::string frames;  // CLASTRACE_FRAME_RANGE
    int zstd_level = 3;
    std::string serve = "auto";
    bool no_capture = false;
    std::string log = "error";
    std::string layer_path;
    uint32_t ray_check = 0;       // CLASTRACE_RAY_CHECK: rays per NV/KHR top level, 0 = off
    std::string background_cpus;  // CLASTRACE_BACKGROUND_CPUS
    std::vector<std::string> command;
};

// The manifest next to this program: the build tree's (tools/../capture/manifest) or the
// installed one (bin/../share/vulkan/explicit_layer.d). Empty: leave it to the loader's search.
std::string find_manifest_dir() {
    std::error_code ec;
    const fs::path self = fs::read_symlink("/proc/self/exe", ec);
    if (ec) return {};
    for (const fs::path& candidate :
         {self.parent_path().parent_path() / "capture" / "manifest",
          self.parent_path().parent_path() / "share" / "vulkan" / "explicit_layer.d"})
        if (fs::exists(candidate / kManifestName, ec)) return candidate.string();
    return {};
}

void prepend_list(const char* variable, const std::string& value) {
    const char* old = std::getenv(variable);
    std::string joined = value;
    if (old && *old) joined += std::string(":") + old;
    setenv(variable, joined.c_str(), 1);
}

// Where execvp would find `name`: a path as given, else the first PATH entry holding an
// executable regular file. Empty, with *error, when the application could not be started.
std::string find_program(const std::string& name, std::string* error) {
    auto runnable = [](const std::string& path, int* err) {
        struct stat st {};
        if (::stat(path.c_str(), &st) != 0)
            *err = errno;
        else if (!S_ISREG(st.st_mode))
            *err = S_ISDIR(st.st_mode) ? EISDIR : EACCES;
        else if (::access(path.c_str(), X_OK) != 0)
            *err = errno;
        else
            return true;
        return false;
    };
    int err = ENOENT;
    if (name.find('/') != std::string::npos) {
        if (runnable(name, &err)) return name;
    } else if (!name.empty()) {
        const char* path = std::getenv("PATH");
        const std::string entries = path ? path : "/bin:/usr/bin";
        for (size_t at = 0; at <= entries.size();) {
            const size_t colon = std::min(entries.find(':', at), entries.size());
            const std::string dir = colon == at ? "." : entries.substr(at, colon - at);
            int candidate_err = 0;
            if (runnable(dir + "/" + name, &candidate_err)) return dir + "/" + name;
            if (candidate_err != ENOENT && candidate_err != ENOTDIR)
                err = candidate_err;  // as execvp: EACCES wins
            at = colon + 1;
        }
        if (err == ENOENT) {
            *error = "cannot run '" + name + "': no such program on PATH";
            return {};
        }
    }
    *error = "cannot run '" + name + "': " + std::strerror(err);
    return {};
}

// The output while the application runs: opened and locked (traces/output_file.h) by this
// process and handed down to the layer (CLASTRACE_OUTPUT_FD), so that a second capture of the
// same path is refused before its application starts, and the final line can tell what the
// capture did to the file.
struct HeldOutput {
    int fd = -1;
    traces::OutputTarget target;
    bool created = false;   // absent before: removed again when nothing was written
    struct stat before {};  // a regular file's state before the application ran

    bool is_file() const {
        return target.kind == traces::OutputKind::kAbsent ||
               target.kind == traces::OutputKind::kRegular;
    }
    bool had_trace() const {
        return !created && target.kind == traces::OutputKind::kRegular && before.st_size > 0;
    }

    // Removes a file this run created and nobody wrote, then lets the lock go.
    void release() {
        struct stat now {};
        if (created && ::fstat(fd, &now) == 0 && now.st_size == 0) ::unlink(target.path.c_str());
        if (fd >= 0) ::close(fd);
        fd = -1;
    }
};

// The last line of a capture: what happened to the output.
void report_output(const std::string& path, HeldOutput& held) {
    if (!held.is_file()) {
        std::fprintf(stderr,
                     "clastrace capture: the trace went to %s '%s' as it was written (a device or "
                     "FIFO keeps no "
                     "size to check here; a write it refused is reported above)\n",
                     traces::output_kind_name(held.target.kind), path.c_str());
        return;
    }
    struct stat after {};
    ::fstat(held.fd, &after);
    const bool untouched = held.had_trace() && after.st_size == held.before.st_size &&
                           after.st_mtim.tv_sec == held.before.st_mtim.tv_sec &&
                           after.st_mtim.tv_nsec == held.before.st_mtim.tv_nsec;
    if (untouched)
        std::fprintf(
            stderr,
            "clastrace capture: '%s' was not written; the earlier trace there is kept (did the "
            "application create a Vulkan device?)\n",
            path.c_str());
    else if (after.st_size == 0)
        std::fprintf(stderr,
                     "clastrace capture: '%s' was not written (did the application create a Vulkan "
                     "device?)\n",
                     path.c_str());
    else
        std::fprintf(stderr, "clastrace capture: wrote '%s' (%llu bytes)%s\n", path.c_str(),
                     (unsigned long long)after.st_size,
                     held.had_trace() ? ", replacing the earlier trace there" : "");
}

int run_capture(const CaptureOptions& o) {
    if (o.output.empty()) {
        std::fprintf(stderr, "clastrace capture: -o names no file (the name is empty)\n");
        return kExitUsage;
    }
    if (o.command.empty()) {
        std::fprintf(stderr, "clastrace capture: no application given (put it after --)\n");
        return kExitUsage;
    }
    std::string problem;
    if (find_program(o.command[0], &problem).empty()) {
        std::fprintf(stderr, "clastrace capture: %s\n", problem.c_str());
        return kExitUsage;
    }
    std::error_code ec;
    const std::string output = fs::absolute(o.output, ec).string();
    HeldOutput held;
    if (!o.no_capture) {
        held.fd = traces::open_output_in_place(output, &held.target, &problem);
        if (held.fd < 0) {
            std::fprintf(stderr, "clastrace capture: %s\n", problem.c_str());
            return kExitUsage;
        }
        held.created = held.target.kind == traces::OutputKind::kAbsent;
        ::fstat(held.fd, &held.before);
    }
    const std::string manifest_dir = o.layer_path.empty() ? find_manifest_dir() : o.layer_path;
    if (!manifest_dir.empty()) prepend_list("VK_ADD_LAYER_PATH", manifest_dir);
    const char* layers = std::getenv("VK_INSTANCE_LAYERS");
    if (!layers || !std::strstr(layers, kLayerName)) prepend_list("VK_INSTANCE_LAYERS", kLayerName);
    setenv("CLASTRACE_OUTPUT", output.c_str(), 1);
    if (held.fd >= 0)
        setenv("CLASTRACE_OUTPUT_FD", std::to_string(held.fd).c_str(), 1);
    else
        unsetenv("CLASTRACE_OUTPUT_FD");
    setenv("CLASTRACE_CAPTURE", o.no_capture ? "0" : "1", 1);
    setenv("CLASTRACE_SERVE", o.serve.c_str(), 1);
    setenv("CLASTRACE_ZSTD_LEVEL", std::to_string(o.zstd_level).c_str(), 1);
    setenv("CLASTRACE_LOG", o.log.c_str(), 1);
    if (o.ray_check) setenv("CLASTRACE_RAY_CHECK", std::to_string(o.ray_check).c_str(), 1);
    if (!o.submit_range.empty())
        setenv("CLASTRACE_SUBMIT_RANGE", o.submit_range.c_str(), 1);
    else
        unsetenv("CLASTRACE_SUBMIT_RANGE");
    if (!o.frames.empty())
        setenv("CLASTRACE_FRAME_RANGE", o.frames.c_str(), 1);
    else
        unsetenv("CLASTRACE_FRAME_RANGE");
    if (!o.background_cpus.empty())
        setenv("CLASTRACE_BACKGROUND_CPUS", o.background_cpus.c_str(), 1);

    std::vector<char*> argv;
    for (const std::string& a : o.command) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    // The child reports a failed exec through this close-on-exec pipe: a successful exec closes
    // it unwritten.
    int exec_report[2];
    if (::pipe2(exec_report, O_CLOEXEC) != 0) {
        std::fprintf(stderr, "clastrace capture: cannot start '%s': %s\n", argv[0],
                     std::strerror(errno));
        held.release();
        return kExitUsage;
    }
    const pid_t child = fork();
    if (child < 0) {
        std::fprintf(stderr, "clastrace capture: cannot start '%s': fork failed: %s\n", argv[0],
                     std::strerror(errno));
        held.release();
        return kExitUsage;
    }
    if (child == 0) {
        if (held.fd >= 0) ::fcntl(held.fd, F_SETFD, 0);  // the layer takes it over
        execvp(argv[0], argv.data());
        const int err = errno;
        [[maybe_unused]] ssize_t n = ::write(exec_report[1], &err, sizeof err);
        _exit(127);
    }
    ::close(exec_report[1]);
    int exec_err = 0;
    ssize_t got;
    while ((got = ::read(exec_report[0], &exec_err, sizeof exec_err)) < 0 && errno == EINTR) {}
    ::close(exec_report[0]);
    int status = 0;
    while (waitpid(child, &status, 0) < 0 && errno == EINTR) {}
    if (got == sizeof exec_err) {
        std::fprintf(stderr, "clastrace capture: cannot run '%s': %s\n", argv[0],
                     std::strerror(exec_err));
        held.release();
        return kExitUsage;
    }
    const int code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    if (!o.no_capture) report_output(output, held);
    held.release();
    return code;  // the application's own exit code
}

// The layer's syntax of CLASTRACE_SUBMIT_RANGE and CLASTRACE_FRAME_RANGE
// (capture/src/layer_config.cpp): checked here too, so a typo stops before the application runs
// instead of capturing everything. `what`: "frame" or "submission".
CLI::Validator index_range_validator(const std::string& what) {
    return CLI::Validator(
        [what](std::string& text) -> std::string {
            auto number = [](const std::string& t) {
                return !t.empty() && t.size() <= 19 &&
                       t.find_first_not_of("0123456789") == std::string::npos;
            };
            const size_t dash = text.find('-');
            const std::string first = text.substr(0, dash);
            const std::string last = dash == std::string::npos ? first : text.substr(dash + 1);
            bool ok = number(first) && (last.empty() || number(last));
            if (ok && !last.empty() && std::stoull(last) < std::stoull(first)) ok = false;
            if (dash == std::string::npos && !number(first)) ok = false;
            return ok ? std::string()
                      : "'" + text + "' is not a " + what + " range: N, A-B (A <= B) or A-";
        },
        "N|A-B|A-");
}

// CLASTRACE_BACKGROUND_CPUS's syntax (capture/src/background_cpus.cpp): spare, app, or CPUs
// and inclusive ranges joined by commas, each CPU below 4096.
CLI::Validator background_cpus_validator() {
    return CLI::Validator(
        [](std::string& text) -> std::string {
            if (text == "spare" || text == "app") return {};
            auto cpu = [](const std::string& t) {
                return !t.empty() && t.size() <= 4 &&
                       t.find_first_not_of("0123456789") == std::string::npos &&
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
            return ok ? std::string()
                      : "'" + text + "' is not spare, app or a CPU list such as 6-7,12";
        },
        "spare|app|LIST");
}

}  // namespace

Command register_capture(CLI::App& app) {
    auto options = std::make_shared<CaptureOptions>();
    CLI::App* sub = app.add_subcommand(
        "capture",
        "Run an application with the capture layer and write its cluster builds to a .clt trace.\n"
        "Exit code: the application's; 2, with one line and before the application starts, when it "
        "cannot be run, "
        "an option is malformed or the output is refused (empty name, unwritable, a directory, "
        "block device or "
        "socket, or locked by another capture).\n"
        "The trace is written in place under a lock: an earlier file is emptied only when the "
        "application creates "
        "its first Vulkan device; a symbolic link's target is written; a character device or FIFO "
        "is written as it "
        "is. The last line says what happened to the output.");
    sub->add_option("-o,--output", options->output, "trace to write (.clt)")->required();
    sub->add_option("--submit-range", options->submit_range,
                    "queue submissions to capture: N, A-B or A- (0-based)")
        ->check(index_range_validator("submission"));
    sub->add_option(
           "--frames", options->frames,
           "frames to capture: N, A-B or A- (0-based; frame N is what is submitted after the N-th "
           "vkQueuePresentKHR and up to the next, or, in a program that does not present, after "
           "the N-th VkFrameBoundaryEXT frame end). With --submit-range too, a submission is "
           "captured only "
           "when it is in both")
        ->check(index_range_validator("frame"));
    sub->add_option(
           "--zstd-level", options->zstd_level,
           "zstd level of the trace's chunks: 1..22, or a fast level -1..-100 (faster, larger)")
        ->check(CLI::Range(-100, 22) &
                CLI::Validator(
                    [](std::string& v) { return std::string(v == "0" ? "0 is not a level" : ""); },
                    "NOT 0"));
    sub->add_option("--serve", options->serve,
                    "serve VK_NV_cluster_acceleration_structure: auto (when the driver "
                    "lacks it), on, off")
        ->check(CLI::IsMember({"auto", "on", "off", "0", "1"}));
    sub->add_flag("--no-capture", options->no_capture, "only serve the extension, write nothing");
    sub->add_option("--log", options->log, "layer messages: quiet, error, info, debug")
        ->check(CLI::IsMember({"quiet", "error", "info", "debug"}));
    sub->add_option(
           "--ray-check", options->ray_check,
           "after each NV or KHR top-level build, trace N rays with the driver and record its "
           "hits (RayQueryCheck; NV needs VK_NV_ray_tracing, KHR VK_KHR_ray_query, which the "
           "layer enables where the device has it)")
        ->check(CLI::Range(0, 1048576));
    sub->add_option("--background-cpus", options->background_cpus,
                    "CPUs for the capture's background threads (trace writing and compression): "
                    "spare (default: "
                    "the CPUs the application may not run on, if any), app (the application's), or "
                    "a list such as "
                    "6-7,12")
        ->check(background_cpus_validator());
    sub->add_option("--layer-path", options->layer_path,
                    "folder holding VkLayer_clastrace_capture.json");
    sub->add_option("command", options->command, "the application and its arguments (after --)")
        ->required();
    return {sub, [options] {
                CaptureOptions o = *options;
                if (o.serve == "on") o.serve = "1";
                if (o.serve == "off") o.serve = "0";
                return run_capture(o);
            }};
}

}  // namespace clastrace::tools
