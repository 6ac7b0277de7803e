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

}  // namespace

LayerConfig parse_layer_config(const std::function<const char*(const char*)>& getenv) {
    LayerConfig config;
    auto value = [&](const char* name) -> std::optional<std::string> {
        const char* v = getenv(name);
        if (!v) return std::nullopt;
        return std::string(v);
    };
    auto reject = [&](const char* name, const std::string& got, const char* expected) {
        config.errors.push_back(std::string(name) + "='" + got + "' is not " + expected +
                                "; using the default");
    };

    if (auto v = value("CLASTRACE_CAPTURE")) {
        if (auto on = parse_switch(*v))
            config.capture = *on;
        else
            reject("CLASTRACE_CAPTURE", *v, "0 or 1");
    }
    if (auto v = value("CLASTRACE_SERVE")) {
        if (*v == "auto")
            config.serve = ServeMode::kAuto;
        else if (auto on = parse_switch(*v))
            config.serve = *on ? ServeMode::kOn : ServeMode::kOff;
        else
            reject("CLASTRACE_SERVE", *v, "0, 1 or auto");
    }
    if (auto v = value("CLASTRACE_OUTPUT")) config.output_path = *v;
    if (auto v = value("CLASTRACE_OUTPUT_FD")) {
        if (auto fd = parse_decimal(*v); fd && *fd <= INT32_MAX)
            config.output_fd = int(*fd);
        else
            reject("CLASTRACE_OUTPUT_FD", *v, "a file descriptor number");
    }
    if (auto v = value("CLASTRACE_SUBMIT_RANGE")) {
        if (auto range = parse_range(*v))
            config.submit_range = *range;
        else
            reject("CLASTRACE_SUBMIT_RANGE", *v, "N, A-B (A <= B) or A-");
    }
    if (auto v = value("CLASTRACE_FRAME_RANGE")) {
        if (auto range = parse_range(*v))
            config.frame_range = *range;
        else
            reject("CLASTRACE_FRAME_RANGE", *v, "N, A-B (A <= B) or A- (0-based frames)");
    }
    if (auto v = value("CLASTRACE_ZSTD_LEVEL")) {
        // zstd's fast levels (-1 fastest of them ... -100) trade ratio for compressor CPU.
        const bool fast = !v->empty() && (*v)[0] == '-';
        auto level = parse_decimal(fast ? v->substr(1) : *v);
        if (level && *level >= 1 && *level <= (fast ? 100u : 22u))
            config.zstd_level = fast ? -int(*level) : int(*level);
        else
            reject("CLASTRACE_ZSTD_LEVEL", *v,
                   "a zstd level from 1 to 22, or a fast level from -1 to -100");
    }
    if (auto v = value("CLASTRACE_LOG")) {
        if (*v == "quiet" || *v == "0")
            config.log = LogLevel::kQuiet;
        else if (*v == "error" || *v == "1")
            config.log = LogLevel::kError;
        else if (*v == "info" || *v == "2")
            config.log = LogLevel::kInfo;
        else if (*v == "debug" || *v == "3")
            config.log = LogLevel::kDebug;
        else
            reject("CLASTRACE_LOG", *v, "quiet, error, info or debug");
    }
    if (auto v = value("CLASTRACE_DEBUG_JSON")) config.debug_json_path = *v;
    if (auto v = value("CLASTRACE_RAY_CHECK")) {
        auto rays = parse_decimal(*v);
        if (rays && *rays <= kMaxRayCheckRays)
            config.ray_check_rays = uint32_t(*rays);
        else
            reject("CLASTRACE_RAY_CHECK", *v, "a ray count from 0 to 1048576");
    }
    if (auto v = value("CLASTRACE_FLUSH_MS")) {
        auto ms = parse_decimal(*v);
        if (ms && *ms <= 3600000)
            config.flush_milliseconds = uint32_t(*ms);
        else
            reject("CLASTRACE_FLUSH_MS", *v, "milliseconds from 0 (never) to 3600000");
    }
    if (auto v = value("CLASTRACE_SHARED_WAIT_MS")) {
        auto ms = parse_decimal(*v);
        if (ms && *ms <= 3600000)
            config.shared_wait_milliseconds = uint32_t(*ms);
        else
            reject("CLASTRACE_SHARED_WAIT_MS", *v, "milliseconds from 0 to 3600000");
    }
    if (auto v = value("CLASTRACE_PRE_RANGE_STATE")) {
        if (auto on = parse_switch(*v))
            config.pre_range_state = *on;
        else
            reject("CLASTRACE_PRE_RANGE_STATE", *v, "0 or 1");
    }
    if (auto v = value("CLASTRACE_FORCE_STAGING")) {
        if (auto on = parse_switch(*v))
            config.force_staging = *on;
        else
            reject("CLASTRACE_FORCE_STAGING", *v, "0 or 1");
    }
    if (auto v = value("CLASTRACE_TIMESTAMPS")) {
        if (auto on = parse_switch(*v))
            config.timestamps = *on;
        else
            reject("CLASTRACE_TIMESTAMPS", *v, "0 or 1");
    }
    if (auto v = value("CLASTRACE_DEVICE_ADDRESS_WRITES")) {
        if (*v == "cheap" || *v == "off" || *v == "exact") {
            config.mark_device_address_writers = *v != "off";
            config.exact_device_address_writes = *v == "exact";
        } else {
            reject("CLASTRACE_DEVICE_ADDRESS_WRITES", *v, "cheap, exact or off");
        }
    }
    if (auto v = value("CLASTRACE_BACKGROUND_CPUS")) {
        if (*v == "spare")
            config.background_cpus = {BackgroundCpus::Mode::kSpare, {}};
        else if (*v == "app")
            config.background_cpus = {BackgroundCpus::Mode::kApp, {}};
        else if (auto cpus = parse_cpu_list(*v))
            config.background_cpus = {BackgroundCpus::Mode::kList, *cpus};
        else
            reject("CLASTRACE_BACKGROUND_CPUS", *v, "spare, app or a CPU list such as 6-7,12");
    }
    if (auto v = value("CLASTRACE_STATS")) {
        if (auto on = parse_switch(*v))
            config.stats = *on;
        else
            reject("CLASTRACE_STATS", *v, "0 or 1");
    }
    if (auto v = value("CLASTRACE_HOST_WRITES")) {
        if (*v == "hash" || *v == "guard") {
            config.host_writes = true;
            config.host_write_guard = *v == "guard";
        } else if (auto on = parse_switch(*v)) {
            config.host_writes = *on;
        } else {
            reject("CLASTRACE_HOST_WRITES", *v, "guard, hash, 1 (guard) or 0");
        }
    }
    if (auto v = value("CLASTRACE_DELTA_CONTENTS")) {
        if (auto on = parse_switch(*v))
            config.delta_contents = *on;
        else
            reject("CLASTRACE_DELTA_CONTENTS", *v, "0 or 1");
    }
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
