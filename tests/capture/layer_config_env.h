// SPDX-License-Identifier: Apache-2.0
// The layer's configuration read from a made-up environment, for the tests of its variables.
#pragma once

#include "clastrace/capture/layer_config.h"

#include <map>
#include <string>

namespace clastrace::capture::test {

// Variables missing from `env` read as unset.
inline LayerConfig parse(const std::map<std::string, std::string>& env) {
    return parse_layer_config([&](const char* name) -> const char* {
        auto it = env.find(name);
        return it == env.end() ? nullptr : it->second.c_str();
    });
}

}  // namespace clastrace::capture::test
