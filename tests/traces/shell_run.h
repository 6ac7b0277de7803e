// SPDX-License-Identifier: Apache-2.0
// A command run through the shell, for the tests that run the built `clastrace`.
#pragma once

#include <string>

namespace clastrace::traces::testing {

struct ShellRun {
    int exit_code = -1;  // -1 when the command did not exit (a signal, an abort)
    std::string output;  // its stdout: the command's own redirections decide what else
};

ShellRun run_shell(const std::string& command);

}  // namespace clastrace::traces::testing
