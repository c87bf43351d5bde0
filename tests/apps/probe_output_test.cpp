// The probe app's force output backends and timing scaffolding: the CSV recorder, rumble
// through an SDL virtual joystick's Rumble callback, the haptic effect parameters, the
// fixed-rate thread and the rate meter (the triple buffer: tests/core/base/triple_buffer_test.cpp).
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <thread>

#include "base/error.h"
#include "force_output.h"
#include "rate_thread.h"
#include "sdl_input.h"

using namespace vx::probe;
namespace fs = std::filesystem;

namespace {

fs::path temp_dir() {
  const fs::path d = fs::path(VX_BINARY_DIR) / "test-out" / "probe_output";
  fs::create_directories(d);
  return d;
}

DeviceTick tick(double wall_s, double fx, double fy, double fz) {
  DeviceTick t;
  t.wall_s = wall_s;
  t.sim_s = wall_s;
  t.probes = 1;
  t.probe[0].device_N = Eigen::Vector3d(fx, fy, fz);
  t.probe[0].raw_N = 2.0 * t.probe[0].device_N;
  t.probe[0].stick_N = Eigen::Vector3d(fx, fy, fz);
  t.probe[0].tip_mm = Eigen::Vector3d(1, 2, 3);
  t.probe[0].contacts = 7;
  return t;
}

}  // namespace

TEST(RecordingForceOutput, WritesEveryTickAndMovesIntoPlace) {
  const fs::path csv = temp_dir() / "force.csv";
  fs::remove(csv);
  {
    RecordingForceOutput rec(csv);
    EXPECT_FALSE(fs::exists(csv));  // written beside, moved into place at stop
    for (int i = 0; i < 10; ++i) rec.write(tick(i * 0.001, 0.0, 0.0, 0.5 * i));
    EXPECT_EQ(rec.device_updates(), 10);
    rec.stop();
  }
  ASSERT_TRUE(fs::exists(csv));
  std::ifstream in(csv);
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line, RecordingForceOutput::header());
  int rows = 0;
  std::string last;
  while (std::getline(in, line)) {
    ++rows;
    last = line;
  }
  EXPECT_EQ(rows, 10);
  // wall_s,sim_s,probe,device_fx,fy,fz,|device|,raw..., |raw| = 2 |device| = 9
  std::istringstream cells(last);
  std::vector<std::string> v;
  for (std::string c; std::getline(cells, c, ',');) v.push_back(c);
  ASSERT_EQ(v.size(), 31u);
  EXPECT_NEAR(std::stod(v[6]), 4.5, 1e-9);
  EXPECT_NEAR(std::stod(v[10]), 9.0, 1e-9);
  EXPECT_EQ(v[16], "7");
  EXPECT_EQ(v[17], "paper");  // the shaping of the tick (DeviceTick::local)
}

TEST(RecordingForceOutput, BadPathsAreClearErrors) {
  EXPECT_THROW(RecordingForceOutput{"/nonexistent-folder/x.csv"}, vx::Error);
  EXPECT_THROW(RecordingForceOutput{temp_dir()}, vx::Error);
}

TEST(HapticForceOutput, CommandPointsWhereTheForceComesFrom) {
  // a force pushing the stick to the right comes from the west (SDL: -x)
  auto c = HapticForceOutput::command_for(Eigen::Vector3d(2.0, 0.0, 0.0), 4.0);
  EXPECT_EQ(c.level, Sint16(std::lround(0.5 * 32767)));
  EXPECT_LT(c.dir_x, 0);
  EXPECT_EQ(c.dir_y, 0);
  // pushing the stick forward (view up, SDL north = -y) comes from the south (+y)
  c = HapticForceOutput::command_for(Eigen::Vector3d(0.0, 8.0, 0.0), 4.0);
  EXPECT_EQ(c.level, 32767);  // clamped at full
  EXPECT_EQ(c.dir_x, 0);
  EXPECT_GT(c.dir_y, 0);
  // the depth component is not rendered by a two-axis stick
  c = HapticForceOutput::command_for(Eigen::Vector3d(0.0, 0.0, 3.0), 4.0);
  EXPECT_EQ(c.level, 0);
}

TEST(HapticForceOutput, AVirtualJoystickHasNoHaptics) {
  auto script = std::make_shared<const JoystickScript>(JoystickScript::parse("0 0 0\n"));
  InputSettings settings;
  settings.script = script;
  SdlInput input(settings);
  std::string why;
  auto haptic = HapticForceOutput::open(input.joystick(0), input.name(0), {}, why);
  EXPECT_EQ(haptic, nullptr);
  EXPECT_FALSE(why.empty());
  auto none = HapticForceOutput::open(nullptr, "x", {}, why);
  EXPECT_EQ(none, nullptr);
}

TEST(RumbleForceOutput, RumblesThroughTheVirtualJoystickRateLimited) {
  auto script = std::make_shared<const JoystickScript>(JoystickScript::parse("0 0 0\n"));
  InputSettings settings;
  settings.script = script;
  SdlInput input(settings);
  DeviceOutputSettings out_settings;
  out_settings.max_force_N = 2.0;
  out_settings.max_update_hz = 100.0;
  std::string why;
  auto rumble = RumbleForceOutput::open(input.joystick(0), input.name(0), out_settings, why);
  ASSERT_NE(rumble, nullptr) << why;
  const VirtualRumble* sink = input.virtual_rumble(0);
  ASSERT_NE(sink, nullptr);
  const int calls0 = sink->calls.load();  // the support probe
  // 1 s of ticks at 1 kHz with a changing force: at most 100 device updates
  for (int i = 0; i < 1000; ++i) rumble->write(tick(i * 0.001, 0.0, 0.0, 1.0 + 0.5 * std::sin(i * 0.01)));
  const int calls = sink->calls.load() - calls0;
  EXPECT_GT(calls, 20);
  EXPECT_LE(calls, 101);
  EXPECT_EQ(rumble->device_updates(), calls);
  // the strength follows |F|: 1.5 N of 2 N max is about 3/4
  rumble->write(tick(2.0, 0.0, 1.5, 0.0));
  EXPECT_NEAR(sink->low.load(), 0.75 * 65535, 200);
  EXPECT_EQ(RumbleForceOutput::strength_for(10.0, 2.0), 65535);
  EXPECT_EQ(RumbleForceOutput::strength_for(0.0, 2.0), 0);
  rumble->stop();
  EXPECT_EQ(sink->low.load(), 0);  // stopped: no rumble left running
}

TEST(ForceOutputs, StopsAllAndReportsTheFirstError) {
  ForceOutputs outs;
  const fs::path csv = temp_dir() / "several.csv";
  outs.add(std::make_unique<RecordingForceOutput>(csv));
  outs.write(tick(0.0, 1, 0, 0));
  outs.stop();
  EXPECT_TRUE(fs::exists(csv));
}

TEST(FixedRateThread, RunsAtItsRateAndStops) {
  std::atomic<int> n{0};
  FixedRateThread t("test", 500.0, [&](std::int64_t) { ++n; });
  t.start();
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  t.stop();
  // 200 ticks expected; loaded CI machines skip some (counted as missed)
  EXPECT_GT(n.load() + t.missed(), 120);
  EXPECT_LT(n.load(), 260);
  EXPECT_EQ(t.ticks(), n.load());
  EXPECT_FALSE(t.failed());
}

TEST(FixedRateThread, RunsItsStartHookOnItsOwnThreadBeforeTheFirstTick) {
  std::atomic<int> order{0};
  std::thread::id hook_thread, body_thread;
  int hook_at = -1, first_tick_at = -1;
  FixedRateThread t(
      "test", 1000.0,
      [&](std::int64_t i) {
        if (i == 0) {
          body_thread = std::this_thread::get_id();
          first_tick_at = order++;
        }
      },
      [&] {
        hook_thread = std::this_thread::get_id();
        hook_at = order++;
      });
  t.start();
  for (int i = 0; i < 200 && t.ticks() == 0; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  t.stop();
  EXPECT_EQ(hook_at, 0);
  EXPECT_EQ(first_tick_at, 1);
  EXPECT_EQ(hook_thread, body_thread);
  EXPECT_NE(hook_thread, std::this_thread::get_id());
}

TEST(FixedRateThread, AnExceptionStopsTheThreadWithTheMessage) {
  FixedRateThread t("physics", 1000.0, [&](std::int64_t i) {
    if (i == 3) throw vx::Error("boom");
  });
  t.start();
  for (int i = 0; i < 200 && !t.failed(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  t.stop();
  EXPECT_TRUE(t.failed());
  EXPECT_EQ(t.error(), "physics thread: boom");
}

TEST(RateMeter, MeasuresOverItsWindow) {
  RateMeter m(0.5);
  const auto t0 = SteadyClock::now();
  m.sample(0, t0);
  EXPECT_FALSE(m.valid());
  m.sample(100, t0 + std::chrono::milliseconds(250));
  EXPECT_FALSE(m.valid());
  m.sample(1000, t0 + std::chrono::seconds(1));
  EXPECT_TRUE(m.valid());
  EXPECT_NEAR(m.rate(), 1000.0, 1e-6);
}
