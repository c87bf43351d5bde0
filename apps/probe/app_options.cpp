#include "app_options.h"

#include <stdexcept>

#include "base/error.h"

namespace vx::probe {

DeviceChoice parse_device_choice(const std::string& s) {
  if (s == "auto") return DeviceChoice::automatic;
  if (s == "haptic") return DeviceChoice::haptic;
  if (s == "rumble") return DeviceChoice::rumble;
  if (s == "none") return DeviceChoice::none;
  throw Error("unknown force output '" + s + "': use auto, haptic, rumble or none");
}

InjectedFault parse_injected_fault(const std::string& s) {
  const auto at = s.find('@');
  const std::string kind = s.substr(0, at);
  InjectedFault f;
  if (kind == "nan")
    f.kind = InjectedFault::Kind::non_finite;
  else if (kind == "runaway")
    f.kind = InjectedFault::Kind::runaway;
  else if (kind == "throw")
    f.kind = InjectedFault::Kind::exception;
  else
    throw Error("--test-fault '" + s + "': use nan@STEP, runaway@STEP or throw@STEP");
  try {
    std::size_t used = 0;
    if (at == std::string::npos) throw std::invalid_argument("no step");
    f.step = std::stoll(s.substr(at + 1), &used);
    if (used != s.size() - at - 1 || f.step < 1) throw std::invalid_argument("bad step");
  } catch (const std::exception&) {
    throw Error("--test-fault '" + s + "': the step must be a whole number >= 1 (nan@120)");
  }
  return f;
}

}  // namespace vx::probe
