// `voxelastic-probe` with faults on purpose (--test-fault, --test-unplug/--test-replug): what the
// hand feels when the physics fails or a stick is pulled out. The force log of the demo scene
// with local shaping (a smooth force, so a jump would show) is read tick by tick.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "support/run_binary.h"

namespace fs = std::filesystem;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "probe" / "voxelastic-probe";
const fs::path kScene = fs::path(VX_SAMPLES_DIR) / "scenes" / "palpation-lesion.json";
const fs::path kScript = fs::path(VX_SAMPLES_DIR) / "scenes" / "palpation-lesion.joy";

struct Tick {
  double wall_s, sim_s, device_N, physics_s;
};

std::vector<Tick> read_ticks(const fs::path& csv) {
  std::ifstream in(csv);
  std::string line;
  std::getline(in, line);
  std::vector<Tick> out;
  while (std::getline(in, line)) {
    std::vector<std::string> c;
    std::stringstream ss(line);
    for (std::string v; std::getline(ss, v, ',');) c.push_back(v);
    if (c.size() < 19) continue;
    out.push_back({std::stod(c[0]), std::stod(c[1]), std::stod(c[6]), std::stod(c[18])});
  }
  return out;
}

std::string q(const fs::path& p) {
  std::string s(1, '\'');
  s += p.string();
  s.push_back('\'');
  return s;
}

/// The largest tick-to-tick change of the device force's magnitude.
double largest_step(const std::vector<Tick>& t) {
  double m = 0;
  for (std::size_t i = 1; i < t.size(); ++i) m = std::max(m, std::abs(t[i].device_N - t[i - 1].device_N));
  return m;
}

/// The force at the last tick at or before `key` (a wall or device time, by `at`).
template <class Key>
double force_at(const std::vector<Tick>& t, double time, Key key) {
  double f = 0;
  for (const Tick& x : t)
    if (key(x) <= time) f = x.device_N;
  return f;
}

class ProbeFaults : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_probe_faults_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  vx::testing::RunResult run(const std::string& extra, const fs::path& csv) const {
    return vx::testing::run_binary(kBinary,
                                   q(kScene) + " --headless --force-shaping local --virtual-joystick " + q(kScript) +
                                       " --force-log " + q(csv) + " " + extra,
                                   dir_, dir_);
  }
  fs::path dir_;
};

TEST_F(ProbeFaults, EachFaultFadesTheForceWithin50msThenRampsUpAndTheSessionGoesOn) {
  // the demo presses from 0.9 s and slides from 2 s to 7.5 s; these steps fall at 2.0, 2.9 and
  // 3.8 s simulated, all while the tool presses the tissue. The session ends at 8 s of the
  // device's clock (local shaping: wall time), so a physics at 0.55x real time or more still
  // makes all three and 0.5 s after the last (at 5 s a host that took a quarter of the CPUs left
  // the physics at 0.69x, and the third fault never came: 2026-11-28)
  const fs::path csv = dir_ / "faults.csv";
  const auto r = run("--duration 8 --test-fault nan@11000 --test-fault runaway@16000 --test-fault throw@21000", csv);
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("faults: 3 physics fault(s) recovered"), std::string::npos) << r.out;
  // the three faults, each named, with the wall time the physics noticed it
  const std::regex line(R"(physics fault at t = ([0-9.]+) s \(wall ([0-9.]+) s; ([a-z_ ]+))");
  std::vector<double> walls, sims;
  std::vector<std::string> kinds;
  for (std::sregex_iterator it(r.err.begin(), r.err.end(), line), end; it != end; ++it) {
    sims.push_back(std::stod((*it)[1]));
    walls.push_back(std::stod((*it)[2]));
    kinds.push_back((*it)[3]);
  }
  ASSERT_EQ(walls.size(), 3u) << r.err;
  EXPECT_EQ(kinds[0].compare(0, 10, "non_finite"), 0) << kinds[0];
  EXPECT_EQ(kinds[1].compare(0, 7, "runaway"), 0) << kinds[1];
  EXPECT_EQ(kinds[2].compare(0, 14, "the step threw"), 0) << kinds[2];

  const std::vector<Tick> t = read_ticks(csv);
  ASSERT_GT(t.size(), 4000u);
  const auto wall = [](const Tick& x) { return x.wall_s; };
  for (std::size_t k = 0; k < walls.size(); ++k) {
    const double w = walls[k];
    const double before = force_at(t, w, wall);
    EXPECT_GT(before, 0.05) << "fault " << k << ": the tool should be pressing";
    // to zero within 50 ms (the device sees the fault at its next tick and fades over 40 ms)
    auto zero = std::find_if(t.begin(), t.end(), [&](const Tick& x) { return x.wall_s > w && x.device_N == 0.0; });
    ASSERT_NE(zero, t.end());
    EXPECT_LE(zero->wall_s - w, 0.050) << "fault " << k;
    // not cut: a fade over 40 ms of the device's clock (a cut reaches zero at the next tick,
    // 1 ms), each step at most 1/40 of the force and a little. Timed, not counted in ticks: where
    // the host stops the machine in a fade the device skips the late ticks and goes on along the
    // same 40 ms (25 ticks in one fade on a host that took 29 % of the CPUs, 2026-11-28 23:15 UTC)
    const auto first = std::find_if(t.begin(), zero, [&](const Tick& x) { return x.wall_s > w; });
    ASSERT_NE(first, zero) << "fault " << k << ": no tick between the fault and zero";
    EXPECT_GE(zero->wall_s - first->wall_s, 0.030) << "fault " << k << ": the fade's length, s";
    // then up again over about 100 ms: a third of the way after 30 ms, most of it after 150 ms
    const double z = zero->wall_s;
    const double at30 = force_at(t, z + 0.030, wall), at150 = force_at(t, z + 0.150, wall);
    EXPECT_GT(at150, 0.5 * before) << "fault " << k;
    EXPECT_LT(at30, 0.45 * at150) << "fault " << k;
  }
  // the hand never felt a jump (the run without faults: 0.007 N; a cut force would be > 0.1 N).
  // Held to 0.05 N as the unplug test below is: on a host that took a fifth to a half of the
  // CPUs (/proc/stat's steal, 2026-11-28 22:00-22:15 UTC) the device thread came late by a few
  // ticks in a fade or a ramp, and the largest step read 0.022 to 0.034 N in five runs of nine;
  // in one more the machine stopped for over 40 ms in a fade (0.13 N, 2 fade ticks), which still
  // fails. A cut is also caught by the fade's 30 ms above (a 5 ms fade, tried: 0.005 s read).
  EXPECT_LT(largest_step(t), 0.05);
  // the session went on: the physics kept stepping after the last fault
  EXPECT_GT(t.back().physics_s, sims.back() + 0.5);
}

TEST_F(ProbeFaults, AStickUnpluggedAndPluggedBackDrivesItsProbeAgain) {
  const fs::path csv = dir_ / "unplug.csv";
  const auto r = run("--duration 4.5 --test-unplug 2.5 --test-replug 3.0", csv);
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("was disconnected"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("is back"), std::string::npos) << r.out;
  const std::vector<Tick> t = read_ticks(csv);
  const auto dev = [](const Tick& x) { return x.sim_s; };  // local shaping: the device's clock
  EXPECT_GT(force_at(t, 2.49, dev), 0.05);
  // unplugged: faded out within 50 ms, then nothing until it is back
  for (const Tick& x : t) {
    if (x.sim_s > 2.56 && x.sim_s < 3.0) {
      EXPECT_EQ(x.device_N, 0.0) << x.sim_s;
    }
  }
  // back: the force ramps up over about 100 ms (the script goes on sliding)
  const double at3 = force_at(t, 3.03, dev), at3_2 = force_at(t, 3.2, dev);
  EXPECT_GT(at3_2, 0.05);
  EXPECT_LT(at3, 0.45 * at3_2);
  // no cut (a cut force steps by more than 0.1 N): 0.007 N quiet, 0.029 N once in a clean-clone
  // CI run beside the other tests (2026-11-27; the device thread late by a few ticks in the ramp)
  EXPECT_LT(largest_step(t), 0.05);
}

}  // namespace
