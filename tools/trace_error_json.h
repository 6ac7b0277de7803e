// SPDX-License-Identifier: Apache-2.0
// The JSON a command prints with --json when it stops before its report: a trace it
// cannot open or an argument the trace contradicts. One shape for every command, so a
// script reads `error.code` whatever the command.
#pragma once

#include "json_output.h"

#include <clastrace/traces/trace_error.h>

#include <nlohmann/json.hpp>

#include <iostream>
#include <string>

namespace clastrace::tools {

inline void print_trace_error_json(const std::string& trace, const traces::TraceError& error) {
    const nlohmann::json j = {{"trace", trace},
                              {"error",
                               {{"code", traces::trace_error_code_name(error.code)},
                                {"offset", error.file_offset},
                                {"message", error.message}}}};
    std::cout << json_text(j) << "\n";  // a file name need not be UTF-8; JSON must be
}

}  // namespace clastrace::tools
