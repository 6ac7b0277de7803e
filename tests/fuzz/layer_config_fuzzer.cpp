// SPDX-License-Identifier: Apache-2.0
// Fuzz target: the capture layer's environment settings (capture/src/layer_config.cpp).
// The bytes are split at newlines into the values of the CLASTRACE_* variables, in order;
// an empty line leaves that variable unset. Whatever they hold, parsing must end with a
// configuration inside the documented bounds and one message per value refused.
#include "clastrace/capture/layer_config.h"

#include <cstring>
#include <string>
#include <vector>

using namespace clastrace::capture;

namespace {

const char* const kVariables[] = {
    "CLASTRACE_CAPTURE",      "CLASTRACE_SERVE",           "CLASTRACE_OUTPUT",
    "CLASTRACE_SUBMIT_RANGE", "CLASTRACE_FRAME_RANGE",     "CLASTRACE_ZSTD_LEVEL",
    "CLASTRACE_LOG",          "CLASTRACE_DEBUG_JSON",      "CLASTRACE_RAY_CHECK",
    "CLASTRACE_FLUSH_MS",     "CLASTRACE_SHARED_WAIT_MS",  "CLASTRACE_FORCE_STAGING",
    "CLASTRACE_TIMESTAMPS",   "CLASTRACE_BACKGROUND_CPUS", "CLASTRACE_STATS",
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    std::vector<std::string> values;
    std::string line;
    for (size_t i = 0; i <= size; ++i) {
        if (i == size || data[i] == '\n') {
            values.push_back(line);
            line.clear();
        } else {
            line.push_back(char(data[i]));
        }
    }
    size_t set = 0;
    const LayerConfig config = parse_layer_config([&](const char* name) -> const char* {
        for (size_t k = 0; k < std::size(kVariables) && k < values.size(); ++k) {
            if (std::strcmp(name, kVariables[k]) == 0 && !values[k].empty()) {
                ++set;
                return values[k].c_str();
            }
        }
        return nullptr;
    });
    if (config.errors.size() > set) __builtin_trap();
    if (config.submit_range.first > config.submit_range.last ||
        config.frame_range.first > config.frame_range.last)
        __builtin_trap();
    if (config.zstd_level < -100 || config.zstd_level == 0 || config.zstd_level > 22)
        __builtin_trap();
    if (config.ray_check_rays > (1u << 20) || config.flush_milliseconds > 3600000 ||
        config.shared_wait_milliseconds > 3600000)
        __builtin_trap();
    return 0;
}
