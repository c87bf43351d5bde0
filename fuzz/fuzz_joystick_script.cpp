// libFuzzer target: the probe app's joystick scripts through JoystickScript::parse() and a
// few samples of the result (docs/robustness.md).
#include <string_view>

#include "fuzz_support.h"
#include "joystick_script.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  return vx::fuzz::run([&] {
    const auto script = vx::probe::JoystickScript::parse(text, "fuzz.joy");
    const double end = script.duration_s();
    for (int stick = 0; stick < script.sticks(); ++stick)
      for (const double t : {-1.0, 0.0, 0.5 * end, end, end + 1.0}) (void)script.sample(stick, t);
  });
}
