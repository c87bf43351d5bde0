#!/usr/bin/env bash
# Fuzzing the readers and parsers with libFuzzer (clang-14, AddressSanitizer + UBSan); what
# each target covers and what was found: docs/robustness.md.
#
#   scripts/fuzz.sh --smoke              build, make the seeds, run every target for
#                                        VX_FUZZ_SMOKE_S seconds (default 10; CI runs this)
#   scripts/fuzz.sh TARGET [SECONDS]     one target for SECONDS (default 3600) on one core,
#                                        growing the corpus fuzz-corpus/TARGET
#   scripts/fuzz.sh --all SECONDS        every target in turn, SECONDS each
#   scripts/fuzz.sh --list               the targets
#
# A crash, a hang (10 s per input), an exception other than vx::Error, or an allocation over
# 1 GiB is a finding: the input is kept as fuzz-findings/TARGET-crash-* (reproduce it with
# build-fuzz/fuzz/TARGET FILE) and the script exits 1.
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${VX_FUZZ_BUILD_DIR:-build-fuzz}
jobs=${VX_JOBS:-$(nproc)}
targets=(fuzz_vti fuzz_mha fuzz_nifti fuzz_nrrd fuzz_dicom_file fuzz_dicom_series fuzz_scene fuzz_joystick_script)

if [ "${1:-}" = "--list" ]; then printf '%s\n' "${targets[@]}"; exit 0; fi
mode=${1:---smoke}

# build (its own folder; ccache when there is one)
launcher=()
if command -v ccache >/dev/null 2>&1; then
  launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache)
  export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$PWD}  # paths relative to the clone: another clone hits the cache
fi
if ! command -v clang++-14 >/dev/null 2>&1; then
  echo "fuzz: clang++-14 is missing (run scripts/install-deps.sh --dev)" >&2
  exit 1
fi
# A build folder configured by scripts/sanitize.sh (ASan + UBSan with the fuzz targets beside the
# tests; CI passes VX_FUZZ_BUILD_DIR=build-asan) is used as it is: only the pipeline and the
# targets carry coverage there. Otherwise the folder is configured for fuzzing alone, with
# coverage in the core too.
if grep -qs '^VOXELASTIC_SANITIZE:BOOL=ON$' "$build_dir/CMakeCache.txt" &&
  grep -qs '^VOXELASTIC_FUZZ:BOOL=ON$' "$build_dir/CMakeCache.txt"; then
  echo "fuzz: the targets of the sanitized build in $build_dir/ (scripts/sanitize.sh) ..."
else
  cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=None -DCMAKE_C_COMPILER=clang-14 -DCMAKE_CXX_COMPILER=clang++-14 \
    -DCMAKE_CXX_FLAGS="-O1" -DCMAKE_C_FLAGS="-O1" "${launcher[@]}" \
    -DVOXELASTIC_FUZZ=ON -DVOXELASTIC_BUILD_TESTS=OFF -DVOXELASTIC_BUILD_APPS=OFF >"$build_dir.configure.log" 2>&1 || {
    cat "$build_dir.configure.log" >&2
    echo "fuzz: cmake configure failed (log above)" >&2
    exit 1
  }
  rm -f "$build_dir.configure.log"
  echo "fuzz: building the targets into $build_dir/ ..."
fi
cmake --build "$build_dir" -j "$jobs" --target fuzz_all

export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=0:allocator_may_return_null=0:handle_abort=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
seeds="$build_dir/seeds"
rm -rf "$seeds"
"$build_dir/fuzz/voxelastic_fuzz_seeds" samples "$seeds"
mkdir -p fuzz-findings

# run_target TARGET SECONDS CORPUS: prints one summary line, returns libFuzzer's status
run_target() {
  local t=$1 secs=$2 corpus=$3 log
  mkdir -p "$corpus"
  log="$build_dir/$t.log"
  set +e
  "$build_dir/fuzz/$t" -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -malloc_limit_mb=1024 \
    -print_final_stats=1 -artifact_prefix="fuzz-findings/$t-" "$corpus" "$seeds/$t" >"$log" 2>&1
  local status=$?
  set -e
  local runs cov
  runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo "?")
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*' || echo "?")
  if [ "$status" -eq 0 ]; then
    printf 'fuzz: %-22s %5ss  %9s inputs  coverage %5s  no finding\n' "$t" "$secs" "$runs" "$cov"
  else
    printf 'fuzz: %-22s FINDING (exit %s): log %s, input in fuzz-findings/\n' "$t" "$status" "$log"
    grep -E 'ERROR: |runtime error|internal error|SUMMARY' "$log" | head -5 | sed 's/^/fuzz:   /'
  fi
  return "$status"
}

failed=0
case "$mode" in
  --smoke)
    secs=${VX_FUZZ_SMOKE_S:-10}
    for t in "${targets[@]}"; do run_target "$t" "$secs" "$build_dir/corpus/$t" || failed=1; done
    ;;
  --all)
    secs=${2:?"--all needs SECONDS per target"}
    for t in "${targets[@]}"; do run_target "$t" "$secs" "fuzz-corpus/$t" || failed=1; done
    ;;
  *)
    if ! printf '%s\n' "${targets[@]}" | grep -qx "$mode"; then
      echo "fuzz: unknown target '$mode'; targets: ${targets[*]}" >&2
      exit 2
    fi
    run_target "$mode" "${2:-3600}" "fuzz-corpus/$mode" || failed=1
    ;;
esac
# a closing line CI reads: targets without a finding, targets with one
bad=$(ls fuzz-findings 2>/dev/null | sed 's/-\(crash\|oom\|timeout\|leak\|slow-unit\)-.*//' | sort -u | wc -l)
ran=$([ "$mode" = "--smoke" ] || [ "$mode" = "--all" ] && echo "${#targets[@]}" || echo 1)
echo "fuzz: $((ran - bad < 0 ? 0 : ran - bad)) passed, $bad failed"
exit $failed
