#!/usr/bin/env bash
# Installs what is missing, then configures and builds into build/ (or $CLASTRACE_BUILD_DIR).
# Extra arguments go to cmake's configure step, e.g. -DCLASTRACE_SANITIZE=address,undefined.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
build=${CLASTRACE_BUILD_DIR:-$root/build}

"$root/scripts/deps.sh"
cmake -S "$root" -B "$build" -G Ninja "$@" >/dev/null
cmake --build "$build" --parallel "$(nproc)"
