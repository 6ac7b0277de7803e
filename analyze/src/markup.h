// SPDX-License-Identifier: Apache-2.0
// Escaping for text that comes from traces (labels, names, messages) into HTML and SVG. The page
// is UTF-8: bytes that are not (a Latin-1 file name, a label cut inside a character) become
// U+FFFD first, by the rule the JSON output follows too (traces::valid_utf8).
#pragma once

#include <clastrace/traces/utf8_text.h>

#include <string>
#include <string_view>

namespace clastrace::analyze {

inline std::string escape_markup(std::string_view raw) {
    const std::string s = traces::valid_utf8(raw);
    std::string out;
    out.reserve(s.size());
    for (char c : s) {
        switch (c) {
        case '&': out += "&amp;"; break;
        case '<': out += "&lt;"; break;
        case '>': out += "&gt;"; break;
        case '"': out += "&quot;"; break;
        case '\'': out += "&#39;"; break;
        default:
            if (static_cast<unsigned char>(c) < 0x20 && c != '\n' && c != '\t')
                out += '?';
            else
                out += c;
        }
    }
    return out;
}

}  // namespace clastrace::analyze
