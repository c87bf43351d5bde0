// The local contact model's force at 1 kHz against the full-rate physics (bench/haptic_accuracy.h):
// the palpation demo's press-and-slide with the physics at 60 and 30 Hz. The target of issue 16:
// within 5 % RMS of the peak force at 60 Hz. `voxelastic bench --haptic` prints the whole table
// (1000, 200, 60, 30 Hz) for docs/probe.md.
#include <gtest/gtest.h>

#include <cstdio>

#include "bench/haptic_accuracy.h"

using namespace vx;

TEST(HapticAccuracy, LocalModelWithin5PercentRmsAt60HzPhysics) {
  HapticAccuracySettings s;
  s.scene = std::string(VX_SAMPLES_DIR) + "/scenes/palpation-lesion.json";
  s.physics_hz = {60.0, 30.0};
  const HapticAccuracyResult r = run_haptic_accuracy(s);
  std::printf("%s", haptic_accuracy_table(r).c_str());
  ASSERT_GT(r.peak_force_n, 0.3);  // the lesion: 0.53 N
  const auto row = [&](const std::string& method, double hz) {
    for (const auto& x : r.rows)
      if (x.method == method && x.physics_hz == hz) return x;
    ADD_FAILURE() << "no row " << method << " at " << hz << " Hz";
    return HapticAccuracyRow{};
  };
  for (const double hz : {60.0, 30.0}) {
    const HapticAccuracyRow local = row("local model (chunks)", hz), held = row("physics force held (chunks)", hz),
                            large = row("local model (large steps)", hz);
    // measured: 60 Hz 1.1 % RMS, 3.4 % peak (held 1.9 %, 5.3 %); 30 Hz 1.9 %, 5.5 % (held 3.6 %, 9.9 %)
    EXPECT_LT(local.rms, 0.05) << hz << " Hz";
    EXPECT_LT(large.rms, 0.05) << hz << " Hz";
    EXPECT_LT(local.rms, 0.7 * held.rms) << hz << " Hz";
    EXPECT_LT(local.peak, held.peak) << hz << " Hz";
    // smooth: no tick-to-tick step above 1 % of the peak (the held force steps 3-5 %)
    EXPECT_LT(local.max_step, 0.01) << hz << " Hz";
  }
  EXPECT_LT(row("local model (chunks)", 60.0).rms, 0.02);
}
