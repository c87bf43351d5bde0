#pragma once
/// @file calibration.h
/// The calibration: make_physics_model() turns a Model and a Material into a PhysicsModel
/// (physics_model.h: the model and the derivation of its constants; docs/model.md sections 5
/// and 6), and the stable-step sums of a calibrated model. It stands above the element pass
/// (elements.h, element_batches.h): the sums take each element's matrix, the derived part
/// builds the batches of the SIMD kernel. The calibration cache's key and store are
/// calibration_key.h (below); physics_model_key.cpp (above) calibrates a reference object.

#include <memory>
#include <vector>

#include "physics/calibration_key.h"
#include "physics/physics_model.h"

namespace vx {

/// Per node, the Gershgorin row sums of the linearised system (docs/model.md section 7):
/// sk_i = sum_e (|K_e| row sum at i + 2 w_i (1 - w_i/W_e) k_v,e) (N/mm; K_e the paper's element
/// matrix, unrelieved: an upper bound of the hourglass element's) and
/// sc_i = sum_e 2 w_i (1 - w_i/W_e) c_e (N*s/mm). omega_i^2 <= sk_i / m_i, gamma_i <= sc_i / m_i.
void node_gershgorin_sums(const PhysicsModel& physics, std::vector<double>& sk, std::vector<double>& sc);

/// The physical mass of node i for a symplectic Euler step of at least `dt` (s) at that node:
/// m >= D^2 sk / 4 + D sc / 2 with D = dt (the inverse of the undamped-or-damped bound
/// dt <= (sqrt(4 sk m + sc^2) - sc) / sk), N*s^2/mm.
[[nodiscard]] double mass_for_time_step(double sk, double sc, double dt);

/// Calibrates `model` (finalized: rest_offsets, element volumes) with `material` and optional
/// per-element overrides. Throws vx::Error for an invalid material, an override of the wrong
/// size or with non-positive values, or an empty/inconsistent model.
[[nodiscard]] std::shared_ptr<const PhysicsModel> make_physics_model(std::shared_ptr<const Model> model,
                                                                     const Material& material,
                                                                     const MaterialField& field = {},
                                                                     const CalibrationOptions& options = {});

/// Convenience: copies `model` into shared ownership.
[[nodiscard]] std::shared_ptr<const PhysicsModel> make_physics_model(const Model& model, const Material& material,
                                                                     const MaterialField& field = {},
                                                                     const CalibrationOptions& options = {});

/// make_physics_model with a calibration cache (calibration_key.h; may be null: none): the
/// calibrated part is loaded from it when it holds this calibration (bit for bit what
/// calibrating gives: the same arrays, the same steps), else computed and offered to it.
[[nodiscard]] std::shared_ptr<const PhysicsModel> make_physics_model(std::shared_ptr<const Model> model,
                                                                     const Material& material,
                                                                     const MaterialField& field,
                                                                     const CalibrationOptions& options,
                                                                     CalibrationCache* cache);

}  // namespace vx
