#!/usr/bin/env bash
# One command from a fresh Debian 12 machine to a passing test suite: installs what is missing,
# builds in Release, runs every test (the slow-labelled ones too) with ctest under a display.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
scripts/build.sh
build_dir=${VX_BUILD_DIR:-build}
scripts/with-display.sh ctest --test-dir "$build_dir" --output-on-failure -j "${VX_JOBS:-$(nproc)}" "$@"
