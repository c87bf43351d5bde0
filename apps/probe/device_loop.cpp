#include "device_loop.h"

#include <pthread.h>
#include <sched.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>

#include "haptics/device_side.h"
#include "sim/simulation.h"
#include "soak.h"
#include "util/thread_priority.h"

namespace vx::probe {

namespace {

/// The calling thread at SCHED_FIFO 1, else nice -10; says which (or that neither was permitted).
std::string raise_device_thread_priority() {
  sched_param sp{};
  sp.sched_priority = 1;
  if (pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0) return "real-time priority (SCHED_FIFO 1)";
  if (set_this_thread_nice(-10)) return "priority nice -10";
  return "default priority (raising it was not permitted)";
}

}  // namespace

DeviceLoop::DeviceLoop(AppShared& shared, DeviceParts parts) : s_(shared), parts_(std::move(parts)) {
  ForceGuardSettings g;
  g.max_force_N = shared.options.max_force_N;  // the device's rated maximum
  for (auto& guard : guards_) guard = DeviceForceGuard(g);
  // a soak's end waits (in simulated time) for the tissue to fall asleep, at most the idle window
  // after which it is put at rest (read here, before the threads start)
  const IntegratorSettings& integ = shared.sim.settings().integrator;
  settle_window_s_ = integ.region_radius_mm > 0 && integ.region_idle_refresh_steps > 0
                         ? integ.region_idle_refresh_window_s
                         : kSoakSettleSim_s;
}

void DeviceLoop::add_commander(const Eigen::Vector3d& start_mm, const Box& allowed) {
  commanders_.emplace_back(start_mm, allowed, parts_.control);
}

Eigen::Vector3d DeviceLoop::add_local_probe(const ProbeSettings& probe, const HapticCouplingSettings& coupling) {
  hands_.emplace_back(probe);
  renderers_.emplace_back();
  renderers_.back().init(coupling);
  arrivals_.emplace_back();
  return hands_.back().state().position_mm;
}

void DeviceLoop::tick(std::int64_t n) {
  // the device thread has the one hard deadline (a tick every millisecond): it asks for the
  // lowest real-time priority (SCHED_FIFO 1; it sleeps between ticks, a tick takes tens of
  // microseconds), else nice -10, else keeps the default (no privilege). On a loaded machine a
  // thread at the default priority wakes up late often enough to skip 5-15 % of the ticks
  // (docs/probe.md, "Force shaping").
  if (n == 0) priority_ = raise_device_thread_priority();
  const auto t0 = SteadyClock::now();
  run_tick();
  const double cost = seconds(SteadyClock::now() - t0);
  cost_sum_s_ += cost;
  cost_max_s_ = std::max(cost_max_s_, cost);
}

void DeviceLoop::run_tick() {
  const auto now = SteadyClock::now();
  const SimClock c = s_.physics.clock();
  const double dt = started_ ? std::min(seconds(now - last_), 0.05) : 0.0;  // a stall is not replayed
  last_ = now;
  started_ = true;
  follow_reset();
  const double now_s = advance_clock(c, now, dt);
  follow_connections(now_s);
  // sticks: the script runs at the device's clock (paper: simulated time, so slow motion keeps
  // the palpation the same)
  // a soak's script starts when the physics has (its start-up can take longer than a script's rest)
  if (s_.options.soak_s > 0 && script_start_s_ < 0 && s_.physics.started.load(std::memory_order_acquire))
    script_start_s_ = now_s;
  const double script_s = s_.options.soak_s > 0 ? std::max(0.0, now_s - std::max(0.0, script_start_s_)) : now_s;
  if (s_.options.soak_s > 0 && script_start_s_ < 0)
    parts_.input->play_script(0.0);
  else
    parts_.input->play_script(script_s);
  parts_.input->poll();
  std::vector<std::string> msgs = parts_.input->take_messages();

  basis_ = s_.basis();
  const bool paused = s_.controls.paused.load();
  DeviceTick tick;
  tick.wall_s = seconds(now - s_.start);
  tick.sim_s = now_s;
  tick.local = s_.local;
  tick.probes = std::min(s_.probes, kMaxSticks);
  std::array<ProbeTick, kMaxSticks> t{};
  for (int p = 0; p < tick.probes; ++p) {
    const ProbeOutput snap = s_.exchange.probe(p);
    t[std::size_t(p)] = stick_of(p);
    ProbeForce& f = tick.probe[std::size_t(p)];
    f.physics_s = snap.time_s;
    f.contacts = snap.contacts;
    if (s_.local) {
      // the local contact model at this tick, for the device's position now
      local_probe(p, t[std::size_t(p)], dt, paused || c.paused, now_s, now, f);
      if (!paused && !c.paused) f.raw_N = snap.raw_force_n;
    } else {
      paper_probe(p, t[std::size_t(p)], snap, paused, c.paused, now_s, f);
    }
    // what reaches the hand: clamped, ramped up after a start, faded out after a fault
    f.device_N = guards_[std::size_t(p)].apply(f.device_N, dt);
    f.stick_N = basis_.transpose() * f.device_N;
  }
  if (s_.local) s_.tool_targets.publish();
  parts_.outputs->write(tick);
  ++ticks_;
  report(tick, t, std::move(msgs));
  check_stop(script_start_s_ < 0 && s_.options.soak_s > 0 ? 0.0 : script_s);
}

void DeviceLoop::follow_connections(double now_s) {
  SdlInput& in = *parts_.input;
  const AppOptions& o = s_.options;
  if (in.count() > 0 && o.test_unplug_s >= 0 && !unplugged_ && now_s >= o.test_unplug_s) {
    in.unplug_virtual(0);
    unplugged_ = true;
  }
  if (in.count() > 0 && o.test_replug_s >= 0 && unplugged_ && !replugged_ && now_s >= o.test_replug_s) {
    in.replug_virtual(0);
    replugged_ = true;
  }
  for (int i = 0; i < in.count() && i < kMaxSticks; ++i) {
    const int changes = in.connection_changes(i);
    if (changes == connection_seen_[std::size_t(i)]) continue;
    connection_seen_[std::size_t(i)] = changes;
    SDL_Joystick* js = in.joystick(i);
    parts_.outputs->reattach(i, js);
    if (js)
      guards_[std::size_t(i)].restart();  // plugged back: from zero, ramping up
    else
      guards_[std::size_t(i)].disconnect();  // unplugged: faded out, then nothing
  }
}

void DeviceLoop::follow_reset() {
  const int fault = s_.physics.fault_generation.load();
  if (fault != fault_seen_) {
    fault_seen_ = fault;
    for (auto& g : guards_) g.interrupt();
  }
  const int gen = s_.controls.reset_generation.load();
  if (gen == reset_seen_) return;
  for (auto& g : guards_) g.interrupt();
  reset_seen_ = gen;
  for (auto& pc : commanders_) pc.reset();
  if (!s_.local) return;
  for (auto& h : hands_) h.reset();
  for (auto& r : renderers_) r.reset();
  for (auto& a : arrivals_) a = ModelArrival{};
  clock_s_ = 0.0;
}

double DeviceLoop::advance_clock(const SimClock& c, SteadyClock::time_point now, double dt) {
  // paper: the simulated time now, from the physics' last report; never ahead of the physics by
  // more than one of its ticks (the half-sine pulse is evaluated within the step being computed).
  // local: the device's own clock, wall time while running: the tool never goes in slow motion
  if (!s_.local) return c.sim_s + (c.paused ? 0.0 : std::min(seconds(now - c.wall), s_.physics_period_s));
  if (!c.paused) clock_s_ += dt;
  s_.device.device_time_us.store(std::llround(clock_s_ * 1e6), std::memory_order_relaxed);
  return clock_s_;
}

DeviceLoop::ProbeTick DeviceLoop::stick_of(int p) {
  ProbeTick t;
  if (p < parts_.input->count()) t.cmd = stick_command(parts_.input->state(p), parts_.control);
  if (p == parts_.keyboard->active_probe()) {
    t.cmd = (t.cmd + stick_command(parts_.keyboard->state(), parts_.keyboard_control)).cwiseMax(-1.0).cwiseMin(1.0);
    t.drag = parts_.keyboard->take_drag();
  }
  return t;
}

void DeviceLoop::local_probe(int p, ProbeTick& t, double dt, bool paused, double now_s, SteadyClock::time_point wall,
                             ProbeForce& f) {
  const auto i = std::size_t(p);
  ProbeDriver& hand = hands_[i];
  // the hand: the stick moves the device position in wall time (the probe's speed limit)
  if (!paused && dt > 0) {
    hand.set_live(commanders_[i].update(t.cmd, t.drag, basis_, hand.state().position_mm, dt));
    hand.advance(now_s, dt);
  }
  const Eigen::Vector3d x = hand.state().position_mm;
  LocalForceRenderer& r = renderers_[i];
  ModelArrival& a = arrivals_[i];
  if (const LocalContactModel* m = s_.device_side.take_local_contact(p)) {
    if (a.seen) {
      const double gap = seconds(wall - a.wall);
      a.period_s = a.period_s > 0 ? 0.8 * a.period_s + 0.2 * gap : gap;
    }
    a.wall = wall;
    a.seen = true;
    a.nodes = m->size();
    a.anchor_N = m->valid ? m->anchor_force_n : Eigen::Vector3d::Zero();
    r.update_model(*m, now_s, a.period_s);
  }
  const LocalForceRenderer::Output& o = r.tick(x, now_s);
  s_.tool_targets.write_buffer()[i] = o.proxy_mm;
  if (!paused) {
    f.device_N = o.force_n;
    f.model_N = o.contact_n;
    f.guard_N = o.guard_n.norm();
  }
  f.tip_mm = o.proxy_mm;
  f.hand_mm = x;
  f.anchor_N = a.anchor_N;
  f.update_age_ms = a.seen ? 1e3 * seconds(wall - a.wall) : 0.0;
  f.stiffness_N_mm = 0.0;
  if (o.stiffness_n_mm.norm() > 0) {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(o.stiffness_n_mm, Eigen::EigenvaluesOnly);
    f.stiffness_N_mm = es.eigenvalues().maxCoeff();
  }
  t.update_mean_N = f.device_N.norm();
  t.plot_mean_N = f.anchor_N.norm();
}

void DeviceLoop::paper_probe(int p, ProbeTick& t, const ProbeOutput& snap, bool paused, bool sim_paused, double now_s,
                             ProbeForce& f) {
  const bool device = s_.device_side.has_device();
  const HalfSinePulse pulse = device ? s_.device_side.output_snapshot(p).pulse : HalfSinePulse{};
  if (!paused)
    s_.exchange.set_live(
        p, commanders_[std::size_t(p)].update(t.cmd, t.drag, basis_, snap.pose.position_mm, s_.device_period_s));
  // the device force: the paper's half sine, at the device's own clock
  if (!paused && !sim_paused) {
    f.device_N = device ? pulse.at(std::max(now_s, snap.time_s)) : snap.raw_force_n;
    f.raw_N = snap.raw_force_n;
    t.update_mean_N = device ? pulse.mean_n.norm() : snap.raw_force_n.norm();
  }
  t.plot_mean_N = t.update_mean_N;
  f.tip_mm = snap.pose.position_mm;
  f.hand_mm = snap.pose.position_mm;
  f.anchor_N = device ? pulse.mean_n : snap.raw_force_n;
  f.update_age_ms = device ? 1e3 * std::max(0.0, now_s - pulse.start_s) : 0.0;
}

void DeviceLoop::report(const DeviceTick& tick, const std::array<ProbeTick, kMaxSticks>& t,
                        std::vector<std::string> msgs) {
  DeviceReport& d = s_.device;
  std::lock_guard lock(d.mutex);
  for (int p = 0; p < tick.probes; ++p) {
    const auto i = std::size_t(p);
    const ProbeForce& f = tick.probe[i];
    // the HUD shows the force of the current device update (the half sine's mean), which
    // reads steadily; the played half sine itself passes through zero 50 times a second
    d.hud.force_N[i] = t[i].update_mean_N;
    d.hud.contacts[i] = f.contacts;
    if (s_.local) d.hud.model_nodes[i] = arrivals_[i].nodes;
    ForceStats& st = d.stats[i];
    st.max_device_N = std::max(st.max_device_N, f.device_N.norm());
    st.max_raw_N = std::max(st.max_raw_N, f.raw_N.norm());
    st.sum_device_N += f.device_N.norm();
    if (st.samples > 0) st.max_step_N = std::max(st.max_step_N, (f.device_N - st.last_N).norm());
    st.last_N = f.device_N;
    ++st.samples;
  }
  // a plot point every 4 ms of the device's time
  std::vector<PlotSample>& plot = d.plot_pending;
  if (plot.empty() || tick.sim_s >= plot.back().t_s + 0.004 || tick.sim_s < plot.back().t_s) {
    PlotSample ps;
    ps.t_s = tick.sim_s;
    for (int p = 0; p < tick.probes; ++p) {
      const auto i = std::size_t(p);
      ps.device_N[i] = float(tick.probe[i].device_N.norm());
      ps.mean_N[i] = float(t[i].plot_mean_N);
      ps.raw_N[i] = float(tick.probe[i].raw_N.norm());
    }
    if (plot.size() > 20000) plot.clear();  // nobody is reading (headless)
    plot.push_back(ps);
  }
  for (auto& m : msgs) d.messages.push_back(std::move(m));
}

void DeviceLoop::check_stop(double script_s) {
  const AppOptions& o = s_.options;
  // a soak's release: its tools are up from here on (soak.h)
  if (o.soak_s > 0 && release_sim_s_ < 0 && script_s >= o.soak_s - soak_rest_s(o.soak_s))
    release_sim_s_ = 1e-6 * double(s_.physics.sim_advanced_us.load(std::memory_order_relaxed));
  if (o.exit_after_script && parts_.script && script_s > parts_.script->duration_s() + 0.25 && soak_settled())
    s_.controls.request_quit(fmt::format("the joystick script ended ({:.2f} s){}", parts_.script->duration_s(),
                                         settle_.empty() ? "" : "; " + settle_));
  // the tissue's simulated time (resets excluded), not the device's clock: with local shaping
  // that clock runs from the open, the start-up included, and ahead of a tissue behind real time
  // (a --duration shorter than a first start's factorisation ended the run with nothing simulated)
  const double simulated_s = 1e-6 * double(s_.physics.sim_advanced_us.load(std::memory_order_relaxed));
  if (o.duration_s > 0 && simulated_s >= o.duration_s)
    s_.controls.request_quit(fmt::format("simulated {:.2f} s (--duration)", o.duration_s));
}

bool DeviceLoop::soak_settled() {
  if (s_.options.soak_s <= 0) return true;
  if (!settle_.empty()) return true;
  // the script's rest runs in wall time: a tissue simulated slower than real time may not have
  // had its idle window since the release yet. Go on until it falls asleep, or until the window
  // has passed in simulated time since the release (then it has been put at rest, or with
  // gravity or without regional solves left to settle), or kSoakSettleWall_s of wall time more.
  const double wall_s = seconds(SteadyClock::now() - s_.start);
  const double sim_s = 1e-6 * double(s_.physics.sim_advanced_us.load(std::memory_order_relaxed));
  if (settle_wall_s_ < 0) {
    settle_wall_s_ = wall_s;
    settle_sim_s_ = sim_s;
  }
  const double waited_wall_s = wall_s - settle_wall_s_, waited_sim_s = sim_s - settle_sim_s_;
  const double since_release_s = sim_s - std::max(0.0, release_sim_s_);
  const char* why = nullptr;
  if (s_.physics.asleep.load(std::memory_order_relaxed))
    why = "the tissue asleep";
  else if (since_release_s >= settle_window_s_ + 0.5)
    why = "its idle window since the release over";
  else if (waited_wall_s >= kSoakSettleWall_s)
    why = "the wall-time limit";
  else if (s_.physics.failed.load())
    why = "the physics stopped";
  if (!why) return false;
  settle_ = fmt::format(
      "the rest went on {:.1f} s more ({:.1f} s simulated; {:.1f} s simulated since the release) "
      "until {}",
      waited_wall_s, waited_sim_s, since_release_s, why);
  return true;
}

}  // namespace vx::probe
