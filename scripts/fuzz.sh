#!/usr/bin/env bash
# Long fuzzing with libFuzzer (docs/fuzzing.md):
#   scripts/fuzz.sh [--jobs N] TARGET|all [SECONDS] [libFuzzer options...]
# Builds TARGET_fuzzer with clang, libFuzzer, ASan and UBSan in build-fuzz/ (or
# $CLASTRACE_FUZZ_BUILD_DIR) and runs it for SECONDS (default 3600) over a working corpus
# in build-fuzz/corpus/TARGET, seeded like the ctest runs. Findings (crash-*, timeout-*,
# oom-*, leak-*) land in build-fuzz/findings/TARGET. `all` runs every target for SECONDS
# each, one after another. CLASTRACE_FUZZ_SKIP=TEXT leaves out seeds whose name holds TEXT.
# --jobs N (or CLASTRACE_FUZZ_JOBS=N) builds with N jobs; default half the cores, at least 1,
# since the machine fuzzing is often shared (ninja alone takes them all).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
build=${CLASTRACE_FUZZ_BUILD_DIR:-$root/build-fuzz}
targets=(trace_reader info_integrity replay_bytes analyze_bytes layer_config replay_built_trace
         engine_object engine_execute engine_nv)

usage() {
  echo "usage: scripts/fuzz.sh [--jobs N] TARGET|all [SECONDS] [libFuzzer options...]"
  echo "targets: ${targets[*]}"
  exit 2
}
jobs=${CLASTRACE_FUZZ_JOBS:-$(( $(nproc) / 2 > 1 ? $(nproc) / 2 : 1 ))}
case ${1:-} in
  --jobs) [[ $# -ge 2 ]] || usage; jobs=$2; shift 2 ;;
  --jobs=*) jobs=${1#--jobs=}; shift ;;
esac
if [[ ! $jobs =~ ^[1-9][0-9]*$ ]]; then
  echo "scripts/fuzz.sh: --jobs/CLASTRACE_FUZZ_JOBS wants a whole number of at least 1, not '$jobs'" >&2
  exit 2
fi
if [[ $# -lt 1 || $1 == -h || $1 == --help ]]; then usage; fi
target=$1
seconds=${2:-3600}
shift $(( $# >= 2 ? 2 : 1 ))
if [[ $target != all && ! " ${targets[*]} " =~ " $target " ]]; then
  echo "scripts/fuzz.sh: no target '$target' (targets: ${targets[*]})" >&2
  exit 2
fi
cxx=$(command -v clang++ || command -v clang++-14 || true)
cc=$(command -v clang || command -v clang-14 || true)
if [[ -z $cxx || -z $cc ]]; then
  echo "scripts/fuzz.sh: needs clang and its libFuzzer runtime (apt-get install clang)" >&2
  exit 2
fi

cmake -S "$root" -B "$build" -G Ninja -DCMAKE_C_COMPILER="$cc" -DCMAKE_CXX_COMPILER="$cxx" \
  -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCLASTRACE_FUZZ=ON -DCLASTRACE_SANITIZE=address,undefined \
  -DCLASTRACE_BUILD_BENCH=OFF >/dev/null

run_target() {
  local name=$1 corpus=$build/corpus/$1 findings=$build/findings/$1
  shift  # the rest are libFuzzer options
  cmake --build "$build" --parallel "$jobs" --target "${name}_fuzzer" fuzz_seed_classes
  mkdir -p "$corpus" "$findings"
  # The seeds, gathered in one folder: the samples' .clt files and the generated classes,
  # less those whose name holds $CLASTRACE_FUZZ_SKIP (e.g. "bomb" while a bound is missing).
  local seeds=$build/seeds-for/$name
  rm -rf "$seeds" && mkdir -p "$seeds"
  case $name in
    trace_reader|info_integrity|replay_bytes|analyze_bytes)
      "$build/tests/fuzz/fuzz_seed_classes" "$build/tests/fuzz/seeds" "$root"/traces/samples/*.clt >/dev/null
      cp "$root"/traces/samples/*.clt "$build"/tests/fuzz/seeds/* "$seeds"/ ;;
    layer_config) cp "$root"/tests/fuzz/corpus/layer_config/* "$seeds"/ ;;
  esac
  if [[ -n ${CLASTRACE_FUZZ_SKIP:-} ]]; then find "$seeds" -name "*${CLASTRACE_FUZZ_SKIP}*" -delete; fi
  echo "fuzzing $name for $seconds s: corpus $corpus, findings $findings"
  # The corpus folder comes first: libFuzzer adds what it learns there, and reads the seeds.
  (cd "$findings" && "$build/tests/fuzz/${name}_fuzzer" -max_total_time="$seconds" -timeout=25 \
     -rss_limit_mb=2048 -max_len=4194304 -artifact_prefix="$findings/" "$@" "$corpus" "$seeds")
}

if [[ $target == all ]]; then
  for t in "${targets[@]}"; do run_target "$t" "$@"; done
else
  run_target "$target" "$@"
fi
