#!/usr/bin/env bash
# Configure and build voxelastic in Release into ./build (or $VX_BUILD_DIR).
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${VX_BUILD_DIR:-build}
jobs=${VX_JOBS:-$(nproc)}
cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=Release >"$build_dir.configure.log" 2>&1 || {
  cat "$build_dir.configure.log" >&2
  echo "build: cmake configure failed (log above; missing packages? run scripts/install-deps.sh)" >&2
  exit 1
}
rm -f "$build_dir.configure.log"
echo "build: compiling with $jobs job(s) into $build_dir/ ..."
cmake --build "$build_dir" -j "$jobs"
