#include "sim/state.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "base/error.h"
#include "base/parallel.h"

namespace vx {

const char* to_string(StepStatus s) {
  switch (s) {
    case StepStatus::ok: return "ok";
    case StepStatus::non_finite: return "non_finite";
    case StepStatus::runaway: return "runaway";
  }
  return "?";
}

std::vector<int> nodes_on_face(const Model& model, BoxFace face, double tol_mm) {
  std::vector<int> out;
  if (model.num_nodes() == 0) return out;
  const int axis = int(face) / 2;
  const bool max_side = int(face) % 2 == 1;
  const double bound = max_side ? model.rest_positions.row(axis).maxCoeff() : model.rest_positions.row(axis).minCoeff();
  for (int i = 0; i < model.num_nodes(); ++i)
    if (std::abs(model.rest_positions(axis, i) - bound) <= tol_mm) out.push_back(i);
  return out;
}

std::vector<int> nodes_in_box(const Model& model, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  std::vector<int> out;
  for (int i = 0; i < model.num_nodes(); ++i) {
    const Eigen::Vector3d p = model.rest_positions.col(i);
    if ((p.array() >= lo.array()).all() && (p.array() <= hi.array()).all()) out.push_back(i);
  }
  return out;
}

int SimState::num_fixed() const {
  int n = 0;
  for (auto f : node_fixed) n += f ? 1 : 0;
  return n;
}

namespace {

void check_nodes(const SimState& s, const std::vector<int>& nodes) {
  for (int i : nodes)
    if (i < 0 || i >= s.num_nodes())
      throw Error("node index " + std::to_string(i) + " out of range 0.." + std::to_string(s.num_nodes() - 1));
}

}  // namespace

void SimState::fix_nodes(const std::vector<int>& nodes) {
  check_nodes(*this, nodes);
  for (int i : nodes) {
    node_fixed[std::size_t(i)] = 1;
    velocities.col(i).setZero();
  }
  ++fixed_version;
}

void SimState::free_nodes(const std::vector<int>& nodes) {
  check_nodes(*this, nodes);
  for (int i : nodes) node_fixed[std::size_t(i)] = 0;
  ++fixed_version;
}

void SimState::free_all_nodes() {
  std::fill(node_fixed.begin(), node_fixed.end(), std::uint8_t(0));
  ++fixed_version;
}

namespace {
/// Asks a pending build to stop (before its future is dropped, which waits for it).
void ask_stop(const IntegratorCache& c) {
  if (c.pending.valid() && c.pending_stop) c.pending_stop->store(true);
}
}  // namespace

IntegratorCache::IntegratorCache() = default;
IntegratorCache::~IntegratorCache() { ask_stop(*this); }
IntegratorCache::IntegratorCache(const IntegratorCache&) {}
IntegratorCache& IntegratorCache::operator=(const IntegratorCache& other) {
  if (this != &other) *this = IntegratorCache();
  return *this;
}
IntegratorCache::IntegratorCache(IntegratorCache&&) noexcept = default;
IntegratorCache& IntegratorCache::operator=(IntegratorCache&& other) noexcept {
  if (this == &other) return *this;
  ask_stop(*this);
  solver = std::move(other.solver);
  fixed_version = other.fixed_version;
  contact_epoch = other.contact_epoch;
  next_step = other.next_step;
  next_time_s = other.next_time_s;
  pending = std::move(other.pending);
  pending_stop = std::move(other.pending_stop);
  pending_fixed_version = other.pending_fixed_version;
  pending_since_s = other.pending_since_s;
  return *this;
}

std::future<IntegratorCache::SolverPtr> IntegratorCache::abandon_pending() {
  ask_stop(*this);
  pending_stop.reset();
  return std::move(pending);
}

double IntegratorCache::pending_age_s() const {
  if (!pending.valid()) return 0.0;
  const double now = std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
  return std::max(0.0, now - pending_since_s);
}

void SimState::reset() {
  positions = physics->model->rest_positions;
  ++positions_version;
  velocities.setZero();
  std::fill(rotations.begin(), rotations.end(), Eigen::Quaterniond::Identity());
  time_s = 0;
  steps = 0;
  energies = {};
  element_stats = {};
  clear_failure();
}

void SimState::clear_failure() {
  status = StepStatus::ok;
  message.clear();
}

SimState make_state(std::shared_ptr<const PhysicsModel> physics) {
  if (!physics) throw Error("make_state: no physics model");
  SimState s;
  s.physics = std::move(physics);
  const PhysicsModel& p = *s.physics;
  const int nn = p.num_nodes(), ne = p.num_elements();
  s.positions = p.model->rest_positions;
  s.velocities = Eigen::Matrix3Xd::Zero(3, nn);
  s.rotations.assign(std::size_t(ne), Eigen::Quaterniond::Identity());
  s.external_forces = Eigen::Matrix3Xd::Zero(3, nn);
  s.node_fixed.assign(std::size_t(nn), 0);
  s.scratch.entry_forces = Eigen::Matrix3Xd::Zero(3, p.num_vertex_entries());
  s.scratch.next_positions = Eigen::Matrix3Xd::Zero(3, nn);
  s.scratch.next_velocities = Eigen::Matrix3Xd::Zero(3, nn);
  s.scratch.element_energy.assign(std::size_t(ne), 0.0);
  s.scratch.element_pass.chunks.resize(std::size_t(element_pass_slots(ne)));
  s.scratch.node_chunk_flags.assign(std::size_t(chunk_count(nn, kNodeGrain)), 0);
  s.scratch.node_chunk_sums.assign(3 * std::size_t(chunk_count(nn, kNodeGrain)), 0.0);
  return s;
}

Energies compute_energies(const SimState& s, int threads) {
  const PhysicsModel& p = *s.physics;
  Energies out;
  // elastic: converge the fits from the state's warm starts on a copy
  std::vector<Eigen::Quaterniond> rot = s.rotations;
  Eigen::Matrix3Xd ef(3, p.num_vertex_entries());
  std::vector<double> en;
  ElementPassScratch scratch;
  ElementPassOptions opt;
  opt.damping = false;
  opt.energy = true;
  opt.rotation.max_iterations = 100;
  opt.rotation.tolerance = 1e-12;
  out.elastic = compute_element_forces(p, s.positions, nullptr, rot, ef, &en, opt, threads, scratch).elastic_energy;
  // kinetic and gravitational, in node chunks reduced in order
  const std::int64_t nn = p.num_nodes();
  const std::int64_t chunks = chunk_count(nn, kNodeGrain);
  std::vector<double> kin(std::size_t(chunks), 0.0), grav(std::size_t(chunks), 0.0);
  const Eigen::Matrix3Xd& rest = p.model->rest_positions;
  parallel_for_chunks(nn, kNodeGrain, threads, [&](std::int64_t c, std::int64_t b, std::int64_t e) {
    double k = 0, g = 0;
    for (std::int64_t i = b; i < e; ++i) {
      k += 0.5 * p.node_mass[std::size_t(i)] * s.velocities.col(i).squaredNorm();
      g -= p.node_mass[std::size_t(i)] * p.node_gravity_ratio[std::size_t(i)] *
           s.gravity_mm_s2.dot(s.positions.col(i) - rest.col(i));
    }
    kin[std::size_t(c)] = k;
    grav[std::size_t(c)] = g;
  });
  for (std::int64_t c = 0; c < chunks; ++c) {
    out.kinetic += kin[std::size_t(c)];
    out.gravitational += grav[std::size_t(c)];
  }
  return out;
}

Eigen::Vector3d elastic_force_on(const SimState& s, const std::vector<int>& nodes, int threads) {
  const PhysicsModel& p = *s.physics;
  std::vector<Eigen::Quaterniond> rot = s.rotations;
  Eigen::Matrix3Xd ef(3, p.num_vertex_entries());
  ElementPassScratch scratch;
  ElementPassOptions opt;
  opt.damping = false;
  opt.rotation.max_iterations = 100;
  opt.rotation.tolerance = 1e-12;
  compute_element_forces(p, s.positions, nullptr, rot, ef, nullptr, opt, threads, scratch);
  Eigen::Vector3d f = Eigen::Vector3d::Zero();
  for (int i : nodes) f += gather_node_force(p, ef, i);
  return f;
}

}  // namespace vx
