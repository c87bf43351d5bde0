#pragma once
/// @file material.h
/// The physical material of the tissue (docs/model.md sections 1, 5 and 6): Young's modulus,
/// density, damping ratio, Poisson ratio, per-element overrides, and the unit conversions of the
/// physics core. The calibration that turns a material into element stiffnesses, masses and
/// damping is physics_model.h.
///
/// Units of the physics core: positions mm, time s, force N, energy N*mm (= mJ).
/// Masses are kept in kg for reports and, for the integrators, in N*s^2/mm
/// (1 kg = 1e-3 N*s^2/mm, because 1 N = 1 kg*m/s^2 = 1000 kg*mm/s^2), so that
/// acceleration [mm/s^2] = force [N] / mass [N*s^2/mm] with no hidden factor 1000.

#include <string>
#include <vector>

namespace vx {

/// A homogeneous material. Defaults: soft tissue.
struct Material {
  double youngs_modulus_kpa{5.0};  ///< Young's modulus E, kPa (1 kPa = 1e-3 N/mm^2)
  double density_kg_m3{1000.0};    ///< density, kg/m^3
  double damping_ratio{0.1};       ///< fraction of each element's critical damping, >= 0
  double poisson_ratio{0.0};       ///< 0 <= nu < 0.5; nu > 0 adds the volume term
};

/// Per-element overrides of the material (heterogeneous tissue, stiff inclusions).
/// Each vector is empty (use Material) or has one value per element.
struct MaterialField {
  std::vector<double> youngs_modulus_kpa;  ///< elements, kPa
  std::vector<double> density_kg_m3;       ///< elements, kg/m^3
};

/// Conversion constants.
inline constexpr double kKpaToNPerMm2 = 1e-3;        ///< 1 kPa = 1e-3 N/mm^2
inline constexpr double kKgM3ToKgPerMm3 = 1e-9;      ///< 1 kg/m^3 = 1e-9 kg/mm^3
inline constexpr double kKgToNs2PerMm = 1e-3;        ///< 1 kg = 1e-3 N*s^2/mm
inline constexpr double kStandardGravityMmS2 = 9806.65;  ///< g, mm/s^2

/// Shear modulus mu and Lame lambda, N/mm^2, of E (kPa) and nu.
[[nodiscard]] double shear_modulus_n_mm2(double youngs_modulus_kpa, double poisson_ratio);
[[nodiscard]] double lame_lambda_n_mm2(double youngs_modulus_kpa, double poisson_ratio);

/// Checks a material; returns an empty string when valid, else what is wrong and the valid range.
[[nodiscard]] std::string validate(const Material& material);

}  // namespace vx
