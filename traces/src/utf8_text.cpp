// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/utf8_text.h>

#include <cstddef>
#include <cstdint>

namespace clastrace::traces {

namespace {

// What starts at the front of some bytes: a well-formed sequence, or the maximal subpart of an
// ill-formed one (a lead byte followed by the continuation bytes it could still take, or a byte
// that starts nothing), which one U+FFFD stands for.
struct Sequence {
    size_t length;
    bool well_formed;
};

Sequence first_sequence(std::string_view bytes) {
    const auto byte = [&](size_t i) { return static_cast<uint8_t>(bytes[i]); };
    const uint8_t lead = byte(0);
    if (lead < 0x80) return {1, true};
    // Continuation bytes after the lead, and the range the first of them must fall in: the
    // narrow ranges are what rules out overlong forms (E0, F0), surrogates (ED) and code
    // points above U+10FFFF (F4).
    size_t continuations = 0;
    uint8_t low = 0x80, high = 0xBF;
    if (lead >= 0xC2 && lead <= 0xDF) {
        continuations = 1;
    } else if (lead >= 0xE0 && lead <= 0xEF) {
        continuations = 2;
        if (lead == 0xE0) low = 0xA0;
        if (lead == 0xED) high = 0x9F;
    } else if (lead >= 0xF0 && lead <= 0xF4) {
        continuations = 3;
        if (lead == 0xF0) low = 0x90;
        if (lead == 0xF4) high = 0x8F;
    } else {
        return {1, false};  // a continuation byte, or C0, C1, F5..FF, which start nothing
    }
    for (size_t i = 1; i <= continuations; ++i) {
        if (i == bytes.size()) return {i, false};  // cut short
        const uint8_t b = byte(i);
        if (b < low || b > high) return {i, false};
        low = 0x80;
        high = 0xBF;
    }
    return {continuations + 1, true};
}

}  // namespace

bool is_valid_utf8(std::string_view bytes) {
    while (!bytes.empty()) {
        const Sequence s = first_sequence(bytes);
        if (!s.well_formed) return false;
        bytes.remove_prefix(s.length);
    }
    return true;
}

std::string valid_utf8(std::string_view bytes) {
    static constexpr std::string_view kReplacement = "\xEF\xBF\xBD";  // U+FFFD
    if (is_valid_utf8(bytes)) return std::string(bytes);
    std::string text;
    text.reserve(bytes.size() + 8);
    while (!bytes.empty()) {
        const Sequence s = first_sequence(bytes);
        text += s.well_formed ? bytes.substr(0, s.length) : kReplacement;
        bytes.remove_prefix(s.length);
    }
    return text;
}

std::string_view utf8_prefix(std::string_view text, size_t max_bytes) {
    if (text.size() <= max_bytes) return text;
    // A continuation byte right after the cut belongs to a character begun before it: cut
    // before that character's lead (at most three bytes back; longer runs are no character).
    size_t cut = max_bytes;
    const auto continues = [&](size_t i) { return (static_cast<uint8_t>(text[i]) & 0xC0) == 0x80; };
    for (size_t back = 0; back < 3 && cut > 0 && continues(cut); ++back) --cut;
    if (continues(cut)) cut = max_bytes;
    return text.substr(0, cut);
}

}  // namespace clastrace::traces
