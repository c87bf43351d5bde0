#include "gui_loop.h"

#include <algorithm>
#include <thread>

#include "convert/decimate_surface.h"
#include "probe_scene.h"
#include "scene/scene.h"

namespace vx::probe {

GuiLoop::GuiLoop(AppShared& shared, ProbeView* view, KeyboardStick& keyboard)
    : s_(shared),
      view_(view),
      keyboard_(keyboard),
      probe_pos_(std::size_t(shared.probes), Eigen::Vector3d::Zero()),
      probe_contacts_(std::size_t(shared.probes), 0),
      shown_surface_(shared.display_surface),
      preview_triangles_(shared.surface_refinement && shared.display_surface ? shared.display_surface->num_triangles()
                                                                             : 0),
      opened_with_preview_(preview_triangles_ > 0),
      soak_(std::max(5.0, 0.1 * shared.options.soak_s), cpu_steal_s, shared.options.device_hz),
      frame_period_(std::chrono::duration_cast<SteadyClock::duration>(
          std::chrono::duration<double>(1.0 / std::max(1.0, shared.options.fps)))) {}

void GuiLoop::on_action(ViewAction a) {
  AppControls& c = s_.controls;
  switch (a) {
    case ViewAction::quit: c.request_quit("quit key"); break;
    case ViewAction::pause: c.paused.store(!c.paused.load()); break;
    case ViewAction::reset_scene: c.reset_requested.store(true); break;
    case ViewAction::screenshot: c.screenshot_requested.store(true); break;
    case ViewAction::next_probe:
      keyboard_.set_active_probe((keyboard_.active_probe() + 1) % std::max(1, s_.probes));
      break;
  }
}

std::string GuiLoop::run(const FixedRateThread& physics, const FixedRateThread& device,
                         const std::atomic<bool>& interrupted) {
  const AppOptions& o = s_.options;
  const bool automated = o.headless || o.frames > 0 || o.duration_s > 0 || o.exit_after_script;
  last_pass_ = SteadyClock::now();
  try {
    while (!s_.controls.quit.load()) {
      if (interrupted.load()) s_.controls.request_quit("interrupted");
      if (physics.failed() || device.failed()) return physics.failed() ? physics.error() : device.error();
      // a scripted or timed run cannot go on without physics (an interactive user can reset)
      if (automated && s_.physics.failed.load()) break;
      const SteadyClock::time_point now = measure(device);
      if (view_) {
        if (!show_frame(*view_, now)) break;
      } else {
        report_headless(now);
      }
    }
  } catch (const std::exception& e) {
    return e.what();
  }
  return {};
}

void GuiLoop::prime(const FixedRateThread& device) {
  const auto now = SteadyClock::now();
  device_rate_.sample(device.ticks(), now);
  update_rate_.sample(s_.physics.updates.load(), now);
}

SteadyClock::time_point GuiLoop::measure(const FixedRateThread& device) {
  const auto now = SteadyClock::now();
  device_rate_.sample(device.ticks(), now);
  if (s_.options.soak_s > 0) {
    // the start-up's work beside the run: the region check, and a solver built in the background
    if (background_done_s_ < 0 && !s_.region_check && s_.physics.started.load(std::memory_order_acquire) &&
        !s_.physics.solver_pending.load(std::memory_order_relaxed))
      background_done_s_ = seconds(now - s_.start);
    soak_.sample(seconds(now - s_.start), device.ticks(),
                 s_.physics.started.load(std::memory_order_acquire) ? s_.physics.startup_s : -1.0,
                 s_.physics.contact_cache_bytes.load(std::memory_order_relaxed), background_done_s_);
  }
  update_rate_.sample(s_.physics.updates.load(), now);
  // the tissue's rate: simulated over wall time of the same window, from the first completed
  // step on; a pause (or a failed physics) restarts the window and is not counted
  const bool started = s_.physics.started.load(std::memory_order_acquire);
  const bool halted = s_.controls.paused.load() || s_.physics.failed.load();
  if (started && halted) {
    paused_s_ += seconds(now - last_pass_);
    meter_.restart();
  } else if (started) {
    meter_.add(s_.physics.sample(s_.start, now));
  }
  last_pass_ = now;
  {
    std::lock_guard lock(s_.device.mutex);
    for (const auto& m : s_.device.messages) s_.say("input: " + m);
    s_.device.messages.clear();
  }
  // the window the HUD, the status lines, the warning and the frame budget all read this pass
  window_ = meter_.over_last(kRateWindow_s);
  behind_ = started && !halted && window_.full && window_.factor() < kBehindFactor;
  if (started && !halted) warn_if_behind(window_);
  report_region_check();
  take_refined_surface();
  return now;
}

void GuiLoop::take_refined_surface() {
  if (!s_.surface_refinement) return;
  if (!s_.surface_refinement->started()) {
    // once the solver is built (the first step, or the background factor ready): the
    // decimation's memory never on top of the factorisation's
    if (s_.physics.started.load(std::memory_order_acquire) &&
        !s_.physics.solver_pending.load(std::memory_order_relaxed))
      s_.surface_refinement->start();
    return;
  }
  if (!s_.surface_refinement->ready()) return;
  const std::shared_ptr<BackgroundDisplaySurface> job = std::move(s_.surface_refinement);
  s_.surface_refinement.reset();
  preview_triangles_ = 0;
  try {
    DecimationReport report;
    std::shared_ptr<const EmbeddedSurface> refined = job->get(&report);
    s_.exchange.offer_surface(std::move(refined));
    s_.say(fmt::format("{} ({:.1f} s after the open, decimated in the background: the preview replaced)",
                       report.summary(), seconds(SteadyClock::now() - s_.start)));
  } catch (const DecimationCancelled&) {
    // the app is quitting
  } catch (const std::exception& e) {
    s_.say(fmt::format("warning: the display surface's decimation failed ({}); the preview stays", e.what()));
  }
}

std::string GuiLoop::surface_note(SteadyClock::time_point now) const {
  if (preview_triangles_ == 0) return {};
  if (s_.surface_refinement && !s_.surface_refinement->started())
    return fmt::format("a preview ({} triangles), decimated once the solver is built", preview_triangles_);
  return fmt::format("a preview ({} triangles) while decimating ({:.0f} s since the open)", preview_triangles_,
                     seconds(now - s_.start));
}

void GuiLoop::report_region_check() {
  if (!s_.region_check || !s_.region_check->ready()) return;
  const RegionCheck c = s_.region_check->get();
  s_.region_check.reset();
  for (const auto& l : c.log) s_.say(l);
  for (const auto& w : c.warnings) s_.say("warning: " + w);
  if (!c.warnings.empty() && c.estimate)
    region_status_ = fmt::format("the regional solve presses about {:.2g}x too hard on this support (console)",
                                 c.estimate->force_ratio);
}

std::string GuiLoop::physics_rate_text(SteadyClock::time_point now) const {
  if (!s_.physics.started.load(std::memory_order_acquire))
    return StartupReport::preparing(seconds(now - s_.start), std::nullopt);
  return describe_physics_rate(window_, kRateWindow_s, s_.local);
}

std::string GuiLoop::solver_note(SteadyClock::time_point now) const {
  // the tissue rests while its solver is factored beside the session (--background-factor)
  if (!s_.physics.started.load(std::memory_order_acquire) || !s_.physics.solver_pending.load(std::memory_order_relaxed))
    return {};
  return fmt::format("factoring in the background ({:.0f} s since the open); the tissue rests till then",
                     seconds(now - s_.start));
}

void GuiLoop::warn_if_behind(const RateWindow& w) {
  if (warned_behind_ || !w.full || w.factor() >= 0.9 || s_.physics.lag_drops.load() == 0) return;
  if (s_.local)
    s_.say(
        fmt::format("note: the tissue cannot keep real time ({:.2f}x over the last {:g} s); the tool and its force "
                    "stay real time (the local contact model carries the force between the physics' updates)",
                    w.factor(), kRateWindow_s));
  else
    s_.say(
        fmt::format("warning: physics cannot keep real time ({:.2f}x over the last {:g} s): the simulation runs in "
                    "slow motion (a smaller model, fewer --threads competitors, a larger time step or "
                    "--force-shaping local help)",
                    w.factor(), kRateWindow_s));
  warned_behind_ = true;
}

HudInfo GuiLoop::hud(SteadyClock::time_point now) {
  HudInfo h;
  h.sim_s = double((s_.local ? s_.device.device_time_us : s_.physics.sim_time_us).load()) * 1e-6;
  h.physics_steps_per_s = window_.steps_per_s();
  h.physics_updates_per_s = update_rate_.rate();
  h.real_time_factor = window_.factor();
  h.physics_rate = physics_rate_text(now);
  h.solver_note = solver_note(now);
  h.surface_note = surface_note(now);
  h.paused = s_.controls.paused.load();
  h.behind_real_time = behind_;
  h.physics_threads = s_.physics.threads.load(std::memory_order_relaxed);
  h.physics_threads_given = s_.physics_threads;
  h.device_hz = device_rate_.rate();
  h.device_target_hz = s_.options.device_hz;
  h.probes = std::min(s_.probes, 2);
  h.active_probe = keyboard_.active_probe();
  const double since_fault_s = seconds(now - s_.start) - 1e-6 * double(s_.physics.fault_wall_us.load());
  if (s_.physics.failed.load())
    h.status = s_.physics.failure;
  else if (s_.physics.faults.load() > 0 && since_fault_s < 5.0)
    h.status = s_.physics.last_fault();  // shown for 5 s
  else
    h.status = region_status_.empty() || s_.accuracy_status.empty() ? region_status_ + s_.accuracy_status
                                                                    : region_status_ + "\n" + s_.accuracy_status;
  std::lock_guard lock(s_.device.mutex);
  h.force_N = s_.device.hud.force_N;
  h.contacts = s_.device.hud.contacts;
  h.model_nodes = s_.device.hud.model_nodes;
  return h;
}

bool GuiLoop::take_frame(ProbeView& view) {
  // the newest frame, if the physics made one since it was asked for; never waited for (no new
  // frame: the surface is not touched)
  if (!s_.exchange.take_frame(frame_)) return false;
  if (frame_.surface && frame_.surface != shown_surface_) {
    // the physics deforms another surface now (the decimated one in place of the preview)
    view.replace_surface(frame_.surface->rest_vertices, frame_.surface->triangles);
    shown_surface_ = frame_.surface;
    surface_replaced_s_ = seconds(SteadyClock::now() - s_.start);
  }
  for (int p = 0; p < s_.probes && p < int(frame_.probes.size()); ++p) {
    probe_pos_[std::size_t(p)] = frame_.probes[std::size_t(p)].pose.position_mm;
    probe_contacts_[std::size_t(p)] = frame_.probes[std::size_t(p)].contacts;
  }
  view.update_geometry(frame_.surface_vertices, frame_.surface_normals, frame_.positions, probe_pos_, probe_contacts_);
  return true;
}

bool GuiLoop::show_frame(ProbeView& view, SteadyClock::time_point now) {
  if (!view.process_events()) {
    window_closed_ = true;
    s_.controls.request_quit("window closed");
    return false;
  }
  s_.set_basis(view.view_basis());
  // the physics makes a frame (the display surface deformed, 4-6 ms on the folded organ) only
  // when asked, and it is asked only when a frame may be drawn; the node positions only while
  // the elements view draws them
  const bool open = frame_allowed(now);
  if (open) s_.exchange.request_frame(view.shows_levels());
  const bool new_frame = take_frame(view);
  std::vector<PlotSample> samples;
  {
    std::lock_guard lock(s_.device.mutex);
    samples.swap(s_.device.plot_pending);
  }
  view.add_plot_samples(samples);
  const bool screenshot = s_.controls.screenshot_requested.exchange(false);
  // a frame draws what changed: what the user did (a key, the mouse, a resize), a screenshot, the
  // tissue and the tools (a new physics frame); with nothing new only the HUD's numbers and the
  // force plot move, and they are redrawn a refresh period apart
  const bool input = view.input_events() != rendered_input_;
  const double since_s = seconds(now - last_render_);
  const double refresh_s = behind_ ? kHudRefreshBehind_s : kHudRefresh_s;
  if (screenshot || input || view.frames() == 0 || (open && (new_frame || since_s >= refresh_s))) {
    view.set_hud(hud(now));
    // behind real time with the cores shared: the display's turn, the physics on one thread
    const bool turn = behind_ && s_.share_cores && s_.physics_threads > 1;
    {
      // the turn ends with the frame, also when drawing it throws
      struct Turn {
        std::atomic<bool>* flag;
        ~Turn() {
          if (flag) flag->store(false, std::memory_order_relaxed);
        }
      } held{turn ? &s_.controls.display_turn : nullptr};
      if (turn) s_.controls.display_turn.store(true, std::memory_order_relaxed);
      view.render();  // no lock held: the physics and the device go on meanwhile
      if (turn && s_.options.test_frame_delay_s > 0)
        std::this_thread::sleep_for(std::chrono::duration<double>(s_.options.test_frame_delay_s));
    }
    last_render_ = now;
    const double took_s = seconds(SteadyClock::now() - now);
    // the first frame's time is the renderer's set-up (its shaders compiled, the surface taken:
    // 0.8 s on the folded organ, more under a sanitizer), not a frame's: it does not set the
    // budget, which after it would have held the next frame for 7 s or more
    last_render_s_ = view.frames() > 1 ? took_s : 0.0;
    if (first_frame_s_ < 0) first_frame_s_ = seconds(SteadyClock::now() - s_.start);
    if (turn) {
      ++display_turns_;
      display_turns_s_ += took_s;
    }
    rendered_input_ = view.input_events();
  }
  if (screenshot) {
    const std::string name = fmt::format("voxelastic-probe-{:06d}.png", view.frames());
    view.save_screenshot(name);
    s_.say("screenshot: " + name);
  }
  if (s_.options.frames > 0 && view.frames() >= s_.options.frames)
    s_.controls.request_quit(fmt::format("{} frames (--frames)", s_.options.frames));
  // sleep to the next frame deadline (a late frame starts the next period now, never a burst).
  const auto after = SteadyClock::now();
  next_frame_ = std::max(next_frame_ + frame_period_, after);
  std::this_thread::sleep_until(next_frame_);
  return true;
}

bool GuiLoop::frame_allowed(SteadyClock::time_point now) const {
  // the tissue behind real time: the physics is short of CPU, and the display keeps its frames
  // to a share of the wall time (on two cores they take the physics' CPU: docs/probe.md)
  return !behind_ || seconds(now - last_render_) >= last_render_s_ / kBehindDuty;
}

void GuiLoop::report_headless(SteadyClock::time_point now) {
  {
    std::lock_guard lock(s_.device.mutex);
    s_.device.plot_pending.clear();
  }
  if (now >= next_report_) {
    std::string rate = physics_rate_text(now);
    if (const std::string note = solver_note(now); !note.empty()) rate += "; solver: " + note;
    if (s_.local)
      s_.say(fmt::format("t = {:.2f} s, physics {:.0f} updates/s, {}, device {:.0f} forces/s",
                         double(s_.device.device_time_us.load()) * 1e-6, update_rate_.rate(), rate,
                         device_rate_.rate()));
    else
      s_.say(fmt::format("t = {:.2f} s simulated, physics {}, device {:.0f} updates/s",
                         double(s_.physics.sim_time_us.load()) * 1e-6, rate, device_rate_.rate()));
    next_report_ = now + std::chrono::seconds(2);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
}

}  // namespace vx::probe
