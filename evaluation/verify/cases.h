#pragma once
/// @file cases.h
/// Private to evaluation/verify: the case functions that verify_cases.cpp lists, one file per
/// theme. Each builds a small synthetic object, measures one effect on the elastic model and
/// records checks against theory and plots into its VerifyContext (verify.h); the table in
/// verify_cases.cpp says what each checks and why its tolerances are what they are.

#include <vector>

#include "model/model.h"
#include "sim/integrator_kind.h"
#include "verify/verify.h"

namespace vx::cases {

// geometry_cases.cpp
/// Element and vertex-entry counts of all-tissue cubes and sphere phantoms against the paper.
void run_model_counts(VerifyContext& ctx);
/// Iso-surface and voxel staircase of the analytic phantoms against their exact shapes.
void run_geometry(VerifyContext& ctx);

// statics_cases.cpp
/// Plate compression of a cube in layout `r`: E measured within `tolerance` (a ratio).
void run_compression(VerifyContext& ctx, Layout r, double tolerance);
/// Hertz indentation on layout `r` at the voxel sizes `voxels_mm` (coarse to fine): the modulus
/// (at the finest and at every size of 0.5 mm or less) and the exponent (at the finest); with two
/// sizes or more, the modulus error must not grow; `against_voxel_layout`: the modulus must come
/// closer to the voxel layout's (1 mm) with every halving and end within 3 % of it.
void run_hertz(VerifyContext& ctx, Layout r, const std::vector<double>& voxels_mm, double modulus_tolerance,
               double exponent_tolerance, bool against_voxel_layout = false);
/// A cantilever under its own weight at the voxel sizes `voxels_mm`: convergence, and the finest
/// within `tolerance` of beam theory.
void run_cantilever(VerifyContext& ctx, Layout r, const std::vector<double>& voxels_mm, double tolerance);
/// Tissue-like Poisson ratios (0.3, 0.45, 0.49): a ball pressed into a bonded block, against a
/// finite-strain reference on the same mesh (finite_brick_reference.h), at 2 and 1 mm voxels.
void run_poisson_hertz(VerifyContext& ctx);
/// The same ratios: a clamped bar's bulge and modulus under compression.
void run_poisson_bulge(VerifyContext& ctx);
/// The same ratios: a cantilever under its own weight against Timoshenko beam theory (Newton's
/// method on the model's forces), at 2, 1 and 0.5 mm voxels.
void run_poisson_cantilever(VerifyContext& ctx);
/// One indentation on the three layouts, against the voxel-level model.
void run_layouts(VerifyContext& ctx);
/// The folded phantom: its model counts at 214 voxels, and hanging from its stem at 107 (the
/// support carries its weight).
void run_folded(VerifyContext& ctx);

// dynamics_cases.cpp
/// The first axial frequency of a fixed-free bar (section `section_voxels` voxels of `h` mm).
void run_frequency(VerifyContext& ctx, Layout r, int section_voxels, double h);
/// Convergence in the time step of the three integrators (first order).
void run_convergence_dt(VerifyContext& ctx);
/// The largest stable step of `kind` against the modulus and its estimate; with `implicit`,
/// also the implicit integrator far above the explicit limits.
void run_stability_dt(VerifyContext& ctx, IntegratorKind kind, bool implicit);
/// One long run of the energy case.
struct EnergyRun {
  IntegratorKind kind;
  double damping, dt_factor;  ///< dt_factor: of the integrator's estimated stable step (implicit: of symplectic's)
  const char* label;
};
/// Long runs of a released bar: the energy stays bounded (and falls when damped).
void run_energy(VerifyContext& ctx, const std::vector<EnergyRun>& runs);

// robustness_cases.cpp
/// Extreme inputs recover or are flagged, never NaN.
void run_extreme(VerifyContext& ctx);
/// A stiff lesion in a soft block is felt: more force over it than away from it.
void run_lesion(VerifyContext& ctx);
void run_palpation_map(VerifyContext& ctx);

// plane_cases.cpp (the 2D slice model, docs/model.md section 12)
/// Quadtree counts of an all-tissue square (exact rings) and the growth of a disk's work.
void run_plane_counts(VerifyContext& ctx);
/// Plate compression of a rectangle in plane stress at Poisson 0, 0.3 and 0.45.
void run_plane_compression(VerifyContext& ctx);
/// A cantilever under a tip load against Timoshenko's beam (hourglass and paper element).
void run_plane_cantilever(VerifyContext& ctx);
/// A circle pressed into a block: contact half-width against the 2D Hertz solution.
void run_plane_contact(VerifyContext& ctx);

}  // namespace vx::cases
