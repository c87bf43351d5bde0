#pragma once
/// @file physics_model.h
/// The immutable physical model: a Model calibrated with a Material (docs/model.md sections 5
/// and 6). Its factory, make_physics_model(), is calibration.h (above the element pass it uses).
///
/// Vertex weights. The paper's element weights its vertices equally, but the gradational
/// layout places vertices asymmetrically (dense where smaller neighbours share their nodes),
/// so an interior element may carry, e.g., extra vertices on its top and bottom faces only:
/// with equal weights its rest spread C0 = sum R0 R0^T is anisotropic and one scalar k makes
/// it up to 50 % stiffer along one axis than across (measured on a 16x16x32 block). Each
/// element therefore gets vertex weights w_i (mean 1, as close to 1 as possible, within
/// [min_weight, max_weight]) that make its weighted spread isotropic about the weighted centroid:
///   sum_i w_i R0_i = 0,   C0 = sum_i w_i R0_i R0_i^T = (S / 3) I,   S = sum_i w_i |R0_i|^2.
/// (The fit A = sum_i m_i r_i R0_i^T of docs/model.md section 2 is the weighted form.) An 8-vertex cube keeps
/// w = 1. The element energy becomes E_e = k/2 sum_i w_i |r_i - Q R0_i|^2 with r_i about the
/// weighted centroid, its force f_i = k w_i (Q R0_i - r_i), and masses and damping follow the
/// weights, so every vertex of an element vibrates at the same omega_e^2 = k / m_unit.
///
/// Calibration (derivation). Under a small symmetric strain eps (d_i = eps R0_i, Q = I):
///   E_e = k/2 sum_i w_i |eps R0_i|^2 = k/2 tr(eps^T eps C0) = (k S / 6) eps:eps,
/// the energy of a linear isotropic solid with Lame parameters mu = k S / (6 V), lambda = 0
/// over the element's volume V. Hence the model alone has Poisson ratio 0 and
///   k_e = 6 mu V_e / S_e,  mu = E / (2 (1 + nu)),   (nu = 0: k_e = 3 E V_e / S_e).
/// Check: an 8-vertex cube of edge h has V = h^3, S = 8 * 3 (h/2)^2 = 6 h^2, so k = E h / 2,
/// i.e. E = 2 k / h. Every level and shape (extra face vertices, partly filled groups) gets
/// its own V_e and S_e, so all levels represent the same material; where the weights cannot
/// make a spread isotropic (counted in PhysicsModel::anisotropic_elements) k is the isotropic
/// average. Verified by tests/core/physics/calibration_slow_test.cpp (static compression and sag of one
/// block for the voxel, uniform and gradational layouts against E).
///
/// The element as implemented (elements.h): the shape-keeping energy split into its affine and
/// non-affine parts, E_e = mu V |F - Q|^2 + k/2 sum_i w_i |r_i - F R0_i|^2, with F the
/// element's consistent deformation gradient (element_gradient.h) and Q its rotation. For an
/// 8-vertex cube F is the paper's least-squares fit A C0^{-1} and, because k S / 3 = 2 mu V,
/// E_e is exactly the paper's k/2 sum_i w_i |r_i - Q R0_i|^2. For the gradational layout's
/// elements with extra face vertices the consistent F passes the patch test (a uniform strain
/// is an equilibrium of the whole model), which the least-squares fit does not (11 % too soft
/// on a 32^3 cube; see element_gradient.h).
///
/// The hourglass element (the default, CalibrationOptions::element; element_modes.h) takes a
/// calibrated fraction of k off the element's bending (hourglass) modes, so that pure bending of
/// each element has linear elasticity's energy (the paper's penalty gives 3 times it on a cube):
/// the affine response and every check above are unchanged.
///
/// The 2D model (a slice of thickness t, plane stress; docs/model.md section 12.2) uses the same
/// element in the slice plane: C0 = (S / 2) I_2 in the plane, E_e = k/2 tr(eps^T eps C0) =
/// (k S / 4) eps:eps = mu V eps:eps, so k_e = 4 mu V_e / S_e (V_e: area times t); the volume term
/// keeps the area (det T = 1 in the plane) with k_v = 2 lambda* V_e and the plane-stress
/// lambda* = 2 mu lambda / (lambda + 2 mu) = E nu / (1 - nu^2); the hourglass element relieves
/// the one bilinear (xy) pattern of the slice.
///
/// Poisson ratio > 0 (volume preservation): an extra projective term per element on its
/// consistent deformation gradient F (one volume constraint per element: mean dilatation),
///   E_v = k_v/2 min_{T: det T = 1} |F - T|^2,
/// whose small-strain energy is k_v (tr eps)^2 / 6, i.e. the lambda (tr eps)^2 V / 2 of linear
/// elasticity with k_v = 3 lambda V_e, lambda = E nu / ((1 + nu)(1 - 2 nu)). It acts on the
/// affine part only: the former term on the vertex fit, k_v/2 min sum_i w_i |r_i - T R0_i|^2,
/// also held every non-affine motion with k_v = 13.5 k (nu 0.45) and locked (docs/model.md
/// section 5, "Locking").
///
/// Masses: element mass rho V_e is lumped onto its vertices in proportion to the weights.
/// Damping: c_e = zeta * 2 sqrt(k_e m_unit), m_unit = rho V_e / sum_i w_i (vertex i gets
/// stiffness k w_i, mass m_unit w_i, damping c w_i), i.e. the damping ratio zeta is relative to
/// the critical damping of the element's own vibration, the same at every element size.

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "model/model.h"
#include "physics/element_batch_layout.h"
#include "physics/element_modes.h"
#include "physics/material.h"
#include "physics/vertex_weights.h"

namespace vx {

/// Which element the calibration builds (elements.h).
enum class ElementKind {
  paper,      ///< the paper's element: every non-affine mode held by the penalty k
  hourglass,  ///< the paper's element with its bending (hourglass) modes relieved to the
              ///< stiffness of linear elasticity (element_modes.h); the same affine response
};

/// "paper" or "hourglass".
[[nodiscard]] const char* to_string(ElementKind kind);
/// The element named `name` ("paper", "hourglass"); throws vx::Error for another name.
[[nodiscard]] ElementKind element_kind_from_string(const std::string& name);

/// Mass scaling for quasi-static simulation (docs/model.md section 6): heavier nodes let an
/// explicit scheme take longer steps. It changes the dynamics, not the statics: every
/// equilibrium (the force on a slowly pressed tool, a sag under gravity) is the same, because
/// the elastic forces are unchanged and gravity keeps acting on the physical mass
/// (PhysicsModel::node_gravity_ratio). A uniform factor s divides every frequency and the wave
/// speed by sqrt(s) and multiplies the stable explicit step by sqrt(s); the element damping
/// coefficients c_e stay as calibrated (the viscous force of a given deformation rate is the
/// same), so the damping rate c/m falls by s and a ring-down lasts up to s times longer. The
/// floor (`time_step_s`) adds mass only to the nodes whose own stable step is shorter than the
/// target: the light dense surface vertices of partly filled elements, which set the stable
/// step of a gradational model and carry little of its mass, so the low modes that a slow
/// press excites barely change.
struct MassScaling {
  double factor{1.0};  ///< every node's mass times this (>= 1)
  /// > 0: each node's mass is raised, where needed, until its own symplectic Euler step
  /// (Gershgorin bound, time_step.h) is at least twice this: the automatic explicit step
  /// ("auto", half the estimate) is then about this long
  double time_step_s{0.0};
  [[nodiscard]] bool active() const { return factor != 1.0 || time_step_s > 0.0; }
  [[nodiscard]] bool operator==(const MassScaling&) const = default;
};

/// How the per-element calibration is done (defaults: the calibrated model).
struct CalibrationOptions {
  ElementKind element{ElementKind::hourglass};
  /// hourglass: the fraction of the penalty taken off the bilinear bending modes; negative
  /// (the default): calibrated per element so that pure bending of its box has linear
  /// elasticity's energy (2/3 on an 8-vertex cube; element_modes.h). At most 0.95.
  double bending_relief{-1.0};
  /// hourglass: the fraction taken off the trilinear (xyz) mode: 7/9, the trilinear field's energy.
  double xyz_relief{7.0 / 9.0};
  bool isotropic_weights{true};  ///< false: equal vertex weights (the paper's plain element)
  double min_weight{0.1};        ///< lower bound of a vertex weight (mean weight is 1)
  double max_weight{4.0};        ///< upper bound of a vertex weight
  MassScaling mass_scaling;      ///< none by default: the physical masses
  /// Poisson ratio > 0, volume models: the fraction of the volume term's stiffness kept on the
  /// element's mean dilatation (one constraint per element); the rest goes to volume points
  /// inside its cells (docs/model.md section 5, "Volume points"). 1: no volume points.
  double volume_mean_fraction{1.0};
  /// Where the volume points sit in each covered cell: (+-p, +-p, +-p) of its half-width
  /// (1/sqrt(3): the 2 x 2 x 2 Gauss points, exact for the trilinear field's linear variation).
  double volume_point_position{0.57735026918962576};
  /// > 0: the volume points' share of k_v per element is at most cap mu / lambda (the dilatation's
  /// variation inside an element costs at most cap mu instead of lambda: no locking as nu -> 0.5),
  /// the rest stays on the mean; <= 0: no cap (volume_mean_fraction alone).
  double volume_variation_cap{0.0};
};

/// The per-entry constants of the element pass of one vertex entry, packed into one 64-byte
/// record (one cache line) so that the force kernel streams a single array in entry order
/// instead of five (copies of PhysicsModel::entry_rest_weighted, entry_gradient,
/// entry_weight, entry_slot and Model::element_vertices).
struct alignas(64) PackedEntry {
  double rest_weighted[3];  ///< w_i R0_i, mm
  double gradient[3];       ///< g_i, 1/mm
  double weight;            ///< w_i
  std::int32_t vertex;      ///< the node of the entry
  std::int32_t slot;        ///< its column of the node-major entry buffers
};
static_assert(sizeof(PackedEntry) == 64);

/// The immutable physical model: a Model plus the calibrated per-element and per-node data
/// the integrators need. Many simulation states share one PhysicsModel.
struct PhysicsModel {
  std::shared_ptr<const Model> model;  ///< the geometry (rest shape, vertex lists)
  Material material;                   ///< the base material (before per-element overrides)
  /// 3: a volume model; 2: a slice model in plane stress (docs/model.md section 12.2): every
  /// element quantity lives in the slice plane, the rotation turns about the plane's normal
  int dimensions{3};
  /// 2D: an orthonormal right-handed frame, columns: the slice's two in-plane axes and its
  /// normal (from the grid's directions); the identity for a volume model
  Eigen::Matrix3d plane_frame{Eigen::Matrix3d::Identity()};
  /// 2D: a point of the slice plane (the rest centre plane of the nodes), LPS mm
  Eigen::Vector3d plane_point_mm{Eigen::Vector3d::Zero()};

  // vertex entries (parallel to model->element_vertices)
  std::vector<double> entry_weight;      ///< entries: vertex weight w_i (mean 1 per element)
  Eigen::Matrix3Xd entry_rest;           ///< 3 x entries: R0_i about the weighted rest centroid, mm
  Eigen::Matrix3Xd entry_rest_weighted;  ///< 3 x entries: w_i R0_i, mm

  // elements
  std::vector<double> element_stiffness;         ///< elements: k_e (per unit weight), N/mm
  std::vector<double> element_damping;           ///< elements: c_e (per unit weight), N*s/mm
  std::vector<double> element_volume_stiffness;  ///< elements: k_v = 3 lambda V_e (2D: 2 lambda* V_e), N*mm
                                                 ///< (energy k_v/2 |F - T|^2; empty when nu = 0)
  std::vector<double> element_mass_kg;           ///< elements: rho V_e, kg
  std::vector<double> element_spread_mm2;        ///< elements: S_e = sum_i w_i |R0_i|^2, mm^2
  std::vector<double> element_fit_scale;         ///< elements: 3 / S_e, 1/mm^2 (A * scale ~ deformation gradient)
  /// Consistent deformation gradient (element_gradient.h): F = sum_i x_i g_i^T.
  Eigen::Matrix3Xd entry_gradient;               ///< 3 x entries: g_i, 1/mm
  std::vector<double> element_affine_stiffness;  ///< elements: 2 mu V_e, N*mm (energy mu V |F - Q|^2)
  std::vector<Eigen::Matrix3d> element_spread;   ///< elements: C0 = sum_i w_i R0_i R0_i^T, mm^2
  ElementKind element{ElementKind::paper};       ///< the element calibrated
  /// hourglass element: kBendingModes x entries, the relief weights h_pi = sqrt(beta_p k) w_i
  /// gamma_pi, sqrt(N/mm) (element_modes.h; the element's energy gets -1/2 sum_p |sum_i h_pi x_i|^2);
  /// empty for the paper's element
  ModeWeights entry_modes;
  /// Volume points (CalibrationOptions::volume_mean_fraction < 1; docs/model.md section 5): per
  /// point s of element e, a volume term k_s/2 min_{det T = 1} |F_s - T|^2 on
  /// F_s = F + sum_t y_(j_t) delta_t^T (F the element's consistent gradient, y positions
  /// relative to the element's first vertex; the deltas of an element's points sum to zero
  /// weighted by k_s, so a uniform strain gives every point F and the patch test holds).
  std::vector<std::int32_t> volume_point_offsets;       ///< elements + 1: the points of e (empty: none)
  std::vector<double> volume_point_stiffness;           ///< points: k_s, N*mm
  std::vector<std::int32_t> volume_point_term_offsets;  ///< points + 1: the terms of s
  std::vector<std::int32_t> volume_term_entry;          ///< terms: the vertex entry j_t
  Eigen::Matrix3Xd volume_term_delta;                   ///< 3 x terms: delta_t, 1/mm
  std::int64_t bending_relief_clamped{0};               ///< hourglass: elements whose calibrated relief was clamped
  std::int64_t gradient_fallback_elements{0};           ///< elements keeping the least-squares gradient
  std::int64_t anisotropic_elements{0};                 ///< elements whose weighted spread stayed anisotropic (> 1e-6)
  double max_anisotropy{0.0};                           ///< largest (max - min) / mean eigenvalue of C0 over elements

  // derived constants of the integrators
  bool damped{false};            ///< some element has damping (c_e > 0)
  double rest_diagonal_mm{0.0};  ///< diagonal of the rest positions' bounding box, mm

  // nodes
  std::vector<double> node_mass_kg;   ///< nodes: lumped (physical) mass, kg
  std::vector<double> node_mass;      ///< nodes: inertial mass, N*s^2/mm (the lumped mass, scaled by mass_scaling)
  std::vector<double> node_inv_mass;  ///< nodes: 1 / node_mass, mm/(N*s^2)
  /// nodes: physical / inertial mass (1 without mass scaling): gravity accelerates a node by
  /// node_gravity_ratio * g, so its weight stays the physical one
  std::vector<double> node_gravity_ratio;
  MassScaling mass_scaling;      ///< what was applied
  double added_mass_kg{0.0};     ///< mass added by the scaling, kg (0 without)
  std::int64_t scaled_nodes{0};  ///< nodes whose mass the scaling raised

  // node -> vertex entries (CSR), entries in increasing order: the deterministic gather.
  // Per-entry buffers of the step (entry forces, projection targets) are stored in this
  // node-major order, so that summing a node's entries reads contiguous memory: the value of
  // vertex entry j sits in column entry_slot[j], node i owns columns
  // node_entry_offsets[i] .. node_entry_offsets[i+1].
  std::vector<std::int32_t> node_entry_offsets;  ///< nodes + 1
  std::vector<std::int32_t> node_entries;        ///< slots: the vertex entry in each slot
  std::vector<std::int32_t> entry_slot;          ///< vertex entries: their slot (inverse of node_entries)
  /// vertex entries: the element pass's constants packed per entry (derived from the above)
  std::vector<PackedEntry> entry_packed;
  /// the same constants in batches of elements, one per SIMD lane (element_batch_layout.h; built and run by
  /// element_batches.h)
  ElementBatches element_batches;

  [[nodiscard]] int num_nodes() const { return model->num_nodes(); }
  [[nodiscard]] int num_elements() const { return model->num_elements(); }
  [[nodiscard]] std::int64_t num_vertex_entries() const { return model->num_vertex_entries(); }
  [[nodiscard]] bool has_volume_term() const { return !element_volume_stiffness.empty(); }
  [[nodiscard]] bool has_volume_points() const { return !volume_point_offsets.empty(); }
  [[nodiscard]] bool has_bending_modes() const { return entry_modes.cols() > 0; }
  [[nodiscard]] bool is_2d() const { return dimensions == 2; }
  /// 2D: the slice plane's unit normal
  [[nodiscard]] Eigen::Vector3d plane_normal() const { return plane_frame.col(2); }
  /// Total mass, kg.
  [[nodiscard]] double total_mass_kg() const;
};

}  // namespace vx
