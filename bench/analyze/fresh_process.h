// SPDX-License-Identifier: Apache-2.0
// The analyze benchmarks measure each run in a fresh process (the program re-executed with
// --one ...), so that a run's peak resident memory (VmHWM) is its own and not a high-water
// mark left by an earlier run.
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <cstdint>
#include <cstring>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

namespace clastrace::bench {

// A field of /proc/self/status in KiB ("VmHWM:", "VmRSS:"); 0 when absent.
inline uint64_t status_kib(const char* field) {
    std::ifstream in("/proc/self/status");
    std::string line;
    const std::size_t n = std::strlen(field);
    while (std::getline(in, line))
        if (line.compare(0, n, field) == 0) return std::stoull(line.substr(n + 1));
    return 0;
}

// Runs `self --one args...` and returns what it printed (up to 511 bytes), or nothing when
// it could not be started or did not exit with status 0.
inline std::optional<std::string> run_fresh_process(const char* self,
                                                    const std::vector<std::string>& args) {
    int fd[2];
    if (pipe(fd) != 0) return std::nullopt;
    pid_t pid = fork();
    if (pid == 0) {
        dup2(fd[1], STDOUT_FILENO);
        close(fd[0]);
        std::vector<char*> argv{const_cast<char*>(self), const_cast<char*>("--one")};
        for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
        argv.push_back(nullptr);
        execv(self, argv.data());
        _exit(127);
    }
    close(fd[1]);
    char buf[512] = {};
    const ssize_t got = read(fd[0], buf, sizeof buf - 1);
    close(fd[0]);
    int status = 0;
    waitpid(pid, &status, 0);
    if (got <= 0 || !WIFEXITED(status) || WEXITSTATUS(status) != 0) return std::nullopt;
    return std::string(buf, size_t(got));
}

}  // namespace clastrace::bench
