#include "physics/material.h"

#include <cmath>
#include <sstream>

namespace vx {

double shear_modulus_n_mm2(double youngs_modulus_kpa, double poisson_ratio) {
  return youngs_modulus_kpa * kKpaToNPerMm2 / (2.0 * (1.0 + poisson_ratio));
}

double lame_lambda_n_mm2(double youngs_modulus_kpa, double poisson_ratio) {
  return youngs_modulus_kpa * kKpaToNPerMm2 * poisson_ratio /
         ((1.0 + poisson_ratio) * (1.0 - 2.0 * poisson_ratio));
}

std::string validate(const Material& m) {
  std::ostringstream err;
  if (!(m.youngs_modulus_kpa > 0) || !std::isfinite(m.youngs_modulus_kpa))
    err << "Young's modulus " << m.youngs_modulus_kpa << " kPa must be > 0 (soft tissue: 1-100 kPa); ";
  if (!(m.density_kg_m3 > 0) || !std::isfinite(m.density_kg_m3))
    err << "density " << m.density_kg_m3 << " kg/m^3 must be > 0 (soft tissue: about 1000-1100); ";
  if (!(m.damping_ratio >= 0) || !std::isfinite(m.damping_ratio))
    err << "damping ratio " << m.damping_ratio << " must be >= 0 (a fraction of critical damping, e.g. 0.1); ";
  if (!(m.poisson_ratio >= 0 && m.poisson_ratio < 0.5))
    err << "Poisson ratio " << m.poisson_ratio
        << " must be in [0, 0.5) (0: the paper's model; tissue ~0.45 adds the volume term; "
           "negative ratios are not supported); ";
  return err.str();
}

}  // namespace vx
