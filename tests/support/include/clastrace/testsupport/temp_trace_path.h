// SPDX-License-Identifier: Apache-2.0
// Where a test writes a trace file: one path per test process in TMPDIR, so that the cases of
// one binary, which ctest runs in parallel processes, never write the same file.
#pragma once

#include <filesystem>
#include <string>
#include <unistd.h>

namespace clastrace::test {

// TMPDIR/<suite>_<pid>_<name>.
inline std::string temp_trace_path(const std::string& suite, const std::string& name) {
    return (std::filesystem::temp_directory_path() /
            (suite + "_" + std::to_string(::getpid()) + "_" + name))
        .string();
}

}  // namespace clastrace::test
