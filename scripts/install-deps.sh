#!/usr/bin/env bash
# Install the Debian 12 packages voxelastic needs to build, test and run headless.
# Only packages that are missing are installed; safe to run again.
set -euo pipefail

packages=(
  build-essential cmake pkg-config
  libeigen3-dev libsuitesparse-dev libmetis-dev libvtk9-dev libdcmtk-dev libsdl2-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libcli11-dev nlohmann-json3-dev libspdlog-dev libfmt-dev
  libopenjp2-7-dev
  xvfb xauth x11-utils dicom3tools gnuplot-nox
  # the palpation sweep (workflow/Snakefile, docs/palpation.md) and its CI test
  snakemake
  # fuzzing and the sanitizer build (scripts/fuzz.sh, scripts/sanitize.sh): clang with its
  # sanitizer and libFuzzer runtimes (libclang_rt.fuzzer is in libclang-rt-14-dev), OpenMP for
  # clang, llvm-symbolizer for readable stacks
  clang-14 libclang-rt-14-dev libomp-14-dev llvm-14
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} Debian packages present"
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
