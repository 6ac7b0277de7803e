#!/usr/bin/env bash
# Second README command: install, build everything (the tests and benchmarks too, into the build
# directory scripts/quickstart.sh may have started), and run the whole test suite (ctest over
# GoogleTest) on lavapipe 25.0.7, the ray-tracing driver scripts/deps.sh --tests unpacks
# (scripts/lavapipe_rt.sh), then the Vulkan-using tests (ctest label `vulkan`) once more on the
# system's lavapipe (Mesa 22.3, what scripts/quickstart.sh runs on). docs/architecture.md
# (Tests) says why both and what each costs.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
build=${CLASTRACE_BUILD_DIR:-$root/build}

"$root/scripts/build.sh"
# Prints VK_DRIVER_FILES=... and LD_LIBRARY_PATH=... (no network once unpacked).
rt_settings=$("$root/scripts/lavapipe_rt.sh")
rt_files=$(sed -n 's/^VK_DRIVER_FILES=//p' <<<"$rt_settings")
rt_libraries=$(sed -n 's/^LD_LIBRARY_PATH=//p' <<<"$rt_settings")
cd "$build"
status=0
echo "clastrace: the test suite on lavapipe 25.0.7 ($rt_files)" >&2
CLASTRACE_TEST_DRIVER_FILES="$rt_files" CLASTRACE_TEST_DRIVER_LIBRARY_PATH="$rt_libraries" \
  ctest --output-on-failure --parallel "$(nproc)" --timeout 600 || status=1
echo "clastrace: the Vulkan-using tests on the system's lavapipe" >&2
env -u CLASTRACE_TEST_DRIVER_FILES -u CLASTRACE_TEST_DRIVER_LIBRARY_PATH \
  ctest --output-on-failure --parallel "$(nproc)" --timeout 600 -L vulkan || status=1
exit $status
