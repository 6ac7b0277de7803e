// SPDX-License-Identifier: Apache-2.0
// The check of a whole-number option. CLI11's own range checks print their bounds in full,
// and the largest double has 309 digits: this one names the option's meaning and its range.
#pragma once

#include <CLI/CLI.hpp>

#include <charconv>
#include <cstdint>
#include <string>

namespace clastrace::tools {

inline CLI::Validator whole_number_from(uint64_t least, uint64_t most, const std::string& what) {
    return CLI::Validator(
        [=](std::string& text) -> std::string {
            uint64_t value = 0;
            const char* end = text.data() + text.size();
            auto [stop, ec] = std::from_chars(text.data(), end, value);
            if (ec != std::errc{} || stop != end || value < least || value > most) {
                return "takes " + what + ", a whole number from " + std::to_string(least) + " to " +
                       std::to_string(most) + ", not '" + text + "'";
            }
            return {};
        },
        std::to_string(least) + ".." + std::to_string(most));
}

}  // namespace clastrace::tools
