#!/usr/bin/env bash
# Runs on the GPU machine from the bundle make_device_bundle.sh staged: probes the device, runs
# nv_ray_tracing_app without and then under the capture layer, and leaves the trace, the
# layer's JSON dump and the logs in $OUT. Debian's libvulkan1 and glvnd libraries (libegl1
# libglvnd0 libopengl0 libgl1 libglx0 libgles2) must already be unpacked into /: without glvnd
# the NVIDIA ICD answers no vkCreateInstance. The bundled glibc fallback below does not work on
# Ubuntu 24.04 (its libX11 needs glibc 2.38); the native run does.
set -uo pipefail
cd "$(dirname "$0")"
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader
grep PRETTY_NAME /etc/os-release; ldd --version | head -1
# Our libraries without glibc go first; glibc stays the system's when it is new enough.
mkdir -p libnative
for f in lib/*.so*; do
  case $(basename "$f") in libc.so*|libm.so*|ld-linux*|libpthread*|libdl*|librt*) ;; *) ln -sf "../$f" libnative/ ;; esac
done
export __EGL_VENDOR_LIBRARY_FILENAMES=${__EGL_VENDOR_LIBRARY_FILENAMES:-/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json}
APP=(env LD_LIBRARY_PATH="$PWD/libnative" ./bin/nv_ray_tracing_app)
if ! "${APP[@]}" --probe; then
  echo "native run failed; using the bundled glibc"
  APP=(./lib/ld-linux-x86-64.so.2 --library-path "$PWD/lib" ./bin/nv_ray_tracing_app)
  "${APP[@]}" --probe
fi
echo "=== without the layer"
"${APP[@]}" ${APP_ARGS:-} 2>&1 | tee "$OUT/app_plain.log"
echo "=== under the layer"
LAYER_ENV=(VK_ADD_LAYER_PATH="$PWD/manifest" VK_INSTANCE_LAYERS=VK_LAYER_CLASTRACE_capture CLASTRACE_LOG=info
           CLASTRACE_RAY_CHECK=${RAY_CHECK:-4096})
env "${LAYER_ENV[@]}" CLASTRACE_OUTPUT="$OUT/${TRACE_NAME:-h100_nv_ray_tracing.clt}" "${APP[@]}" ${APP_ARGS:-} 2>&1 | tee "$OUT/app_layer.log"
echo "=== without the layer, again (the driver's answers must repeat: same digest)"
"${APP[@]}" ${APP_ARGS:-} 2>&1 | grep traced | tee -a "$OUT/app_plain.log"
if [ -n "${RAY_CHECK_LARGE:-}" ]; then
  echo "=== under the layer, CLASTRACE_RAY_CHECK=$RAY_CHECK_LARGE (cost of a large check)"
  env "${LAYER_ENV[@]}" CLASTRACE_RAY_CHECK="$RAY_CHECK_LARGE" CLASTRACE_OUTPUT=/tmp/large.clt "${APP[@]}" ${APP_ARGS:-} 2>&1 |
    grep -E "clastrace|traced" | tee "$OUT/app_layer_large.log"
  ls -la /tmp/large.clt
fi
echo "=== under the layer, JSON dump"
env "${LAYER_ENV[@]}" CLASTRACE_DEBUG_JSON="$OUT/capture.json" "${APP[@]}" ${APP_ARGS:-} >"$OUT/app_json.log" 2>&1
echo "json rc=$?"; tail -3 "$OUT/app_json.log"
ls -la "$OUT"
