// SPDX-License-Identifier: Apache-2.0
// How the clastrace program prints a JSON document: indented, and valid UTF-8 whatever bytes its
// strings hold (a Latin-1 file name, an application's name in an old trace). Each ill-formed
// sequence becomes U+FFFD, the rule of traces::valid_utf8 (nlohmann's `replace` handler follows
// it), where the default handler would throw and end the program with no output.
#pragma once

#include <nlohmann/json.hpp>

#include <string>

namespace clastrace::tools {

inline std::string json_text(const nlohmann::json& document) {
    return document.dump(2, ' ', false, nlohmann::json::error_handler_t::replace);
}

}  // namespace clastrace::tools
