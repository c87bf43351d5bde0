#include "physics/material.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "base/error.h"
#include "base/parallel.h"
#include "physics/element_gradient.h"
#include "physics/elements.h"

namespace vx {

double PhysicsModel::total_mass_kg() const {
  double m = 0;
  for (double x : node_mass_kg) m += x;
  return m;
}

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

namespace {

void check_field(const std::vector<double>& v, int elements, const char* what) {
  if (v.empty()) return;
  if (int(v.size()) != elements)
    throw Error(std::string("material field: ") + what + " has " + std::to_string(v.size()) +
                " values, the model has " + std::to_string(elements) + " elements");
  for (std::size_t e = 0; e < v.size(); ++e)
    if (!(v[e] > 0) || !std::isfinite(v[e]))
      throw Error(std::string("material field: ") + what + " of element " + std::to_string(e) + " is " +
                  std::to_string(v[e]) + ", must be > 0");
}

}  // namespace

namespace {

/// (max - min) / mean eigenvalue of a symmetric 3x3 matrix.
double anisotropy_of(const Eigen::Matrix3d& c) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(c);
  const Eigen::Vector3d ev = eig.eigenvalues();
  const double mean = ev.sum() / 3.0;
  return mean > 0 ? (ev.maxCoeff() - ev.minCoeff()) / mean : 0.0;
}

}  // namespace

Eigen::VectorXd isotropic_weights(const Eigen::Matrix3Xd& points, double min_weight, double max_weight,
                                  double* anisotropy) {
  const int n = int(points.cols());
  Eigen::VectorXd w = Eigen::VectorXd::Ones(n);
  // centred and scaled for conditioning
  Eigen::Matrix3Xd x = points.colwise() - points.rowwise().mean();
  const double scale = std::sqrt(x.colwise().squaredNorm().mean());
  if (scale > 0) x /= scale;
  std::vector<std::uint8_t> at_bound(std::size_t(n), 0);
  Eigen::Matrix3d central = Eigen::Matrix3d::Identity();
  const auto moments = [&](Eigen::Vector3d& c) {
    const double s0 = w.sum();
    c = x * w / s0;
    Eigen::Matrix3d m = Eigen::Matrix3d::Zero();
    for (int i = 0; i < n; ++i) m += w(i) * (x.col(i) - c) * (x.col(i) - c).transpose();
    return m;
  };
  for (int outer = 0; outer < n; ++outer) {
    for (int it = 0; it < 30; ++it) {
      // constraints: sum w = n, off-diagonals of the central spread 0, its diagonal equal
      Eigen::Vector3d c;
      central = moments(c);
      Eigen::Matrix<double, 6, 1> g;
      g << w.sum() - n, central(0, 1), central(0, 2), central(1, 2), central(0, 0) - central(1, 1),
          central(1, 1) - central(2, 2);
      if (g.cwiseAbs().maxCoeff() < 1e-13) break;
      // Jacobian: d(central)/dw_i = (x_i - c)(x_i - c)^T; entries at the bound do not move
      Eigen::Matrix<double, 6, Eigen::Dynamic> jac(6, n);
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d d = x.col(i) - c;
        jac.col(i) << 1.0, d.x() * d.y(), d.x() * d.z(), d.y() * d.z(), d.x() * d.x() - d.y() * d.y(),
            d.y() * d.y() - d.z() * d.z();
        if (at_bound[std::size_t(i)]) jac.col(i).setZero();
      }
      // least change of w towards 1 that zeroes the linearised constraints
      Eigen::VectorXd u = w - Eigen::VectorXd::Ones(n);
      for (int i = 0; i < n; ++i)
        if (at_bound[std::size_t(i)]) u(i) = 0;
      Eigen::Matrix<double, 6, 6> jj = jac * jac.transpose();
      jj.diagonal().array() += 1e-12 * (jj.trace() + 1.0);
      const Eigen::Matrix<double, 6, 1> lambda = jj.ldlt().solve(jac * u - g);
      Eigen::VectorXd delta = -u + jac.transpose() * lambda;
      for (int i = 0; i < n; ++i)
        if (at_bound[std::size_t(i)]) delta(i) = 0;
      if (!delta.allFinite()) break;
      w += delta;
      if (delta.cwiseAbs().maxCoeff() < 1e-12) break;  // stalled: the bounded compromise
    }
    // weights outside the bounds: hold them at the bound and solve again
    bool changed = false;
    for (int i = 0; i < n; ++i)
      if (w(i) < min_weight || w(i) > max_weight) {
        w(i) = std::clamp(w(i), min_weight, max_weight);
        at_bound[std::size_t(i)] = 1;
        changed = true;
      }
    if (!changed) break;
  }
  // keep the result only where it is valid and more isotropic than equal weights
  Eigen::Vector3d c;
  double aniso = std::numeric_limits<double>::infinity();
  if (w.allFinite() && (w.array() >= min_weight - 1e-9).all() && (w.array() <= max_weight + 1e-9).all()) {
    w *= n / w.sum();
    aniso = anisotropy_of(moments(c));
  }
  const Eigen::VectorXd weighted = w;
  w.setOnes();
  const double plain = anisotropy_of(moments(c));
  if (aniso < plain) {
    w = weighted;
  } else {
    aniso = plain;
  }
  if (anisotropy) *anisotropy = aniso;
  return w;
}

std::shared_ptr<const PhysicsModel> make_physics_model(std::shared_ptr<const Model> model_ptr,
                                                       const Material& material,
                                                       const MaterialField& field,
                                                       const CalibrationOptions& options) {
  if (!model_ptr) throw Error("make_physics_model: no model");
  if (const std::string bad = validate(material); !bad.empty()) throw Error("material: " + bad);
  if (!(options.min_weight > 0 && options.min_weight <= 1 && options.max_weight >= 1))
    throw Error("calibration: weight bounds [" + std::to_string(options.min_weight) + ", " +
                std::to_string(options.max_weight) + "] must satisfy 0 < min <= 1 <= max");
  const Model& m = *model_ptr;
  const int ne = m.num_elements(), nn = m.num_nodes();
  if (ne == 0 || nn == 0) throw Error("make_physics_model: the model has no elements");
  if (m.rest_offsets.cols() != m.num_vertex_entries() || int(m.element_volume_mm3.size()) != ne)
    throw Error("make_physics_model: the model is not finalized (call Model::finalize())");
  if (const std::string bad = m.validate(); !bad.empty()) throw Error("make_physics_model: model: " + bad);
  check_field(field.youngs_modulus_kpa, ne, "youngs_modulus_kpa");
  check_field(field.density_kg_m3, ne, "density_kg_m3");

  auto p = std::make_shared<PhysicsModel>();
  p->model = std::move(model_ptr);
  p->material = material;
  const bool volume = material.poisson_ratio > 0;
  p->element_stiffness.resize(std::size_t(ne));
  p->element_damping.resize(std::size_t(ne));
  p->element_mass_kg.resize(std::size_t(ne));
  p->element_spread_mm2.resize(std::size_t(ne));
  p->element_fit_scale.resize(std::size_t(ne));
  p->element_affine_stiffness.resize(std::size_t(ne));
  p->element_spread.resize(std::size_t(ne));
  if (volume) {
    p->element_volume_stiffness.resize(std::size_t(ne));
    p->element_spread_inv_sqrt.resize(std::size_t(ne));
    p->element_spread_sqrt_det.resize(std::size_t(ne));
  }
  p->node_mass_kg.assign(std::size_t(nn), 0.0);

  const std::int64_t entries = m.num_vertex_entries();
  p->entry_weight.resize(std::size_t(entries));
  p->entry_rest.resize(3, entries);
  p->entry_rest_weighted.resize(3, entries);
  // per element, in parallel (independent): weights, rest offsets, spread, stiffness, damping
  std::vector<double> aniso(std::size_t(ne), 0.0);
  std::vector<std::uint8_t> bad(std::size_t(ne), 0);
  parallel_for(ne, 64, 0, [&](std::int64_t e0, std::int64_t e1) {
    for (int e = int(e0); e < int(e1); ++e) {
      const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
      // vertex weights making the weighted rest spread isotropic
      Eigen::Matrix3Xd pts(3, n);
      for (int i = 0; i < n; ++i) pts.col(i) = m.rest_positions.col(m.element_vertices[b + i]);
      const Eigen::VectorXd w = options.isotropic_weights
                                    ? isotropic_weights(pts, options.min_weight, options.max_weight)
                                    : Eigen::VectorXd::Ones(n);
      const double wsum = w.sum();
      const Eigen::Vector3d centroid = pts * w / wsum;
      // rest offsets about the weighted centroid, spread S_e and C0
      double s = 0;
      Eigen::Matrix3d c0 = Eigen::Matrix3d::Zero();
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d r0 = pts.col(i) - centroid;
        p->entry_weight[std::size_t(b + i)] = w(i);
        p->entry_rest.col(b + i) = r0;
        p->entry_rest_weighted.col(b + i) = w(i) * r0;
        s += w(i) * r0.squaredNorm();
        c0 += w(i) * r0 * r0.transpose();
      }
      aniso[std::size_t(e)] = anisotropy_of(c0);
      const double vol = m.element_volume_mm3[e];
      if (!(s > 0) || !(vol > 0)) {
        bad[std::size_t(e)] = 1;
        continue;
      }
      const double e_kpa = field.youngs_modulus_kpa.empty() ? material.youngs_modulus_kpa : field.youngs_modulus_kpa[e];
      const double rho = field.density_kg_m3.empty() ? material.density_kg_m3 : field.density_kg_m3[e];
      const double mu = shear_modulus_n_mm2(e_kpa, material.poisson_ratio);
      // k_e = 6 mu V / S (see the header's derivation)
      const double k = 6.0 * mu * vol / s;
      const double mass_kg = rho * kKgM3ToKgPerMm3 * vol;
      const double m_unit = mass_kg * kKgToNs2PerMm / wsum;  // per unit weight, N*s^2/mm
      p->element_stiffness[e] = k;
      p->element_damping[e] = material.damping_ratio * 2.0 * std::sqrt(k * m_unit);
      p->element_mass_kg[e] = mass_kg;
      p->element_spread_mm2[e] = s;
      p->element_fit_scale[e] = 3.0 / s;
      p->element_affine_stiffness[e] = 2.0 * mu * vol;
      p->element_spread[e] = c0;
      if (volume) {
        const double lambda = lame_lambda_n_mm2(e_kpa, material.poisson_ratio);
        p->element_volume_stiffness[e] = 9.0 * lambda * vol / s;
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(c0);
        const Eigen::Vector3d ev = eig.eigenvalues().cwiseMax(1e-12 * eig.eigenvalues().maxCoeff());
        p->element_spread_inv_sqrt[e] =
            eig.eigenvectors() * ev.cwiseSqrt().cwiseInverse().asDiagonal() * eig.eigenvectors().transpose();
        p->element_spread_sqrt_det[e] = std::sqrt(ev.prod());
      }
    }
  });
  // consistent deformation gradients; the least-squares fit g_i = C0^{-1} w_i R0_i where the
  // boundary shares cannot be formed (a hand-edited model)
  ElementGradients grads = compute_element_gradients(m);
  p->entry_gradient = std::move(grads.entry_gradient);
  p->gradient_fallback_elements = grads.fallback_elements;
  for (int e = 0; e < ne; ++e) {
    if (!grads.element_fallback[std::size_t(e)] || bad[std::size_t(e)]) continue;
    const Eigen::Matrix3d inv = p->element_spread[std::size_t(e)].inverse();
    for (int j = m.element_offsets[e]; j < m.element_offsets[e + 1]; ++j)
      p->entry_gradient.col(j) = inv * p->entry_rest_weighted.col(j);
  }
  // serial, in element order: checks, statistics, lumped node masses (deterministic sums)
  for (int e = 0; e < ne; ++e) {
    if (bad[std::size_t(e)])
      throw Error("make_physics_model: element " + std::to_string(e) + " has no rest extent or volume");
    p->max_anisotropy = std::max(p->max_anisotropy, aniso[std::size_t(e)]);
    if (aniso[std::size_t(e)] > 1e-6) ++p->anisotropic_elements;
    const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
    double wsum = 0;
    for (int i = 0; i < n; ++i) wsum += p->entry_weight[std::size_t(b + i)];
    for (int i = 0; i < n; ++i)
      p->node_mass_kg[std::size_t(m.element_vertices[b + i])] += p->element_mass_kg[e] * p->entry_weight[std::size_t(b + i)] / wsum;
  }

  p->node_mass.resize(std::size_t(nn));
  p->node_inv_mass.resize(std::size_t(nn));
  for (int i = 0; i < nn; ++i) {
    if (!(p->node_mass_kg[i] > 0)) throw Error("make_physics_model: node " + std::to_string(i) + " belongs to no element");
    p->node_mass[i] = p->node_mass_kg[i] * kKgToNs2PerMm;
    p->node_inv_mass[i] = 1.0 / p->node_mass[i];
  }

  // node -> entries CSR by counting sort (entries stay in increasing order per node)
  p->node_entry_offsets.assign(std::size_t(nn) + 1, 0);
  for (auto v : m.element_vertices) ++p->node_entry_offsets[std::size_t(v) + 1];
  for (int i = 0; i < nn; ++i) p->node_entry_offsets[i + 1] += p->node_entry_offsets[i];
  p->node_entries.resize(m.element_vertices.size());
  p->entry_slot.resize(m.element_vertices.size());
  std::vector<std::int32_t> fill(p->node_entry_offsets.begin(), p->node_entry_offsets.end() - 1);
  for (std::size_t j = 0; j < m.element_vertices.size(); ++j) {
    const std::int32_t slot = fill[std::size_t(m.element_vertices[j])]++;
    p->node_entries[std::size_t(slot)] = std::int32_t(j);
    p->entry_slot[j] = slot;
  }
  p->entry_packed.resize(m.element_vertices.size());
  for (std::size_t j = 0; j < m.element_vertices.size(); ++j) {
    PackedEntry& pe = p->entry_packed[j];
    for (int d = 0; d < 3; ++d) {
      pe.rest_weighted[d] = p->entry_rest_weighted(d, std::int64_t(j));
      pe.gradient[d] = p->entry_gradient(d, std::int64_t(j));
    }
    pe.weight = p->entry_weight[j];
    pe.vertex = m.element_vertices[j];
    pe.slot = p->entry_slot[j];
  }
  build_element_batches(*p, kElementGrain, p->element_batches);
  return p;
}

std::shared_ptr<const PhysicsModel> make_physics_model(const Model& model, const Material& material,
                                                       const MaterialField& field, const CalibrationOptions& options) {
  return make_physics_model(std::make_shared<const Model>(model), material, field, options);
}

}  // namespace vx
