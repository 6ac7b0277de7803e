// SPDX-License-Identifier: Apache-2.0
#include "text_table.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>

#include <fmt/format.h>

namespace clastrace::analyze {

TextTable& TextTable::column(std::string header, Align align) {
    headers_.push_back(std::move(header));
    aligns_.push_back(align);
    return *this;
}

TextTable& TextTable::row(std::vector<std::string> cells) {
    cells.resize(headers_.size());
    // Labels and messages come from the trace: a newline or tab would break the alignment.
    for (auto& cell : cells)
        for (char& ch : cell)
            if (static_cast<unsigned char>(ch) < 0x20 || ch == 0x7f) ch = '?';
    rows_.push_back(std::move(cells));
    return *this;
}

static std::string fit(const std::string& s, std::size_t width) {
    if (s.size() <= width) return s;
    if (width == 0) return {};
    return s.substr(0, width - 1) + "~";
}

// "18446744073709551615" -> "18.4E": SI prefixes for numbers too wide for a terminal column.
// Text that is not a plain decimal number (hex addresses, percentages) is left alone.
static bool compact_number(std::string& s) {
    if (s.empty() || s.rfind("0x", 0) == 0) return false;
    char* end = nullptr;
    double v = std::strtod(s.c_str(), &end);
    if (end != s.c_str() + s.size() || !std::isfinite(v)) return false;
    static const char* prefixes[] = {"", "k", "M", "G", "T", "P", "E", "Z", "Y"};
    int p = 0;
    double a = std::fabs(v);
    while (a >= 999.95 && p < 8) {
        a /= 1000.0;
        v /= 1000.0;
        ++p;
    }
    if (p == 0) return false;
    s = a < 99.95 ? fmt::format("{:.1f}{}", v, prefixes[p])
                  : fmt::format("{:.0f}{}", v, prefixes[p]);
    return true;
}

void TextTable::print(std::ostream& out, std::size_t max_width, const std::string& indent) const {
    const std::size_t n = headers_.size();
    std::vector<std::vector<std::string>> rows = rows_;
    std::vector<std::size_t> width(n);
    auto measure = [&] {
        for (std::size_t c = 0; c < n; ++c) {
            width[c] = headers_[c].size();
            for (const auto& r : rows) width[c] = std::max(width[c], r[c].size());
        }
    };
    measure();
    auto total = [&] {
        std::size_t t = indent.size();
        for (std::size_t c = 0; c < n; ++c) t += width[c] + (c ? 2 : 0);
        return t;
    };
    // Numbers wider than `longer_than` become "1.8E"-style, in the widest column where that
    // narrows the column (a long header may keep it as wide as it was).
    auto compact_widest = [&](std::size_t longer_than) {
        std::size_t best = n, best_width = 0;
        for (std::size_t c = 0; c < n; ++c) {
            if (aligns_[c] != Align::kRight || width[c] <= longer_than) continue;
            std::size_t w = headers_[c].size();
            for (const auto& r : rows) {
                std::string probe = r[c];
                if (probe.size() > longer_than) compact_number(probe);
                w = std::max(w, probe.size());
            }
            if (w < width[c] && (best == n || width[c] > width[best])) {
                best = c;
                best_width = w;
            }
        }
        if (best == n) return false;
        for (auto& r : rows)
            if (r[best].size() > longer_than) compact_number(r[best]);
        width[best] = best_width;
        return true;
    };
    // First huge numbers, then long text, then any remaining long numbers.
    while (total() > max_width && compact_widest(9)) {}
    // Shrink the widest left-aligned column (text such as names and labels) until it fits.
    while (total() > max_width) {
        std::size_t widest = n;
        for (std::size_t c = 0; c < n; ++c)
            if (aligns_[c] == Align::kLeft && width[c] > 4 &&
                (widest == n || width[c] > width[widest]))
                widest = c;
        if (widest == n) break;
        --width[widest];
    }
    while (total() > max_width && compact_widest(6)) {}
    auto line = [&](const std::vector<std::string>& cells) {
        std::string s = indent;
        for (std::size_t c = 0; c < n; ++c) {
            std::string cell = fit(cells[c], width[c]);
            std::string pad(width[c] - cell.size(), ' ');
            if (c) s += "  ";
            s += aligns_[c] == Align::kLeft ? cell + pad : pad + cell;
        }
        while (!s.empty() && s.back() == ' ') s.pop_back();
        out << s << '\n';
    };
    line(headers_);
    std::vector<std::string> rule;
    for (std::size_t c = 0; c < n; ++c) rule.push_back(std::string(width[c], '-'));
    line(rule);
    for (const auto& r : rows) line(r);
}

}  // namespace clastrace::analyze
