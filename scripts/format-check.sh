#!/usr/bin/env bash
# Checks the C++ lines changed since BASE (default HEAD: the uncommitted change, staged or not)
# against .clang-format, and prints what clang-format would make of them as a diff. Only the
# changed lines are looked at: the tree is not reformatted as a whole. Exit status 1 when a
# changed line is off style (fix: the same command with --fix, or `git clang-format BASE`).
#   scripts/format-check.sh [--fix] [BASE]
set -euo pipefail
cd "$(dirname "$0")/.."
fix=0
if [[ "${1:-}" == "--fix" ]]; then fix=1; shift; fi
base=${1:-HEAD}
tool=$(command -v git-clang-format-14 || command -v git-clang-format || true)
binary=$(command -v clang-format-14 || command -v clang-format || true)
if [[ -z "$tool" || -z "$binary" ]]; then
  echo "format-check: needs clang-format and git-clang-format (Debian: apt-get install clang-format-14)" >&2
  exit 2
fi
paths=('*.cpp' '*.h' '*.inl' '*.h.in')
if ((fix)); then
  "$tool" --binary "$binary" "$base" -- "${paths[@]}"
  exit 0
fi
out=$("$tool" --binary "$binary" --diff "$base" -- "${paths[@]}")
if [[ -z "$out" || "$out" == "no modified files to format" || "$out" == "clang-format did not modify any files" ]]; then
  echo "format-check: the changed lines keep the style (.clang-format)"
  exit 0
fi
printf '%s\n' "$out"
echo "format-check: the lines above are off style; scripts/format-check.sh --fix $base formats them" >&2
exit 1
