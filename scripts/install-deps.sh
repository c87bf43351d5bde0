#!/usr/bin/env bash
# Install the Debian 12 packages voxelastic needs.
#   scripts/install-deps.sh         to build, test, install and run it (headless too)
#   scripts/install-deps.sh --dev   also the developer's tools: clang, LLVM and their sanitizer
#                                   and libFuzzer runtimes for scripts/sanitize.sh and scripts/fuzz.sh
# Only packages that are missing are installed; safe to run again.
set -euo pipefail

usage() { echo "usage: scripts/install-deps.sh [--dev]" >&2; exit 2; }
dev=0
for arg in "$@"; do
  case "$arg" in
    --dev) dev=1 ;;
    -h|--help) sed -n '2,6p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "install-deps: unknown option '$arg'" >&2; usage ;;
  esac
done

# a user's: the compiler and libraries, the test suite's (built by default), what the
# programs run at run time (Xvfb for 3D pictures without a display; plots need nothing),
# help2man for the man pages `cmake --install` writes, dciodvfy to check written DICOM and
# xmllint (libxml2-utils) the Slicer description of `convert --xml`
packages=(
  build-essential cmake pkg-config
  libeigen3-dev libsuitesparse-dev libmetis-dev libvtk9-dev libdcmtk-dev libsdl2-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libcli11-dev nlohmann-json3-dev libspdlog-dev libfmt-dev
  libopenjp2-7-dev
  # OpenBLAS, single-threaded, as the libblas.so.3 CHOLMOD's supernodes call (Debian's alternatives
  # put it above the reference BLAS): the folded organ factors in 4.7 s instead of 17.4 s
  # (docs/bench.md); single-threaded, so it never competes with the physics' OpenMP threads
  libopenblas0-serial
  xvfb xauth x11-utils dicom3tools libxml2-utils help2man
  # the palpation sweep (workflow/Snakefile, docs/palpation.md) and its CI test
  snakemake
)
# a developer's: fuzzing and the sanitizer build (scripts/fuzz.sh, scripts/sanitize.sh): clang
# with its sanitizer and libFuzzer runtimes (libclang_rt.fuzzer is in libclang-rt-14-dev),
# OpenMP for clang, llvm-symbolizer for readable stacks
dev_packages=(
  clang-14 libclang-rt-14-dev libomp-14-dev llvm-14
)
if [ "$dev" -eq 1 ]; then packages+=("${dev_packages[@]}"); fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} Debian packages present$([ "$dev" -eq 1 ] && echo " (with the developer's)")"
  exit 0
fi

echo "install-deps: installing ${#missing[@]} missing package(s): ${missing[*]}"
sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then sudo_cmd=(sudo); else
    echo "install-deps: not root and no sudo; install these packages yourself: ${missing[*]}" >&2
    exit 1
  fi
fi
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "install-deps: done"
