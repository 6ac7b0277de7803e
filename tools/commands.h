// SPDX-License-Identifier: Apache-2.0
// Subcommand registration for the clastrace program. A command adds its CLI11
// subcommand to the app and returns the function main() calls when it was chosen.
#pragma once

#include <CLI/CLI.hpp>

#include <functional>

namespace clastrace::tools {

// Exit codes shared by every command.
inline constexpr int kExitOk = 0;        // ran, nothing found
inline constexpr int kExitFindings = 1;  // ran, found damage or other findings
inline constexpr int kExitUsage = 2;     // bad arguments or unreadable input

struct Command {
    CLI::App* app = nullptr;   // the subcommand
    std::function<int()> run;  // runs it after parsing; returns an exit code
};

Command register_info(CLI::App& app);
Command register_replay(CLI::App& app);
Command register_capture(CLI::App& app);
Command register_analyze(CLI::App& app);

}  // namespace clastrace::tools
