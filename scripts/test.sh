#!/usr/bin/env bash
# Second README command: install, build everything (the tests and benchmarks too, into the build
# directory scripts/quickstart.sh may have started), and run the whole test suite (ctest over
# GoogleTest).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
build=${CLASTRACE_BUILD_DIR:-$root/build}

"$root/scripts/build.sh"
cd "$build"
ctest --output-on-failure --parallel "$(nproc)" --timeout 600
