#!/usr/bin/env bash
# First README command: install, build, and run the main job on the shipped sample trace.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
build=${CLASTRACE_BUILD_DIR:-$root/build}

"$root/scripts/build.sh"
"$build/tools/clastrace" info "$root/traces/samples/sample.clt"
"$build/tools/clastrace" replay "$root/traces/samples/sample.clt"
"$build/tools/clastrace" analyze "$root/traces/samples/sample.clt" --html "$build/sample-report.html"
