// SPDX-License-Identifier: Apache-2.0
// Plain decimal numbers in the layer's settings (CLASTRACE_* values, CPU lists): digits only,
// no sign, no spaces, at most `maxDigits` of them (19 keeps any value inside uint64_t).
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>

namespace clastrace::capture {

inline std::optional<uint64_t> parse_decimal(const std::string& text, size_t max_digits = 19) {
    if (text.empty() || text.size() > max_digits || max_digits > 19) return std::nullopt;
    uint64_t value = 0;
    for (char c : text) {
        if (c < '0' || c > '9') return std::nullopt;
        value = value * 10 + uint64_t(c - '0');
    }
    return value;
}

}  // namespace clastrace::capture
