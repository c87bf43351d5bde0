#include "sim_exchange.h"

#include "base/error.h"

namespace vx::probe {

SimulationExchange::SimulationExchange(const Simulation& sim) {
  const std::size_t np = std::size_t(sim.num_probes());
  for (const ProbeSettings& p : sim.settings().probes) {
    names_.push_back(p.name);
    live_probe_.push_back(p.drive == ProbeDrive::live);
  }
  live_.resize(np);
  live_dirty_.assign(np, false);
  for (int i = 0; i < int(np); ++i) published_.push_back(sim.probe(i));
}

void SimulationExchange::set_live(int i, const LiveCommand& command) {
  if (i < 0 || i >= int(names_.size()))
    throw Error("simulation: no probe " + std::to_string(i) + " (the scene has " + std::to_string(names_.size()) + ")");
  if (!live_probe_[std::size_t(i)])
    throw Error("simulation: probe " + std::to_string(i) + " (" + names_[std::size_t(i)] +
                ") is not live; give it \"live\": {} in the scene");
  std::lock_guard lock(mutex_);
  live_[std::size_t(i)] = command;
  live_dirty_[std::size_t(i)] = true;
  live_pending_.store(true, std::memory_order_release);
}

ProbeOutput SimulationExchange::probe(int i) const {
  std::lock_guard lock(mutex_);
  return published_.at(std::size_t(i));
}

bool SimulationExchange::take_frame(SimulationFrame& out) {
  std::lock_guard lock(mutex_);
  if (!frame_ready_) return false;
  std::swap(out, frame_);
  frame_ready_ = false;
  return true;
}

void SimulationExchange::apply_live(Simulation& sim) {
  if (!live_pending_.exchange(false, std::memory_order_acq_rel)) return;
  std::lock_guard lock(mutex_);
  for (std::size_t i = 0; i < live_.size(); ++i)
    if (live_dirty_[i]) {
      sim.set_live(int(i), live_[i]);
      live_dirty_[i] = false;
    }
}

void SimulationExchange::offer_surface(std::shared_ptr<const EmbeddedSurface> surface) {
  std::lock_guard lock(mutex_);
  offered_surface_ = std::move(surface);
  surface_offered_.store(true, std::memory_order_release);
}

void SimulationExchange::publish(Simulation& sim) {
  if (surface_offered_.exchange(false, std::memory_order_acq_rel)) {
    std::shared_ptr<const EmbeddedSurface> surface;
    {
      std::lock_guard lock(mutex_);
      surface.swap(offered_surface_);
    }
    sim.set_surface(std::move(surface));
    surfaces_taken_.fetch_add(1, std::memory_order_relaxed);
  }
  const bool frame = frame_requested_.exchange(false, std::memory_order_acq_rel);
  // the surface deformed and the frame copied before the lock (the device thread reads the
  // outputs meanwhile); under it only swapped
  if (frame) sim.copy_frame(staging_, frame_positions_.load(std::memory_order_relaxed));
  std::lock_guard lock(mutex_);
  for (std::size_t i = 0; i < published_.size(); ++i) published_[i] = sim.probe(int(i));
  if (frame) {
    std::swap(frame_, staging_);
    frame_ready_ = true;
    frames_published_.fetch_add(1, std::memory_order_relaxed);
  }
}

}  // namespace vx::probe
