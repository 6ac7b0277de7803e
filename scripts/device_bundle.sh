#!/usr/bin/env bash
# Packs the CPU benches, the capture layer and the frames app of a build, with the Debian
# libraries they load, into one tarball for a machine without package registries (the lent
# GPU host runs Ubuntu; docs/benchmarks.md, "Running on the device machine"):
#   scripts/device_bundle.sh [--before DIR] [--perf] [--debs DIR] BUILD_DIR OUT.tgz
# --before DIR  also packs DIR's binaries (the same names, e.g. copied from the session's first
#               build) as bin-before/ and layer-before/, so that device_run.sh can interleave
#               before and after in one call: both sides of a comparison on one machine.
# --perf        also packs this machine's `perf` with its libraries, and keeps the binaries'
#               symbols (debug info is stripped either way: the bundle must stay small).
# --debs DIR    also packs DIR's .deb files, which device_run.sh unpacks over / before its
#               parts (the NVIDIA driver there wants glvnd's libEGL/libGLX and the loader:
#               `apt-get download libvulkan1 libglvnd0 libegl1 libglx0 libgl1 libgles2 libopengl0`).
# The bundle unpacks to one folder holding device_run.sh; run it with OUT set, see its header.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
benches=(bench_engine_nv bench_engine_clusters replay_throughput_bench trace_throughput_bench
         capture_overhead_bench)
layer=libVkLayer_clastrace_capture.so

usage() {
  echo "usage: scripts/device_bundle.sh [--before DIR] [--perf] [--debs DIR] BUILD_DIR OUT.tgz" >&2
  exit 2
}
before= perf= debs=
while [[ $# -gt 0 && $1 == --* ]]; do
  case $1 in
    --before) [[ $# -ge 2 ]] || usage; before=$2; shift 2 ;;
    --perf) perf=1; shift ;;
    --debs) [[ $# -ge 2 ]] || usage; debs=$2; shift 2 ;;
    --help) usage ;;
    *) echo "scripts/device_bundle.sh: unknown option '$1'" >&2; usage ;;
  esac
done
[[ $# -eq 2 ]] || usage
build=$(cd "$1" && pwd)
out_tgz=$2
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
b=$stage/bundle
mkdir -p "$b/bin-after" "$b/layer-after" "$b/lib"

# The one place a binary is looked up: benches under bench/, the app under tests/, the layer
# under capture/.
find_built() {
  local found
  found=$(find "$build/$1" -type f -name "$2" -perm -u+x | head -1)
  [[ -n $found ]] || { echo "scripts/device_bundle.sh: no $2 under $build/$1 (build it first)" >&2; exit 1; }
  echo "$found"
}
for name in "${benches[@]}"; do cp "$(find_built bench "$name")" "$b/bin-after/"; done
cp "$(find_built tests capture_frames_app)" "$b/bin-after/"
cp "$build/capture/$layer" "$b/layer-after/"

if [[ -n $before ]]; then
  mkdir -p "$b/bin-before" "$b/layer-before"
  for name in "${benches[@]}" capture_frames_app; do
    [[ -f $before/$name ]] && cp "$before/$name" "$b/bin-before/"
  done
  [[ -f $before/$layer ]] && cp "$before/$layer" "$b/layer-before/"
fi
for side in "$b"/layer-*; do
  [[ -f $side/$layer ]] || continue
  sed 's#"library_path": "[^"]*"#"library_path": "./'"$layer"'"#' \
    "$build/capture/manifest/VkLayer_clastrace_capture.json" > "$side/VkLayer_clastrace_capture.json"
done
[[ -n $perf ]] && cp "$(command -v perf)" "$b/bin-after/perf"
if [[ -n $debs ]]; then mkdir -p "$b/debs"; cp "$debs"/*.deb "$b/debs/"; fi

# The host's own C runtime stays: Ubuntu 24.04's glibc is newer than Debian 12's.
for f in "$b"/bin-*/* "$b"/layer-*/"$layer"; do
  [[ -f $f ]] || continue
  ldd "$f" | awk '/=>/ {print $3}' | grep -v -E 'libc\.so|libm\.so|libpthread|libdl|librt|ld-linux|libgcc_s' |
    while read -r lib; do cp -L -n "$lib" "$b/lib/"; done
done
strip --strip-debug "$b"/bin-*/* "$b"/layer-*/*.so "$b"/lib/* 2>/dev/null || true

mesh=/usr/share/assimp/models/OBJ/WusonOBJ.obj
[[ -f $mesh ]] && cp "$mesh" "$b/"
cp "$root/scripts/device_run.sh" "$b/"
tar -C "$stage" -czf "$out_tgz" bundle
echo "scripts/device_bundle.sh: $out_tgz ($(du -h "$out_tgz" | cut -f1)); on the device:" \
  "tar -C /tmp -xzf $(basename "$out_tgz") && OUT=\$OUT bash /tmp/bundle/device_run.sh PART..."
