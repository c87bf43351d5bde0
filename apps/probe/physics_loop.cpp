#include "physics_loop.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <thread>

#include "base/error.h"
#include "haptics/device_side.h"
#include "sim/projective_solver.h"
#include "sim/simulation.h"
#include "util/thread_priority.h"

namespace vx::probe {

void PhysicsLoop::tick() {
  const auto now = SteadyClock::now();
  // after a quit: no more steps; the run's interval ends here (the step running at the quit
  // included), not when the other threads have wound down
  if (s_.controls.quit.load()) {
    if (!s_.physics.ended.load(std::memory_order_relaxed)) {
      s_.physics.at_end = s_.physics.sample(s_.start, now);
      s_.physics.ended.store(true, std::memory_order_release);
    }
    return;
  }
  // local shaping: the device thread is the one with a deadline; the physics' updates yield to
  // it when the CPU is short (Linux: per thread; the display yields more)
  if (s_.local && !started_) (void)set_this_thread_nice(2);
  // sharing the cores: this thread's own OpenMP setting is what the core's loops follow
  const bool display_turn = s_.share_cores && s_.controls.display_turn.load(std::memory_order_relaxed);
  if (s_.share_cores) set_threads(display_turn ? 1 : share_.threads());
  apply_reset();
  Simulation& sim = s_.sim;
  const bool paused = s_.controls.paused.load();
  const double elapsed = started_ ? seconds(now - last_) : 0.0;
  last_ = now;
  if (!paused && !sim.failed()) {
    const double t0 = sim.time_s();
    const bool was_started = s_.physics.started.load(std::memory_order_relaxed);
    int steps = 0;
    try {
      steps = advance(now, elapsed);
    } catch (const Cancelled&) {
      // the session quits while a step waited for the solver being built (AppControls::request_quit
      // stopped it): no fault, the next tick ends the run
      s_.physics.quit_while_waiting.store(true);
    } catch (const std::exception& e) {
      // the step may have left the solver half done: it refactors
      recover(fmt::format("the step threw: {}", e.what()), true);
    }
    if (sim.failed()) recover(fmt::format("{}: {}", to_string(sim.state().status), sim.state().message), false);
    // the start-up's step (the factorisation) is not a step's load
    if (was_started) share_cores(steps, seconds(SteadyClock::now() - now), sim.time_s() - t0, display_turn);
    if (steps > 0 && !sim.failed()) keep_good_state(SteadyClock::now());
    if (publish(steps, t0)) {
      // the start-up ended: real time starts now (its wall time is not replayed, nor a lag)
      last_ = SteadyClock::now();
      sim_target_s_ = sim.time_s();
    }
  }
  started_ = true;
  s_.physics.sim_time_us.store(std::int64_t(std::llround(sim.time_s() * 1e6)), std::memory_order_relaxed);
  s_.physics.set_clock(SimClock{sim.time_s(), now, paused || sim.failed()});
}

void PhysicsLoop::recover(const std::string& what, bool drop_solver) {
  Simulation& sim = s_.sim;
  PhysicsReport& r = s_.physics;
  // the device fades its force out first (it reads the generation at its next tick)
  r.fault_generation.fetch_add(1);
  r.faults.fetch_add(1);
  const double wall_s = seconds(SteadyClock::now() - s_.start);
  r.fault_wall_us.store(std::llround(1e6 * wall_s));
  // a physics that fails again and again from rest too is not a fault to ride out: it stops the
  // run as before (the physics thread's error)
  if (++faults_since_good_ > 5)
    throw std::runtime_error(
        fmt::format("the physics failed {} times in a row, the last: {}", faults_since_good_, what));
  const bool to_rest = good_.empty() || faults_since_good_ >= 3;
  if (rest_.empty()) {
    sim.save_tissue(rest_);
    rest_.positions = sim.physics().model->rest_positions;
    rest_.velocities.setZero();
    std::fill(rest_.rotations.begin(), rest_.rotations.end(), Eigen::Quaterniond::Identity());
    rest_.step = 0;
  }
  const TissueSnapshot& back = to_rest ? rest_ : good_;
  sim.restore_tissue(back, drop_solver || to_rest);
  const std::string line =
      fmt::format("physics fault at t = {:.3f} s (wall {:.4f} s; {}); the tissue is back to {}, the session goes on",
                  sim.time_s(), wall_s, what, to_rest ? "rest" : fmt::format("its state at t = {:.3f} s", back.time_s));
  r.set_last_fault(line);
  fmt::print(stderr, "voxelastic-probe: {}\n", line);
}

void PhysicsLoop::keep_good_state(SteadyClock::time_point now) {
  if (!good_.empty() && seconds(now - good_wall_) < snapshot_every_s_) return;
  const auto t0 = SteadyClock::now();
  s_.sim.save_tissue(good_);
  if (s_.options.soak_s > 0) soak_watch();
  good_wall_ = now;
  faults_since_good_ = 0;
  PhysicsReport& r = s_.physics;
  r.snapshots.fetch_add(1, std::memory_order_relaxed);
  const auto t1 = SteadyClock::now();
  add_time(r.in_snapshots_us, t0, t1);
  const double copy_s = seconds(t1 - t0);
  snapshot_every_s_ = std::max(kSnapshotEvery_s, kSnapshotCostShare * copy_s);
  const std::int64_t us = std::llround(1e6 * copy_s);
  if (us > r.snapshot_max_us.load(std::memory_order_relaxed)) r.snapshot_max_us.store(us, std::memory_order_relaxed);
}

void PhysicsLoop::finish() {
  if (s_.options.soak_s > 0 && soak_ref_.cols() > 0) s_.physics.soak_final_mm = soak_displacement_mm();
  s_.physics.soak_counters = s_.sim.counters();
  s_.physics.soak_end_s = s_.sim.time_s();
}

double PhysicsLoop::soak_displacement_mm() const {
  if (soak_ref_.cols() != s_.sim.state().positions.cols()) return 0.0;
  return (s_.sim.state().positions - soak_ref_).colwise().norm().maxCoeff();
}

void PhysicsLoop::soak_watch() {
  Simulation& sim = s_.sim;
  // the contact solve's cache, from the first snapshot on (reserved when the solver was set up)
  if (const auto& solver = sim.state().integrator_cache.solver)
    s_.physics.contact_cache_bytes.store(std::int64_t(solver->contact_cache_bytes()), std::memory_order_relaxed);
  if (soak_ref_.cols() == 0) {
    // without gravity the rest is the model's own shape; with it, the tissue's state once it has
    // sagged for a second with no tool touching
    if (sim.state().gravity_mm_s2.isZero(0.0)) {
      soak_ref_ = sim.physics().model->rest_positions;
      s_.physics.soak_ref_is_shape = true;
      return;
    }
    int contacts = 0;
    for (int p = 0; p < s_.probes; ++p) contacts += sim.probe(p).contacts;
    if (sim.time_s() < 1.0 || contacts > 0) return;
    soak_ref_ = sim.state().positions;
    s_.physics.soak_ref_s = sim.time_s();
    return;
  }
  s_.physics.soak_peak_mm = std::max(s_.physics.soak_peak_mm, soak_displacement_mm());
}

void PhysicsLoop::apply_reset() {
  if (!s_.controls.reset_requested.exchange(false)) return;
  s_.sim.reset();
  s_.exchange.publish(s_.sim);
  good_ = TissueSnapshot{};
  faults_since_good_ = 0;
  sim_target_s_ = 0.0;
  s_.controls.reset_generation.fetch_add(1);
}

int PhysicsLoop::advance(SteadyClock::time_point now, double elapsed) {
  Simulation& sim = s_.sim;
  const double period = s_.physics_period_s;
  const double t0 = sim.time_s();
  sim_target_s_ += std::min(elapsed, 0.1);  // a long stall is not replayed
  // at most twice real time per tick: catch up a little, never burst
  const int budget = std::max(1, int(std::ceil(2.0 * period / sim.dt_s())));
  int done = 0;
  if (s_.local) {
    // the steps the wall clock asks for, as many as fit in one physics period (a slow physics
    // publishes at its rate and falls behind in simulated time)
    int want = std::clamp(int(std::floor((sim_target_s_ - t0) / sim.dt_s() + 0.5)), 0, budget);
    if (step_cost_s_ > 0) want = std::min(want, std::max(1, int(0.9 * period / step_cost_s_)));
    done = local_update(want, now);
  } else {
    while (done < budget && !sim.failed() && sim.time_s() < sim_target_s_ - 0.5 * sim.dt_s()) {
      step_once();
      ++done;
    }
  }
  const double lag = sim_target_s_ - sim.time_s();
  lag_s_ = lag;
  if (lag > std::max(0.05, 3.0 * period)) {
    // cannot keep real time: drop the lag and go on in slow motion (the start-up's lag is the
    // start-up, not slow motion)
    lag_dropped_s_ += lag;
    if (s_.physics.started.load(std::memory_order_relaxed)) s_.physics.lag_drops.fetch_add(1);
    sim_target_s_ = sim.time_s();
  }
  return done;
}

void PhysicsLoop::step_once() {
  Simulation& sim = s_.sim;
  // the device's live commands since the last step
  s_.exchange.apply_live(sim);
  // an injected fault (tests): into the state the step starts from, through the same checks
  for (InjectedFault& f : faults_) {
    if (f.step != sim.steps() + 1) continue;
    const std::int64_t at = f.step;
    f.step = -1;  // once: a failed step is not counted, the next one has the same number
    if (f.kind == InjectedFault::Kind::exception)
      throw std::runtime_error(fmt::format("injected fault at step {} (--test-fault throw)", at));
    TissueSnapshot bad;
    sim.save_tissue(bad);
    const Eigen::Index node = bad.positions.cols() / 2;
    if (f.kind == InjectedFault::Kind::non_finite)
      bad.positions(0, node) = std::numeric_limits<double>::quiet_NaN();
    else
      bad.velocities.col(node) = Eigen::Vector3d(1e7, 0.0, 0.0);
    sim.restore_tissue(bad);
  }
  const std::int64_t rest_steps = sim.counters().steps_at_rest, sleeps = sim.counters().sleeps;
  const auto t0 = SteadyClock::now();
  sim.step();
  // the test hook's delay stands for a slower step: in it, before its outputs
  double delay = step_delay_s_;
  if (first_step_delay_s_ > 0 && !first_step_done_) delay += first_step_delay_s_;
  first_step_done_ = true;
  if (delay > 0) std::this_thread::sleep_for(std::chrono::duration<double>(delay));
  const auto t1 = SteadyClock::now();
  add_time(s_.physics.in_steps_us, t0, t1);
  // asleep: this step computed nothing, or the tissue fell asleep in it
  const SimulationCounters& c = sim.counters();
  s_.physics.asleep.store(c.steps_at_rest > rest_steps || c.sleeps > sleeps, std::memory_order_relaxed);
  // the solver built in the background while the tissue rests: when it was taken, how long steps
  // waited for it
  PhysicsReport& r = s_.physics;
  const bool pending = sim.solver_pending();
  if (r.solver_pending.load(std::memory_order_relaxed) && !pending)
    r.solver_ready_us.store(std::llround(1e6 * seconds(t1 - s_.start)), std::memory_order_relaxed);
  r.solver_pending.store(pending, std::memory_order_relaxed);
  r.factor_wait_us.store(std::llround(1e6 * c.factor_wait_s), std::memory_order_relaxed);
  // the probes' outputs (and a frame when the GUI asked) for the other threads
  if (!sim.failed()) {
    s_.exchange.publish(sim);
    add_time(s_.physics.in_outputs_us, t1, SteadyClock::now());
  }
}

int PhysicsLoop::local_update(int steps, SteadyClock::time_point start) {
  if (steps <= 0) return 0;
  Simulation& sim = s_.sim;
  // the tool from where the physics has it to where the device last put it, over the update
  if (s_.tool_targets.fetch()) have_targets_ = true;
  const std::array<Eigen::Vector3d, kMaxSticks>& to = s_.tool_targets.read_buffer();
  const int np = std::min(s_.probes, kMaxSticks);
  std::array<Eigen::Vector3d, kMaxSticks> from{};
  for (int p = 0; p < np; ++p) from[std::size_t(p)] = sim.probe(p).pose.position_mm;
  int done = 0;
  const auto deadline = start + std::chrono::duration_cast<SteadyClock::duration>(
                                    std::chrono::duration<double>(0.9 * s_.physics_period_s));
  for (int k = 1; k <= steps && !sim.failed() && !s_.controls.quit.load(std::memory_order_relaxed); ++k) {
    if (have_targets_)
      for (int p = 0; p < np; ++p)
        sim.set_live(p, {LiveCommand::Kind::position,
                         from[std::size_t(p)] + (to[std::size_t(p)] - from[std::size_t(p)]) * (double(k) / steps)});
    step_once();
    ++done;
    // out of time (the steps took longer than they used to): the tool goes on from where it is
    // at the next update
    if (k < steps && SteadyClock::now() >= deadline) break;
  }
  if (done > 0) {
    const double per_step = seconds(SteadyClock::now() - start) / done;
    step_cost_s_ = step_cost_s_ > 0 ? 0.7 * step_cost_s_ + 0.3 * per_step : per_step;
  }
  if (done > 0 && !sim.failed()) {
    const auto t0 = SteadyClock::now();
    s_.device_side.publish_local_contact();
    add_time(s_.physics.in_local_models_us, t0, SteadyClock::now());
    s_.physics.updates.fetch_add(1, std::memory_order_relaxed);
  }
  return done;
}

void PhysicsLoop::set_threads(int threads) {
  if (threads == omp_threads_) return;
  omp_set_num_threads(threads);
  omp_threads_ = threads;
}

void PhysicsLoop::share_cores(int steps, double busy_s, double sim_s, bool display_turn) {
  if (!s_.share_cores || steps <= 0) return;
  PhysicsReport& r = s_.physics;
  if (display_turn) {
    // the steps the display's turn held to one thread (read from the setting they ran with)
    if (omp_get_max_threads() == 1) r.steps_in_display_turns.fetch_add(steps, std::memory_order_relaxed);
    // on one thread of more while the display drew: not the sharing's measure of its threads
    if (share_.threads() > 1) return;
  }
  if (share_.threads() == 1) r.steps_on_one.fetch_add(steps, std::memory_order_relaxed);
  const int before = share_.threads();
  const int next = share_.after_steps(seconds(SteadyClock::now() - s_.start), busy_s, sim_s, lag_s_);
  r.thread_trials.store(share_.trials(), std::memory_order_relaxed);
  r.thread_trials_kept.store(share_.trials_kept(), std::memory_order_relaxed);
  if (next == before) return;
  r.threads.store(next, std::memory_order_relaxed);
  r.thread_changes.store(share_.changes(), std::memory_order_relaxed);
}

void PhysicsLoop::add_time(std::atomic<std::int64_t>& to, SteadyClock::time_point from, SteadyClock::time_point until) {
  // after the start-up only: the interval the final line's real-time factor names
  if (!s_.physics.started.load(std::memory_order_relaxed)) return;
  to.fetch_add(std::chrono::duration_cast<std::chrono::microseconds>(until - from).count(), std::memory_order_relaxed);
}

bool PhysicsLoop::publish(int steps, double sim_before_s) {
  Simulation& sim = s_.sim;
  PhysicsReport& r = s_.physics;
  bool just_started = false;
  const std::int64_t total = r.steps.fetch_add(steps, std::memory_order_relaxed) + steps;
  const std::int64_t advanced_us = std::llround((sim.time_s() - sim_before_s) * 1e6);
  const std::int64_t advanced = r.sim_advanced_us.fetch_add(advanced_us, std::memory_order_relaxed) + advanced_us;
  // the start-up ends with the first completed step (the factorisation happens in it)
  if (steps > 0 && !r.started.load(std::memory_order_relaxed)) {
    const auto end = SteadyClock::now();
    r.startup_s = seconds(end - s_.start);
    r.at_startup = RateSample{r.startup_s, double(advanced) * 1e-6, total};
    r.started.store(true, std::memory_order_release);
    just_started = true;
  }
  if (sim.failed() && !r.failed.load()) {
    r.failure = fmt::format("physics stopped at t = {:.3f} s: {} ({}); press r to reset", sim.time_s(),
                            to_string(sim.state().status), sim.state().message);
    r.failed.store(true);
  }
  return just_started;
}

}  // namespace vx::probe
