#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Fails (exit 1) when a tracked source differs from .clang-format's layout; prints the places.
# ctest runs it as style.format; scripts/apply_style.sh PART fixes what it finds.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
format=${CLANG_FORMAT:-$(command -v clang-format-14 || command -v clang-format || true)}
[[ -n "$format" ]] || { echo "style: clang-format not found (scripts/deps.sh installs it)" >&2; exit 2; }
mapfile -t files < <(python3 scripts/style_pass.py files abi traces engine replay analyze capture \
  tools tests bench examples common)
if ! "$format" --dry-run -Werror "${files[@]}"; then
  echo "style: files above differ from .clang-format; run scripts/apply_style.sh PART" >&2
  exit 1
fi
echo "style: ${#files[@]} files formatted"
