// SPDX-License-Identifier: Apache-2.0
// Number formatting shared by the renderers. Ratios with a zero denominator have no value:
// renderers print "-" (text, HTML) or null (JSON) for them.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include <clastrace/common/hex.h>
#include <fmt/format.h>

namespace clastrace::analyze::fmtu {

inline std::optional<double> ratio(uint64_t num, uint64_t den) {
    if (den == 0) return std::nullopt;
    return static_cast<double>(num) / static_cast<double>(den);
}

// Events per second from a count and nanoseconds.
inline std::optional<double> per_second(uint64_t count, uint64_t ns) {
    if (ns == 0) return std::nullopt;
    return static_cast<double>(count) * 1e9 / static_cast<double>(ns);
}

inline std::string fixed(std::optional<double> v, int decimals) {
    return v ? fmt::format("{:.{}f}", *v, decimals) : std::string("-");
}

inline std::string percent(std::optional<double> v) {
    return v ? fmt::format("{:.1f}%", *v * 100.0) : "-";
}

inline std::string ms(uint64_t ns) { return fmt::format("{:.3f}", static_cast<double>(ns) / 1e6); }

using common::hex;

// Signed difference a - b as text ("-12" when b > a).
inline std::string difference(uint64_t a, uint64_t b) {
    return a >= b ? fmt::format("{}", a - b) : fmt::format("-{}", b - a);
}

inline std::string human_bytes(uint64_t bytes) {
    static const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
    double v = static_cast<double>(bytes);
    int u = 0;
    while (v >= 1024.0 && u < 6) {
        v /= 1024.0;
        ++u;
    }
    return u == 0 ? fmt::format("{} B", bytes) : fmt::format("{:.1f} {}", v, units[u]);
}

}  // namespace clastrace::analyze::fmtu
