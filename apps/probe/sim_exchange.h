#pragma once
/// @file sim_exchange.h
/// The hand-off between the physics thread, which owns the Simulation (one single-threaded
/// step: sim/simulation.h), and the app's other loops:
///
///   device -> physics: a live command per probe (set_live), handed to the simulation before the
///                      physics thread's next step (apply_live);
///   physics -> device: each probe's output after the last step or reset (publish, probe);
///   physics -> GUI:    a frame (the deformed surface, the probes, the node positions when asked
///                      for) copied at the end of a step once the GUI asked for one
///                      (request_frame, publish, take_frame), never waited for.
///
/// One mutex guards the commands, the outputs and the frame; it is held only to copy the small
/// things (commands, outputs) and to swap the frame, which is copied before the lock: the device
/// thread reads the outputs at 1 kHz and never waits for the megabytes of a frame. The mutex
/// inherits priority (base/pi_mutex.h): the device thread at SCHED_FIFO that waits for it lends
/// the physics thread its priority, so it never waits for a core the physics thread lacks.

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "base/pi_mutex.h"
#include "sim/probe.h"
#include "sim/simulation.h"

namespace vx::probe {

class SimulationExchange {
 public:
  /// Sized for `sim`'s probes, their outputs now published (before any thread starts).
  explicit SimulationExchange(const Simulation& sim);

  // --- any thread -----------------------------------------------------------------------------
  /// Live input for probe `i` (a `live` probe), handed to the simulation before its next step.
  /// Throws vx::Error for a bad index or a probe that is not live.
  void set_live(int i, const LiveCommand& command);
  /// Probe `i` after the last published step: pose, raw force, contacts.
  [[nodiscard]] ProbeOutput probe(int i) const;
  /// Asks the physics thread to copy a frame at the end of its next step, with the node
  /// positions or without them (a display drawing the surface only).
  void request_frame(bool with_positions = true) {
    frame_positions_.store(with_positions, std::memory_order_relaxed);
    frame_requested_.store(true, std::memory_order_release);
  }
  /// Swaps the latest frame into `out` if a new one is ready; returns whether it was.
  bool take_frame(SimulationFrame& out);
  [[nodiscard]] std::int64_t frames_published() const { return frames_published_.load(std::memory_order_relaxed); }
  /// A display surface for the simulation to deform instead of its own from the next publish
  /// on (Simulation::set_surface: the probe app's preview replaced by the decimated surface once
  /// it is ready). Each frame carries its surface, so the display takes the new triangles with
  /// the first frame of it. Must be embedded in the simulation's model.
  void offer_surface(std::shared_ptr<const EmbeddedSurface> surface);
  /// Surfaces offered and taken by the simulation so far.
  [[nodiscard]] std::int64_t surfaces_taken() const { return surfaces_taken_.load(std::memory_order_relaxed); }

  // --- the physics thread ---------------------------------------------------------------------
  /// The live commands set since the last call, to `sim` (before a step).
  void apply_live(Simulation& sim);
  /// After a step or a reset: an offered surface to `sim`, the probes' outputs, and a frame when
  /// one was asked for.
  void publish(Simulation& sim);

 private:
  std::vector<std::string> names_;  ///< per probe, for messages
  std::vector<bool> live_probe_;    ///< per probe: driven live
  mutable PiMutex mutex_;
  std::vector<LiveCommand> live_;  ///< guarded
  std::vector<bool> live_dirty_;   ///< guarded
  std::atomic<bool> live_pending_{false};
  std::vector<ProbeOutput> published_;  ///< guarded
  std::atomic<bool> frame_requested_{false};
  std::atomic<bool> frame_positions_{true};
  SimulationFrame staging_;  ///< the physics thread's: the next frame, copied before the lock
  SimulationFrame frame_;    ///< guarded
  bool frame_ready_{false};  ///< guarded
  std::atomic<std::int64_t> frames_published_{0};
  std::shared_ptr<const EmbeddedSurface> offered_surface_;  ///< guarded
  std::atomic<bool> surface_offered_{false};
  std::atomic<std::int64_t> surfaces_taken_{0};
};

}  // namespace vx::probe
