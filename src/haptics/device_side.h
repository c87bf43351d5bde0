#pragma once
/// @file device_side.h
/// The device side of a simulation (docs/model.md section 9): what a haptic device needs from
/// the physics, computed beside it and kept out of the physics step (sim/simulation.h).
///
///   - the device force: each probe's raw force averaged and played as half sines
///     (device_force.h), only with a device (or when the simulation does all the work);
///   - the local contact models (local_contact.h, settings.local_contact): each step feeds the
///     per-node contact forces into the anchor's means; publish_local_contact() (called by
///     whoever runs the physics, at the end of each physics update) hands the device thread one
///     LocalContactModel per probe through a lock-free triple buffer, its compliance from the
///     implicit integrator's factor or a patch (local_compliance.h).
///
/// A DeviceSide attaches itself to one Simulation (Simulation::set_step_listener) for its
/// lifetime: the simulation tells it of every step and reset, on the physics thread. Other
/// threads may call only the methods marked "any thread".
///
/// Units: mm, s, N.

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "base/pi_mutex.h"
#include "base/triple_buffer.h"
#include "haptics/device_force.h"
#include "haptics/local_compliance.h"
#include "haptics/local_contact.h"
#include "sim/simulation.h"

namespace vx {

/// How a simulation builds the local contact models it publishes (local_contact.h).
struct LocalContactSettings {
  /// Candidates besides the nodes in contact: the nodes within this gap of the tool, mm; <= 0:
  /// the broad-phase skin (twice the mean voxel size). It covers the tool's travel between
  /// two physics updates (20 mm/s for 50 ms: 1 mm).
  double margin_mm{0.0};
  int max_nodes{LocalContactSolver::kMaxNodes};  ///< at most this many candidates (nearest kept)
  /// The anchor (tool position, per-node forces) is an exponential mean over this time, s;
  /// < 0: automatic: 0 for the implicit integrator (its contact forces are smooth: the last
  /// step), 2 ms for the explicit ones (their node impulses jitter from step to step).
  double average_s{-1.0};
  /// The time between two physics updates (the probe app sets its physics period), s.
  double update_period_s{0.02};
  /// The compliance: the implicit integrator's own factor when it has one and one step spans
  /// at least half an update (its step's exact linearisation, as SOFA does) and the material
  /// has Poisson 0; else, or when false, A_T on a patch (local_compliance.h) at the horizon.
  bool integrator_compliance{true};
  /// The patch's T, s: long enough for the quasi-static response of a tissue the tool moves
  /// smoothly (a short T adds the inertia of a sudden jump: on a 16 mm block the contact
  /// stiffness at T = 2 ms is 1.35x that at 20 ms, and at 1 kHz updates the model then overshoots
  /// the force's change: 0.21 % RMS error against 0.07 % at 0.1 s).
  double horizon_s{0.1};
  /// W is scaled by this. 1: the projective matrix as it is, the exact linearisation of an
  /// implicit step of one local/global iteration. Converged (or explicit) dynamics respond
  /// along the true tangent, which the projective matrix overestimates (it leaves out the
  /// rotations' derivatives): 1.22x under a ball pressed into a block
  /// (tests/core/haptics/local_contact_test.cpp), 1.0 under a flat plate. 1.2 halves the demo's
  /// error at 60 Hz (1.05 % -> 0.56 % RMS), but a model softer than the tissue, anchored one
  /// update late, returns more energy than it took: the closed-loop test goes active (docs/probe.md).
  /// A stiffer model errs on the dissipative side, hence 1.
  double compliance_scale{1.0};
  double patch_radius_mm{0.0};  ///< patch: radius; <= 0: max(6 x tool radius, 12 x voxel size)

  /// Empty when valid, else what is wrong.
  [[nodiscard]] std::string validate() const;
};

/// What the device side does besides the physics (plain settings; the scene file fills them).
struct DeviceSideSettings {
  std::optional<DeviceForceSettings> device;          ///< absent: no device, no force shaping
  std::optional<LocalContactSettings> local_contact;  ///< absent: no local contact models
};

/// A probe's device force after a step.
struct DeviceOutput {
  Eigen::Vector3d shaped_force_n{Eigen::Vector3d::Zero()};  ///< device force now (zero without a device)
  HalfSinePulse pulse;                                      ///< the half sine being played (device only)
};

/// Work done and skipped, cumulative.
struct DeviceSideCounters {
  std::int64_t device_shaping_steps{0};    ///< probe-steps whose device force was shaped
  std::int64_t device_shaping_skipped{0};  ///< probe-steps not shaped (no device)
};

/// The device side of one simulation; see the file comment.
class DeviceSide final : public StepListener {
 public:
  /// Checks the settings (throws vx::Error with what is wrong), prepares every buffer and
  /// attaches to `sim`, which must outlive it (and have no other listener).
  DeviceSide(Simulation& sim, DeviceSideSettings settings);
  ~DeviceSide() override;
  DeviceSide(const DeviceSide&) = delete;
  DeviceSide& operator=(const DeviceSide&) = delete;

  [[nodiscard]] const DeviceSideSettings& settings() const { return settings_; }
  [[nodiscard]] const DeviceSideCounters& counters() const { return counters_; }
  /// A device with the paper's half sines (a `local` device is the probe app's: it shapes the
  /// force from the local contact models, and no half sines are played for it).
  [[nodiscard]] bool has_device() const {
    return settings_.device.has_value() && settings_.device->shaping == ForceShaping::paper;
  }
  /// Probe `i`'s device force after the last step (physics thread).
  [[nodiscard]] const DeviceOutput& output(int i) const { return outputs_[std::size_t(i)]; }

  // --- any thread ---------------------------------------------------------------------------
  /// Probe `i`'s device force after the last completed step (a device thread can evaluate
  /// pulse.at(its own time) between physics steps).
  [[nodiscard]] DeviceOutput output_snapshot(int i) const;
  /// Device thread (one consumer): the newest local contact model of probe `i` if one was
  /// published since the last call, else null. The model stays valid until the next call for
  /// the same probe. Null without settings.local_contact.
  [[nodiscard]] const LocalContactModel* take_local_contact(int i);

  // --- physics thread -------------------------------------------------------------------------
  /// Builds one local contact model per probe from the state now and the anchor means, and
  /// publishes them (settings.local_contact; else does nothing). Call it at the end of each
  /// physics update (after a chunk of steps). Allocates when the candidates grow.
  void publish_local_contact();
  /// Surface nodes per chunk of the local models' scan for candidates (build_local_contact): the
  /// chunks on the calling thread's OpenMP threads, their finds in chunk order (the same model on
  /// any thread count). The folded organ's 274,533 surface nodes: 135 chunks.
  static constexpr std::int64_t kLocalScanGrain = 2048;
  /// Builds probe `i`'s local contact model into `out` without publishing it (tests, tools).
  void build_local_contact(int i, LocalContactModel& out);
  [[nodiscard]] bool has_local_contact() const { return settings_.local_contact.has_value(); }
  /// Local contact models published so far.
  [[nodiscard]] std::int64_t local_contact_updates() const { return local_updates_; }
  /// The patch compliance (explicit integrators), for reports.
  [[nodiscard]] const PatchCompliance& patch_compliance() const { return patch_; }

  /// StepListener: the simulation's step and reset.
  void after_step() override;
  void after_reset() override;

 private:
  /// Feeds this step's per-node contact forces into the anchor means.
  void accumulate_local_contact();
  /// The local contact models take their compliance from the integrator's factor.
  [[nodiscard]] bool use_integrator_compliance() const;
  /// The scale of the local contact models' compliance (LocalContactSettings::compliance_scale).
  [[nodiscard]] double local_compliance_scale() const;
  [[nodiscard]] int num_probes() const { return sim_.num_probes(); }

  /// The anchor of one probe's local contact model: exponential means over average_s.
  struct LocalAnchor {
    bool started{false};
    Eigen::Vector3d pose{Eigen::Vector3d::Zero()};
    std::vector<Eigen::Vector3d> node_force;  ///< per node: mean force of the tool on it, N (lambda n)
    std::vector<std::int32_t> nodes;          ///< nodes with a nonzero mean force
    std::vector<std::uint8_t> listed;         ///< per node: in `nodes`
  };

  Simulation& sim_;
  DeviceSideSettings settings_;
  bool shape_{false};
  std::vector<DeviceForceShaper> shapers_;
  std::vector<DeviceOutput> outputs_;
  DeviceSideCounters counters_;

  // local contact models
  double local_average_s_{0.0};
  std::vector<LocalAnchor> local_anchor_;
  std::vector<std::unique_ptr<TripleBuffer<LocalContactModel>>> local_out_;
  PatchCompliance patch_;
  std::int64_t local_updates_{0};
  struct LocalCandidate {
    std::int32_t node;
    double force_n, gap_mm;
    Eigen::Vector3d normal;
  };
  std::vector<LocalCandidate> local_candidates_;
  /// each chunk's finds of the surface's scan for candidates (kept: no allocation once the
  /// largest contact has been seen)
  std::vector<std::vector<LocalCandidate>> local_found_;
  Eigen::MatrixXd local_g_;

  // shared with other threads
  mutable PiMutex mutex_;
  std::vector<DeviceOutput> published_;  ///< guarded
};

}  // namespace vx
