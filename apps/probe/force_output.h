#pragma once
/// @file force_output.h
/// Force output behind one interface, written by the device thread at its steady rate
/// (about 1 kHz): an SDL haptic constant-force effect on a force-feedback joystick, rumble
/// where only that exists, and a recording backend (CSV) for tests and absent devices.
/// Devices cannot take an update every millisecond (each SDL_HapticUpdateEffect is a
/// syscall), so the device backends rate-limit themselves; the recorder logs every tick.

#include <SDL.h>

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "joystick_script.h"

namespace vx::probe {

/// The force of one probe at one device tick.
struct ProbeForce {
  Eigen::Vector3d device_N{0, 0, 0};  ///< force for the device (shaped), world frame, N
  Eigen::Vector3d raw_N{0, 0, 0};     ///< latest raw reaction sum from the physics, world frame, N
  Eigen::Vector3d stick_N{0, 0, 0};   ///< device_N in the view frame (x right, y up, z away), N
  Eigen::Vector3d tip_mm{0, 0, 0};    ///< probe reference point (tip), LPS mm (local: the tool, i.e. the proxy)
  int contacts{0};                    ///< surface nodes in contact at the last physics step
  // what the two shapings are compared by (docs/probe.md, "Force shaping")
  double physics_s{0.0};              ///< simulated time of the physics' last step, s
  Eigen::Vector3d hand_mm{0, 0, 0};   ///< the device (hand) position, LPS mm (paper: the tool's)
  Eigen::Vector3d model_N{0, 0, 0};   ///< local: the local contact model's force at the tool (no damping or offset)
  Eigen::Vector3d anchor_N{0, 0, 0};  ///< the force the device's update started from: local, the
                                      ///< physics' force at the model's anchor; paper, the half sine's mean
  double update_age_ms{0.0};          ///< time since that update reached the device, ms
  double stiffness_N_mm{0.0};         ///< local: the largest stiffness the hand feels, N/mm
  double guard_N{0.0};                ///< local: the energy guard's correction, N
};

/// One device tick: the forces of every probe.
struct DeviceTick {
  double wall_s{0.0};   ///< wall time since the start, s
  double sim_s{0.0};    ///< paper: simulated time; local: the device's clock (the script's time), s
  bool local{false};    ///< the shaping: the local contact model (else the paper's half sines)
  int probes{0};        ///< entries used in `probe`
  std::array<ProbeForce, kMaxSticks> probe{};
};

/// Where device forces go.
class ForceOutput {
 public:
  virtual ~ForceOutput() = default;
  /// One line for the console, e.g. "haptic constant force on 'X' (probe 0, max 4 N, 100 Hz)".
  [[nodiscard]] virtual std::string describe() const = 0;
  /// A few words for the HUD, e.g. "haptic 'X'", "log forces.csv".
  [[nodiscard]] virtual std::string label() const = 0;
  /// Called at every device tick from the device thread.
  virtual void write(const DeviceTick& tick) = 0;
  /// Zero force and release the device / flush the file; called once at the end. Throws
  /// vx::Error when a file cannot be completed.
  virtual void stop() = 0;
  /// How many times the device was actually commanded (rate-limited backends: fewer than ticks).
  [[nodiscard]] virtual std::int64_t device_updates() const = 0;
  /// The joystick of `probe` was unplugged (null) or plugged back (device thread): a device
  /// backend of that probe lets go of the old one and takes the new one. Others ignore it.
  virtual void reattach(int /*probe*/, SDL_Joystick* /*joystick*/) {}
};

/// Settings shared by the device backends.
struct DeviceOutputSettings {
  int probe{0};                   ///< which probe's force this device renders
  double max_force_N{2.0};        ///< force that maps to the device's full level
  double max_update_hz{100.0};    ///< at most this many device commands per second
  double min_change{0.01};        ///< skip an update when the level changed by less (fraction of full)
};

/// SDL haptic constant-force effect (a force-feedback joystick, evdev driver). The stick's
/// two axes render the view-frame x (right) and y (up = stick forward) force components.
class HapticForceOutput final : public ForceOutput {
 public:
  /// Opens the joystick's haptic device and creates the effect; returns nullptr and sets
  /// `why` when the joystick has no haptics or no constant-force effect.
  [[nodiscard]] static std::unique_ptr<HapticForceOutput> open(SDL_Joystick* joystick, const std::string& name,
                                                               const DeviceOutputSettings& settings, std::string& why);
  ~HapticForceOutput() override;
  [[nodiscard]] std::string describe() const override;
  [[nodiscard]] std::string label() const override { return "haptic '" + name_ + "'"; }
  void write(const DeviceTick& tick) override;
  void stop() override;
  [[nodiscard]] std::int64_t device_updates() const override { return updates_; }
  void reattach(int probe, SDL_Joystick* joystick) override;

  /// The effect parameters (level 0..32767 and SDL cartesian direction, "where the force comes
  /// from") for a view-frame force; exposed for tests.
  struct Command {
    Sint16 level{0};
    Sint32 dir_x{0};
    Sint32 dir_y{0};
  };
  [[nodiscard]] static Command command_for(const Eigen::Vector3d& stick_N, double max_force_N);

 private:
  HapticForceOutput() = default;
  /// Opens the haptic device of `joystick` and starts the effect; false (and `why`) when not.
  bool start(SDL_Joystick* joystick, std::string& why);
  /// Lets go of the haptic device (its effect stopped when it is still there).
  void release();
  SDL_Haptic* haptic_{nullptr};
  int effect_{-1};
  std::string name_;
  DeviceOutputSettings settings_;
  SDL_HapticEffect effect_data_{};
  Command last_{};
  double last_update_s_{-1e9};
  std::int64_t updates_{0};
  bool stopped_{false};
};

/// Rumble (vibration) where the device has no directional force: the rumble strength follows
/// the force magnitude. Also the test sink with an SDL virtual joystick (its Rumble callback).
class RumbleForceOutput final : public ForceOutput {
 public:
  /// Returns nullptr and sets `why` when the joystick cannot rumble.
  [[nodiscard]] static std::unique_ptr<RumbleForceOutput> open(SDL_Joystick* joystick, const std::string& name,
                                                               const DeviceOutputSettings& settings, std::string& why);
  [[nodiscard]] std::string describe() const override;
  [[nodiscard]] std::string label() const override { return "rumble '" + name_ + "'"; }
  void write(const DeviceTick& tick) override;
  void stop() override;
  [[nodiscard]] std::int64_t device_updates() const override { return updates_; }
  void reattach(int probe, SDL_Joystick* joystick) override;

  /// The rumble strength 0..65535 for a force magnitude; exposed for tests.
  [[nodiscard]] static Uint16 strength_for(double force_N, double max_force_N);

 private:
  RumbleForceOutput() = default;
  SDL_Joystick* joystick_{nullptr};
  std::string name_;
  DeviceOutputSettings settings_;
  Uint16 last_{0};
  double last_update_s_{-1e9};
  std::int64_t updates_{0};
  bool stopped_{false};
};

/// Records every tick as one CSV row per probe:
/// `wall_s,sim_s,probe,device_fx_n,device_fy_n,device_fz_n,device_n,raw_fx_n,raw_fy_n,raw_fz_n,raw_n,`
/// `stick_x_n,stick_y_n,tip_x_mm,tip_y_mm,tip_z_mm,contacts,`
/// `shaping,physics_s,hand_x_mm,hand_y_mm,hand_z_mm,model_fx_n,model_fy_n,model_fz_n,`
/// `anchor_fx_n,anchor_fy_n,anchor_fz_n,update_age_ms,stiffness_n_mm,guard_n` (ProbeForce).
/// The file is written next to the target and renamed into place by stop(): no partial logs.
class RecordingForceOutput final : public ForceOutput {
 public:
  /// Opens the file; throws vx::Error when it cannot be created.
  explicit RecordingForceOutput(const std::filesystem::path& csv);
  ~RecordingForceOutput() override;
  [[nodiscard]] std::string describe() const override;
  [[nodiscard]] std::string label() const override { return "log " + path_.filename().string(); }
  void write(const DeviceTick& tick) override;
  void stop() override;
  [[nodiscard]] std::int64_t device_updates() const override { return rows_; }
  /// The CSV header line (without newline).
  [[nodiscard]] static const char* header();

 private:
  std::filesystem::path path_;
  std::filesystem::path tmp_;
  std::ofstream out_;
  std::int64_t rows_{0};
  bool stopped_{false};
};

/// Several outputs written together (a device and the recorder).
class ForceOutputs {
 public:
  void add(std::unique_ptr<ForceOutput> output) { outputs_.push_back(std::move(output)); }
  [[nodiscard]] bool empty() const { return outputs_.empty(); }
  [[nodiscard]] const std::vector<std::unique_ptr<ForceOutput>>& all() const { return outputs_; }
  void write(const DeviceTick& tick) {
    for (auto& o : outputs_) o->write(tick);
  }
  /// Stops every output (all of them, even when one throws; the first error is rethrown).
  void stop();
  void reattach(int probe, SDL_Joystick* joystick) {
    for (auto& o : outputs_) o->reattach(probe, joystick);
  }

 private:
  std::vector<std::unique_ptr<ForceOutput>> outputs_;
};

}  // namespace vx::probe
