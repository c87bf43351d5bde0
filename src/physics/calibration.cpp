#include "physics/calibration.h"

#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <unordered_map>

#include "base/content_hash.h"
#include "base/error.h"
#include "base/huge_pages.h"
#include "base/parallel.h"
#include "physics/element_batches.h"
#include "physics/element_gradient.h"
#include "physics/elements.h"
#include "physics/vertex_weights.h"

namespace vx {

namespace {

/// The largest relief fraction (the element stays positive definite below 1).
constexpr double kMaxRelief = 0.95;

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

/// The inputs of make_physics_model(), checked (throws vx::Error with what is wrong).
void check_inputs(const Model* model, const Material& material, const MaterialField& field,
                  const CalibrationOptions& options) {
  if (!model) throw Error("make_physics_model: no model");
  if (const std::string bad = validate(material); !bad.empty()) throw Error("material: " + bad);
  if (!(options.mass_scaling.factor >= 1.0) || !std::isfinite(options.mass_scaling.factor) ||
      !(options.mass_scaling.time_step_s >= 0.0) || !std::isfinite(options.mass_scaling.time_step_s))
    throw Error("mass scaling: factor " + std::to_string(options.mass_scaling.factor) + " must be >= 1 and time step " +
                std::to_string(options.mass_scaling.time_step_s) + " s >= 0");
  if (!(options.min_weight > 0 && options.min_weight <= 1 && options.max_weight >= 1))
    throw Error("calibration: weight bounds [" + std::to_string(options.min_weight) + ", " +
                std::to_string(options.max_weight) + "] must satisfy 0 < min <= 1 <= max");
  if (!(options.bending_relief <= kMaxRelief) || !(options.xyz_relief >= 0.0 && options.xyz_relief <= kMaxRelief))
    throw Error("calibration: bending relief " + std::to_string(options.bending_relief) + " and xyz relief " +
                std::to_string(options.xyz_relief) + " must be at most " + std::to_string(kMaxRelief) +
                " (a negative bending relief: calibrated), the xyz relief at least 0");
  const Model& m = *model;
  const int ne = m.num_elements(), nn = m.num_nodes();
  if (ne == 0 || nn == 0) throw Error("make_physics_model: the model has no elements");
  if (m.rest_offsets.cols() != m.num_vertex_entries() || int(m.element_volume_mm3.size()) != ne)
    throw Error("make_physics_model: the model is not finalized (call Model::finalize())");
  if (const std::string bad = m.validate(); !bad.empty()) throw Error("make_physics_model: model: " + bad);
  if (!(options.volume_mean_fraction >= 0.0 && options.volume_mean_fraction <= 1.0) ||
      !(options.volume_point_position > 0.0 && options.volume_point_position <= 1.0))
    throw Error("calibration: volume mean fraction " + std::to_string(options.volume_mean_fraction) +
                " must be in [0, 1] and volume point position " + std::to_string(options.volume_point_position) +
                " in (0, 1]");
  check_field(field.youngs_modulus_kpa, ne, "youngs_modulus_kpa");
  check_field(field.density_kg_m3, ne, "density_kg_m3");
}

/// The dimensions and, for a slice model, its plane: the frame of the grid's first two
/// directions (orthonormalised, right-handed) and the nodes' rest centre plane.
void set_plane(PhysicsModel& p) {
  const Model& m = *p.model;
  p.dimensions = m.dimensions;
  if (!m.is_2d()) return;
  const Eigen::Vector3d e1 = m.grid.direction.col(0).normalized();
  const Eigen::Vector3d e2 = (m.grid.direction.col(1) - e1.dot(m.grid.direction.col(1)) * e1).normalized();
  p.plane_frame.col(0) = e1;
  p.plane_frame.col(1) = e2;
  p.plane_frame.col(2) = e1.cross(e2);
  p.plane_point_mm = m.rest_positions.rowwise().mean();
}

/// Sizes the per-element and per-entry arrays of `p` (p.model and p.material set).
void allocate(PhysicsModel& p) {
  const Model& m = *p.model;
  const std::size_t ne = std::size_t(m.num_elements());
  const bool volume = p.material.poisson_ratio > 0;
  p.element_stiffness.resize(ne);
  p.element_damping.resize(ne);
  p.element_mass_kg.resize(ne);
  p.element_spread_mm2.resize(ne);
  p.element_fit_scale.resize(ne);
  p.element_affine_stiffness.resize(ne);
  p.element_spread.resize(ne);
  if (volume) {
    p.element_volume_stiffness.resize(ne);
  }
  p.node_mass_kg.assign(std::size_t(m.num_nodes()), 0.0);
  const std::int64_t entries = m.num_vertex_entries();
  p.entry_weight.resize(std::size_t(entries));
  p.entry_rest.resize(3, entries);
  p.entry_rest_weighted.resize(3, entries);
  if (p.element != ElementKind::paper) p.entry_modes.resize(kBendingModes, entries);
}

/// Elements by shape: of[e] is the lowest-numbered element with e's level and e's vertices at
/// the same lattice offsets from its anchor, in the same order (e itself when it is the first).
/// A folded organ's 64,059 elements have 10,572 shapes.
std::vector<std::int32_t> element_shapes(const Model& m) {
  const int ne = m.num_elements();
  const auto offsets_equal = [&m](int a, int b) {
    const int ba = m.element_offsets[a], bb = m.element_offsets[b], n = m.element_offsets[a + 1] - ba;
    if (m.element_level[std::size_t(a)] != m.element_level[std::size_t(b)] || m.element_offsets[b + 1] - bb != n)
      return false;
    for (int i = 0; i < n; ++i)
      if (m.node_lattice.col(m.element_vertices[ba + i]) - m.element_anchor.col(a) !=
          m.node_lattice.col(m.element_vertices[bb + i]) - m.element_anchor.col(b))
        return false;
    return true;
  };
  const auto count = static_cast<std::size_t>(ne);
  std::vector<std::uint64_t> hash(count);
  parallel_for(ne, 1024, 0, [&](std::int64_t e0, std::int64_t e1) {
    for (int e = int(e0); e < int(e1); ++e) {
      ContentHash h;
      h.add_value(std::int32_t(m.element_level[std::size_t(e)]));
      for (int j = m.element_offsets[e]; j < m.element_offsets[e + 1]; ++j) {
        const Eigen::Vector3i d = m.node_lattice.col(m.element_vertices[j]) - m.element_anchor.col(e);
        h.add(d.data(), sizeof(int) * 3);
      }
      hash[std::size_t(e)] = h.value();
    }
  });
  std::vector<std::int32_t> of(count);
  std::unordered_map<std::uint64_t, std::int32_t> first;
  first.reserve(count / 4);
  for (int e = 0; e < ne; ++e) {
    const auto [it, added] = first.emplace(hash[std::size_t(e)], e);
    // a hash collision between two shapes: the later element keeps its own
    of[std::size_t(e)] = added || !offsets_equal(it->second, e) ? e : it->second;
  }
  return of;
}

/// Per element, in parallel (independent): vertex weights, rest offsets, spread, stiffness,
/// damping, mass. anisotropy[e] gets the weighted spread's anisotropy; bad[e] = 1 for an element
/// without rest extent or volume.
///
/// The isotropic weights depend on an element's rest shape only (isotropic_weights centres its
/// points), so they are solved once per shape (element_shapes: the first element of it) and
/// shared by the elements whose rest vertices are that element's moved by a translation
/// (checked to 1e-12 of the element's size; an element that is not, a hand-edited model's,
/// gets its own). Solved from each element's own coordinates, congruent elements could get
/// different weights: the bounded solve's active set (which weights sit at a bound) turns on
/// rounding where the constraints leave a choice (on the folded organ, 133 of its 3,127 shapes
/// of more than one element; weights up to 3.9 apart, element stiffness up to 22 %). Shared,
/// the same shape is the same element everywhere, and the calibration solves 10,572 shapes
/// instead of 64,059 elements there.
void calibrate_elements(PhysicsModel& p, const MaterialField& field, const CalibrationOptions& options,
                        std::vector<double>& anisotropy, std::vector<std::uint8_t>& bad) {
  const Model& m = *p.model;
  const Material& material = p.material;
  const int ne = m.num_elements();
  const bool volume = material.poisson_ratio > 0;
  const int dims = p.dimensions;
  const Eigen::Matrix3d& frame = p.plane_frame;  // the identity for a volume model
  anisotropy.assign(std::size_t(ne), 0.0);
  bad.assign(std::size_t(ne), 0);
  const auto points_of = [&m](int e) {
    const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
    Eigen::Matrix3Xd pts(3, n);
    for (int i = 0; i < n; ++i) pts.col(i) = m.rest_positions.col(m.element_vertices[b + i]);
    return pts;
  };
  const auto solve_weights = [&](const Eigen::Matrix3Xd& pts) {
    return isotropic_weights(frame.transpose() * pts, options.min_weight, options.max_weight, nullptr, dims);
  };
  // the weights of each shape's first element, at its entries
  std::vector<std::int32_t> shape;
  std::vector<double> shape_weight;
  if (options.isotropic_weights) {
    shape = element_shapes(m);
    shape_weight.resize(m.element_vertices.size());
    parallel_for(ne, 64, 0, [&](std::int64_t e0, std::int64_t e1) {
      for (int e = int(e0); e < int(e1); ++e) {
        if (shape[std::size_t(e)] != e) continue;
        const Eigen::VectorXd w = solve_weights(points_of(e));
        for (Eigen::Index i = 0; i < w.size(); ++i) shape_weight[std::size_t(m.element_offsets[e] + i)] = w(i);
      }
    });
  }
  parallel_for(ne, 64, 0, [&](std::int64_t e0, std::int64_t e1) {
    for (int e = int(e0); e < int(e1); ++e) {
      const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
      // vertex weights making the weighted rest spread isotropic (2D: in the slice plane)
      const Eigen::Matrix3Xd pts = points_of(e);
      Eigen::VectorXd w = Eigen::VectorXd::Ones(n);
      if (options.isotropic_weights) {
        const int s = shape[std::size_t(e)], bs = m.element_offsets[s];
        bool shared = true;
        if (s != e) {
          // the same shape up to a translation (always, for a model built from a grid)
          const Eigen::Matrix3Xd first = points_of(s);
          const Eigen::Matrix3Xd moved = (first.colwise() - first.col(0)) - (pts.colwise() - pts.col(0));
          const double size = (first.rowwise().maxCoeff() - first.rowwise().minCoeff()).norm();
          shared = moved.cwiseAbs().maxCoeff() <= 1e-12 * size;
        }
        if (shared)
          for (int i = 0; i < n; ++i) w(i) = shape_weight[std::size_t(bs + i)];
        else
          w = solve_weights(pts);
      }
      const double wsum = w.sum();
      const Eigen::Vector3d centroid = pts * w / wsum;
      // rest offsets about the weighted centroid, spread S_e and C0
      double s = 0;
      Eigen::Matrix3d c0 = Eigen::Matrix3d::Zero();
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d r0 = pts.col(i) - centroid;
        p.entry_weight[std::size_t(b + i)] = w(i);
        p.entry_rest.col(b + i) = r0;
        p.entry_rest_weighted.col(b + i) = w(i) * r0;
        s += w(i) * r0.squaredNorm();
        c0 += w(i) * r0 * r0.transpose();
      }
      anisotropy[std::size_t(e)] = spread_anisotropy(frame.transpose() * c0 * frame, dims);
      const double vol = m.element_volume_mm3[e];
      if (!(s > 0) || !(vol > 0)) {
        bad[std::size_t(e)] = 1;
        continue;
      }
      const double e_kpa = field.youngs_modulus_kpa.empty() ? material.youngs_modulus_kpa : field.youngs_modulus_kpa[e];
      const double rho = field.density_kg_m3.empty() ? material.density_kg_m3 : field.density_kg_m3[e];
      const double mu = shear_modulus_n_mm2(e_kpa, material.poisson_ratio);
      // k_e = 6 mu V / S (see the header's derivation); 2D: 4 mu V / S
      const double k = (dims == 2 ? 4.0 : 6.0) * mu * vol / s;
      const double mass_kg = rho * kKgM3ToKgPerMm3 * vol;
      const double m_unit = mass_kg * kKgToNs2PerMm / wsum;  // per unit weight, N*s^2/mm
      p.element_stiffness[e] = k;
      p.element_damping[e] = material.damping_ratio * 2.0 * std::sqrt(k * m_unit);

      p.element_mass_kg[e] = mass_kg;
      p.element_spread_mm2[e] = s;
      p.element_fit_scale[e] = double(dims) / s;
      p.element_affine_stiffness[e] = 2.0 * mu * vol;
      p.element_spread[e] = c0;
      if (volume) {
        // the volume term k_v/2 min_{det T = 1} |F - T|^2 on the consistent F (docs/model.md
        // section 5): its small-strain energy k_v (tr eps)^2 / (2 d) is lambda V (tr eps)^2 / 2 for
        // k_v = d lambda V; 2D (plane stress): lambda* = 2 mu lambda / (lambda + 2 mu), k_v = 2 lambda* V
        const double lambda = lame_lambda_n_mm2(e_kpa, material.poisson_ratio);
        const double lam = dims == 2 ? 2.0 * mu * lambda / (lambda + 2.0 * mu) : lambda;
        p.element_volume_stiffness[e] = double(dims) * lam * vol;
      }
    }
  });
}

/// Consistent deformation gradients; the least-squares fit g_i = C0^{-1} w_i R0_i where the
/// boundary shares cannot be formed (a hand-edited model).
void set_gradients(PhysicsModel& p, const std::vector<std::uint8_t>& bad) {
  const Model& m = *p.model;
  ElementGradients grads = compute_element_gradients(m);
  p.entry_gradient = std::move(grads.entry_gradient);
  p.gradient_fallback_elements = grads.fallback_elements;
  for (int e = 0; e < m.num_elements(); ++e) {
    if (!grads.element_fallback[std::size_t(e)] || bad[std::size_t(e)]) continue;
    // 2D: the inverse in the slice plane (C0 has no normal part)
    const Eigen::Matrix3d inv =
        p.is_2d() ? Eigen::Matrix3d(p.element_spread[std::size_t(e)].completeOrthogonalDecomposition().pseudoInverse())
                  : Eigen::Matrix3d(p.element_spread[std::size_t(e)].inverse());
    for (int j = m.element_offsets[e]; j < m.element_offsets[e + 1]; ++j)
      p.entry_gradient.col(j) = inv * p.entry_rest_weighted.col(j);
  }
}

/// The volume points (PhysicsModel::volume_point_offsets; docs/model.md section 5, "Volume
/// points"): per covered cell of a volume model's element, 8 points at (+-p, +-p, +-p) of the
/// cell's half-width, F_s = F + sum_a y_a delta_a^T with delta_a = grad N_a(point) (the cell's
/// trilinear shape functions on its 8 corners) less the element's mean over its cells of
/// grad N_a(cell centre); k_s = (1 - fraction) k_v V_cell / V_cells / 8, the element's own
/// term keeping fraction k_v. An element whose cell corners are not all its vertices keeps
/// all of k_v on its mean (none here: every cell corner is a lattice node of its element).
void set_volume_points(PhysicsModel& p, const CalibrationOptions& options) {
  double alpha = options.volume_mean_fraction;
  if (options.volume_variation_cap > 0) {  // (1 - alpha) lambda <= cap mu
    const double nu = p.material.poisson_ratio;
    const double lambda_over_mu = 2.0 * nu / (1.0 - 2.0 * nu);
    if (lambda_over_mu > 0) alpha = std::max(0.0, 1.0 - options.volume_variation_cap / lambda_over_mu);
  }
  if (!p.has_volume_term() || p.is_2d() || !(alpha < 1.0)) return;
  const Model& m = *p.model;
  const int ne = m.num_elements();
  const double pos = options.volume_point_position;
  p.volume_point_offsets.assign(1, 0);
  std::vector<Eigen::Vector3d> deltas;
  for (int e = 0; e < ne; ++e) {
    const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
    const int w = m.layout == Layout::voxel ? 1 : m.element_cell_voxels[std::size_t(e)];
    const Eigen::Vector3i anchor = m.element_anchor.col(e);
    const int mask = m.layout == Layout::voxel ? 1 : m.element_cells[std::size_t(e)];
    // the boxes: the union of the tissue cells when it is a box (a full group, a slab, a bar, a
    // cell: its corners are the element's vertices), else each cell (when its corners are)
    Eigen::Vector3i lo(2, 2, 2), hi(-1, -1, -1);
    int count = 0;
    for (int bit = 0; bit < 8; ++bit) {
      if (!(mask & (1 << bit))) continue;
      const Eigen::Vector3i cell(bit & 1, (bit >> 1) & 1, (bit >> 2) & 1);
      lo = lo.cwiseMin(cell);
      hi = hi.cwiseMax(cell);
      ++count;
    }
    std::vector<std::pair<Eigen::Vector3i, Eigen::Vector3i>> boxes;  // lowest cell, extent in cells
    const Eigen::Vector3i ext = (hi - lo).array() + 1;
    if (count == ext.prod()) {
      boxes.emplace_back(lo, ext);
    } else {
      for (int bit = 0; bit < 8; ++bit)
        if (mask & (1 << bit))
          boxes.emplace_back(Eigen::Vector3i(bit & 1, (bit >> 1) & 1, (bit >> 2) & 1), Eigen::Vector3i(1, 1, 1));
    }
    // their corners' local indices, rest Jacobians
    std::vector<std::array<int, 8>> corners;
    std::vector<Eigen::Matrix3d> jinv_t;
    std::vector<double> cell_volume;
    bool ok = true;
    for (const auto& [cell, size] : boxes) {
      std::array<int, 8> c{};
      for (int a = 0; a < 8 && ok; ++a) {
        const Eigen::Vector3i lat =
            anchor + w * (cell + Eigen::Vector3i(a & 1, (a >> 1) & 1, (a >> 2) & 1).cwiseProduct(size));
        c[std::size_t(a)] = -1;
        for (int i = 0; i < n; ++i)
          if (m.node_lattice.col(m.element_vertices[b + i]) == lat) c[std::size_t(a)] = i;
        ok = c[std::size_t(a)] >= 0;
      }
      if (!ok) break;
      // J = dx/dxi (xi in [-1, 1]^3): half the mean edge along each axis
      Eigen::Matrix3d jac = Eigen::Matrix3d::Zero();
      for (int a = 0; a < 8; ++a) {
        const Eigen::Vector3d x = m.rest_positions.col(m.element_vertices[b + c[std::size_t(a)]]);
        jac.col(0) += ((a & 1) ? 0.125 : -0.125) * x;
        jac.col(1) += (((a >> 1) & 1) ? 0.125 : -0.125) * x;
        jac.col(2) += (((a >> 2) & 1) ? 0.125 : -0.125) * x;
      }
      const double det = jac.determinant();
      if (!(std::abs(det) > 0)) {
        ok = false;
        break;
      }
      corners.push_back(c);
      jinv_t.push_back(jac.inverse().transpose());
      cell_volume.push_back(8.0 * std::abs(det));
    }
    if (!ok || corners.empty()) {
      p.volume_point_offsets.push_back(p.volume_point_offsets.back());
      continue;
    }
    const int nc = int(corners.size());
    double vsum = 0;
    for (const double v : cell_volume) vsum += v;
    // grad N_a at xi of one cell (physical, 1/mm)
    auto grad = [&](int cell, int a, const Eigen::Vector3d& xi) {
      const Eigen::Vector3d s((a & 1) ? 1.0 : -1.0, ((a >> 1) & 1) ? 1.0 : -1.0, ((a >> 2) & 1) ? 1.0 : -1.0);
      const Eigen::Vector3d d(s.x() * (1 + s.y() * xi.y()) * (1 + s.z() * xi.z()),
                              s.y() * (1 + s.x() * xi.x()) * (1 + s.z() * xi.z()),
                              s.z() * (1 + s.x() * xi.x()) * (1 + s.y() * xi.y()));
      return Eigen::Vector3d(jinv_t[std::size_t(cell)] * (0.125 * d));
    };
    Eigen::Matrix3Xd mean = Eigen::Matrix3Xd::Zero(3, n);  // the element's mean of the cells' centre gradients
    for (int cl = 0; cl < nc; ++cl)
      for (int a = 0; a < 8; ++a)
        mean.col(corners[std::size_t(cl)][std::size_t(a)]) += grad(cl, a, Eigen::Vector3d::Zero()) / nc;
    const double kv = p.element_volume_stiffness[std::size_t(e)];
    for (int cl = 0; cl < nc; ++cl) {
      const double ks = (1.0 - alpha) * kv * cell_volume[std::size_t(cl)] / vsum / 8.0;
      for (int q = 0; q < 8; ++q) {
        const Eigen::Vector3d xi((q & 1) ? pos : -pos, ((q >> 1) & 1) ? pos : -pos, ((q >> 2) & 1) ? pos : -pos);
        Eigen::Matrix3Xd d = -mean;
        for (int a = 0; a < 8; ++a) d.col(corners[std::size_t(cl)][std::size_t(a)]) += grad(cl, a, xi);
        if (p.volume_point_term_offsets.empty()) p.volume_point_term_offsets.push_back(0);
        const double scale = d.cwiseAbs().maxCoeff();
        for (int i = 0; i < n; ++i) {
          if (!(d.col(i).cwiseAbs().maxCoeff() > 1e-12 * scale)) continue;
          p.volume_term_entry.push_back(b + i);
          deltas.push_back(d.col(i));
        }
        p.volume_point_term_offsets.push_back(std::int32_t(p.volume_term_entry.size()));
        p.volume_point_stiffness.push_back(ks);
      }
    }
    p.element_volume_stiffness[std::size_t(e)] = alpha * kv;
    p.volume_point_offsets.push_back(std::int32_t(p.volume_point_stiffness.size()));
  }
  p.volume_term_delta.resize(3, Eigen::Index(deltas.size()));
  for (std::size_t t = 0; t < deltas.size(); ++t) p.volume_term_delta.col(Eigen::Index(t)) = deltas[t];
  if (p.volume_point_stiffness.empty()) p.volume_point_offsets.clear();
}

/// The hourglass element's relief weights (element_modes.h), per element in its grid axes.
void set_bending_modes(PhysicsModel& p, const CalibrationOptions& options) {
  if (p.element == ElementKind::paper) return;
  const Model& m = *p.model;
  // the element's axes: the grid's index axes (the nearest orthogonal frame to its direction)
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(m.grid.direction, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Matrix3d to_grid = (svd.matrixU() * svd.matrixV().transpose()).transpose();
  std::vector<std::uint8_t> clamped(std::size_t(m.num_elements()), 0);
  parallel_for(m.num_elements(), 64, 0, [&](std::int64_t e0, std::int64_t e1) {
    for (int e = int(e0); e < int(e1); ++e) {
      const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
      const Eigen::VectorXd w = Eigen::Map<const Eigen::VectorXd>(p.entry_weight.data() + b, n);
      const Eigen::Matrix3Xd local = to_grid * p.entry_rest.middleCols(b, n);
      const ModeWeights gamma = bending_patterns(local, w, p.dimensions);
      const double k = p.element_stiffness[std::size_t(e)];
      double beta = options.bending_relief;
      if (beta < 0) {
        const double vol = m.element_volume_mm3[std::size_t(e)];
        const double mu = 0.5 * p.element_affine_stiffness[std::size_t(e)] / vol;
        beta = calibrated_bending_relief(local, w, to_grid * p.entry_gradient.middleCols(b, n), gamma, k, mu, vol,
                                         options.xyz_relief, p.dimensions, p.material.poisson_ratio);
        if (!(beta >= 0.0 && beta <= kMaxRelief)) {
          beta = std::isfinite(beta) ? std::clamp(beta, 0.0, kMaxRelief) : 0.0;
          clamped[std::size_t(e)] = 1;
        }
      }
      const Eigen::Vector4d root(std::sqrt(beta * k), std::sqrt(beta * k), std::sqrt(beta * k),
                                 std::sqrt(options.xyz_relief * k));
      p.entry_modes.middleCols(b, n) = root.asDiagonal() * gamma * w.asDiagonal();
    }
  });
  for (const auto c : clamped) p.bending_relief_clamped += c;
}

/// Serial, in element order: checks, statistics, lumped node masses (deterministic sums).
void lump_masses(PhysicsModel& p, const std::vector<double>& anisotropy, const std::vector<std::uint8_t>& bad) {
  const Model& m = *p.model;
  const int nn = m.num_nodes();
  for (int e = 0; e < m.num_elements(); ++e) {
    if (bad[std::size_t(e)])
      throw Error("make_physics_model: element " + std::to_string(e) + " has no rest extent or volume");
    p.max_anisotropy = std::max(p.max_anisotropy, anisotropy[std::size_t(e)]);
    if (anisotropy[std::size_t(e)] > 1e-6) ++p.anisotropic_elements;
    const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
    double wsum = 0;
    for (int i = 0; i < n; ++i) wsum += p.entry_weight[std::size_t(b + i)];
    for (int i = 0; i < n; ++i)
      p.node_mass_kg[std::size_t(m.element_vertices[b + i])] +=
          p.element_mass_kg[e] * p.entry_weight[std::size_t(b + i)] / wsum;
  }
  for (int i = 0; i < nn; ++i)
    if (!(p.node_mass_kg[i] > 0))
      throw Error("make_physics_model: node " + std::to_string(i) + " belongs to no element");
}

/// The inertial masses of the lumped ones (before mass scaling).
void set_node_masses(PhysicsModel& p) {
  const int nn = p.num_nodes();
  p.node_mass.resize(std::size_t(nn));
  p.node_inv_mass.resize(std::size_t(nn));
  p.node_gravity_ratio.assign(std::size_t(nn), 1.0);
  for (int i = 0; i < nn; ++i) {
    p.node_mass[i] = p.node_mass_kg[i] * kKgToNs2PerMm;
    p.node_inv_mass[i] = 1.0 / p.node_mass[i];
  }
}

/// Mass scaling (MassScaling): the inertial masses times the factor, then raised to the floor
/// that gives each node a symplectic Euler step of twice the target. Gravity keeps the physical
/// weight (node_gravity_ratio).
void scale_masses(PhysicsModel& p, const MassScaling& ms) {
  p.mass_scaling = ms;
  if (!ms.active()) return;
  const int nn = p.num_nodes();
  std::vector<double> sk, sc;
  if (ms.time_step_s > 0) node_gershgorin_sums(p, sk, sc);
  // the global estimate takes the largest omega^2 and the largest damping rate over all nodes,
  // which may belong to different nodes: a per-node floor for 2 x target gives a little less
  // globally, so the floor's step D is the smallest (bisection) whose estimate reaches it
  const double want = 2.0 * ms.time_step_s;
  const auto apply = [&](double d) {
    double w2 = 0, gamma = 0;
    for (int i = 0; i < nn; ++i) {
      const double physical = p.node_mass_kg[std::size_t(i)] * kKgToNs2PerMm;
      double m = physical * ms.factor;
      if (d > 0) m = std::max(m, mass_for_time_step(sk[std::size_t(i)], sc[std::size_t(i)], d));
      p.node_mass[std::size_t(i)] = m;
      w2 = std::max(w2, sk.empty() ? 0.0 : sk[std::size_t(i)] / m);
      gamma = std::max(gamma, sc.empty() ? 0.0 : sc[std::size_t(i)] / m);
    }
    return w2 > 0 ? (std::sqrt(4.0 * w2 + gamma * gamma) - gamma) / w2 : std::numeric_limits<double>::infinity();
  };
  if (ms.time_step_s > 0 && apply(want) < want) {
    double lo = want, hi = 2.0 * want;
    while (apply(hi) < want && hi < 1e6 * want) lo = hi, hi *= 2.0;
    for (int it = 0; it < 50 && hi - lo > 1e-6 * want; ++it) {
      const double mid = 0.5 * (lo + hi);
      (apply(mid) >= want ? hi : lo) = mid;
    }
    apply(hi);
  } else {
    apply(ms.time_step_s > 0 ? want : 0.0);
  }
  double added = 0;
  for (int i = 0; i < nn; ++i) {
    const double physical = p.node_mass_kg[std::size_t(i)] * kKgToNs2PerMm;
    const double m = p.node_mass[std::size_t(i)];
    if (m > physical) ++p.scaled_nodes;
    added += m - physical;
    p.node_inv_mass[std::size_t(i)] = 1.0 / m;
    p.node_gravity_ratio[std::size_t(i)] = physical / m;
  }
  p.added_mass_kg = added / kKgToNs2PerMm;
}

/// Node -> entries CSR by counting sort (entries stay in increasing order per node), and the
/// element pass's packed per-entry constants.
void index_entries(PhysicsModel& p) {
  const Model& m = *p.model;
  const int nn = m.num_nodes();
  p.node_entry_offsets.assign(std::size_t(nn) + 1, 0);
  for (auto v : m.element_vertices) ++p.node_entry_offsets[std::size_t(v) + 1];
  for (int i = 0; i < nn; ++i) p.node_entry_offsets[i + 1] += p.node_entry_offsets[i];
  p.node_entries.resize(m.element_vertices.size());
  p.entry_slot.resize(m.element_vertices.size());
  std::vector<std::int32_t> fill(p.node_entry_offsets.begin(), p.node_entry_offsets.end() - 1);
  for (std::size_t j = 0; j < m.element_vertices.size(); ++j) {
    const std::int32_t slot = fill[std::size_t(m.element_vertices[j])]++;
    p.node_entries[std::size_t(slot)] = std::int32_t(j);
    p.entry_slot[j] = slot;
  }
  p.entry_packed.reserve(m.element_vertices.size());
  prefer_huge_pages(p.entry_packed.data(), m.element_vertices.size() * sizeof(PackedEntry));
  p.entry_packed.resize(m.element_vertices.size());
  for (std::size_t j = 0; j < m.element_vertices.size(); ++j) {
    PackedEntry& pe = p.entry_packed[j];
    for (int d = 0; d < 3; ++d) {
      pe.rest_weighted[d] = p.entry_rest_weighted(d, std::int64_t(j));
      pe.gradient[d] = p.entry_gradient(d, std::int64_t(j));
    }
    pe.weight = p.entry_weight[j];
    pe.vertex = m.element_vertices[j];
    pe.slot = p.entry_slot[j];
  }
}

}  // namespace

void node_gershgorin_sums(const PhysicsModel& p, std::vector<double>& sk, std::vector<double>& sc) {
  const Model& m = *p.model;
  const int nn = p.num_nodes(), ne = p.num_elements();
  sk.assign(std::size_t(nn), 0.0);
  sc.assign(std::size_t(nn), 0.0);
  Eigen::MatrixXd ke;
  for (int e = 0; e < ne; ++e) {
    const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
    const double c = p.element_damping[std::size_t(e)];
    double wsum = 0;
    for (int j = b; j < b + n; ++j) wsum += p.entry_weight[std::size_t(j)];
    // the elastic matrix K_e (with the volume term's k_v g g^T), and 2 w_i (1 - w_i / W) of
    // diag(w) - w w^T / W for the damping term. The hourglass element's K_e is the paper's less its (positive) relief,
    // so the paper's K_e bounds its frequencies; its own smaller row sums would raise the
    // explicit Euler ratio sc / sk above the limit of the modes it does not relieve (measured: a
    // damped block ran away at 0.9 times that estimate; docs/model.md section 7)
    element_elastic_matrix(p, e, ke, false);
    for (int j = b; j < b + n; ++j) {
      const double w = p.entry_weight[std::size_t(j)];
      const double row = 2.0 * w * (1.0 - w / wsum);
      sk[std::size_t(m.element_vertices[j])] += ke.row(j - b).cwiseAbs().sum();
      sc[std::size_t(m.element_vertices[j])] += row * c;
    }
  }
}

double mass_for_time_step(double sk, double sc, double dt) {
  // dt(m) = (sqrt(4 sk m + sc^2) - sc) / sk >= D  <=>  4 sk m >= (D sk + sc)^2 - sc^2
  return 0.25 * dt * dt * sk + 0.5 * dt * sc;
}

std::shared_ptr<const PhysicsModel> make_physics_model(std::shared_ptr<const Model> model_ptr, const Material& material,
                                                       const MaterialField& field, const CalibrationOptions& options,
                                                       CalibrationCache* cache) {
  check_inputs(model_ptr.get(), material, field, options);
  auto p = std::make_shared<PhysicsModel>();
  p->model = std::move(model_ptr);
  p->material = material;
  p->element = options.element;
  set_plane(*p);
  // the calibrated part: the per-element work, loaded when the cache holds it
  CalibrationKey key;
  if (cache) key = calibration_key(*p->model, material, field, options);
  if (!cache || !cache->load(key, *p)) {
    const auto t0 = std::chrono::steady_clock::now();
    allocate(*p);
    std::vector<double> anisotropy;
    std::vector<std::uint8_t> bad;
    calibrate_elements(*p, field, options, anisotropy, bad);
    set_gradients(*p, bad);
    set_volume_points(*p, options);
    set_bending_modes(*p, options);
    lump_masses(*p, anisotropy, bad);
    if (cache) cache->store(key, p, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  // the derived part: fields of its own (the cache may still be writing the calibrated part)
  set_node_masses(*p);
  index_entries(*p);
  build_element_batches(*p, kElementGrain, p->element_batches);
  scale_masses(*p, options.mass_scaling);
  // derived constants of the integrators
  p->damped = std::any_of(p->element_damping.begin(), p->element_damping.end(), [](double c) { return c > 0; });
  const Eigen::Matrix3Xd& r = p->model->rest_positions;
  p->rest_diagonal_mm = (r.rowwise().maxCoeff() - r.rowwise().minCoeff()).norm();
  return p;
}

std::shared_ptr<const PhysicsModel> make_physics_model(std::shared_ptr<const Model> model, const Material& material,
                                                       const MaterialField& field, const CalibrationOptions& options) {
  return make_physics_model(std::move(model), material, field, options, nullptr);
}

std::shared_ptr<const PhysicsModel> make_physics_model(const Model& model, const Material& material,
                                                       const MaterialField& field, const CalibrationOptions& options) {
  return make_physics_model(std::make_shared<const Model>(model), material, field, options);
}

}  // namespace vx
