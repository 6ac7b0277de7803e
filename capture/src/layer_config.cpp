// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/layer_config.h"

#include "decimal_text.h"

#include <cstdio>
#include <cstdlib>
#include <mutex>

namespace clastrace::capture {
namespace {

constexpr uint64_t kMaxRayCheckRays = 1u << 20;  // 48 MiB of rays and answers per check

std::optional<bool> parse_switch(const std::string& text) {
    if (text == "1" || text == "on" || text == "true") return true;
    if (text == "0" || text == "off" || text == "false") return false;
    return std::nullopt;
}

std::optional<IndexRange> parse_range(const std::string& text) {
    const size_t dash = text.find('-');
    if (dash == std::string::npos) {
        auto single = parse_decimal(text);
        if (!single) return std::nullopt;
        return IndexRange{*single, *single};
    }
    auto first = parse_decimal(text.substr(0, dash));
    if (!first) return std::nullopt;
    const std::string tail = text.substr(dash + 1);
    if (tail.empty()) return IndexRange{*first, UINT64_MAX};
    auto last = parse_decimal(tail);
    if (!last || *last < *first) return std::nullopt;
    return IndexRange{*first, *last};
}

// Reads the layer's variables one by one into a LayerConfig; a value that does not parse
// leaves the default and adds one line to `errors`.
class SettingReader {
public:
    SettingReader(const std::function<const char*(const char*)>& getenv, LayerConfig* config)
        : getenv_(getenv), config_(config) {}

    std::optional<std::string> value(const char* name) const {
        const char* v = getenv_(name);
        if (!v) return std::nullopt;
        return std::string(v);
    }
    void reject(const char* name, const std::string& got, const char* expected) {
        config_->errors.push_back(std::string(name) + "='" + got + "' is not " + expected +
                                  "; using the default");
    }
    void read_switch(const char* name, bool* field) {
        if (auto v = value(name)) {
            if (auto on = parse_switch(*v))
                *field = *on;
            else
                reject(name, *v, "0 or 1");
        }
    }
    void read_range(const char* name, IndexRange* field, const char* expected) {
        if (auto v = value(name)) {
            if (auto range = parse_range(*v))
                *field = *range;
            else
                reject(name, *v, expected);
        }
    }
    void read_at_most(const char* name, uint64_t max, uint32_t* field, const char* expected) {
        if (auto v = value(name)) {
            auto n = parse_decimal(*v);
            if (n && *n <= max)
                *field = uint32_t(*n);
            else
                reject(name, *v, expected);
        }
    }

private:
    const std::function<const char*(const char*)>& getenv_;
    LayerConfig* config_;
};

void read_output_settings(SettingReader& r, LayerConfig& config) {
    if (auto v = r.value("CLASTRACE_OUTPUT")) config.output_path = *v;
    if (auto v = r.value("CLASTRACE_OUTPUT_FD")) {
        if (auto fd = parse_decimal(*v); fd && *fd <= INT32_MAX)
            config.output_fd = int(*fd);
        else
            r.reject("CLASTRACE_OUTPUT_FD", *v, "a file descriptor number");
    }
    if (auto v = r.value("CLASTRACE_ZSTD_LEVEL")) {
        // zstd's fast levels (-1 fastest of them ... -100) trade ratio for compressor CPU.
        const bool fast = !v->empty() && (*v)[0] == '-';
        auto level = parse_decimal(fast ? v->substr(1) : *v);
        if (level && *level >= 1 && *level <= (fast ? 100u : 22u))
            config.zstd_level = fast ? -int(*level) : int(*level);
        else
            r.reject("CLASTRACE_ZSTD_LEVEL", *v,
                     "a zstd level from 1 to 22, or a fast level from -1 to -100");
    }
    if (auto v = r.value("CLASTRACE_LOG")) {
        if (*v == "quiet" || *v == "0")
            config.log = LogLevel::kQuiet;
        else if (*v == "error" || *v == "1")
            config.log = LogLevel::kError;
        else if (*v == "info" || *v == "2")
            config.log = LogLevel::kInfo;
        else if (*v == "debug" || *v == "3")
            config.log = LogLevel::kDebug;
        else
            r.reject("CLASTRACE_LOG", *v, "quiet, error, info or debug");
    }
    if (auto v = r.value("CLASTRACE_DEBUG_JSON")) config.debug_json_path = *v;
    r.read_at_most("CLASTRACE_FLUSH_MS", 3600000, &config.flush_milliseconds,
                   "milliseconds from 0 (never) to 3600000");
    r.read_switch("CLASTRACE_STATS", &config.stats);
    r.read_switch("CLASTRACE_DELTA_CONTENTS", &config.delta_contents);
    if (auto v = r.value("CLASTRACE_BACKGROUND_CPUS")) {
        if (*v == "spare")
            config.background_cpus = {BackgroundCpus::Mode::kSpare, {}};
        else if (*v == "app")
            config.background_cpus = {BackgroundCpus::Mode::kApp, {}};
        else if (auto cpus = parse_cpu_list(*v))
            config.background_cpus = {BackgroundCpus::Mode::kList, *cpus};
        else
            r.reject("CLASTRACE_BACKGROUND_CPUS", *v, "spare, app or a CPU list such as 6-7,12");
    }
}

void read_capture_settings(SettingReader& r, LayerConfig& config) {
    r.read_switch("CLASTRACE_CAPTURE", &config.capture);
    if (auto v = r.value("CLASTRACE_SERVE")) {
        if (*v == "auto")
            config.serve = ServeMode::kAuto;
        else if (auto on = parse_switch(*v))
            config.serve = *on ? ServeMode::kOn : ServeMode::kOff;
        else
            r.reject("CLASTRACE_SERVE", *v, "0, 1 or auto");
    }
    r.read_range("CLASTRACE_SUBMIT_RANGE", &config.submit_range, "N, A-B (A <= B) or A-");
    r.read_range("CLASTRACE_FRAME_RANGE", &config.frame_range,
                 "N, A-B (A <= B) or A- (0-based frames)");
    r.read_at_most("CLASTRACE_RAY_CHECK", kMaxRayCheckRays, &config.ray_check_rays,
                   "a ray count from 0 to 1048576");
    r.read_at_most("CLASTRACE_SHARED_WAIT_MS", 3600000, &config.shared_wait_milliseconds,
                   "milliseconds from 0 to 3600000");
    r.read_switch("CLASTRACE_PRE_RANGE_STATE", &config.pre_range_state);
    r.read_switch("CLASTRACE_FORCE_STAGING", &config.force_staging);
    r.read_switch("CLASTRACE_TIMESTAMPS", &config.timestamps);
    r.read_switch("CLASTRACE_GUARD_REST", &config.guard_rest);
    if (auto v = r.value("CLASTRACE_DEVICE_ADDRESS_WRITES")) {
        if (*v == "cheap" || *v == "off" || *v == "exact") {
            config.mark_device_address_writers = *v != "off";
            config.exact_device_address_writes = *v == "exact";
        } else {
            r.reject("CLASTRACE_DEVICE_ADDRESS_WRITES", *v, "cheap, exact or off");
        }
    }
    if (auto v = r.value("CLASTRACE_HOST_WRITES")) {
        if (*v == "hash" || *v == "guard") {
            config.host_writes = true;
            config.host_write_guard = *v == "guard";
        } else if (auto on = parse_switch(*v)) {
            config.host_writes = *on;
        } else {
            r.reject("CLASTRACE_HOST_WRITES", *v, "guard, hash, 1 (guard) or 0");
        }
    }
}

}  // namespace

LayerConfig parse_layer_config(const std::function<const char*(const char*)>& getenv) {
    LayerConfig config;
    SettingReader reader(getenv, &config);
    read_capture_settings(reader, config);
    read_output_settings(reader, config);
    return config;
}

const LayerConfig& layer_config() {
    static const LayerConfig kConfig = [] {
        LayerConfig parsed = parse_layer_config([](const char* name) { return std::getenv(name); });
        // Errors are printed even when CLASTRACE_LOG is quiet: a setting the user made was ignored.
        for (const std::string& error : parsed.errors)
            std::fprintf(stderr, "clastrace: %s\n", error.c_str());
        return parsed;
    }();
    return kConfig;
}

}  // namespace clastrace::capture
