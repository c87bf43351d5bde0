#!/usr/bin/env bash
# complete.sh COMPLETION_FILE WORD...: what bash completion offers for the last WORD of the line
# (run by install_test.cmake with the installed programs first on PATH)
set -euo pipefail
source "$1"
shift
COMP_WORDS=("$@")
COMP_CWORD=$(($# - 1))
_voxelastic
echo "${COMPREPLY[*]}"
