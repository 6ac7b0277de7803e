#!/usr/bin/env bash
# Installs the packages clastrace needs from Debian 12's archive, when missing.
#   scripts/deps.sh          what the tool, the layer and the sample application need to build
#                            and run (scripts/quickstart.sh)
#   scripts/deps.sh --tests  that, plus what the test suite and benchmarks use (scripts/test.sh),
#                            and the ray-tracing test driver, lavapipe 25.0.7, unpacked privately
#                            (scripts/lavapipe_rt.sh; the system's Mesa stays as it is)
# A no-op when all are present; needs root (or sudo) only when something is missing.
set -euo pipefail

RUN_PACKAGES=(
  build-essential cmake ninja-build pkg-config git
  libvulkan-dev mesa-vulkan-drivers glslang-tools
  libzstd-dev zstd flatbuffers-compiler libflatbuffers-dev libxxhash-dev
  libembree-dev libtbb-dev libmeshoptimizer-dev assimp-testmodels
  libcli11-dev nlohmann-json3-dev libfmt-dev
)
# GoogleTest and Google Benchmark; vulkaninfo and the validation layers, which the capture
# tests run under the layer; an X server for the frame-range tests; chromium and a font for
# the HTML report tests; clang-format for the style check (style.format).
TEST_PACKAGES=(
  libgtest-dev libgmock-dev libbenchmark-dev
  vulkan-tools vulkan-validationlayers
  xvfb xauth libxcb1-dev
  clang-format
  chromium fonts-dejavu-core
)

packages=("${RUN_PACKAGES[@]}")
tests=0
case "${1:-}" in
  "") ;;
  --tests) packages+=("${TEST_PACKAGES[@]}"); tests=1 ;;
  *) echo "usage: scripts/deps.sh [--tests]" >&2; exit 2 ;;
esac

missing=()
for p in "${packages[@]}"; do
  status=$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null || true)
  [[ "$status" == "install ok installed" ]] || missing+=("$p")
done
if [[ ${#missing[@]} -gt 0 ]]; then
  echo "clastrace: installing ${missing[*]}" >&2
  SUDO=""
  [[ $(id -u) -eq 0 ]] || SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
# After vulkan-tools, so that the driver's check can run vulkaninfo; no root needed.
if [[ $tests -eq 1 ]]; then
  "$(dirname "${BASH_SOURCE[0]}")/lavapipe_rt.sh" >/dev/null
fi
