// SPDX-License-Identifier: Apache-2.0
// Hexadecimal text of numbers and byte strings, the one spelling every part uses in its
// messages: lowercase digits, numbers with a 0x prefix, bytes without one.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

namespace clastrace::common {

// "0x" and the value's digits, at least `min_digits` of them (zero-padded): hex(255) is
// "0xff", hex(255, 4) is "0x00ff".
inline std::string hex(uint64_t value, int min_digits = 1) {
    char digits[16];
    int count = 0;
    do {
        digits[count++] = "0123456789abcdef"[value & 15];
        value >>= 4;
    } while (value != 0);
    std::string text = "0x";
    if (min_digits > count) text.append(std::size_t(min_digits - count), '0');
    while (count > 0) text.push_back(digits[--count]);
    return text;
}

// Two digits a byte, no prefix or separator: {0x01, 0xab} is "01ab".
inline std::string hex_bytes(std::span<const uint8_t> bytes) {
    std::string text;
    text.reserve(bytes.size() * 2);
    for (uint8_t b : bytes) {
        text.push_back("0123456789abcdef"[b >> 4]);
        text.push_back("0123456789abcdef"[b & 15]);
    }
    return text;
}

inline std::string hex_bytes(std::span<const std::byte> bytes) {
    return hex_bytes({reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()});
}

}  // namespace clastrace::common
