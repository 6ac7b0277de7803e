#!/usr/bin/env bash
# First README command: install and build only what it runs (scripts/build.sh --run-only: the
# clastrace tool, the capture layer, the sample application), run the main job on the shipped
# sample trace, then capture the sample application under the layer on lavapipe, replay and
# analyze that trace. scripts/test.sh builds the tests into the same build directory.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
build=${CLASTRACE_BUILD_DIR:-$root/build}
clastrace="$build/tools/clastrace"

"$root/scripts/build.sh" --run-only
"$clastrace" info "$root/traces/samples/sample.clt"
"$clastrace" replay "$root/traces/samples/sample.clt"
"$clastrace" analyze "$root/traces/samples/sample.clt" --html "$build/sample-report.html"

# examples/cluster_scene on lavapipe (CPU Vulkan, in scripts/deps.sh): the layer serves
# VK_NV_cluster_acceleration_structure there and records every build with what it read. The
# system's lavapipe, or the driver the tests are pointed at (CLASTRACE_TEST_DRIVER_FILES and
# CLASTRACE_TEST_DRIVER_LIBRARY_PATH, as in tests/support's test_driver.h and scripts/test.sh).
lavapipe=${CLASTRACE_TEST_DRIVER_FILES:-$(ls /usr/share/vulkan/icd.d/lvp_icd.*.json 2>/dev/null | head -n 1 || true)}
if [[ -z "$lavapipe" || ! -f "$lavapipe" ]]; then
  echo "quickstart: lavapipe's ICD manifest${lavapipe:+ $lavapipe} is missing (apt-get install mesa-vulkan-drivers); skipping the capture" >&2
  exit 1
fi
libraries=${CLASTRACE_TEST_DRIVER_FILES:+${CLASTRACE_TEST_DRIVER_LIBRARY_PATH:-}}
trace="$build/cluster_scene.clt"
VK_DRIVER_FILES="$lavapipe" LD_LIBRARY_PATH="$libraries${LD_LIBRARY_PATH:+${libraries:+:}$LD_LIBRARY_PATH}" \
  "$clastrace" capture -o "$trace" -- "$build/examples/cluster_scene/cluster_scene"
"$clastrace" replay "$trace"
"$clastrace" analyze "$trace" --html "$build/cluster_scene-report.html"
echo "quickstart: captured $trace; HTML reports: $build/sample-report.html, $build/cluster_scene-report.html"
