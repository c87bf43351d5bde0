#!/usr/bin/env bash
# The threaded tests under ThreadSanitizer (clang-14, -O1), in their own build folder
# (build-tsan): the triple buffer and the fixed-rate thread, the app's live probe and frames
# (SimulationExchange) and local contact models handed across threads, OpenMP loops on two threads, a solver built on a thread of its own, and the probe app
# (physics, device and display threads) run headless and under Xvfb. CI runs this after
# scripts/sanitize.sh. Only the targets these tests need are built. Extra arguments go to ctest.
# Any data race or lock-order inversion fails the test that hit it (TSan exits with 66).
# OpenMP: clang's -fopenmp uses LLVM's runtime (libomp), whose TSan support (Archer,
# libarcher.so) tells TSan about its barriers and tasks; GCC's libgomp would need a
# TSan-instrumented rebuild. Suppressions: tests/sanitizers/tsan.supp, third-party code only.
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${VX_TSAN_BUILD_DIR:-build-tsan}
jobs=${VX_JOBS:-$(nproc)}
launcher=()
if command -v ccache >/dev/null 2>&1; then
  launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache)
  export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$PWD}
fi
if ! command -v clang++-14 >/dev/null 2>&1; then
  echo "tsan: clang++-14 is missing (run scripts/install-deps.sh --dev)" >&2
  exit 1
fi
archer=/usr/lib/llvm-14/lib/libarcher.so
if [ ! -f "$archer" ]; then
  echo "tsan: $archer is missing (libomp-14-dev: scripts/install-deps.sh --dev)" >&2
  exit 1
fi
cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=None -DCMAKE_C_COMPILER=clang-14 -DCMAKE_CXX_COMPILER=clang++-14 \
  -DCMAKE_CXX_FLAGS="-O1" -DCMAKE_C_FLAGS="-O1" "${launcher[@]}" \
  -DVOXELASTIC_TSAN=ON -DVOXELASTIC_BUILD_MICROBENCH=OFF -DVOXELASTIC_BUILD_SLOW_TESTS=OFF >"$build_dir.configure.log" 2>&1 || {
  cat "$build_dir.configure.log" >&2
  echo "tsan: cmake configure failed (log above)" >&2
  exit 1
}
rm -f "$build_dir.configure.log"
# the test executables with threads, and the app probe_app_test runs
targets=(triple_buffer_test probe_output_test probe_sim_exchange_test simulation_test device_side_test factor_cache_test
  calibration_cache_test still_far_field_test quasi_static_test probe_app_test voxelastic-probe)
echo "tsan: building ${targets[*]} with ThreadSanitizer into $build_dir/ ..."
cmake --build "$build_dir" -j "$jobs" --target "${targets[@]}"
# the tests of those executables that start threads (std::thread, FixedRateThread, OpenMP on
# two threads, the app's three loops); the rest of them run single-threaded code the ASan pass
# already covers. Of the app's tests: the paper's half sines and local shaping, two sticks, the
# region check beside the physics, the display thread under Xvfb; left out are the ones that
# start no thread (usage and input errors), the 2D model's (the same loops) and the two that
# assert wall times (start-up, slowed physics), which TSan's 5-15x slow-down makes meaningless,
# and the display's turn with the physics (a relaxed atomic flag between the two threads), whose
# first turn needs frames of a fraction of a second: under TSan a frame takes seconds (one frame
# in its 3 s run, tried 2026-11-30).
app='ScriptedPalpationFeelsTheLesion|LocalShapingAtSixtyUpdatesFeelsTheLesionSmoothly|TwoJoysticksGraspWithTwoProbes'
app+='|TheRegionCheckOfAWeakSupportIsReportedDuringTheRun|WindowScreenshotUnderADisplay'
tests="^TripleBuffer\\.|^FixedRateThread\\.|^Simulation\\.SameResultsOnOneAndTwoThreads\$|^SimulationExchange\\.LiveProbeAcrossThreads\$|^DeviceSide\\.LocalContactModelsAcrossThreads\$|^ProbeApp\\.($app)\$"
# the factor cache's writer thread beside the solver (io/factor_cache.h, background_writes)
tests+="|^FactorCacheTest\\.AFactorWrittenInTheBackgroundOutlivesItsSolverAndIsFoundAtOnce\$"
# ... and the calibration cache's, reading the calibrated arrays while make_physics_model sets the derived ones
tests+="|^CalibrationCacheTest\\.ACalibrationWrittenInTheBackgroundIsTheFileWrittenInPlaceAndIsFoundAtOnce\$"
# a solver built on a thread of its own while the tissue rests (integrators.h, factor_in_background)
tests+="|^RegionalSolve\\.ASolverBuiltInTheBackgroundWhileTheTissueRestsPressesTheSame\$"
# the regional solves' passes over the closure on two threads (sim/projective_solver.h, still_far_field_nodes)
tests+="|^StillFarField\\.ARegionalPressIsTheSameBitForBitAsOneThatVisitsEveryNode\$"
export TSAN_OPTIONS=${TSAN_OPTIONS:-ignore_noninstrumented_modules=1:suppressions=$PWD/tests/sanitizers/tsan.supp:second_deadlock_stack=1:history_size=4}
export OMP_TOOL_LIBRARIES=$archer
# the app's tests time their runs; one at a time so that two TSan-slowed apps do not share a core
scripts/with-display.sh ctest --test-dir "$build_dir" -R "$tests" --output-on-failure -j 1 "$@"
