#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The test suite's ray-tracing driver: Mesa 25.0.7's lavapipe from Debian 12's bookworm-backports
# (Vulkan 1.4.305 with VK_KHR_acceleration_structure, VK_KHR_ray_query,
# VK_KHR_ray_tracing_pipeline, VK_EXT_mesh_shader and sparse binding, on Debian 12's own LLVM 15),
# downloaded with a private apt setup and unpacked with `dpkg -x` into a folder of its own, so the
# system's apt sources and its Mesa (22.3) stay as they are.
#   scripts/lavapipe_rt.sh         fetch and unpack when missing (no network once there), check
#                                  it, print the two settings that select it
# The folder: $CLASTRACE_RT_DRIVER_DIR, else ${XDG_CACHE_HOME:-~/.cache}/clastrace/lavapipe-25.0.7.
# It holds lvp_icd.json (the ICD manifest, library_path absolute), root/ (the unpacked packages)
# and env.sh (VK_DRIVER_FILES and LD_LIBRARY_PATH; `. env.sh` runs a shell on this driver).
# CLASTRACE_RT_APT_SOURCE replaces the apt line (e.g. a snapshot.debian.org mirror once
# bookworm-backports has moved past these versions).
# Exit codes: 0 ready; 1 the download, the unpack or the check failed (said on stderr).
set -euo pipefail

MESA_VERSION="25.0.7-2~bpo12+1"
LIBDRM_VERSION="2.4.123-1~bpo12+1"
API_VERSION="1.4.305"
# What lavapipe 25.0.7 needs from bookworm-backports (its Depends: libdrm2 and libdrm-amdgpu1
# >= 2.4.121; Debian 12 has 2.4.114). mesa-libgallium is not among them: libvulkan_lvp.so
# carries gallium inside.
PACKAGES=(
  "mesa-vulkan-drivers=$MESA_VERSION"
  "libdrm2=$LIBDRM_VERSION"
  "libdrm-amdgpu1=$LIBDRM_VERSION"
)
# The ray-tracing suite's reason for this driver: each must be listed by vulkaninfo.
EXTENSIONS=(VK_KHR_acceleration_structure VK_KHR_ray_query VK_KHR_ray_tracing_pipeline
  VK_KHR_ray_tracing_position_fetch VK_EXT_mesh_shader)

dir=${CLASTRACE_RT_DRIVER_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/clastrace/lavapipe-25.0.7}
source_line=${CLASTRACE_RT_APT_SOURCE:-deb http://deb.debian.org/debian bookworm-backports main}
libdir="$dir/root/usr/lib/x86_64-linux-gnu"
manifest="$dir/lvp_icd.json"
stamp="$dir/ready"

fail() {
  echo "lavapipe_rt: $*" >&2
  exit 1
}

# Downloads the packages into $dir/debs with apt's lists and cache under $dir/apt.
download() {
  local apt="$dir/apt"
  mkdir -p "$apt/lists/partial" "$apt/cache/archives/partial" "$dir/debs"
  echo "$source_line" >"$apt/sources.list"
  local options=(-o "Dir::Etc::sourcelist=$apt/sources.list" -o "Dir::Etc::sourceparts=-"
    -o "Dir::State::Lists=$apt/lists" -o "Dir::Cache=$apt/cache" -o "APT::Get::List-Cleanup=0")
  echo "lavapipe_rt: downloading lavapipe $MESA_VERSION ($source_line) into $dir" >&2
  # apt's warning that the _apt user cannot reach a private folder is harmless: it downloads
  # as the caller then.
  apt-get -qq --error-on=any "${options[@]}" update 2>"$apt/update.log" ||
    fail "apt-get update of '$source_line' failed (network or mirror; $apt/update.log):
$(tail -n 5 "$apt/update.log")"
  (cd "$dir/debs" && apt-get -qq "${options[@]}" download "${PACKAGES[@]}") 2>"$apt/download.log" ||
    fail "apt-get download ${PACKAGES[*]} failed ($apt/download.log):
$(grep -v '_apt' "$apt/download.log" | tail -n 5)
(a source that no longer has these versions: set CLASTRACE_RT_APT_SOURCE to a snapshot.debian.org line)"
}

# Unpacks each package into $dir/root after checking its version.
unpack() {
  rm -rf "$dir/root"
  local p name version deb
  for p in "${PACKAGES[@]}"; do
    name=${p%%=*}
    version=${p#*=}
    deb=$(ls "$dir/debs/${name}_"*.deb 2>/dev/null | head -n 1 || true)
    [[ -n "$deb" ]] || fail "$name was not downloaded into $dir/debs"
    [[ $(dpkg-deb -f "$deb" Version) == "$version" ]] ||
      fail "$deb is version $(dpkg-deb -f "$deb" Version), not $version"
    dpkg -x "$deb" "$dir/root"
  done
}

# lvp_icd.json: the package's manifest with library_path made absolute; env.sh beside it.
write_manifest() {
  local shipped="$dir/root/usr/share/vulkan/icd.d/lvp_icd.json"
  [[ -f "$shipped" && -f "$libdir/libvulkan_lvp.so" ]] || fail "the unpack in $dir/root lacks lavapipe"
  grep -q "\"api_version\": \"$API_VERSION\"" "$shipped" ||
    fail "$shipped does not declare api_version $API_VERSION"
  sed -E "s|\"library_path\": \"[^\"]*\"|\"library_path\": \"$libdir/libvulkan_lvp.so\"|" \
    "$shipped" >"$manifest"
  printf 'export VK_DRIVER_FILES=%q\nexport LD_LIBRARY_PATH=%q${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}\n' \
    "$manifest" "$libdir" >"$dir/env.sh"
}

# The driver the loader finds through the manifest is this Mesa and lists every extension
# above, when vulkaninfo is installed (vulkan-tools, scripts/deps.sh --tests).
check_driver() {
  command -v vulkaninfo >/dev/null || return 0
  local info
  info=$(env -u VK_ICD_FILENAMES -u VK_INSTANCE_LAYERS VK_DRIVER_FILES="$manifest" \
    LD_LIBRARY_PATH="$libdir${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" \
    XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}" vulkaninfo 2>/dev/null) ||
    fail "vulkaninfo fails on $manifest"
  grep -q "driverInfo *= Mesa ${MESA_VERSION}" <<<"$info" ||
    fail "vulkaninfo on $manifest does not name Mesa $MESA_VERSION: $(grep -m1 driverInfo <<<"$info")"
  local e
  for e in "${EXTENSIONS[@]}"; do
    grep -q "^[[:space:]]*$e " <<<"$info" || fail "lavapipe $MESA_VERSION in $dir lacks $e"
  done
  grep -q "sparseBinding *= true" <<<"$info" || fail "lavapipe $MESA_VERSION in $dir lacks sparseBinding"
}

if [[ ! -f "$stamp" || $(cat "$stamp") != "$MESA_VERSION" ]]; then
  mkdir -p "$dir"
  rm -f "$stamp"
  download
  unpack
  write_manifest
  check_driver
  rm -rf "$dir/debs" "$dir/apt"  # the unpack is what is kept
  echo "$MESA_VERSION" >"$stamp"
fi
echo "VK_DRIVER_FILES=$manifest"
echo "LD_LIBRARY_PATH=$libdir"
