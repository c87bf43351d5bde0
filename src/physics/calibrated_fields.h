#pragma once
/// @file calibrated_fields.h
/// The calibrated part of a PhysicsModel as one list (what the calibration cache keeps,
/// calibration_key.h): every field in the one order in which the key hashes them
/// (physics_model_key.cpp) and the cache file holds them (pipeline/io/calibration_cache.cpp,
/// which also checks their counts, reads them and moves them in by this list). A new calibrated
/// field is added here once.

#include "physics/physics_model.h"

namespace vx {

/// The count a calibrated field has in a model of its size (the cache file's check).
enum class CalibratedCount {
  entries,          ///< the model's vertex entries
  mode_entries,     ///< vertex entries; none for the paper's element
  elements,         ///< elements
  volume_elements,  ///< elements with a volume term (Poisson ratio above 0); else none
  any,              ///< any count (the reader checks the structure they make)
  terms,            ///< the volume point terms (volume_term_entry's count)
  nodes,            ///< nodes
  one,              ///< a single value
};

/// Calls f(what, count, p.field...) for every calibrated field in order, for one or more
/// PhysicsModels `p` (const or not): one to hash or write the fields, two to move them from the
/// second to the first. `what` names the field in a reader's messages.
template <typename F, typename... P>
void for_each_calibrated_field(F&& f, P&... p) {
  using C = CalibratedCount;
  // vertex entries
  f("the vertex weights", C::entries, p.entry_weight...);
  f("the rest offsets", C::entries, p.entry_rest...);
  f("the weighted rest offsets", C::entries, p.entry_rest_weighted...);
  f("the gradients", C::entries, p.entry_gradient...);
  f("the bending-mode weights", C::mode_entries, p.entry_modes...);
  // elements
  f("the element stiffness", C::elements, p.element_stiffness...);
  f("the element damping", C::elements, p.element_damping...);
  f("the volume stiffness", C::volume_elements, p.element_volume_stiffness...);
  f("the element masses", C::elements, p.element_mass_kg...);
  f("the element spreads", C::elements, p.element_spread_mm2...);
  f("the fit scales", C::elements, p.element_fit_scale...);
  f("the affine stiffness", C::elements, p.element_affine_stiffness...);
  f("the spread matrices", C::elements, p.element_spread...);
  // volume points
  f("the volume point offsets", C::any, p.volume_point_offsets...);
  f("the volume point stiffness", C::any, p.volume_point_stiffness...);
  f("the volume point term offsets", C::any, p.volume_point_term_offsets...);
  f("the volume point terms", C::any, p.volume_term_entry...);
  f("the volume point deltas", C::terms, p.volume_term_delta...);
  // nodes, counts
  f("the node masses", C::nodes, p.node_mass_kg...);
  f("the counts", C::one, p.bending_relief_clamped...);
  f("the counts", C::one, p.gradient_fallback_elements...);
  f("the counts", C::one, p.anisotropic_elements...);
  f("the counts", C::one, p.max_anisotropy...);
}

}  // namespace vx
