#pragma once
/// @file integrator_kind.h
/// The time integrators the simulation offers (docs/model.md section 7): their names in scene
/// files and on the command line.

#include <cstdint>
#include <string>

namespace vx {

/// The available integrators.
enum class IntegratorKind : std::uint8_t {
  explicit_euler,    ///< the paper's eq. 1-2: x' = x + dt v (the old velocity), v' = v + dt a
  symplectic_euler,  ///< semi-implicit: v' = v + dt a, x' = x + dt v'
  implicit,          ///< backward Euler by projective dynamics (projective_solver.h)
};
[[nodiscard]] const char* to_string(IntegratorKind k);
/// Parses "explicit_euler", "symplectic_euler" or "implicit"; throws vx::Error otherwise.
[[nodiscard]] IntegratorKind parse_integrator(const std::string& s);

}  // namespace vx
