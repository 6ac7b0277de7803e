#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The mechanical style pass (docs/style.md) for one part, meant to be committed as one commit:
#   scripts/apply_style.sh PART     PART: abi traces engine replay analyze capture tools tests
#                                         bench examples common
# Steps, in order: clang-tidy's naming fixes (.clang-tidy) for the names the part declares,
# applied wherever they are used (so renaming capture/ also changes tests/ and bench/);
# .hpp -> .h with includes and CMake lists following; #ifndef guards -> #pragma once; the SPDX
# line first in every .cpp/.h/.c; clang-format -i. abi/ is only given SPDX and clang-format:
# its names mirror Vulkan's. Idempotent: a second run changes nothing.
# CLASTRACE_STYLE_NO_RENAME=1 skips the names (no clang-tidy, no compile database): layout,
# headers and SPDX only.
#
# It configures its own build folder ($CLASTRACE_STYLE_BUILD, default build-style) for the
# compile database and generates the FlatBuffers and SPIR-V headers; it compiles nothing else.
# clang-tidy runs only where it must: first on the part's own translation units (plus one unit
# for any header of the part none of them reads), then on units elsewhere that read a name
# being changed. Times measured on the 2-core machine while six builds shared it (load ~12):
# abi 1-4 s; capture 90-300 s (25 capture units, then 16 of tests/ and bench/; 618 names, 62
# files); the dependency scan of all ~276 units is ~2 min of that and is cached in the build
# folder for the next part. Not measured: traces and analyze (their snake_case enum values
# become kPascalCase, so their second round reaches many tests: expect 10-20 min), tests (~150
# units of its own: expect 20-40 min). Layout alone (CLASTRACE_STYLE_NO_RENAME=1): seconds.
# Order for the whole tree: abi traces engine replay analyze capture tools tests bench examples
# common (a part's renames reach into the parts after it, not back).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
part=${1:?usage: scripts/apply_style.sh PART (abi traces engine replay analyze capture tools tests bench examples common)}
cd "$root"
python3 scripts/style_pass.py files "$part" >/dev/null  # rejects an unknown part
[[ -d "$part" ]] || { echo "style: $part: no such folder, nothing to do"; exit 0; }
build=${CLASTRACE_STYLE_BUILD:-$root/build-style}
start=$SECONDS

if [[ "$part" != abi && -z "${CLASTRACE_STYLE_NO_RENAME:-}" ]]; then
  cmake -S . -B "$build" -G Ninja -DCMAKE_EXPORT_COMPILE_COMMANDS=ON >/dev/null
  # Headers made at build time (FlatBuffers, SPIR-V) must exist for clang-tidy to parse.
  generated=$(ninja -C "$build" -t targets all | awk -F: '/CUSTOM_COMMAND/ && $1 ~ /\.h$/ && $1 !~ /^\// {print $1}')
  [[ -z "$generated" ]] || ninja -C "$build" $generated >/dev/null
  python3 scripts/style_pass.py rename "$part" "$build"
fi
python3 scripts/style_pass.py headers "$part"
python3 scripts/style_pass.py spdx "$part"
python3 scripts/style_pass.py files "$part" | xargs -r clang-format-14 -i
echo "style: $part done in $((SECONDS - start)) s"
