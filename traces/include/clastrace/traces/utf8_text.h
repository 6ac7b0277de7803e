// SPDX-License-Identifier: Apache-2.0
// Text that comes from outside the tool (names an application passed to Vulkan, a trace's file
// name, labels, messages) is bytes in whatever encoding its author used; what the tool stores in
// a trace and prints as JSON or HTML is UTF-8. One rule turns the first into the second, here.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

namespace clastrace::traces {

// True when `bytes` is well-formed UTF-8 (Unicode table 3-7: no overlong forms, no surrogates,
// nothing above U+10FFFF, no sequence cut short).
bool is_valid_utf8(std::string_view bytes);

// `bytes` with each maximal ill-formed subpart replaced by one U+FFFD (Unicode's recommended
// practice, which nlohmann::json's error_handler_t::replace follows too, so a JSON document
// dumped with it agrees with this). Well-formed text comes back unchanged.
std::string valid_utf8(std::string_view bytes);

// The longest prefix of `text` of at most `max_bytes` bytes that does not cut a character in
// two (shortened labels and names stay as valid as they were).
std::string_view utf8_prefix(std::string_view text, size_t max_bytes);

}  // namespace clastrace::traces
