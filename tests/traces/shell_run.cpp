// SPDX-License-Identifier: Apache-2.0
#include "shell_run.h"

#include <array>
#include <cstdio>
#include <sys/wait.h>

namespace clastrace::traces::testing {

ShellRun run_shell(const std::string& command) {
    ShellRun r;
    FILE* p = popen(command.c_str(), "r");
    if (!p) return r;
    std::array<char, 4096> buffer;
    for (size_t n; (n = fread(buffer.data(), 1, buffer.size(), p)) > 0;)
        r.output.append(buffer.data(), n);
    const int status = pclose(p);
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    return r;
}

}  // namespace clastrace::traces::testing
