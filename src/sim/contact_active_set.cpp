#include "sim/contact_active_set.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "base/parallel.h"
#include "physics/elements.h"

namespace vx {

namespace {

/// Nodes per chunk of the re-check's copy of the constrained iterate.
constexpr std::int64_t kTrialGrain = 1024;

bool key_less(const ContactConstraint& a, const ContactConstraint& b) {
  return a.owner != b.owner ? a.owner < b.owner : a.node < b.node;
}

/// Solves S lambda = d in place (S: n x n row-major, symmetric positive definite; lower
/// triangle used) by Cholesky. S is the Hadamard product of the normals' Gram matrix and G,
/// positive definite unless one node has two parallel constraints; a pivot below 1e-12 of its
/// diagonal (that case) is raised to it, which splits the force between them.
void dense_solve(double* a, int n, double* b) {
  for (int j = 0; j < n; ++j) {
    double piv = a[j * n + j];
    for (int k = 0; k < j; ++k) piv -= a[j * n + k] * a[j * n + k];
    const double floor = 1e-12 * std::abs(a[j * n + j]);
    piv = std::sqrt(std::max(piv, floor > 0 ? floor : 1e-300));
    a[j * n + j] = piv;
    for (int i = j + 1; i < n; ++i) {
      double v = a[i * n + j];
      for (int k = 0; k < j; ++k) v -= a[i * n + k] * a[j * n + k];
      a[i * n + j] = v / piv;
    }
  }
  for (int i = 0; i < n; ++i) {
    double v = b[i];
    for (int k = 0; k < i; ++k) v -= a[i * n + k] * b[k];
    b[i] = v / a[i * n + i];
  }
  for (int i = n - 1; i >= 0; --i) {
    double v = b[i];
    for (int k = i + 1; k < n; ++k) v -= a[k * n + i] * b[k];
    b[i] = v / a[i * n + i];
  }
}

}  // namespace

void ContactActiveSet::bind(const std::vector<int>& free_index, const std::vector<int>& free_nodes) {
  free_index_ = &free_index;
  free_nodes_ = &free_nodes;
  const int nf = num_free();
  // written (zeros) so that their pages are mapped here, with the solver's other buffers
  // (ProjectiveSolver's constructor), not at the first contact solve
  unconstrained_.setZero(nf, 3);
  trial_.setZero(3, Eigen::Index(free_index.size()));
  column_slot_.assign(std::size_t(nf), -1);
  slot_free_.clear();
  slot_last_used_.clear();
  used_slots_ = 0;
  forward_bytes_ = 0;
  for (auto& z : forward_) z.value.clear();
  gram_.setConstant(std::numeric_limits<double>::quiet_NaN());
  reserved_ = false;
}

void ContactActiveSet::reserve(const SparseFactor& factor) {
  const auto [values, segments] = factor.longest_unit_forward();
  const double per_slot = double(values) * sizeof(double) + double(segments) * (2 * sizeof(int) + sizeof(std::int64_t));
  int slots = std::min(kMaxSlots, num_free());
  slots = std::max(std::min(slots, 16), std::min(slots, int(kColumnBudgetBytes / std::max(per_slot, 1.0))));
  if (int(forward_.size()) < slots) grow_slots(slots);
  gram_.setConstant(std::numeric_limits<double>::quiet_NaN());  // written once: resident
  for (SparseFactor::UnitForward& z : forward_) {
    // written once at the longest size (resident), then emptied: the capacity stays
    z.value.assign(std::size_t(values), 0.0);
    z.first.assign(std::size_t(segments), 0);
    z.count.assign(std::size_t(segments), 0);
    z.offset.assign(std::size_t(segments), 0);
    z.value.clear(), z.first.clear(), z.count.clear(), z.offset.clear();
  }
  used_slots_ = 0;
  forward_bytes_ = 0;
  column_slot_.assign(std::size_t(num_free()), -1);
  std::fill(slot_free_.begin(), slot_free_.end(), -1);
  std::fill(slot_last_used_.begin(), slot_last_used_.end(), 0);
  reserved_ = true;
}

std::size_t ContactActiveSet::cache_bytes() const {
  std::size_t bytes = std::size_t(gram_.size()) * sizeof(double);
  for (const SparseFactor::UnitForward& z : forward_)
    bytes += z.value.capacity() * sizeof(double) + z.first.capacity() * sizeof(int) + z.count.capacity() * sizeof(int) +
             z.offset.capacity() * sizeof(std::int64_t);
  return bytes;
}

/// Room for `capacity` slots; the cached columns and G entries keep their slots (the new
/// entries of G are NaN: not yet computed).
void ContactActiveSet::grow_slots(int capacity) {
  forward_.resize(std::size_t(capacity));
  Eigen::MatrixXd g = Eigen::MatrixXd::Constant(capacity, capacity, std::numeric_limits<double>::quiet_NaN());
  g.topLeftCorner(gram_.rows(), gram_.cols()) = gram_;
  gram_.swap(g);
  slot_free_.resize(std::size_t(capacity), -1);
  slot_last_used_.resize(std::size_t(capacity), 0);
}

/// The slot of free node f, solving its forward vector when it has none (allocates when the
/// cache grows).
int ContactActiveSet::column_of(int f, SparseFactor& factor, ContactSolveCounters& counters) {
  int slot = column_slot_[std::size_t(f)];
  if (slot < 0) {
    if (used_slots_ < int(forward_.size()) ||
        (!reserved_ && used_slots_ < kMaxSlots && double(forward_bytes_) < kColumnBudgetBytes)) {
      slot = used_slots_++;
      if (slot >= int(forward_.size())) grow_slots(int(forward_.size()) + std::max(16, int(forward_.size())));
    } else {
      // full: reuse the least recently used slot (never one of this solve)
      std::int64_t oldest = solve_count_;
      for (int k = 0; k < used_slots_; ++k)
        if (slot_last_used_[std::size_t(k)] < oldest) oldest = slot_last_used_[std::size_t(k)], slot = k;
      if (slot < 0) {  // all in use now: grow beyond the budget
        grow_slots(int(forward_.size()) + 16);
        slot = used_slots_++;
      } else {
        column_slot_[std::size_t(slot_free_[std::size_t(slot)])] = -1;
        forward_bytes_ -= forward_[std::size_t(slot)].bytes();
        gram_.row(slot).setConstant(std::numeric_limits<double>::quiet_NaN());
        gram_.col(slot).setConstant(std::numeric_limits<double>::quiet_NaN());
      }
    }
    factor.forward_unit(f, forward_[std::size_t(slot)]);  // the factor's rows are the free indices
    forward_bytes_ += forward_[std::size_t(slot)].bytes();
    column_slot_[std::size_t(f)] = slot;
    slot_free_[std::size_t(slot)] = f;
    ++counters.columns;
  }
  slot_last_used_[std::size_t(slot)] = solve_count_;
  return slot;
}

double ContactActiveSet::gram(int a, int b) {
  double& g = gram_(a, b);
  if (std::isnan(g)) {
    g = SparseFactor::dot(forward_[std::size_t(a)], forward_[std::size_t(b)]);
    gram_(b, a) = g;
  }
  return g;
}

/// Position of candidate c's node for the current multipliers of the working set.
Eigen::Vector3d ContactActiveSet::constrained_position(int c, SparseFactor& factor, ContactSolveCounters& counters) {
  const int f = candidate_free_[std::size_t(c)];
  Eigen::Vector3d xi = unconstrained_.row(f).transpose();
  if (working_.empty()) return xi;
  const int slot = column_of(f, factor, counters);
  for (std::size_t b = 0; b < working_.size(); ++b)
    xi += gram(slot, working_column_[b]) *
          Eigen::Vector3d(working_force_[3 * b], working_force_[3 * b + 1], working_force_[3 * b + 2]);
  return xi;
}

/// Active-set iteration on the candidates with x_u = unconstrained_; leaves the multipliers in
/// candidates_[c].force_n (0 off the working set) and working_force_/working_column_ for the
/// working set. Returns the rounds taken.
int ContactActiveSet::iterate_working_set(SparseFactor& factor, ContactSolveCounters& counters) {
  const int nc = int(candidates_.size());
  int round = 1;
  for (;; ++round) {
    working_.clear();
    for (int c = 0; c < nc; ++c) {
      candidates_[std::size_t(c)].force_n = 0.0;
      if (in_working_set_[std::size_t(c)]) working_.push_back(c);
    }
    const int nw = int(working_.size());
    working_column_.resize(std::size_t(nw));
    working_force_.resize(3 * std::size_t(nw));
    schur_.resize(std::size_t(nw) * std::size_t(nw));
    schur_rhs_.resize(std::size_t(nw));
    for (int a = 0; a < nw; ++a)
      working_column_[std::size_t(a)] =
          column_of(candidate_free_[std::size_t(working_[std::size_t(a)])], factor, counters);
    // S_ab = (n_a . n_b) G_ab, d_a = n_a . (p_a - x_u,a)
    for (int a = 0; a < nw; ++a) {
      const ContactConstraint& ca = candidates_[std::size_t(working_[std::size_t(a)])];
      const int fa = candidate_free_[std::size_t(working_[std::size_t(a)])];
      for (int b = 0; b <= a; ++b) {
        const ContactConstraint& cb = candidates_[std::size_t(working_[std::size_t(b)])];
        schur_[std::size_t(a * nw + b)] =
            ca.normal.dot(cb.normal) * gram(working_column_[std::size_t(a)], working_column_[std::size_t(b)]);
      }
      schur_rhs_[std::size_t(a)] = ca.normal.dot(ca.point_mm - unconstrained_.row(fa).transpose());
    }
    if (nw > 0) dense_solve(schur_.data(), nw, schur_rhs_.data());
    // the members that pull leave the working set
    bool pulled = false;
    for (int a = 0; a < nw; ++a) {
      const int c = working_[std::size_t(a)];
      const double lambda = schur_rhs_[std::size_t(a)];
      candidates_[std::size_t(c)].force_n = lambda;
      const Eigen::Vector3d ln = lambda * candidates_[std::size_t(c)].normal;
      for (int k = 0; k < 3; ++k) working_force_[3 * std::size_t(a) + std::size_t(k)] = ln[k];
      if (!(lambda >= 0.0)) {  // pulls (or NaN)
        in_working_set_[std::size_t(c)] = 0;
        pulled = true;
      }
    }
    if (round >= kMaxRounds) break;
    if (pulled) continue;
    // the candidates off the working set that the solution pushes through their surface join it
    bool added = false;
    for (int c = 0; c < nc; ++c) {
      if (in_working_set_[std::size_t(c)]) continue;
      const ContactConstraint& cc = candidates_[std::size_t(c)];
      if (cc.normal.dot(constrained_position(c, factor, counters) - cc.point_mm) < -kGapToleranceMm) {
        in_working_set_[std::size_t(c)] = 1;
        added = true;
      }
    }
    if (!added) break;
  }
  // (not converged within the rounds: keep the multipliers that push; the rest are zero)
  for (std::size_t a = 0; a < working_.size(); ++a)
    if (!(candidates_[std::size_t(working_[a])].force_n >= 0.0)) {
      candidates_[std::size_t(working_[a])].force_n = 0.0;
      for (int k = 0; k < 3; ++k) working_force_[3 * a + std::size_t(k)] = 0.0;
    }
  return round;
}

/// solution = x_u + sum over the working set of G e_j lambda_j n_j^T: one backward pass for all
/// of them (SparseFactor::add_response3), on the region's rows with regional solves.
/// With `from_forward`, one backward pass gives x_u and the response together on the closure.
void ContactActiveSet::apply_working_forces(Eigen::MatrixX3d& solution, SparseFactor& factor, bool from_forward) {
  if (!from_forward) solution = unconstrained_;
  working_forward_.clear();
  for (std::size_t b = 0; b < working_.size(); ++b)
    working_forward_.push_back(&forward_[std::size_t(working_column_[b])]);
  if (from_forward)
    factor.backward3_partial(working_forward_, working_force_, solution);
  else if (!working_.empty())
    factor.add_response3(working_forward_, working_force_, solution, partial_);
}

void ContactActiveSet::unconstrained_from_forward(std::size_t from, SparseFactor& factor,
                                                  ContactSolveCounters& counters) {
  for (std::size_t c = from; c < candidates_.size(); ++c) {
    const int f = candidate_free_[c];
    unconstrained_.row(f) = factor.solution_row(forward_[std::size_t(column_of(f, factor, counters))]).transpose();
  }
}

/// Keeps the candidates from `from` on whose nodes are free and records their free indices.
void ContactActiveSet::index_candidates(std::size_t from) {
  const std::vector<int>& free_index = *free_index_;
  std::size_t k = from;
  for (std::size_t c = from; c < candidates_.size(); ++c)
    if (candidates_[c].node >= 0 && std::size_t(candidates_[c].node) < free_index.size() &&
        free_index[std::size_t(candidates_[c].node)] >= 0)
      candidates_[k++] = candidates_[c];
  candidates_.resize(k);
  candidate_free_.resize(k);
  in_working_set_.resize(k, 0);
  for (std::size_t c = from; c < k; ++c) candidate_free_[c] = free_index[std::size_t(candidates_[c].node)];
}

void ContactActiveSet::compliance(const std::vector<int>& free, SparseFactor& factor, Eigen::MatrixXd& g) {
  ++solve_count_;  // the columns of this call are not reused for one another
  const int m = int(free.size());
  g.resize(m, m);
  ContactSolveCounters counters;
  std::vector<int> slot(static_cast<std::size_t>(m));
  for (int a = 0; a < m; ++a) slot[std::size_t(a)] = column_of(free[std::size_t(a)], factor, counters);
  for (int a = 0; a < m; ++a)
    for (int b = 0; b < m; ++b) g(b, a) = gram(slot[std::size_t(b)], slot[std::size_t(a)]);
}

void ContactActiveSet::solve(ContactProvider& provider, const Eigen::Matrix3Xd& x, SparseFactor& factor,
                             Eigen::MatrixX3d& solution, ContactSolveCounters& counters, bool from_forward) {
  const std::vector<int>& free_index = *free_index_;
  ++solve_count_;
  if (!from_forward) unconstrained_ = solution;
  // candidates near the surfaces at the current iterate, sorted by (owner, node)
  candidates_.clear();
  provider.collect(x, true, candidates_);
  index_candidates(0);
  std::sort(candidates_.begin(), candidates_.end(), key_less);
  for (std::size_t c = 0; c < candidates_.size(); ++c)
    candidate_free_[c] = free_index[std::size_t(candidates_[c].node)];
  if (from_forward) unconstrained_from_forward(0, factor, counters);
  // warm start: the last solve's active set (both sorted by key)
  std::fill(in_working_set_.begin(), in_working_set_.end(), std::uint8_t(0));
  for (std::size_t c = 0, a = 0; c < candidates_.size() && a < active_.size();) {
    if (key_less(candidates_[c], active_[a])) {
      ++c;
    } else if (key_less(active_[a], candidates_[c])) {
      ++a;
    } else {
      in_working_set_[c] = 1;
      ++c;
      ++a;
    }
  }
  const std::size_t sorted = candidates_.size();
  for (int pass = 0;; ++pass) {
    counters.rounds += iterate_working_set(factor, counters);
    apply_working_forces(solution, factor, from_forward);
    if (pass + 1 >= kMaxPasses) break;
    // nodes that were not candidates but that the constrained solution puts inside a probe
    // (they moved farther than the provider's margin in this solve): add them and redo
    // (under the regional solves' promise, the moving nodes only once the period's first copy
    // put every node in place: the others' rows and positions have not changed since)
    const bool moving_only = moving_period_ != 0 && trial_period_ == moving_period_ && trial_.cols() == x.cols();
    if (!moving_only) trial_.resize(3, x.cols());
    const std::int64_t n = moving_only ? std::int64_t(moving_->size()) : x.cols();
    parallel_for(n, kTrialGrain, threads_, [&](std::int64_t b, std::int64_t e) {
      for (std::int64_t k = b; k < e; ++k) {
        const std::int64_t i = moving_only ? (*moving_)[std::size_t(k)] : k;
        const int f = std::size_t(i) < free_index.size() ? free_index[std::size_t(i)] : -1;
        trial_.col(i) = f >= 0 ? Eigen::Vector3d(solution.row(f).transpose()) : Eigen::Vector3d(x.col(i));
      }
    });
    trial_period_ = moving_period_;
    extra_.clear();
    provider.collect(trial_, false, extra_);
    const std::size_t before = candidates_.size();
    for (const ContactConstraint& e : extra_) {
      const auto end_sorted = candidates_.begin() + std::ptrdiff_t(sorted);
      const auto it = std::lower_bound(candidates_.begin(), end_sorted, e, key_less);
      bool known = it != end_sorted && !key_less(e, *it);
      for (std::size_t c = sorted; c < candidates_.size() && !known; ++c)
        known = candidates_[c].owner == e.owner && candidates_[c].node == e.node;
      if (!known) candidates_.push_back(e);
    }
    index_candidates(before);
    if (candidates_.size() == before) break;
    if (from_forward) unconstrained_from_forward(before, factor, counters);
  }
  // the active set, sorted by key, with the multipliers
  active_.clear();
  for (const int c : working_)
    if (candidates_[std::size_t(c)].force_n > 0.0) active_.push_back(candidates_[std::size_t(c)]);
  std::sort(active_.begin(), active_.end(), key_less);
}

}  // namespace vx
