#!/usr/bin/env bash
# Configure and build voxelastic in Release into ./build (or $VX_BUILD_DIR).
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${VX_BUILD_DIR:-build}
jobs=${VX_JOBS:-$(nproc)}
# ccache, when there is one, makes rebuilds (and CI on a machine that built before) cheap
launcher=()
if command -v ccache >/dev/null 2>&1; then
  launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache)
  export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$PWD}  # paths relative to the clone: another clone hits the cache
fi
cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=Release "${launcher[@]}" >"$build_dir.configure.log" 2>&1 || {
  cat "$build_dir.configure.log" >&2
  echo "build: cmake configure failed (log above; missing packages? run scripts/install-deps.sh)" >&2
  exit 1
}
rm -f "$build_dir.configure.log"
echo "build: compiling with $jobs job(s) into $build_dir/ ..."
cmake --build "$build_dir" -j "$jobs"
