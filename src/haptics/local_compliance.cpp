#include "haptics/local_compliance.h"

#include <algorithm>
#include <cmath>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include "base/error.h"
#include "sim/projective_solver.h"

namespace vx {

double poisson_compliance_stiffening(double nu) { return nu > 0 ? 1.0 / (1.0 - nu) : 1.0; }

void PatchCompliance::init(std::shared_ptr<const PhysicsModel> physics, const std::vector<std::uint8_t>& node_fixed,
                           double horizon_s) {
  if (!physics || !physics->model) throw Error("patch compliance: no physics model");
  if (!(horizon_s > 0) || !std::isfinite(horizon_s)) throw Error("patch compliance: the horizon must be > 0 s");
  physics_ = std::move(physics);
  fixed_ = node_fixed;
  horizon_ = horizon_s;
  const int nn = physics_->num_nodes();
  fixed_.resize(std::size_t(nn), 0);
  free_nodes_ = std::size_t(std::count(fixed_.begin(), fixed_.end(), std::uint8_t(0)));
  patch_index_.assign(std::size_t(nn), -1);
  has_patch_ = false;
  refactors_ = 0;
  columns_solved_ = 0;
}

bool PatchCompliance::build_patch(const Eigen::Vector3d& centre, double radius_mm) {
  const PhysicsModel& p = *physics_;
  const Eigen::Matrix3Xd& rest = p.model->rest_positions;
  const int nn = p.num_nodes();
  for (const int i : patch_nodes_) patch_index_[std::size_t(i)] = -1;
  patch_nodes_.clear();
  const double r2 = radius_mm * radius_mm;
  for (int i = 0; i < nn; ++i)
    if (!fixed_[std::size_t(i)] && (rest.col(i) - centre).squaredNorm() <= r2) {
      patch_index_[std::size_t(i)] = int(patch_nodes_.size());
      patch_nodes_.push_back(i);
    }
  const int np = int(patch_nodes_.size());
  // the patch's block of A_T (the nodes beyond it held), assembled from the elements that touch
  // the patch: A_T over the whole model was kept once (issue 25: about 60 MB for its lower
  // triangle on the 1 mm folded organ, and twice that in triplets at the start-up)
  const Model& m = *p.model;
  const int ne = p.num_elements();
  const double t = horizon_;
  ProjectiveSetup setup;  // the implicit integrator's matrix at the horizon T
  setup.time_step_s = t;
  setup.damping = p.damped;
  trip_.clear();
  for (int e = 0; e < ne; ++e) {
    const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
    const int* v = m.element_vertices.data() + b;
    bool touches = false;
    for (int i = 0; i < n && !touches; ++i) touches = patch_index_[std::size_t(v[i])] >= 0;
    if (!touches) continue;
    // the volume term left out, its effect on the contact a factor in nu (the header)
    for_each_projective_entry(
        p, e, setup, ke_,
        [&](int a, int c, double value) {
          const int pa = patch_index_[std::size_t(v[a])], pc = patch_index_[std::size_t(v[c])];
          if (pa >= 0 && pc >= 0) trip_.emplace_back(pa, pc, value);
        },
        false, poisson_compliance_stiffening(p.material.poisson_ratio));
  }
  for (int k = 0; k < np; ++k)
    trip_.emplace_back(k, k, p.node_mass[std::size_t(patch_nodes_[std::size_t(k)])] / (t * t));
  patch_matrix_.resize(np, np);
  patch_matrix_.setFromTriplets(trip_.begin(), trip_.end());
  // Eigen's simplicial LDL^T on an AMD ordering, not the whole model's CHOLMOD with METIS: on the
  // 1 mm folded organ's patches (1,000-9,000 nodes at 12-24 mm) it factors 2.5-3.3x faster (8.9
  // against 29.4 ms at 12 mm, 86 against 219 ms at 24 mm; METIS's ordering is the difference)
  // and a new patch with its columns costs half (probe_release_slow_test's DISABLED_PatchMemory)
  has_patch_ = np > 0 && factor_.compute(patch_matrix_, SparseFactor::Backend::eigen_amd);
  centre_ = centre;
  radius_ = radius_mm;
  column_slot_.assign(std::size_t(np), -1);
  // the columns' buffer grows only for a patch larger than any before, and then with half as
  // much again to spare (at most the model's free nodes): a session meets patches of a few sizes
  // around the first (the CI soak at 0.45: 1,368 nodes, then 1,558), so the buffer moves once or
  // twice, not at every larger patch
  const std::size_t need = std::size_t(np) * std::size_t(kCacheColumns);
  if (columns_.size() < need) {
    const std::size_t spare = std::min<std::size_t>(std::size_t(np) + std::size_t(np) / 2, free_nodes_);
    columns_.clear();
    columns_.shrink_to_fit();
    columns_.resize(std::max(spare * std::size_t(kCacheColumns), need));
  }
  slot_column_.reserve(std::size_t(kCacheColumns));
  slot_column_.clear();
#if defined(__GLIBC__)
  // the old factor, the factorisation's work space and a smaller patch's columns (megabytes,
  // another size each patch) were freed into the heap, which glibc keeps: without this the
  // resident memory climbs with the patches visited though the live heap stays the same (issue
  // 27: +2.5 MB over 200 patches of the soak's organ, probe_release_slow_test's PatchMemory; with
  // it, the live patch's size). Last, after the columns' buffer has moved: trimmed before it, the
  // CI soak at 0.45 kept the first patch's 2.8 MB of columns when a larger patch came (+2.85 %).
  malloc_trim(0);
#endif
  ++refactors_;
  return has_patch_;
}

std::size_t PatchCompliance::cache_bytes() const {
  return columns_.capacity() * sizeof(double) + (column_slot_.capacity() + slot_column_.capacity()) * sizeof(int) +
         trip_.capacity() * sizeof(Eigen::Triplet<double>) +
         std::size_t(patch_matrix_.data().allocatedSize()) * (sizeof(double) + sizeof(int)) +
         std::size_t(patch_matrix_.outerSize() + 1) * sizeof(int);
}

bool PatchCompliance::compute(const std::vector<std::int32_t>& nodes, double radius_mm, Eigen::MatrixXd& g) {
  if (!physics_) return false;
  const int m = int(nodes.size());
  g.resize(m, m);
  if (m == 0) return true;
  const Eigen::Matrix3Xd& rest = physics_->model->rest_positions;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const int i : nodes) {
    if (i < 0 || i >= physics_->num_nodes() || fixed_[std::size_t(i)]) return false;
    centre += rest.col(i);
  }
  centre /= m;
  // a contact wider than the patch asked for (a rod lying along the tissue, a plate) gets one
  // wide enough for it, its nodes in the inner three quarters; the radius doubles, so that the
  // steps of one wide contact keep their patch while its extent drifts
  if (!(radius_mm > 0) || !std::isfinite(radius_mm)) return false;
  double extent = 0.0;
  for (const int i : nodes) extent = std::max(extent, (rest.col(i) - centre).norm());
  double radius = radius_mm;
  while (extent > 0.75 * radius) radius *= 2.0;
  // keep the patch while the contact stays near its centre and inside its inner part
  bool keep = has_patch_ && radius_ == radius && (centre - centre_).norm() <= 0.25 * radius;
  for (int a = 0; a < m && keep; ++a)
    keep = patch_index_[std::size_t(nodes[std::size_t(a)])] >= 0 &&
           (rest.col(nodes[std::size_t(a)]) - centre_).norm() <= 0.75 * radius;
  if (!keep && !build_patch(centre, radius)) return false;
  // columns of the nodes (cached per patch, at most kCacheColumns: when this contact's new ones
  // do not fit, the cache starts over with this contact's)
  if (m > kCacheColumns) return false;
  int missing = 0;
  for (int a = 0; a < m; ++a) {
    const int k = patch_index_[std::size_t(nodes[std::size_t(a)])];
    if (k < 0) return false;  // not in the patch (cannot happen: the radius holds the contact)
    missing += column_slot_[std::size_t(k)] < 0 ? 1 : 0;
  }
  if (cached_columns() + missing > kCacheColumns) {
    for (const int k : slot_column_) column_slot_[std::size_t(k)] = -1;
    slot_column_.clear();
    ++cache_restarts_;
  }
  const std::size_t np = patch_nodes_.size();
  // the missing columns take the next slots, solved together (SparseFactor::solve_units: one pass
  // over the patch's factor for every kUnitLanes; the slide of the folded organ's press solves about
  // 300, 7 ms each one at a time)
  const int first_slot = cached_columns();
  for (int a = 0; a < m; ++a) {
    const int k = patch_index_[std::size_t(nodes[std::size_t(a)])];
    if (column_slot_[std::size_t(k)] < 0) {
      column_slot_[std::size_t(k)] = cached_columns();
      slot_column_.push_back(k);
    }
  }
  const int solved = cached_columns() - first_slot;
  factor_.solve_units(slot_column_.data() + first_slot, solved, columns_.data() + std::size_t(first_slot) * np, np);
  columns_solved_ += solved;
  for (int a = 0; a < m; ++a) {
    const double* col =
        columns_.data() + std::size_t(column_slot_[std::size_t(patch_index_[std::size_t(nodes[std::size_t(a)])])]) * np;
    for (int b = 0; b < m; ++b) g(b, a) = col[patch_index_[std::size_t(nodes[std::size_t(b)])]];
  }
  g = 0.5 * (g + g.transpose()).eval();  // symmetric to the last bit
  return true;
}

}  // namespace vx
