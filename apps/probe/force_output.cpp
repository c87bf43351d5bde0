#include "force_output.h"

#include <fmt/core.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <iterator>
#include <system_error>

#include "base/error.h"

namespace vx::probe {

namespace {

double fraction(double force_N, double max_force_N) {
  return max_force_N > 0 ? std::clamp(force_N / max_force_N, 0.0, 1.0) : 0.0;
}

double min_interval_s(const DeviceOutputSettings& s) {
  return s.max_update_hz > 0 ? 1.0 / s.max_update_hz : 0.0;
}

}  // namespace

// ---------------------------------------------------------------- haptic constant force

HapticForceOutput::Command HapticForceOutput::command_for(const Eigen::Vector3d& stick_N, double max_force_N) {
  // the stick renders the screen-plane components: x = right (east), y = up = stick forward (north)
  const Eigen::Vector2d push(stick_N.x(), stick_N.y());
  Command c;
  const double f = push.norm();
  c.level = Sint16(std::lround(fraction(f, max_force_N) * 32767.0));
  if (f <= 0) return c;
  // SDL wants where the force comes from (the opposite of the push), in SDL's device
  // coordinates (east = +x, north = -y): push (x, y_up) comes from (-x, +y_up)
  const Eigen::Vector2d from = -push / f;
  c.dir_x = Sint32(std::lround(from.x() * 10000.0));
  c.dir_y = Sint32(std::lround(-from.y() * 10000.0));
  return c;
}

std::unique_ptr<HapticForceOutput> HapticForceOutput::open(SDL_Joystick* joystick, const std::string& name,
                                                           const DeviceOutputSettings& settings, std::string& why) {
  if (!joystick) {
    why = "no joystick";
    return nullptr;
  }
  std::unique_ptr<HapticForceOutput> out(new HapticForceOutput());
  out->name_ = name;
  out->settings_ = settings;
  if (!out->start(joystick, why)) return nullptr;
  return out;
}

bool HapticForceOutput::start(SDL_Joystick* joystick, std::string& why) {
  if (SDL_JoystickIsHaptic(joystick) != SDL_TRUE) {
    why = "no force feedback (SDL haptic) on this joystick";
    return false;
  }
  SDL_Haptic* haptic = SDL_HapticOpenFromJoystick(joystick);
  if (!haptic) {
    why = std::string("cannot open its haptic device: ") + SDL_GetError();
    return false;
  }
  const unsigned int features = SDL_HapticQuery(haptic);
  if (!(features & SDL_HAPTIC_CONSTANT)) {
    SDL_HapticClose(haptic);
    why = "its haptic device has no constant-force effect";
    return false;
  }
  // full gain, no spring pulling the stick to the centre (it would mask the tissue force)
  if (features & SDL_HAPTIC_GAIN) SDL_HapticSetGain(haptic, 100);
  if (features & SDL_HAPTIC_AUTOCENTER) SDL_HapticSetAutocenter(haptic, 0);
  SDL_HapticEffect& e = effect_data_;
  e = SDL_HapticEffect{};
  e.type = SDL_HAPTIC_CONSTANT;
  e.constant.direction.type = SDL_HAPTIC_CARTESIAN;
  e.constant.direction.dir[0] = 0;
  e.constant.direction.dir[1] = 1;
  e.constant.length = SDL_HAPTIC_INFINITY;
  e.constant.level = 0;
  effect_ = SDL_HapticNewEffect(haptic, &e);
  if (effect_ < 0) {
    why = std::string("cannot create the constant-force effect: ") + SDL_GetError();
    SDL_HapticClose(haptic);
    return false;
  }
  if (SDL_HapticRunEffect(haptic, effect_, 1) != 0) {
    why = std::string("cannot start the constant-force effect: ") + SDL_GetError();
    SDL_HapticDestroyEffect(haptic, effect_);
    SDL_HapticClose(haptic);
    return false;
  }
  haptic_ = haptic;
  last_ = Command{};
  last_update_s_ = -1e9;
  return true;
}

void HapticForceOutput::release() {
  if (!haptic_) return;
  SDL_HapticStopEffect(haptic_, effect_);
  SDL_HapticDestroyEffect(haptic_, effect_);
  SDL_HapticClose(haptic_);
  haptic_ = nullptr;
}

void HapticForceOutput::reattach(int probe, SDL_Joystick* joystick) {
  if (probe != settings_.probe || stopped_) return;
  release();
  std::string why;
  if (joystick) (void)start(joystick, why);  // a stick that comes back without force feedback stays silent
}

HapticForceOutput::~HapticForceOutput() {
  try {
    stop();
  } catch (...) {
  }
}

std::string HapticForceOutput::describe() const {
  return fmt::format("haptic constant force on '{}' (probe {}, {:g} N = full level, at most {:g} updates/s)", name_,
                     settings_.probe, settings_.max_force_N, settings_.max_update_hz);
}

void HapticForceOutput::write(const DeviceTick& tick) {
  if (stopped_ || !haptic_ || settings_.probe >= tick.probes) return;
  const Command c = command_for(tick.probe[std::size_t(settings_.probe)].stick_N, settings_.max_force_N);
  // rate limit: each update is a syscall; skip updates that change nothing noticeable
  if (tick.wall_s - last_update_s_ < min_interval_s(settings_)) return;
  const bool level_changed = std::abs(double(c.level) - double(last_.level)) >= settings_.min_change * 32767.0;
  const bool to_zero = c.level == 0 && last_.level != 0;
  // direction: a turn of more than about 3 degrees while a force is felt
  const double dot = (double(c.dir_x) * last_.dir_x + double(c.dir_y) * last_.dir_y) / 1e8;
  const bool turned = c.level > 0 && dot < 0.9986;
  if (!level_changed && !to_zero && !turned) return;
  effect_data_.constant.level = c.level;
  if (c.level > 0) {
    effect_data_.constant.direction.dir[0] = c.dir_x;
    effect_data_.constant.direction.dir[1] = c.dir_y;
  }
  if (SDL_HapticUpdateEffect(haptic_, effect_, &effect_data_) == 0) ++updates_;
  last_ = c;
  last_update_s_ = tick.wall_s;
}

void HapticForceOutput::stop() {
  if (stopped_) return;
  stopped_ = true;
  release();
}

// ---------------------------------------------------------------- rumble

Uint16 RumbleForceOutput::strength_for(double force_N, double max_force_N) {
  return Uint16(std::lround(fraction(force_N, max_force_N) * 65535.0));
}

std::unique_ptr<RumbleForceOutput> RumbleForceOutput::open(SDL_Joystick* joystick, const std::string& name,
                                                           const DeviceOutputSettings& settings, std::string& why) {
  if (!joystick) {
    why = "no joystick";
    return nullptr;
  }
  // a zero-length rumble probes for support without shaking anything
  if (SDL_JoystickRumble(joystick, 0, 0, 0) != 0) {
    why = "it cannot rumble either";
    return nullptr;
  }
  std::unique_ptr<RumbleForceOutput> out(new RumbleForceOutput());
  out->joystick_ = joystick;
  out->name_ = name;
  out->settings_ = settings;
  return out;
}

std::string RumbleForceOutput::describe() const {
  return fmt::format("rumble on '{}' (probe {}, strength follows |force|, {:g} N = full, at most {:g} updates/s)",
                     name_, settings_.probe, settings_.max_force_N, settings_.max_update_hz);
}

void RumbleForceOutput::write(const DeviceTick& tick) {
  if (stopped_ || !joystick_ || settings_.probe >= tick.probes) return;
  const Uint16 s = strength_for(tick.probe[std::size_t(settings_.probe)].device_N.norm(), settings_.max_force_N);
  const double interval = min_interval_s(settings_);
  if (tick.wall_s - last_update_s_ < interval) return;
  const bool changed = std::abs(int(s) - int(last_)) >= int(settings_.min_change * 65535.0) || (s == 0 && last_ != 0);
  // re-send a steady rumble before it runs out (its duration covers a few intervals)
  const bool refresh = s > 0 && tick.wall_s - last_update_s_ > 0.1;
  if (!changed && !refresh) return;
  // low-frequency motor for the force, the high one a little weaker for a crisp feel
  const Uint32 duration_ms = 250;
  if (SDL_JoystickRumble(joystick_, s, Uint16(s / 2), s ? duration_ms : 0) == 0) ++updates_;
  last_ = s;
  last_update_s_ = tick.wall_s;
}

void RumbleForceOutput::reattach(int probe, SDL_Joystick* joystick) {
  if (probe != settings_.probe) return;
  joystick_ = joystick;  // null while unplugged: nothing is sent to a closed joystick
  last_ = 0;
  last_update_s_ = -1e9;
}

void RumbleForceOutput::stop() {
  if (stopped_) return;
  stopped_ = true;
  if (joystick_ && SDL_JoystickGetAttached(joystick_)) SDL_JoystickRumble(joystick_, 0, 0, 0);
}

// ---------------------------------------------------------------- recording (CSV)

const char* RecordingForceOutput::header() {
  return "wall_s,sim_s,probe,device_fx_n,device_fy_n,device_fz_n,device_n,raw_fx_n,raw_fy_n,raw_fz_n,raw_n,"
         "stick_x_n,stick_y_n,tip_x_mm,tip_y_mm,tip_z_mm,contacts,"
         "shaping,physics_s,hand_x_mm,hand_y_mm,hand_z_mm,model_fx_n,model_fy_n,model_fz_n,"
         "anchor_fx_n,anchor_fy_n,anchor_fz_n,update_age_ms,stiffness_n_mm,guard_n";
}

RecordingForceOutput::RecordingForceOutput(const std::filesystem::path& csv) : path_(csv) {
  if (csv.empty()) throw Error("force log: empty path");
  if (std::filesystem::is_directory(csv)) throw Error("force log '" + csv.string() + "' is a folder; give a .csv file path");
  const auto parent = csv.parent_path();
  if (!parent.empty() && !std::filesystem::is_directory(parent))
    throw Error("force log '" + csv.string() + "': folder '" + parent.string() + "' does not exist");
  tmp_ = csv;
  tmp_ += ".partial";
  out_.open(tmp_, std::ios::binary | std::ios::trunc);
  if (!out_) throw Error("cannot create force log '" + tmp_.string() + "' (permission?)");
  out_ << header() << '\n';
}

RecordingForceOutput::~RecordingForceOutput() {
  try {
    stop();
  } catch (...) {
  }
}

std::string RecordingForceOutput::describe() const {
  return fmt::format("force log (CSV, every device tick) to '{}'", path_.string());
}

void RecordingForceOutput::write(const DeviceTick& tick) {
  if (stopped_) return;
  fmt::memory_buffer buf;
  for (int p = 0; p < tick.probes; ++p) {
    const ProbeForce& f = tick.probe[std::size_t(p)];
    fmt::format_to(std::back_inserter(buf),
                   "{:.6f},{:.6f},{},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},"
                   "{:.4f},{:.4f},{:.4f},{},{},{:.6f},{:.4f},{:.4f},{:.4f},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},"
                   "{:.3f},{:.4g},{:.4g}\n",
                   tick.wall_s, tick.sim_s, p, f.device_N.x(), f.device_N.y(), f.device_N.z(), f.device_N.norm(),
                   f.raw_N.x(), f.raw_N.y(), f.raw_N.z(), f.raw_N.norm(), f.stick_N.x(), f.stick_N.y(), f.tip_mm.x(),
                   f.tip_mm.y(), f.tip_mm.z(), f.contacts, tick.local ? "local" : "paper", f.physics_s, f.hand_mm.x(),
                   f.hand_mm.y(), f.hand_mm.z(), f.model_N.x(), f.model_N.y(), f.model_N.z(), f.anchor_N.x(),
                   f.anchor_N.y(), f.anchor_N.z(), f.update_age_ms, f.stiffness_N_mm, f.guard_N);
    ++rows_;
  }
  out_.write(buf.data(), std::streamsize(buf.size()));
}

void RecordingForceOutput::stop() {
  if (stopped_) return;
  stopped_ = true;
  out_.flush();
  const bool ok = bool(out_);
  out_.close();
  if (!ok) {
    std::error_code ec;
    std::filesystem::remove(tmp_, ec);
    throw Error("writing force log '" + tmp_.string() + "' failed (disk full?)");
  }
  std::error_code ec;
  std::filesystem::rename(tmp_, path_, ec);
  if (ec) throw Error("cannot move force log into place '" + path_.string() + "': " + ec.message());
}

// ---------------------------------------------------------------- several

void ForceOutputs::stop() {
  std::string first_error;
  for (auto& o : outputs_) {
    try {
      o->stop();
    } catch (const std::exception& e) {
      if (first_error.empty()) first_error = e.what();
    }
  }
  if (!first_error.empty()) throw Error(first_error);
}

}  // namespace vx::probe
