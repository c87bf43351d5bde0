#include "joystick_script.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include "base/error.h"

namespace vx::probe {

namespace {

std::string where(const std::string& source, int line) {
  return source + ":" + std::to_string(line);
}

bool parse_double(const std::string& token, double& out) {
  try {
    std::size_t used = 0;
    out = std::stod(token, &used);
    return used == token.size() && std::isfinite(out);
  } catch (...) {
    return false;
  }
}

}  // namespace

JoystickScript JoystickScript::parse(std::string_view text, const std::string& source) {
  JoystickScript script;
  int declared_sticks = 0;
  int max_stick = -1;
  std::istringstream in{std::string(text)};
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    // drop the comment and split into tokens
    if (const auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::istringstream tokens(line);
    std::vector<std::string> tok;
    for (std::string t; tokens >> t;) tok.push_back(t);
    if (tok.empty()) continue;

    // the optional header
    if (tok[0] == "sticks") {
      if (tok.size() != 2 || (tok[1] != "1" && tok[1] != "2"))
        throw Error(where(source, n) + ": expected 'sticks 1' or 'sticks 2'");
      declared_sticks = tok[1] == "1" ? 1 : 2;
      continue;
    }

    // a keyframe: t stick a0 [a1 a2 a3] [bBITS]
    ScriptKey key;
    if (tok.size() < 3)
      throw Error(where(source, n) + ": expected 't_s stick a0 [a1 a2 a3] [bBITS]', got '" + line + "'");
    if (!parse_double(tok[0], key.t_s) || key.t_s < 0)
      throw Error(where(source, n) + ": time '" + tok[0] + "' is not a number >= 0 (seconds)");
    if (key.t_s > kMaxScriptTime_s)
      throw Error(where(source, n) + ": time " + tok[0] + " s is beyond the longest script (" +
                  std::to_string(int(kMaxScriptTime_s)) + " s, a day and a bit): a run would never end; the unit is s");
    if (tok[1] != "0" && tok[1] != "1")
      throw Error(where(source, n) + ": stick '" + tok[1] + "' must be 0 or 1");
    const int stick = tok[1] == "0" ? 0 : 1;
    std::size_t i = 2;
    int axis = 0;
    for (; i < tok.size() && tok[i][0] != 'b'; ++i, ++axis) {
      if (axis >= kScriptAxes)
        throw Error(where(source, n) + ": more than " + std::to_string(kScriptAxes) + " axis values");
      double v = 0;
      if (!parse_double(tok[i], v) || v < -1.0 || v > 1.0)
        throw Error(where(source, n) + ": axis value '" + tok[i] + "' is not a number in [-1, 1]");
      key.axes[std::size_t(axis)] = v;
    }
    if (axis == 0) throw Error(where(source, n) + ": a keyframe needs at least one axis value");
    if (i < tok.size()) {
      const std::string& bits = tok[i];
      if (bits.size() < 2 || bits.size() > 1 + kScriptButtons ||
          bits.find_first_not_of("01", 1) != std::string::npos)
        throw Error(where(source, n) + ": buttons '" + bits + "' must be 'b' and up to " +
                    std::to_string(kScriptButtons) + " digits 0/1 (button 0 first)");
      for (std::size_t b = 1; b < bits.size(); ++b)
        if (bits[b] == '1') key.buttons |= 1u << (b - 1);
      if (i + 1 != tok.size()) throw Error(where(source, n) + ": unexpected text after the buttons");
    }
    auto& keys = script.keys_[std::size_t(stick)];
    if (!keys.empty() && key.t_s < keys.back().t_s)
      throw Error(where(source, n) + ": time " + tok[0] + " s goes back (previous keyframe of stick " +
                  tok[1] + " is at " + std::to_string(keys.back().t_s) + " s)");
    keys.push_back(key);
    max_stick = std::max(max_stick, stick);
  }
  if (max_stick < 0) throw Error(source + ": no keyframes (lines 't_s stick a0 a1 a2')");
  if (declared_sticks && max_stick + 1 > declared_sticks)
    throw Error(source + ": keyframes for stick 1 but the header says 'sticks 1'");
  script.sticks_ = std::max(declared_sticks, max_stick + 1);
  for (int s = 0; s < script.sticks_; ++s)
    if (script.keys_[std::size_t(s)].empty())
      script.keys_[std::size_t(s)].push_back(ScriptKey{});  // a declared stick without keys rests
  return script;
}

JoystickScript JoystickScript::load(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot read joystick script '" + path.string() + "': " +
                       (std::filesystem::exists(path) ? "permission denied or not a file" : "no such file"));
  std::ostringstream text;
  text << in.rdbuf();
  return parse(text.str(), path.string());
}

double JoystickScript::duration_s() const {
  double d = 0;
  for (int s = 0; s < sticks_; ++s) d = std::max(d, keys_[std::size_t(s)].back().t_s);
  return d;
}

ScriptSample JoystickScript::sample(int stick, double t_s) const {
  const auto& keys = keys_[std::size_t(std::clamp(stick, 0, sticks_ - 1))];
  ScriptSample out;
  // first keyframe after t
  const auto next = std::upper_bound(keys.begin(), keys.end(), t_s,
                                     [](double t, const ScriptKey& k) { return t < k.t_s; });
  if (next == keys.begin()) {
    out.axes = keys.front().axes;
    out.buttons = keys.front().buttons;
    return out;
  }
  const ScriptKey& a = *(next - 1);
  out.buttons = a.buttons;
  if (next == keys.end()) {
    out.axes = a.axes;
    return out;
  }
  const ScriptKey& b = *next;
  const double span = b.t_s - a.t_s;
  const double w = span > 0 ? (t_s - a.t_s) / span : 1.0;
  for (int i = 0; i < kScriptAxes; ++i)
    out.axes[std::size_t(i)] = a.axes[std::size_t(i)] + w * (b.axes[std::size_t(i)] - a.axes[std::size_t(i)]);
  return out;
}

}  // namespace vx::probe
