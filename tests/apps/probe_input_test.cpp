// The probe app's input layer: joystick scripts, SDL virtual joysticks fed by them, the
// stick-to-probe mapping (rate and position control) and the keyboard stick.
#include <gtest/gtest.h>

#include <cmath>
#include <thread>

#include "base/error.h"
#include "joystick_script.h"
#include "sdl_input.h"
#include "stick_control.h"

using namespace vx::probe;

namespace {

const char* kScript = R"(# a palpation
sticks 1
0.0  0   0.0  0.0  0.0
1.0  0   1.0 -0.5  0.0  0.0  b01
2.0  0   0.0  0.5  0.0  1.0
)";

}  // namespace

TEST(JoystickScript, ParsesAndInterpolates) {
  const JoystickScript s = JoystickScript::parse(kScript, "test");
  EXPECT_EQ(s.sticks(), 1);
  EXPECT_DOUBLE_EQ(s.duration_s(), 2.0);
  ASSERT_EQ(s.keys(0).size(), 3u);
  // halfway between the first two keys
  ScriptSample a = s.sample(0, 0.5);
  EXPECT_NEAR(a.axes[0], 0.5, 1e-12);
  EXPECT_NEAR(a.axes[1], -0.25, 1e-12);
  EXPECT_EQ(a.buttons, 0u);  // buttons hold the last key at or before t
  a = s.sample(0, 1.5);
  EXPECT_NEAR(a.axes[0], 0.5, 1e-12);
  EXPECT_NEAR(a.axes[1], 0.0, 1e-12);
  EXPECT_NEAR(a.axes[3], 0.5, 1e-12);
  EXPECT_EQ(a.buttons, 2u);  // b01: button 1
  // before the first and after the last key the end values hold
  EXPECT_NEAR(s.sample(0, -1.0).axes[0], 0.0, 1e-12);
  EXPECT_NEAR(s.sample(0, 10.0).axes[1], 0.5, 1e-12);
}

TEST(JoystickScript, TwoSticks) {
  const JoystickScript s = JoystickScript::parse("0 0 0.1\n0 1 -0.2 0.3\n1 1 0.2 0.3\n");
  EXPECT_EQ(s.sticks(), 2);
  EXPECT_NEAR(s.sample(1, 0.5).axes[0], 0.0, 1e-12);
  EXPECT_NEAR(s.sample(0, 0.5).axes[0], 0.1, 1e-12);
}

TEST(JoystickScript, RejectsBadLinesWithTheLineNumber) {
  const auto message = [](const char* text) {
    try {
      (void)JoystickScript::parse(text, "s.joy");
    } catch (const vx::Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message("0 0 1.5\n").find("s.joy:1"), std::string::npos);         // out of [-1, 1]
  EXPECT_NE(message("0 0 0\n1 0 x\n").find("s.joy:2"), std::string::npos);     // not a number
  EXPECT_NE(message("1 0 0\n0.5 0 0\n").find("goes back"), std::string::npos); // time goes back
  EXPECT_NE(message("0 2 0\n").find("must be 0 or 1"), std::string::npos);     // stick index
  EXPECT_NE(message("0 0 0 0 0 0 0\n").find("more than"), std::string::npos);  // too many axes
  EXPECT_NE(message("0 0 0 b2\n").find("buttons"), std::string::npos);         // bad buttons
  EXPECT_NE(message("# nothing\n").find("no keyframes"), std::string::npos);
  EXPECT_NE(message("sticks 1\n0 1 0\n").find("sticks 1"), std::string::npos);
  EXPECT_THROW((void)JoystickScript::load("/nonexistent/x.joy"), vx::Error);
}

TEST(JoystickScript, TheSampleScriptParses) {
  const JoystickScript s = JoystickScript::load(std::string(VX_SAMPLES_DIR) + "/scenes/palpation-lesion.joy");
  EXPECT_GE(s.sticks(), 1);
  EXPECT_GT(s.duration_s(), 5.0);
}

TEST(SdlInput, VirtualJoystickPlaysTheScript) {
  auto script = std::make_shared<const JoystickScript>(JoystickScript::parse(kScript, "test"));
  InputSettings settings;
  settings.script = script;
  SdlInput input(settings);
  ASSERT_EQ(input.count(), 1);
  EXPECT_TRUE(input.is_virtual(0));
  ASSERT_NE(input.joystick(0), nullptr);
  input.play_script(1.0);
  input.poll();
  const StickState& s = input.state(0);
  EXPECT_TRUE(s.present);
  EXPECT_EQ(s.num_axes, kScriptAxes);
  EXPECT_NEAR(s.axes[0], 1.0, 1e-4);
  EXPECT_NEAR(s.axes[1], -0.5, 1e-4);
  EXPECT_EQ(s.buttons & 0x3u, 2u);
  input.play_script(2.0);
  input.poll();
  EXPECT_NEAR(input.state(0).axes[0], 0.0, 1e-4);
  EXPECT_NEAR(input.state(0).axes[3], 1.0, 1e-4);
  EXPECT_EQ(input.state(0).buttons & 0x3u, 0u);
  EXPECT_NE(input.describe().find("virtual"), std::string::npos);
}

TEST(SdlInput, TwoVirtualJoysticksAndReopen) {
  auto script = std::make_shared<const JoystickScript>(JoystickScript::parse("0 0 0.5\n0 1 -0.5\n"));
  for (int round = 0; round < 2; ++round) {  // SDL is initialised and shut down cleanly each time
    InputSettings settings;
    settings.script = script;
    SdlInput input(settings);
    ASSERT_EQ(input.count(), 2);
    input.play_script(0.0);
    input.poll();
    EXPECT_NEAR(input.state(0).axes[0], 0.5, 1e-4);
    EXPECT_NEAR(input.state(1).axes[0], -0.5, 1e-4);
  }
}

TEST(SdlInput, NoJoystickIsFine) {
  InputSettings settings;
  settings.joysticks = false;
  SdlInput input(settings);
  EXPECT_EQ(input.count(), 0);
  input.poll();
  EXPECT_EQ(input.describe(), "no joystick");
}

TEST(StickControl, CommandsInTheViewFrame) {
  ControlSettings c;
  c.mapping.dead_zone = 0.1;
  StickState s;
  s.present = true;
  s.num_axes = 4;
  s.axes = {0.05, 0.0, 0.0, 0.0};
  EXPECT_EQ(stick_command(s, c), Eigen::Vector3d::Zero());  // inside the dead zone
  s.axes = {1.0, -1.0, 0.0, 0.0};                          // right, pushed forward
  EXPECT_TRUE(stick_command(s, c).isApprox(Eigen::Vector3d(1, 1, 0)));
  s.axes = {0.55, 0.0, 0.0, 0.0};
  EXPECT_NEAR(stick_command(s, c).x(), 0.5, 1e-12);  // rescaled past the dead zone
  // the third axis from buttons, the hat, or an axis
  s.axes = {0, 0, 0, 0};
  s.buttons = 1u;  // z_away_button 0
  EXPECT_NEAR(stick_command(s, c).z(), 1.0, 1e-12);
  s.buttons = 2u;
  EXPECT_NEAR(stick_command(s, c).z(), -1.0, 1e-12);
  s.buttons = 0;
  s.hat = SDL_HAT_UP;
  EXPECT_NEAR(stick_command(s, c).z(), 1.0, 1e-12);
  s.hat = 0;
  c.z_axis = 3;
  s.axes = {0, 0, 0, -1.0};
  EXPECT_NEAR(stick_command(s, c).z(), -1.0, 1e-12);
  c.invert_z_axis = true;
  EXPECT_NEAR(stick_command(s, c).z(), 1.0, 1e-12);
  // an absent stick commands nothing
  s.present = false;
  EXPECT_EQ(stick_command(s, c), Eigen::Vector3d::Zero());
}

TEST(ProbeCommander, RateControlSendsAVelocityThatStaysInTheBox) {
  ControlSettings c;
  c.mapping.max_speed_mm_s = 20.0;
  const Box box{Eigen::Vector3d(-10, -10, -10), Eigen::Vector3d(10, 10, 10)};
  ProbeCommander pc(Eigen::Vector3d::Zero(), box, c);
  Eigen::Matrix3d basis;  // right = +x, up = +z, away = +y
  basis << 1, 0, 0, 0, 0, 1, 0, 1, 0;
  const Eigen::Vector3d none = Eigen::Vector3d::Zero();
  vx::LiveCommand l = pc.update(Eigen::Vector3d(0.5, 0, 0), none, basis, none, 0.001);
  EXPECT_EQ(l.kind, vx::LiveCommand::Kind::velocity);
  EXPECT_TRUE(l.value.isApprox(Eigen::Vector3d(10, 0, 0)));  // half tilt: half speed, to the right
  l = pc.update(Eigen::Vector3d(0, -1, 1), none, basis, none, 0.001);  // down and away
  EXPECT_TRUE(l.value.isApprox(Eigen::Vector3d(0, 20, -20)));
  // at the bottom of the box, moving down is cut, moving sideways is not
  l = pc.update(Eigen::Vector3d(1, -1, 0), none, basis, Eigen::Vector3d(0, 0, -10), 0.001);
  EXPECT_TRUE(l.value.isApprox(Eigen::Vector3d(20, 0, 0)));
  // just above the bottom: only down to the boundary within the tick
  l = pc.update(Eigen::Vector3d(0, -1, 0), none, basis, Eigen::Vector3d(0, 0, -9.99), 0.001);
  EXPECT_NEAR(l.value.z(), -10.0, 1e-9);
  // a mouse drag of 1 mm to the right is worked off at a bounded speed and only once
  double moved = 0.0;
  l = pc.update(none, Eigen::Vector3d(1, 0, 0), basis, none, 0.001);
  moved += l.value.x() * 0.001;
  EXPECT_LE(l.value.norm(), 40.0 + 1e-9);
  for (int i = 0; i < 2000; ++i) moved += pc.update(none, none, basis, none, 0.001).value.x() * 0.001;
  EXPECT_NEAR(moved, 1.0, 1e-6);
}

TEST(ProbeCommander, PositionControlSendsAClampedTarget) {
  ControlSettings c;
  c.mapping.mode = vx::JoystickMode::position;
  c.mapping.max_speed_mm_s = 10.0;
  c.mapping.range_mm = 5.0;
  const Box box{Eigen::Vector3d(-100, -100, -3), Eigen::Vector3d(100, 100, 100)};
  ProbeCommander pc(Eigen::Vector3d(1, 2, 3), box, c);
  const Eigen::Matrix3d basis = Eigen::Matrix3d::Identity();
  const Eigen::Vector3d none = Eigen::Vector3d::Zero();
  vx::LiveCommand l = pc.update(Eigen::Vector3d(1, -0.5, 0), none, basis, none, 0.001);
  EXPECT_EQ(l.kind, vx::LiveCommand::Kind::position);
  EXPECT_TRUE(l.value.isApprox(Eigen::Vector3d(6, -0.5, 3)));  // home + range x tilt
  // depth from the buttons is a rate: 10 mm/s for 0.1 s
  for (int i = 0; i < 100; ++i) l = pc.update(Eigen::Vector3d(0, 0, -1), none, basis, none, 0.001);
  EXPECT_NEAR(l.value.z(), 2.0, 1e-9);
  // the target never leaves the allowed box
  l = pc.update(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 0, -50), basis, none, 0.001);
  EXPECT_NEAR(l.value.z(), -3.0, 1e-9);
  pc.reset();
  l = pc.update(none, none, basis, none, 0.001);
  EXPECT_TRUE(l.value.isApprox(Eigen::Vector3d(1, 2, 3)));
}

TEST(KeyboardStick, KeysAndAutoRepeat) {
  KeyboardStick k;
  k.press(KeyboardStick::right);
  k.press(KeyboardStick::up);
  StickState s = k.state();
  EXPECT_DOUBLE_EQ(s.axes[0], 1.0);
  EXPECT_DOUBLE_EQ(s.axes[1], -1.0);  // SDL sign: up = -1
  ControlSettings c;
  EXPECT_TRUE(stick_command(s, c).isApprox(Eigen::Vector3d(1, 1, 0)));
  // X11 auto-repeat: release immediately followed by press keeps the key held
  k.release(KeyboardStick::right);
  k.press(KeyboardStick::right);
  EXPECT_DOUBLE_EQ(k.state().axes[0], 1.0);
  // a real release ends it after the grace
  k.release(KeyboardStick::right);
  std::this_thread::sleep_for(std::chrono::milliseconds(120));
  EXPECT_DOUBLE_EQ(k.state().axes[0], 0.0);
  k.press(KeyboardStick::away);
  EXPECT_EQ(k.state().buttons, 1u);
  k.add_drag(Eigen::Vector3d(1, 2, 3));
  k.add_drag(Eigen::Vector3d(1, 0, 0));
  EXPECT_EQ(k.take_drag(), Eigen::Vector3d(2, 2, 3));
  EXPECT_EQ(k.take_drag(), Eigen::Vector3d::Zero());
  k.set_active_probe(1);
  EXPECT_EQ(k.active_probe(), 1);
  k.clear();
  EXPECT_EQ(k.state().buttons, 0u);
}
