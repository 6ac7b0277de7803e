// SPDX-License-Identifier: Apache-2.0
// clastrace: capture, replay and analyze acceleration-structure builds.
#include "commands.h"

#include <cstdio>
#include <vector>

int main(int argc, char** argv) {
    using namespace clastrace::tools;
    CLI::App app{
        "clastrace: capture, replay and analyze Vulkan (cluster) acceleration-structure builds"};
    app.require_subcommand(1, 1);
    app.set_version_flag("--version", "clastrace 0.1.0");

    std::vector<Command> commands = {
        register_info(app),
        register_replay(app),
        register_capture(app),
        register_analyze(app),
    };

    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        // --help/--version are "errors" with exit code 0; everything else is a usage error.
        int code = app.exit(e);
        return code == 0 ? kExitOk : kExitUsage;
    }
    for (const Command& c : commands) {
        if (c.app->parsed()) return c.run();
    }
    return kExitUsage;
}
