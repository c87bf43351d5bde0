#include "sim/projective_solver.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <iterator>
#include <numeric>
#include <string>

#include "base/content_hash.h"
#include "base/error.h"
#include "base/parallel.h"
#include "sim/state.h"
#include "sim/step_report.h"

namespace vx {

ProjectiveSolver::ProjectiveSolver(std::shared_ptr<const PhysicsModel> physics,
                                   const std::vector<std::uint8_t>& node_fixed, const ProjectiveSetup& setup,
                                   FactorCache* factor_cache, int threads, const std::function<bool()>& stop)
    : physics_(std::move(physics)), setup_(setup) {
  const PhysicsModel& p = *physics_;
  const int nn = p.num_nodes(), ne = p.num_elements();
  if (int(node_fixed.size()) != nn) throw Error("projective solver: node_fixed has the wrong size");
  numbering_ = number_nodes(node_fixed);
  if (!setup_.inertia) check_held();
  assemble_and_factor(factor_cache, threads, stop);
  const int nf = num_free(), nc = int(numbering_.fixed_nodes.size());
  const std::int64_t entries = p.num_vertex_entries();
  // buffers of a solve, written here (zeros) so that their pages are mapped now: a solver built in
  // the background while the tissue rests (the probe app) would otherwise take the first touch of
  // about 75 MB on the folded organ (page faults) in its first solve, the tool's first touch
  targets_.setZero(3, entries);
  start_offsets_.setZero(3, entries);
  damping_rotations_.assign(std::size_t(ne), Eigen::Quaterniond::Identity());
  rhs_const_.setZero(nf, 3);
  rhs_.setZero(nf, 3);
  rhs_previous_.setZero(nf, 3);
  solution_.setZero(nf, 3);
  fixed_positions_.setZero(nc, 3);  // solve() compares against the last (fixed_still)
  element_chunk_stats_.assign(std::size_t(chunk_count(ne, kElementGrain)), ElementPassStats{});
  free_chunk_sums_.assign(2 * std::size_t(chunk_count(nf, kNodeGrain)), 0.0);
  contact_set_.bind(numbering_.free_index, numbering_.free_nodes);
}

/// Every connected part of the model must hold a fixed node (static solve).
void ProjectiveSolver::check_held() const {
  const PhysicsModel& p = *physics_;
  const Model& m = *p.model;
  std::vector<int> parent(std::size_t(p.num_nodes()));
  std::iota(parent.begin(), parent.end(), 0);
  const auto find = [&](int a) {
    while (parent[std::size_t(a)] != a) a = parent[std::size_t(a)] = parent[std::size_t(parent[std::size_t(a)])];
    return a;
  };
  for (int e = 0; e < p.num_elements(); ++e)
    for (int j = m.element_offsets[e] + 1; j < m.element_offsets[e + 1]; ++j)
      parent[std::size_t(find(m.element_vertices[j]))] = find(m.element_vertices[m.element_offsets[e]]);
  std::vector<std::uint8_t> held(std::size_t(p.num_nodes()), 0);
  for (int i : numbering_.fixed_nodes) held[std::size_t(find(i))] = 1;
  for (int i = 0; i < p.num_nodes(); ++i)
    if (!held[std::size_t(find(i))])
      throw Error("static solve: node " + std::to_string(i) +
                  " belongs to a part of the model that no fixed node holds; fix nodes in every part "
                  "(e.g. nodes_on_face) before solving");
}

NodeNumbering number_nodes(const std::vector<std::uint8_t>& node_fixed) {
  NodeNumbering n;
  n.free_index.assign(node_fixed.size(), -1);
  n.fixed_index.assign(node_fixed.size(), -1);
  for (std::size_t i = 0; i < node_fixed.size(); ++i) {
    if (node_fixed[i]) {
      n.fixed_index[i] = int(n.fixed_nodes.size());
      n.fixed_nodes.push_back(int(i));
    } else {
      n.free_index[i] = int(n.free_nodes.size());
      n.free_nodes.push_back(int(i));
    }
  }
  return n;
}

namespace {

/// A number no other period of the regional solves' promise has, in any solver (the contact
/// outlives a solver: a new factor must not continue an old solver's period).
std::uint64_t next_watch_period() {
  static std::atomic<std::uint64_t> counter{0};
  return ++counter;
}

/// Calls emit(free_row, node, value) for every entry of sum_e (K_e + kappa_e (diag(w) - w w^T / W))
/// on a free row, elements [e_begin, e_end) in order (node: the column's node, free or fixed).
template <typename Emit>
void for_each_element_entry(const PhysicsModel& p, const NodeNumbering& numbering, const ProjectiveSetup& setup,
                            int e_begin, int e_end, Eigen::MatrixXd& ke, Emit&& emit) {
  const Model& m = *p.model;
  const std::vector<int>& free_index = numbering.free_index;
  for (int e = e_begin; e < e_end; ++e) {
    const int* v = m.element_vertices.data() + m.element_offsets[e];
    for_each_projective_entry(p, e, setup, ke, [&](int a, int b, double value) {
      if (const int fi = free_index[std::size_t(v[a])]; fi >= 0) emit(fi, v[b], value);
    });
  }
}

/// The mass term's diagonal entries (free index, value), with inertia.
template <typename Emit>
void for_each_mass_entry(const PhysicsModel& p, const NodeNumbering& numbering, const ProjectiveSetup& setup,
                         Emit&& emit) {
  if (!setup.inertia) return;
  const double dt = setup.time_step_s;
  for (std::size_t i = 0; i < numbering.free_index.size(); ++i)
    if (const int f = numbering.free_index[i]; f >= 0) emit(f, p.node_mass[i] / (dt * dt));
}

constexpr int kKeyElementGrain = 512;

}  // namespace

void assemble_projective_matrix(const PhysicsModel& p, const NodeNumbering& numbering, const ProjectiveSetup& setup,
                                Eigen::SparseMatrix<double>& a_free, Eigen::SparseMatrix<double>* a_free_fixed,
                                int threads) {
  const Model& m = *p.model;
  const int ne = p.num_elements();
  const int nf = int(numbering.free_nodes.size()), nc = int(numbering.fixed_nodes.size());
  const std::vector<int>& free_index = numbering.free_index;
  const std::vector<int>& fixed_index = numbering.fixed_index;
  // the lower triangle only (all the factor reads): half the triplets, which with their sort are
  // the assembly's memory peak (about 0.4 GB on the 1 mm folded organ). The elements in chunks
  // on `threads`: each chunk's entries counted from the topology first (every element emits all
  // its vertex pairs), so that each writes its own stretch of one array, in the serial order:
  // the same triplets in the same order, so the same sums to the bit, on any number of threads
  const std::int64_t chunks = chunk_count(ne, kKeyElementGrain);
  std::vector<std::size_t> ff_at(std::size_t(chunks) + 1, 0), fc_at(std::size_t(chunks) + 1, 0);
  parallel_for_chunks(ne, kKeyElementGrain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
    std::size_t ff = 0, fc = 0;
    for (std::int64_t el = b; el < e; ++el) {
      const int o = m.element_offsets[el], n = m.element_offsets[el + 1] - o;
      const int* v = m.element_vertices.data() + o;
      for (int i = 0; i < n; ++i) {
        const int fi = free_index[std::size_t(v[i])];
        if (fi < 0) continue;
        for (int j = 0; j < n; ++j) {
          const int fj = free_index[std::size_t(v[j])];
          ff += fj >= 0 && fi >= fj ? 1 : 0;
          fc += fj < 0 ? 1 : 0;
        }
      }
    }
    ff_at[std::size_t(c) + 1] = ff;
    fc_at[std::size_t(c) + 1] = a_free_fixed ? fc : 0;
  });
  for (std::int64_t c = 0; c < chunks; ++c) {
    ff_at[std::size_t(c) + 1] += ff_at[std::size_t(c)];
    fc_at[std::size_t(c) + 1] += fc_at[std::size_t(c)];
  }
  std::vector<Eigen::Triplet<double>> tff(ff_at.back() + (setup.inertia ? std::size_t(nf) : 0)), tfc(fc_at.back());
  parallel_for_chunks(ne, kKeyElementGrain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
    Eigen::Triplet<double>* ff = tff.data() + ff_at[std::size_t(c)];
    Eigen::Triplet<double>* fc = tfc.data() + fc_at[std::size_t(c)];
    Eigen::MatrixXd ke;
    for_each_element_entry(p, numbering, setup, int(b), int(e), ke, [&](int fi, int node, double v) {
      if (const int fj = free_index[std::size_t(node)]; fj >= 0) {
        if (fi >= fj) *ff++ = Eigen::Triplet<double>(fi, fj, v);
      } else if (a_free_fixed)
        *fc++ = Eigen::Triplet<double>(fi, fixed_index[std::size_t(node)], v);
    });
  });
  std::size_t k = ff_at.back();
  for_each_mass_entry(p, numbering, setup, [&](int f, double v) { tff[k++] = Eigen::Triplet<double>(f, f, v); });
  a_free.resize(nf, nf);
  a_free.setFromTriplets(tff.begin(), tff.end());
  if (a_free_fixed) {
    a_free_fixed->resize(nf, nc);
    a_free_fixed->setFromTriplets(tfc.begin(), tfc.end());
  }
}

FactorKey projective_matrix_key(const PhysicsModel& p, const NodeNumbering& numbering, const ProjectiveSetup& setup,
                                int threads, Eigen::SparseMatrix<double>* a_free_fixed) {
  const int ne = p.num_elements();
  const std::vector<int>& free_index = numbering.free_index;
  const std::vector<int>& fixed_index = numbering.fixed_index;
  // the entries in chunks of elements, each chunk's hash apart, combined in chunk order: the
  // same key on any number of threads
  const std::int64_t chunks = chunk_count(ne, kKeyElementGrain);
  std::vector<std::uint64_t> chunk_hash(std::size_t(chunks), 0);
  auto chunk_fixed = std::vector<std::vector<Eigen::Triplet<double>>>(std::size_t(chunks));
  parallel_for_chunks(ne, kKeyElementGrain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
    ContentHash h;
    Eigen::MatrixXd ke;
    for_each_element_entry(p, numbering, setup, int(b), int(e), ke, [&](int fi, int node, double v) {
      const int fj = free_index[std::size_t(node)];
      h.add_value(fi);
      h.add_value(fj >= 0 ? fj : -1 - fixed_index[std::size_t(node)]);
      h.add_value(v);
      if (fj < 0 && a_free_fixed) chunk_fixed[std::size_t(c)].emplace_back(fi, fixed_index[std::size_t(node)], v);
    });
    chunk_hash[std::size_t(c)] = h.value();
  });
  ContentHash key;
  const std::int64_t nf = std::int64_t(numbering.free_nodes.size()), nc = std::int64_t(numbering.fixed_nodes.size());
  key.add_value(nf);
  key.add_value(nc);
  key.add(chunk_hash.data(), chunk_hash.size() * sizeof(std::uint64_t));
  std::int64_t entries = 0;
  for_each_mass_entry(p, numbering, setup, [&](int f, double v) {
    key.add_value(f);
    key.add_value(v);
  });
  const SparseFactor::Backend backend = SparseFactor::best_backend();
  key.add_value(std::uint8_t(backend));
  for (const auto& c : chunk_fixed) entries += std::int64_t(c.size());
  if (a_free_fixed) {
    std::vector<Eigen::Triplet<double>> tfc;
    tfc.reserve(std::size_t(entries));
    for (const auto& c : chunk_fixed) tfc.insert(tfc.end(), c.begin(), c.end());
    a_free_fixed->resize(nf, nc);
    a_free_fixed->setFromTriplets(tfc.begin(), tfc.end());
  }
  FactorKey k;
  k.hash = key.value();
  k.rows = nf;
  k.nonzeros = std::int64_t(p.num_vertex_entries());  // a size to name the file by; the hash holds the content
  k.backend = std::uint8_t(backend);
  return k;
}

double projective_centring_weight(const PhysicsModel& p, int e, const ProjectiveSetup& setup) {
  return (setup.damping ? p.element_damping[std::size_t(e)] / setup.time_step_s : 0.0);
}

/// Assembles M/dt^2 + sum_e (K_e + kappa_e (diag(w) - w w^T / W)), split into free-free (factored)
/// and free-fixed, with kappa_e = k_v,e (+ c_e / dt): the volume and damping terms.
void ProjectiveSolver::assemble_and_factor(FactorCache* cache, int threads, const std::function<bool()>& stop) {
  const auto stop_at = [&](const char* where) {
    if (stop && stop())
      throw Cancelled("the implicit solver's set-up (" + std::to_string(num_free()) + " free nodes) was stopped " +
                      where);
  };
  stop_at("before it began");
  const PhysicsModel& p = *physics_;
  const int ne = p.num_elements(), nf = num_free();
  centring_weight_.resize(std::size_t(ne));
  for (int e = 0; e < ne; ++e) centring_weight_[std::size_t(e)] = projective_centring_weight(p, e, setup_);
  FactorKey key;
  if (cache) {
    // the key from the element entries (a fraction of the assembly's cost), the coupling to the
    // fixed nodes with it: a factor found needs nothing else
    key = projective_matrix_key(p, numbering_, setup_, threads, &a_free_fixed_);
    key.single = setup_.single_precision_sweeps && key.backend == std::uint8_t(SparseFactor::Backend::cholmod);
    stop_at("after the matrix's key, before the factor cache");
    if (cache->load(key, factor_) && factor_.size() == nf) {
      if (setup_.single_precision_sweeps) factor_.use_single_precision_sweeps();  // a file of doubles: converted
      return;
    }
    factor_ = SparseFactor();  // none, or not this matrix's after all: factor it
  }
  stop_at("before the assembly");
  SparseFactor::Matrix a;
  assemble_projective_matrix(p, numbering_, setup_, a, &a_free_fixed_, threads);
  // the order kept for this pattern (the model and its support; another material, step or
  // damping): METIS's time saved, the same factor's structure
  const bool ordered = cache && SparseFactor::best_backend() == SparseFactor::Backend::cholmod;
  FactorKey pattern;
  std::vector<int> order;
  if (ordered) {
    pattern = SparseFactor::pattern_key(a);
    if (!cache->load_order(pattern, order) || int(order.size()) != nf) order.clear();
  }
  if (!factor_.compute(a, SparseFactor::Backend::automatic, order, stop))
    throw Error("implicit integrator: the system matrix could not be factored (" + std::to_string(nf) +
                " free nodes); is a part of the model held by nothing?");
  // before the cache keeps it: the file holds the values the sweeps read (half the bytes)
  if (setup_.single_precision_sweeps) factor_.use_single_precision_sweeps();
  stop_at("before the factor cache kept its factor");  // (a factor stopped is not kept)
  if (cache) cache->store(key, factor_);
  if (ordered && order.empty()) cache->store_order(pattern, factor_);
}

void ProjectiveSolver::solve(SimState& s, Eigen::Matrix3Xd& x, const ProjectiveIterations& its,
                             ContactProvider* contact, StepReport& rep) {
  const int threads = its.threads;
  factor_.set_threads(threads);  // the large supernodes' rows (the same bits on any number of threads)
  contact_set_.set_threads(threads);
  // the fixed nodes' coupling: rhs_const -= A_fc x_c
  bool fixed_still = true;  // every fixed node where it was at the last solve
  if (!numbering_.fixed_nodes.empty()) {
    for (std::size_t c = 0; c < numbering_.fixed_nodes.size(); ++c) {
      const Eigen::RowVector3d p = x.col(numbering_.fixed_nodes[c]).transpose();
      fixed_still = fixed_still && p == fixed_positions_.row(Eigen::Index(c));
      fixed_positions_.row(Eigen::Index(c)) = p;
    }
    rhs_const_.noalias() -= a_free_fixed_ * fixed_positions_;
  }
  // the first solve computes every element's targets and the whole solution (a regional solve
  // needs them all to exist), and so does the first after the region moved; the others only
  // the region's
  const bool region = region_;
  if (!targets_valid_) region_ = false;
  last_full_ = !region_;
  // the far field carried (docs/model.md section 7): anchored at the first regional solve after a
  // full one, its rows' right-hand side held bitwise at the anchor's (so the forward half does not
  // see them change) and its motion put into the forward solution by the forward fields
  const bool carry = far_degree_ > 0 && region_ && !solve_far_field_ && setup_.inertia && factor_.partial_ready();
  if (!carry) far_.ready = false;
  if (carry && !far_.ready) far_.ready = anchor_far_field(s, x);
  const bool carried = carry && far_.ready;
  if (carried) {
    for (std::size_t r = 0; r < far_.rows.size(); ++r)
      rhs_const_.row(far_.rows[r]) = far_.frozen_rhs.row(Eigen::Index(r));
    carry_far_field_in(setup_.time_step_s);
    factor_.set_product_fields(&far_.forward, far_.fields);
  }
  // The promise to the contact (ContactProvider::watch_moving): a regional solve (nothing
  // carried) that follows one over the same closure, from the state it left (no reset, restore
  // or jump in time) with the fixed nodes where they were, keeps every node outside the closure
  // where it was: the last solve did not move it, so its velocity is 0 and the iterate starts it
  // there, and this one writes only the closure's rows. Its contact then checks the closure's
  // nodes only for the broad phase's move and the re-check's copy; the period runs while such
  // solves follow one another.
  const bool partial_now = region_ && !solve_far_field_ && !carried;
  const int run = partial_run(s);
  const bool steady = partial_now && run >= 1 && fixed_still && !visit_still_;
  if (steady && !last_steady_) watch_period_ = next_watch_period();
  if (steady) ++steady_solves_;
  if (contact) contact->watch_moving(steady ? &closure_nodes_ : nullptr, steady ? watch_period_ : 0);
  contact_set_.watch_moving(steady ? &closure_nodes_ : nullptr, steady ? watch_period_ : 0);
  // The rows a steady solve's right-hand side can change on (docs/model.md section 7, "Passes
  // over the closure only"): after two steady solves over this closure, a free node outside it
  // has velocity 0 in this step and the last, so its inertial term is the last step's bit for
  // bit given the same gravity and no external force; its elements' targets were not recomputed
  // since, and the fixed nodes' coupling is the same (fixed_still). Its rows of the right-hand
  // side are then the last solve's, which the factor keeps (the forward half's last b): the
  // gathering, the comparison and the residual visit the closure's rows only.
  const bool inputs_same =
      its.inputs_given && !its.external_forces && last_inputs_quiet_ && its.gravity_mm_s2 == last_gravity_;
  last_inputs_quiet_ = its.inputs_given && !its.external_forces;
  last_gravity_ = its.gravity_mm_s2;
  const std::vector<int>* rows = steady && run >= 2 && inputs_same ? &factor_.partial_rows() : nullptr;
  if (rows) ++closure_pass_solves_;
  if (setup_.damping) record_start_shape(s.positions, threads);
  double max_update = std::numeric_limits<double>::infinity();
  ElementPassStats last;
  ContactSolveCounters counters;
  int it = 0;
  // past max_iterations only while no tool touches and the tissue still moves (free_max_iterations)
  const auto tool_touches = [&] {
    if (!contact) return false;
    const int tools = contact->tool_owners();
    for (const ContactConstraint& c : contact_set_.active())
      if (c.owner < tools) return true;
    return false;
  };
  const int cap = std::max(its.max_iterations, its.free_max_iterations);
  for (; it < cap; ++it) {
    if (it >= its.max_iterations && (max_update <= its.free_tolerance_mm || tool_touches())) break;
    // local: rotation fits and targets; global: right-hand side, solve, contact
    last = local_step(s, x, its.rotation, threads);
    gather_rhs(threads, rows);
    if (it > 0) {
      const auto [rms, largest] = difference_norms(rhs_, rhs_previous_, threads, rows);
      rep.residual_n = rms;
      rep.max_residual_n = largest;
      if (its.tolerance_mm > 0 && max_update <= its.tolerance_mm) break;
      if (its.residual_tolerance_n > 0 && largest <= its.residual_tolerance_n) break;
    }
    // with contact on a region, the solve's backward half waits for the contact forces: one
    // backward pass for both (docs/model.md section 8)
    const bool partial = region_ && !solve_far_field_;
    const bool halves = partial && contact && factor_.partial_ready();
    if (halves)
      factor_.forward3_partial(rhs_, rows);
    else if (partial)
      factor_.solve3_partial(rhs_, solution_, rows);
    else
      factor_.solve3(rhs_, solution_);
    if (contact) {
      contact_set_.set_partial(partial);  // the full refresh after a region move applies contact everywhere
      contact_set_.solve(*contact, x, factor_, solution_, counters, halves);
    }
    max_update = scatter(x, threads, steady);
    rhs_previous_.swap(rhs_);
  }
  if (carried) {
    carry_far_field_out(x);
    factor_.set_product_fields(nullptr, 0);
  }
  // paused between solves: the positions may be set from outside (a sleep put at rest)
  if (contact && steady) contact->watch_moving(nullptr, watch_period_);
  partial_run_ = partial_now ? run + 1 : 0;
  run_closure_version_ = closure_version_;
  run_positions_version_ = s.positions_version;
  last_steady_ = steady;
  region_ = region;
  targets_valid_ = true;
  rep.contact_rounds += counters.rounds;
  rep.contact_columns += counters.columns;
  if (contact) rep.contacts = int(contact_set_.active().size());
  rep.iterations = it;
  rep.max_update_mm = it > 0 ? max_update : 0.0;
  rep.inverted_elements = last.inverted;
  rep.unconverged_rotations = last.unconverged;
  s.element_stats = last;
}

namespace {

/// The monomials of degree <= `degree` of r (1, x, y, z, x^2, y^2, z^2, xy, xz, yz).
int monomials(int degree, const Eigen::Vector3d& r, double* out) {
  int n = 0;
  out[n++] = 1.0;
  if (degree >= 1)
    for (int c = 0; c < 3; ++c) out[n++] = r[c];
  if (degree >= 2) {
    for (int c = 0; c < 3; ++c) out[n++] = r[c] * r[c];
    out[n++] = r.x() * r.y();
    out[n++] = r.x() * r.z();
    out[n++] = r.y() * r.z();
  }
  return n;
}

}  // namespace

/// Anchors the far field at the state's positions (the last full solve's): its rows (the free
/// rows outside the closure), the fields' forward solutions (one forward pass over the factor for
/// 18 columns at a time), their mass matrix, and the start velocity's projection. False when
/// there is no far field to carry (too few rows for the fields).
bool ProjectiveSolver::anchor_far_field(const SimState& s, const Eigen::Matrix3Xd& x) {
  const PhysicsModel& p = *physics_;
  const int nf = num_free();
  const double dt = setup_.time_step_s, inv_dt2 = 1.0 / (dt * dt);
  std::vector<std::uint8_t> in_closure(std::size_t(nf), 0);
  for (const int r : factor_.partial_rows()) in_closure[std::size_t(r)] = 1;
  far_.rows.clear();
  for (int f = 0; f < nf; ++f)
    if (!in_closure[std::size_t(f)]) far_.rows.push_back(f);
  const Eigen::Index m = Eigen::Index(far_.rows.size());
  double scratch[10];
  const int nm = monomials(far_degree_, Eigen::Vector3d::Zero(), scratch), fields = 3 * nm;
  if (m < 4 * nm) return false;
  far_.anchor.resize(m, 3);
  far_.frozen_rhs.resize(m, 3);
  double mass = 0;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero(), lo = Eigen::Vector3d::Constant(1e300), hi = -lo;
  for (Eigen::Index r = 0; r < m; ++r) {
    const int f = far_.rows[std::size_t(r)], i = numbering_.free_nodes[std::size_t(f)];
    const double mi = p.node_mass[std::size_t(i)];
    far_.anchor.row(r) = s.positions.col(i).transpose();
    mass += mi;
    centre += mi * s.positions.col(i);
    lo = lo.cwiseMin(s.positions.col(i));
    hi = hi.cwiseMax(s.positions.col(i));
  }
  if (!(mass > 0)) return false;
  far_.centre = centre / mass;
  const double scale = std::max(0.5 * (hi - lo).maxCoeff(), 1e-9);
  // g_k = M U_k on the far rows, U^T M U, (M U)^T a, and the projection of the start iterate's
  // displacement (dt v); the right-hand side at q = 0
  far_.phi.resize(m, nm);
  Eigen::MatrixXd g = Eigen::MatrixXd::Zero(nf, 3 * fields), gram = Eigen::MatrixXd::Zero(fields, fields);
  far_.anchor_products = Eigen::VectorXd::Zero(fields);
  Eigen::VectorXd start = Eigen::VectorXd::Zero(fields);
  Eigen::MatrixXd mono_gram = Eigen::MatrixXd::Zero(nm, nm);
  for (Eigen::Index r = 0; r < m; ++r) {
    const int f = far_.rows[std::size_t(r)], i = numbering_.free_nodes[std::size_t(f)];
    const double mi = p.node_mass[std::size_t(i)];
    const Eigen::Vector3d a = far_.anchor.row(r).transpose(), d = x.col(i) - a;  // d: dt v
    double ph[10];
    monomials(far_degree_, (a - far_.centre) / scale, ph);
    for (int j = 0; j < nm; ++j) {
      far_.phi(r, j) = ph[j];
      for (int c = 0; c < 3; ++c) {
        g(f, 3 * (3 * j + c) + c) = mi * ph[j];  // field k = 3 j + c: e_c phi_j
        far_.anchor_products[3 * j + c] += mi * ph[j] * a[c];
        start[3 * j + c] += mi * ph[j] * d[c];
      }
      for (int l = 0; l < nm; ++l) mono_gram(j, l) += mi * ph[j] * ph[l];
    }
    far_.frozen_rhs.row(r) = rhs_const_.row(f) - (mi * inv_dt2) * d.transpose();
  }
  for (int j = 0; j < nm; ++j)
    for (int l = 0; l < nm; ++l)
      for (int c = 0; c < 3; ++c) gram(3 * j + c, 3 * l + c) = mono_gram(j, l);
  far_.scale = scale;
  far_.fields = fields;
  far_.gram.compute(gram);
  if (far_.gram.info() != Eigen::Success || !(far_.gram.rcond() > 1e-12)) return false;
  factor_.forward_fields(g, far_.forward);
  far_.q = Eigen::VectorXd::Zero(fields);
  far_.q_previous = -far_.gram.solve(start);
  far_.applied = Eigen::VectorXd::Zero(fields);
  return true;
}

/// Puts this step's far-field inertia into the forward solution: the anchor moved to
/// a + U (2 q - q_previous) (y = x_n + dt v_n), i.e. the far rows' right-hand side changed by
/// M U (2 q - q_previous) / dt^2 since the anchor.
void ProjectiveSolver::carry_far_field_in(double dt) {
  const Eigen::VectorXd coef = (2.0 * far_.q - far_.q_previous) / (dt * dt);
  const Eigen::VectorXd delta = coef - far_.applied;
  factor_.add_forward_fields(far_.forward, far_.fields, delta.data());
  far_.applied = coef;
}

/// After the solve: q from the products of the fields with the exact solution (the far rows'
/// mass-weighted projection onto the fields), and the far nodes moved there.
void ProjectiveSolver::carry_far_field_out(Eigen::Matrix3Xd& x) {
  const Eigen::Index fields = far_.fields, nm = fields / 3;
  Eigen::VectorXd products(fields);
  for (Eigen::Index k = 0; k < fields; ++k) products[k] = factor_.field_products()[std::size_t(k)];
  far_.q_previous = far_.q;
  far_.q = far_.gram.solve(products - far_.anchor_products);
  const Eigen::Map<const Eigen::Matrix3Xd> coef(far_.q.data(), 3, nm);  // column j: phi_j's vector
  for (std::size_t r = 0; r < far_.rows.size(); ++r) {
    const int f = far_.rows[r], i = numbering_.free_nodes[std::size_t(f)];
    const Eigen::Vector3d pos =
        far_.anchor.row(Eigen::Index(r)).transpose() + coef * far_.phi.row(Eigen::Index(r)).transpose();
    x.col(i) = pos;
    solution_.row(f) = pos.transpose();
  }
}

bool ProjectiveSolver::contact_compliance(const std::vector<std::int32_t>& nodes, Eigen::MatrixXd& g) {
  std::vector<int> free(nodes.size());
  for (std::size_t a = 0; a < nodes.size(); ++a) {
    const int i = nodes[a];
    if (i < 0 || std::size_t(i) >= numbering_.free_index.size() || numbering_.free_index[std::size_t(i)] < 0)
      return false;
    free[a] = numbering_.free_index[std::size_t(i)];
  }
  contact_set_.compliance(free, factor_, g);
  return true;
}

void ProjectiveSolver::set_region(const std::vector<int>& awake_nodes) {
  if (!factor_.supports_partial()) return;
  const PhysicsModel& p = *physics_;
  const Model& m = *p.model;
  std::vector<std::uint8_t> awake(std::size_t(p.num_nodes()), 0);
  for (int i : awake_nodes) awake[std::size_t(i)] = 1;
  region_elements_.clear();
  std::vector<std::uint8_t> wanted(std::size_t(p.num_nodes()), 0);
  for (int e = 0; e < p.num_elements(); ++e) {
    bool any = false;
    for (int j = m.element_offsets[e]; j < m.element_offsets[e + 1] && !any; ++j)
      any = awake[std::size_t(m.element_vertices[j])];
    if (!any) continue;
    region_elements_.push_back(e);
    for (int j = m.element_offsets[e]; j < m.element_offsets[e + 1]; ++j)
      wanted[std::size_t(m.element_vertices[j])] = 1;
  }
  std::vector<int> rows;
  for (int f = 0; f < num_free(); ++f)
    if (wanted[std::size_t(numbering_.free_nodes[std::size_t(f)])]) rows.push_back(f);
  factor_.set_partial_rows(rows);
  closure_nodes_.clear();
  for (const int r : factor_.partial_rows()) closure_nodes_.push_back(numbering_.free_nodes[std::size_t(r)]);
  // the node passes' nodes: the closure's and the fixed ones, ascending
  pass_nodes_.clear();
  std::merge(closure_nodes_.begin(), closure_nodes_.end(), numbering_.fixed_nodes.begin(), numbering_.fixed_nodes.end(),
             std::back_inserter(pass_nodes_));
  ++closure_version_;
  region_ = true;
  // the next solve is a full one: every element's targets and every node's position brought up
  // to date (the far field that slept while the tool moved), then regional solves again
  if (refresh_on_move_) targets_valid_ = false;
  contact_set_.set_partial(!solve_far_field_);  // the cached forward vectors hold for any region
}

int ProjectiveSolver::partial_run(const SimState& s) const {
  // a slice model's nodes are all put back on its plane after every step (Simulation::hold_plane)
  if (physics_->is_2d()) return 0;
  return run_closure_version_ == closure_version_ && run_positions_version_ == s.positions_version ? partial_run_ : 0;
}

const std::vector<int>* ProjectiveSolver::still_far_field_nodes(const SimState& s, bool after_solve) const {
  // before a solve: the last one was regional over this closure (the positions: the one before
  // wrote them where they are); after one: it and the two before (the velocities: the step before
  // last wrote the buffer this step writes, 0 if it was regional over this closure)
  return !visit_still_ && partial_run(s) >= (after_solve ? 3 : 1) ? &pass_nodes_ : nullptr;
}

void ProjectiveSolver::clear_region() {
  if (!region_) return;
  region_ = false;
  ++closure_version_;
  region_elements_.clear();
  contact_set_.set_partial(false);
}

/// Relative offsets of the vertices at the start of the step (for the damping term).
void ProjectiveSolver::record_start_shape(const Eigen::Matrix3Xd& x, int threads) {
  const PhysicsModel& p = *physics_;
  const Model& m = *p.model;
  parallel_for(active_elements(), kElementGrain, threads, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t k = b; k < e; ++k) {
      const std::int64_t el = active_element(k);
      const int o = m.element_offsets[el], n = m.element_offsets[el + 1] - o;
      Eigen::Vector3d c = Eigen::Vector3d::Zero();
      double sw = 0;
      for (int j = o; j < o + n; ++j) {
        c += p.entry_weight[std::size_t(j)] * x.col(m.element_vertices[j]);
        sw += p.entry_weight[std::size_t(j)];
      }
      c /= sw;
      for (int j = o; j < o + n; ++j) start_offsets_.col(j) = x.col(m.element_vertices[j]) - c;
      damping_rotations_[std::size_t(el)] = Eigen::Quaterniond::Identity();
    }
  });
}

/// Local step: per element the rotation fits and the per-entry targets
/// t_i = 2 mu V Q g_i + w_i (k_v T R0_i + (c/dt) R_d r_i^n)  (w_i: vertex weight, g_i: gradient weight).
ElementPassStats ProjectiveSolver::local_step(SimState& s, const Eigen::Matrix3Xd& x, const RotationFitSettings& fit,
                                              int threads) {
  const PhysicsModel& p = *physics_;
  const Model& m = *p.model;
  const bool volume = p.has_volume_term();
  const bool damping = setup_.damping;
  const double inv_dt = 1.0 / setup_.time_step_s;
  const std::int64_t count = active_elements();
  parallel_for_chunks(count, kElementGrain, threads, [&](std::int64_t chunk, std::int64_t b, std::int64_t e) {
    ElementPassStats st;
    for (std::int64_t k = b; k < e; ++k) {
      const std::int64_t el = active_element(k);
      const int o = m.element_offsets[el], n = m.element_offsets[el + 1] - o;
      // (sum w R0 = sum w r^n = 0: no centring needed)
      const Eigen::Vector3d x0 = x.col(m.element_vertices[o]);
      Eigen::Matrix3d fg = Eigen::Matrix3d::Zero(), ad = Eigen::Matrix3d::Zero();
      for (int j = o; j < o + n; ++j) {
        const Eigen::Vector3d y = x.col(m.element_vertices[j]) - x0;
        fg.noalias() += y * p.entry_gradient.col(j).transpose();
        if (damping) ad.noalias() += (p.entry_weight[std::size_t(j)] * y) * start_offsets_.col(j).transpose();
      }
      const std::int32_t* slot = p.entry_slot.data();
      if (!fg.allFinite()) {
        ++st.non_finite;
        for (int j = o; j < o + n; ++j) targets_.col(slot[j]).setZero();
        continue;
      }
      bool conv = true;
      Eigen::Matrix3d rq;
      st.rotation_iterations += fit_element_rotation(p, fg, s.rotations[std::size_t(el)], fit, &conv, &rq);
      st.unconverged += conv ? 0 : 1;
      if (element_determinant(p, fg) <= 0) ++st.inverted;
      Eigen::Matrix3d mg = p.element_affine_stiffness[std::size_t(el)] * rq;
      if (volume) {
        Eigen::Quaterniond qv = s.rotations[std::size_t(el)];
        mg += p.element_volume_stiffness[std::size_t(el)] * element_closest_with_determinant(p, fg, 1.0, qv, fit);
      }
      if (damping) {
        Eigen::Matrix3d rd;
        fit_element_rotation(p, ad, damping_rotations_[std::size_t(el)], fit, nullptr, &rd);
        const Eigen::Matrix3d md = p.element_damping[std::size_t(el)] * inv_dt * rd;
        for (int j = o; j < o + n; ++j)
          targets_.col(slot[j]).noalias() =
              mg * p.entry_gradient.col(j) + p.entry_weight[std::size_t(j)] * (md * start_offsets_.col(j));
      } else {
        for (int j = o; j < o + n; ++j) targets_.col(slot[j]).noalias() = mg * p.entry_gradient.col(j);
      }
      if (volume && p.has_volume_points()) {  // + sum_s k_s T_s (g_j + delta_sj)
        Eigen::Matrix3d tsum = Eigen::Matrix3d::Zero();
        for_each_volume_point(p, x.data(), int(el), fg, s.rotations[std::size_t(el)], fit,
                              [&](int sp, const Eigen::Matrix3d&, const Eigen::Matrix3d& ts) {
                                const Eigen::Matrix3d kt = p.volume_point_stiffness[std::size_t(sp)] * ts;
                                tsum += kt;
                                for (int t = p.volume_point_term_offsets[std::size_t(sp)];
                                     t < p.volume_point_term_offsets[std::size_t(sp) + 1]; ++t)
                                  targets_.col(slot[p.volume_term_entry[std::size_t(t)]]).noalias() +=
                                      kt * p.volume_term_delta.col(t);
                              });
        for (int j = o; j < o + n; ++j) targets_.col(slot[j]).noalias() += tsum * p.entry_gradient.col(j);
      }
    }
    element_chunk_stats_[std::size_t(chunk)] = st;
  });
  ElementPassStats total;
  for (std::int64_t c = 0; c < chunk_count(count, kElementGrain); ++c) total.add(element_chunk_stats_[std::size_t(c)]);
  return total;
}

/// The global right-hand side: per free node, the constant part plus its targets in entry order;
/// on every free row, or on `rows` only (solve(): the others are the last solve's).
void ProjectiveSolver::gather_rhs(int threads, const std::vector<int>* rows) {
  const PhysicsModel& p = *physics_;
  parallel_for(rows ? std::int64_t(rows->size()) : num_free(), kNodeGrain, threads,
               [&](std::int64_t b, std::int64_t e) {
                 for (std::int64_t k = b; k < e; ++k) {
                   const std::int64_t f = rows ? (*rows)[std::size_t(k)] : k;
                   const Eigen::Vector3d t = gather_node_force(p, targets_, numbering_.free_nodes[std::size_t(f)]);
                   rhs_.row(f) = rhs_const_.row(f) + t.transpose();
                 }
               });
}

/// Writes the solution into x; returns the largest node move. `closure_only`: a steady regional
/// solve (solve()), whose rows outside the closure are where x has them already.
double ProjectiveSolver::scatter(Eigen::Matrix3Xd& x, int threads, bool closure_only) {
  const std::vector<int>& rows = factor_.partial_rows();
  const std::int64_t nf = closure_only ? std::int64_t(rows.size()) : std::int64_t(num_free());
  const std::int64_t chunks = chunk_count(nf, kNodeGrain);
  parallel_for_chunks(nf, kNodeGrain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
    double mx = 0;
    for (std::int64_t k = b; k < e; ++k) {
      const std::int64_t f = closure_only ? rows[std::size_t(k)] : k;
      const int i = numbering_.free_nodes[std::size_t(f)];
      const Eigen::Vector3d nx = solution_.row(f).transpose();
      mx = std::max(mx, (nx - x.col(i)).squaredNorm());
      x.col(i) = nx;
    }
    free_chunk_sums_[std::size_t(c)] = mx;
  });
  double mx = 0;
  for (std::int64_t c = 0; c < chunks; ++c) mx = std::max(mx, free_chunk_sums_[std::size_t(c)]);
  return std::sqrt(mx);
}

/// The RMS over the free rows and the largest row norm of a - b; with `rows`, a and b are equal
/// on the other rows (gather_rhs), which are not read.
std::pair<double, double> ProjectiveSolver::difference_norms(const Eigen::MatrixX3d& a, const Eigen::MatrixX3d& b,
                                                             int threads, const std::vector<int>* rows) {
  const int nf = num_free();
  if (nf == 0) return {0.0, 0.0};
  const std::int64_t visited = rows ? std::int64_t(rows->size()) : nf;
  const std::int64_t chunks = chunk_count(visited, kNodeGrain);
  parallel_for_chunks(visited, kNodeGrain, threads, [&](std::int64_t c, std::int64_t lo, std::int64_t hi) {
    double s = 0, mx = 0;
    for (std::int64_t k = lo; k < hi; ++k) {
      const std::int64_t f = rows ? (*rows)[std::size_t(k)] : k;
      const double d2 = (a.row(f) - b.row(f)).squaredNorm();
      s += d2;
      mx = std::max(mx, d2);
    }
    free_chunk_sums_[2 * std::size_t(c)] = s;
    free_chunk_sums_[2 * std::size_t(c) + 1] = mx;
  });
  double s = 0, mx = 0;
  for (std::int64_t c = 0; c < chunks; ++c) {
    s += free_chunk_sums_[2 * std::size_t(c)];
    mx = std::max(mx, free_chunk_sums_[2 * std::size_t(c) + 1]);
  }
  return {std::sqrt(s / nf), std::sqrt(mx)};
}

}  // namespace vx
