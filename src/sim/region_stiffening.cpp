#include "sim/region_stiffening.h"

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCore>
#include <chrono>
#include <cmath>
#include <limits>

#include "base/content_hash.h"
#include "sim/projective_solver.h"

namespace vx {

namespace {

/// The stiffness of the free nodes (n x c displacements u -> forces, c = 1 or 3): K u (the
/// projective matrix per coordinate, plus `shift` m/dt^2 per node); with 3 columns also less each
/// element's rotation curvature a_e skew(H_e) g_i with H_e = sum_j u_j g_j^T and a_e = 2 mu V
/// (the tangent at rest: the projective matrix charges a small rotation mu V |skew H|^2 that the
/// element's rotation fit gives back, elements.h).
struct Tangent {
  const PhysicsModel& p;
  const Eigen::SparseMatrix<double>& k_lower;
  const Eigen::VectorXd* shift;  ///< per free node, N/mm (null: none)
  const std::vector<int>& free_index;

  void apply(const Eigen::MatrixXd& u, Eigen::MatrixXd& y) const {
    y.noalias() = k_lower.selfadjointView<Eigen::Lower>() * u;
    if (shift) y += shift->asDiagonal() * u;
    if (u.cols() != 3) return;
    const Model& m = *p.model;
    for (int e = 0; e < p.num_elements(); ++e) {
      const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
      Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
      for (int j = b; j < b + n; ++j)
        if (const int f = free_index[std::size_t(m.element_vertices[j])]; f >= 0)
          h.noalias() += u.row(f).transpose() * p.entry_gradient.col(j).transpose();
      const Eigen::Matrix3d skew = 0.5 * p.element_affine_stiffness[std::size_t(e)] * (h - h.transpose());
      for (int j = b; j < b + n; ++j)
        if (const int f = free_index[std::size_t(m.element_vertices[j])]; f >= 0)
          y.row(f) -= (skew * p.entry_gradient.col(j)).transpose();
    }
  }
};

/// Conjugate gradients on T u = f preconditioned per coordinate by `ic`; returns the sum of
/// f . u (NaN when it did not converge) and the iterations.
template <class Preconditioner>
double compliance(const Tangent& t, const Preconditioner& ic, const Eigen::MatrixXd& f,
                  const RegionStiffeningSettings& s, int& iterations) {
  const Eigen::Index n = f.rows(), cols = f.cols();
  Eigen::MatrixXd x = Eigen::MatrixXd::Zero(n, cols), r = f, z(n, cols), p, q(n, cols);
  const auto precondition = [&](const Eigen::MatrixXd& in, Eigen::MatrixXd& out) {
    for (Eigen::Index c = 0; c < cols; ++c) out.col(c) = ic.solve(in.col(c));
  };
  precondition(r, z);
  p = z;
  double rz = (r.array() * z.array()).sum();
  const double f_norm = f.norm();
  iterations = 0;
  for (; iterations < s.max_iterations; ++iterations) {
    if (r.norm() <= s.tolerance * f_norm) return (f.array() * x.array()).sum();
    if (s.cancel && s.cancel->load(std::memory_order_relaxed)) break;
    t.apply(p, q);
    const double alpha = rz / (p.array() * q.array()).sum();
    if (!(alpha > 0) || !std::isfinite(alpha)) break;
    x += alpha * p;
    r -= alpha * q;
    precondition(r, z);
    const double rz_next = (r.array() * z.array()).sum();
    p = z + (rz_next / rz) * p;
    rz = rz_next;
  }
  return r.norm() <= s.tolerance * f_norm ? (f.array() * x.array()).sum() : std::numeric_limits<double>::quiet_NaN();
}

/// Raised when what an estimate computes from the same input changes (its cached files then miss).
constexpr std::uint32_t kEstimateVersion = 1;

/// The content an estimate is computed from (RegionStiffeningCache's key).
std::uint64_t estimate_key(const PhysicsModel& p, const Eigen::SparseMatrix<double>& k_lower, const Eigen::MatrixXd& f,
                           const Eigen::VectorXd& held, const std::vector<int>& free_index,
                           const RegionStiffeningSettings& s) {
  ContentHash h;
  h.add_value(kEstimateVersion);
  h.add_value(std::int32_t(s.rotation_curvature));
  h.add_value(s.tolerance);
  h.add_value(std::int32_t(s.max_iterations));
  h.add_value(std::int64_t(k_lower.rows()));
  h.add_value(std::int64_t(k_lower.nonZeros()));
  h.add(k_lower.outerIndexPtr(), sizeof(int) * std::size_t(k_lower.outerSize() + 1));
  h.add(k_lower.innerIndexPtr(), sizeof(int) * std::size_t(k_lower.nonZeros()));
  h.add(k_lower.valuePtr(), sizeof(double) * std::size_t(k_lower.nonZeros()));
  h.add_matrix(f);
  h.add_matrix(held);
  h.add_vector(free_index);
  if (s.rotation_curvature) {
    h.add_vector(p.model->element_offsets);
    h.add_vector(p.model->element_vertices);
    h.add_matrix(p.entry_gradient);
    h.add_vector(p.element_affine_stiffness);
  }
  return h.value();
}

}  // namespace

RegionStiffeningEstimate estimate_region_stiffening(const PhysicsModel& p, const std::vector<std::uint8_t>& node_fixed,
                                                    const RegionStiffeningSettings& s) {
  const auto start = std::chrono::steady_clock::now();
  RegionStiffeningEstimate out;
  const auto done = [&](std::string reason) {
    out.reason = std::move(reason);
    out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return out;
  };
  const int nn = p.num_nodes();
  if (int(node_fixed.size()) != nn) return done("node_fixed has the wrong size");
  if (!(s.region_radius_mm > 0) || !(s.time_step_s > 0)) return done("no region");
  const NodeNumbering numbering = number_nodes(node_fixed);
  const std::vector<int>& free_index = numbering.free_index;
  const std::vector<int>& free_nodes = numbering.free_nodes;
  if (numbering.fixed_nodes.empty()) return done("no node is fixed (the whole model floats)");
  if (free_nodes.empty()) return done("every node is fixed");
  const Eigen::Matrix3Xd& x = p.model->rest_positions;
  // the load: the free nodes within the tool's radius of the free node nearest to the tool
  int nearest = -1;
  double best = std::numeric_limits<double>::infinity();
  for (int i : free_nodes)
    if (const double d = (x.col(i) - s.tool_mm).squaredNorm(); d < best) best = d, nearest = i;
  const int nf = int(free_nodes.size());
  // pressed towards that node (down when the tool sits on it)
  Eigen::Vector3d dir = x.col(nearest) - s.tool_mm;
  dir = dir.norm() > 1e-9 ? Eigen::Vector3d(dir.normalized()) : Eigen::Vector3d(0, 0, -1);
  Eigen::MatrixXd f = Eigen::MatrixXd::Zero(nf, s.rotation_curvature ? 3 : 1);
  std::vector<int> load;
  const double r_load2 = s.tool_radius_mm * s.tool_radius_mm;
  for (int k = 0; k < nf; ++k)
    if ((x.col(free_nodes[std::size_t(k)]) - x.col(nearest)).squaredNorm() <= r_load2) load.push_back(k);
  for (int k : load) {
    if (s.rotation_curvature)
      f.row(k) = dir.transpose() / double(load.size());
    else
      f(k, 0) = 1.0 / double(load.size());
  }
  out.load_nodes = int(load.size());
  // K: the static matrix (no mass, no damping term); K + D_far: the far field held by m / dt^2
  ProjectiveSetup stat;
  stat.inertia = false;
  stat.damping = false;
  stat.time_step_s = 1.0;
  Eigen::SparseMatrix<double> k_lower;  // the lower triangle, as assembled
  assemble_projective_matrix(p, numbering, stat, k_lower, nullptr);
  Eigen::VectorXd held = Eigen::VectorXd::Zero(nf);
  const double r2 = s.region_radius_mm * s.region_radius_mm, inv_dt2 = 1.0 / (s.time_step_s * s.time_step_s);
  for (int kf = 0; kf < nf; ++kf) {
    const int i = free_nodes[std::size_t(kf)];
    if ((x.col(i) - s.tool_mm).squaredNorm() <= r2) {
      ++out.region_nodes;
    } else {
      ++out.far_nodes;
      held(kf) = p.node_mass[std::size_t(i)] * inv_dt2;
    }
  }
  if (out.far_nodes == 0) {
    out.valid = true;
    out.force_ratio = 1.0;
    return done("the region covers the whole model");
  }
  // the same content solved before: its estimate
  std::uint64_t key = 0;
  if (s.cache) {
    k_lower.makeCompressed();
    key = estimate_key(p, k_lower, f, held, free_index, s);
    if (std::optional<RegionStiffeningEstimate> kept = s.cache->load(key, nf);
        kept && kept->valid && kept->region_nodes == out.region_nodes && kept->far_nodes == out.far_nodes &&
        kept->load_nodes == out.load_nodes) {
      out = *kept;
      out.loaded = true;
      return done("");
    }
  }
  // one preconditioner for both: an incomplete Cholesky factor of K (D_far is a small shift), in
  // the model's own node order. An AMD ordering (fill-reducing, which an incomplete factor with a
  // fixed pattern does not need) made a full symmetric copy of K, and converged slower: 28 + 25
  // CG iterations against 23 + 20 on region_stiffening_slow_test's stem
  Eigen::IncompleteCholesky<double, Eigen::Lower, Eigen::NaturalOrdering<int>> ic;
  ic.compute(k_lower);
  if (ic.info() != Eigen::Success) return done("the incomplete factor failed");
  out.compliance_full_mm_n = compliance(Tangent{p, k_lower, nullptr, free_index}, ic, f, s, out.iterations_full);
  out.compliance_region_mm_n = compliance(Tangent{p, k_lower, &held, free_index}, ic, f, s, out.iterations_region);
  if (s.cancel && s.cancel->load()) return done("cancelled");
  if (!std::isfinite(out.compliance_full_mm_n) || !std::isfinite(out.compliance_region_mm_n) ||
      !(out.compliance_region_mm_n > 0))
    return done("the solve did not converge (a part of the model held by nothing?)");
  out.force_ratio = out.compliance_full_mm_n / out.compliance_region_mm_n;
  out.valid = true;
  done("");
  if (s.cache) s.cache->store(key, nf, out);
  return out;
}

}  // namespace vx
