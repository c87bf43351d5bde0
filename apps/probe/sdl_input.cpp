#include "sdl_input.h"

#include <fmt/core.h>

#include <algorithm>
#include <cmath>

#include "base/error.h"

namespace vx::probe {

namespace {


int SDLCALL virtual_rumble_callback(void* userdata, Uint16 low, Uint16 high) {
  auto* r = static_cast<VirtualRumble*>(userdata);
  r->low.store(low);
  r->high.store(high);
  r->calls.fetch_add(1);
  return 0;
}

double normalise_axis(Sint16 v) { return std::clamp(double(v) / 32767.0, -1.0, 1.0); }

Sint16 to_axis(double v) { return Sint16(std::lround(std::clamp(v, -1.0, 1.0) * 32767.0)); }

// drain SDL's event queue; report removed joysticks (instance ids) and added ones (device indices)
void drain_events(std::vector<SDL_JoystickID>* removed, std::vector<int>* added = nullptr) {
  SDL_Event e;
  while (SDL_PollEvent(&e)) {
    if (removed && e.type == SDL_JOYDEVICEREMOVED) removed->push_back(e.jdevice.which);
    if (added && e.type == SDL_JOYDEVICEADDED) added->push_back(e.jdevice.which);
  }
}

}  // namespace

SdlInput::SdlInput(const InputSettings& settings) : script_(settings.script) {
  // joystick input must keep flowing although SDL has no window of its own
  SDL_SetHint(SDL_HINT_JOYSTICK_ALLOW_BACKGROUND_EVENTS, "1");
  if (SDL_InitSubSystem(SDL_INIT_JOYSTICK) != 0) {
    const std::string why = SDL_GetError();
    SDL_Quit();
    // virtual joysticks need SDL; without a script the keyboard and mouse still work
    if (settings.script) throw Error("cannot initialise SDL joystick support (needed for --virtual-joystick): " + why);
    messages_.push_back("SDL joystick support is unavailable (" + why + "): keyboard and mouse only");
    return;
  }
  subsystems_ = SDL_INIT_JOYSTICK;
  // force feedback is optional: without it the devices can still rumble or log
  if (SDL_InitSubSystem(SDL_INIT_HAPTIC) == 0)
    subsystems_ |= SDL_INIT_HAPTIC;
  else
    messages_.push_back(std::string("SDL haptic support is unavailable (") + SDL_GetError() +
                        "): no constant-force effects");
  const int max_sticks = std::clamp(settings.max_sticks, 1, kMaxSticks);

  try {
    if (script_) {
      // one virtual joystick per scripted stick
      const int n = std::min(script_->sticks(), max_sticks);
      for (int s = 0; s < n; ++s) {
        Stick stick;
        stick.is_virtual = true;
        stick.rumble = std::make_unique<VirtualRumble>();
        stick.name = fmt::format("voxelastic virtual joystick {}", s);
        stick.device_index = attach_virtual(stick);
        stick.js = SDL_JoystickOpen(stick.device_index);
        if (!stick.js)
          throw Error(std::string("cannot open the SDL virtual joystick: ") + SDL_GetError());
        stick.id = SDL_JoystickInstanceID(stick.js);
        sticks_.push_back(std::move(stick));
      }
    } else if (settings.joysticks) {
      // the first physical joysticks, in SDL's order
      for (int i = 0; i < SDL_NumJoysticks() && int(sticks_.size()) < max_sticks; ++i) {
        SDL_Joystick* js = SDL_JoystickOpen(i);
        if (!js) {
          messages_.push_back(fmt::format("joystick {} could not be opened ({}), skipped", i, SDL_GetError()));
          continue;
        }
        Stick stick;
        stick.js = js;
        stick.id = SDL_JoystickInstanceID(js);
        stick.device_index = i;
        const char* name = SDL_JoystickName(js);
        stick.name = name ? name : fmt::format("joystick {}", i);
        sticks_.push_back(std::move(stick));
      }
    }
  } catch (...) {
    for (auto& s : sticks_)
      if (s.js) SDL_JoystickClose(s.js);
    SDL_QuitSubSystem(subsystems_);
    SDL_Quit();
    throw;
  }
  // the attach/open events are of no interest
  drain_events(nullptr);
  // initial state
  if (script_) play_script(0.0);
  poll();
}

SdlInput::~SdlInput() {
  for (auto& s : sticks_)
    if (s.js) SDL_JoystickClose(s.js);
  sticks_.clear();
  // quitting the joystick subsystem also detaches the virtual joysticks
  if (subsystems_) SDL_QuitSubSystem(subsystems_);
  SDL_Quit();
}

int SdlInput::attach_virtual(Stick& stick) {
  SDL_VirtualJoystickDesc desc{};
  desc.version = SDL_VIRTUAL_JOYSTICK_DESC_VERSION;
  desc.type = SDL_JOYSTICK_TYPE_GAMECONTROLLER;
  desc.naxes = kScriptAxes;
  desc.nbuttons = kScriptButtons;
  desc.nhats = 0;
  desc.name = stick.name.c_str();
  desc.userdata = stick.rumble.get();
  desc.Rumble = &virtual_rumble_callback;
  const int index = SDL_JoystickAttachVirtualEx(&desc);
  if (index < 0) throw Error(std::string("cannot attach an SDL virtual joystick: ") + SDL_GetError());
  return index;
}

void SdlInput::unplug_virtual(int i) {
  Stick& s = sticks_[std::size_t(i)];
  if (!s.is_virtual || !s.js) return;
  // SDL posts SDL_JOYDEVICEREMOVED: poll() closes it as it would a physical stick pulled out
  for (int index = 0; index < SDL_NumJoysticks(); ++index)
    if (SDL_JoystickGetDeviceInstanceID(index) == s.id) {
      SDL_JoystickDetachVirtual(index);
      return;
    }
}

void SdlInput::replug_virtual(int i) {
  Stick& s = sticks_[std::size_t(i)];
  if (!s.is_virtual || s.js) return;
  (void)attach_virtual(s);  // SDL posts SDL_JOYDEVICEADDED: poll() opens it into its old place
}

void SdlInput::take_added(const std::vector<int>& device_indices) {
  for (const int index : device_indices) {
    if (index < 0 || index >= SDL_NumJoysticks()) continue;
    const SDL_JoystickID id = SDL_JoystickGetDeviceInstanceID(index);
    const bool open = std::any_of(sticks_.begin(), sticks_.end(), [&](const Stick& s) { return s.js && s.id == id; });
    if (open) continue;
    const bool is_virtual = SDL_JoystickIsVirtual(index) == SDL_TRUE;
    auto place = std::find_if(sticks_.begin(), sticks_.end(),
                              [&](const Stick& s) { return !s.js && s.is_virtual == is_virtual; });
    if (place == sticks_.end()) continue;  // no empty place of its kind: not ours
    SDL_Joystick* js = SDL_JoystickOpen(index);
    if (!js) {
      messages_.push_back(fmt::format("a joystick was plugged in but could not be opened ({})", SDL_GetError()));
      continue;
    }
    place->js = js;
    place->id = SDL_JoystickInstanceID(js);
    place->device_index = index;
    ++place->changes;
    const char* name = SDL_JoystickName(js);
    const std::string was = place->name;
    if (!is_virtual && name) place->name = name;
    messages_.push_back(fmt::format("joystick '{}' is back (was '{}'): it drives probe {} again, its force ramps up",
                                    place->name, was, int(place - sticks_.begin())));
  }
}

const VirtualRumble* SdlInput::virtual_rumble(int i) const {
  return sticks_[std::size_t(i)].rumble.get();
}

std::string SdlInput::describe() const {
  if (sticks_.empty()) return "no joystick";
  std::string out;
  for (std::size_t i = 0; i < sticks_.size(); ++i) {
    const auto& s = sticks_[i];
    if (!out.empty()) out += "; ";
    const int axes = s.js ? SDL_JoystickNumAxes(s.js) : 0;
    const int buttons = s.js ? SDL_JoystickNumButtons(s.js) : 0;
    out += fmt::format("stick {}: '{}' ({}{} axes, {} buttons)", i, s.name,
                       s.is_virtual ? "virtual, " : "", axes, buttons);
  }
  return out;
}

void SdlInput::play_script(double t_s) {
  if (!script_) return;
  for (std::size_t i = 0; i < sticks_.size(); ++i) {
    auto& s = sticks_[i];
    if (!s.is_virtual || !s.js) continue;
    const ScriptSample v = script_->sample(int(i), t_s);
    for (int a = 0; a < kScriptAxes; ++a) SDL_JoystickSetVirtualAxis(s.js, a, to_axis(v.axes[std::size_t(a)]));
    for (int b = 0; b < kScriptButtons; ++b)
      SDL_JoystickSetVirtualButton(s.js, b, (v.buttons >> b) & 1u ? SDL_PRESSED : SDL_RELEASED);
  }
}

void SdlInput::poll() {
  if (!subsystems_) return;
  // pumping applies the virtual values and delivers hotplug events
  std::vector<SDL_JoystickID> removed;
  std::vector<int> added;
  SDL_JoystickUpdate();
  drain_events(&removed, &added);
  for (auto& s : sticks_) {
    if (s.js && (std::find(removed.begin(), removed.end(), s.id) != removed.end() ||
                 !SDL_JoystickGetAttached(s.js))) {
      messages_.push_back(fmt::format(
          "joystick '{}' was disconnected: its probe stops (keyboard still works; plug it back to go on)", s.name));
      SDL_JoystickClose(s.js);
      s.js = nullptr;
      ++s.changes;
    }
  }
  // plugged (back) in: into the places left empty
  if (!added.empty()) take_added(added);
  for (auto& s : sticks_) {
    StickState& st = s.state;
    if (!s.js) {
      st = StickState{};
      continue;
    }
    st.present = true;
    st.num_axes = std::min(SDL_JoystickNumAxes(s.js), kStickAxes);
    for (int a = 0; a < kStickAxes; ++a)
      st.axes[std::size_t(a)] = a < st.num_axes ? normalise_axis(SDL_JoystickGetAxis(s.js, a)) : 0.0;
    st.buttons = 0;
    const int nb = std::min(SDL_JoystickNumButtons(s.js), 32);
    for (int b = 0; b < nb; ++b)
      if (SDL_JoystickGetButton(s.js, b)) st.buttons |= 1u << b;
    st.hat = SDL_JoystickNumHats(s.js) > 0 ? SDL_JoystickGetHat(s.js, 0) : 0;
  }
}

std::vector<std::string> SdlInput::take_messages() {
  std::vector<std::string> out;
  out.swap(messages_);
  return out;
}

}  // namespace vx::probe
