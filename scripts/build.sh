#!/usr/bin/env bash
# Installs what is missing, then configures and builds into build/ (or $CLASTRACE_BUILD_DIR).
#   scripts/build.sh [ARGS]             everything: the tool, the layer, the sample application,
#                                       the tests and the benchmarks (scripts/test.sh)
#   scripts/build.sh --run-only [ARGS]  only what scripts/quickstart.sh runs: clastrace, the
#                                       capture layer and examples/cluster_scene
# ARGS go to cmake's configure step, e.g. -DCLASTRACE_SANITIZE=address,undefined. Both share one
# build directory: a full build after --run-only adds the tests and benchmarks and rebuilds
# nothing that is already built.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
build=${CLASTRACE_BUILD_DIR:-$root/build}

if [[ "${1:-}" == "--run-only" ]]; then
  shift
  "$root/scripts/deps.sh"
  # A fresh directory leaves the tests and benchmarks out, so GoogleTest need not be installed,
  # and is built with RelWithDebInfo's -O2 but without debug info (-g costs compile and link
  # time: docs/benchmarks.md); one that already exists keeps its settings.
  fresh=()
  [[ -f "$build/CMakeCache.txt" ]] || fresh=(
    -DCLASTRACE_BUILD_TESTS=OFF -DCLASTRACE_BUILD_BENCH=OFF
    -DCMAKE_BUILD_TYPE=Release "-DCMAKE_CXX_FLAGS_RELEASE=-O2 -DNDEBUG" "-DCMAKE_C_FLAGS_RELEASE=-O2 -DNDEBUG")
  cmake -S "$root" -B "$build" -G Ninja "${fresh[@]}" "$@" >/dev/null
  # clastrace depends on the layer (`clastrace capture` loads it from the build tree).
  cmake --build "$build" --parallel "$(nproc)" --target clastrace cluster_scene
else
  "$root/scripts/deps.sh" --tests
  cmake -S "$root" -B "$build" -G Ninja -DCLASTRACE_BUILD_TESTS=ON -DCLASTRACE_BUILD_BENCH=ON "$@" >/dev/null
  cmake --build "$build" --parallel "$(nproc)"
fi
