#!/usr/bin/env bash
# Stages what the GPU machine needs to capture traces/samples/h100_nv_ray_tracing.clt: the
# application, the layer (with a manifest naming it by a relative path), every shared library
# they load from this Debian machine (the GPU machine is Ubuntu and reaches no registry), and
# device_run.sh. Usage: make_device_bundle.sh BUILD_DIR OUT_DIR
set -euo pipefail
build=${1:?build dir}
out=${2:?bundle dir}
here=$(cd "$(dirname "$0")" && pwd)
rm -rf "$out"
mkdir -p "$out/bin" "$out/lib" "$out/manifest"
cp "$build/tests/apps/nv_ray_tracing_app" "$out/bin/"
cp "$build/capture/libVkLayer_clastrace_capture.so" "$out/lib/"
sed -e 's|"library_path": *"[^"]*"|"library_path": "../lib/libVkLayer_clastrace_capture.so"|' \
  "$build/capture/manifest/VkLayer_clastrace_capture.json" >"$out/manifest/VkLayer_clastrace_capture.json"
# Every library either binary loads (glibc included, for the ld-linux fallback in device_run.sh).
for binary in "$out/bin/nv_ray_tracing_app" "$out/lib/libVkLayer_clastrace_capture.so"; do
  ldd "$binary" | awk '/=> \//{print $3}' | while read -r lib; do cp -L -n "$lib" "$out/lib/"; done
done
cp -L /lib64/ld-linux-x86-64.so.2 "$out/lib/"
strip --strip-debug "$out/bin/nv_ray_tracing_app" "$out/lib/libVkLayer_clastrace_capture.so"
cp "$here/device_run.sh" "$out/"
du -sh "$out"
