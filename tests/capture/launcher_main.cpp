// Stand-in for tools/main.cpp with only the capture command, so its tests run before the CLI
// registers it.
#include "commands.h"

namespace clastrace::tools {
Command register_capture(CLI::App& app);
}

int main(int argc, char** argv) {
  using namespace clastrace::tools;
  CLI::App app{"clastrace (capture only)"};
  app.require_subcommand(1, 1);
  Command capture = register_capture(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? kExitOk : kExitUsage;
  }
  return capture.run();
}
