#include "sim/static_solver.h"

#include "base/error.h"
#include "sim/projective_solver.h"

namespace vx {

StepReport solve_static(SimState& s, const StaticSolveSettings& settings) {
  if (settings.max_iterations < 1) throw Error("static solve: max_iterations must be >= 1");
  const PhysicsModel& p = *s.physics;
  ProjectiveSetup setup;
  setup.time_step_s = 1.0;
  setup.inertia = false;
  setup.damping = false;
  ProjectiveSolver solver(s.physics, s.node_fixed, setup);
  StepReport rep;
  rep.refactored = true;
  rep.factor_nonzeros = solver.factor_nonzeros();
  // rhs = gravity + external forces (the solve subtracts the fixed nodes' coupling)
  const std::vector<int>& free = solver.free_nodes();
  Eigen::MatrixX3d& rc = solver.constant_rhs();
  for (std::size_t f = 0; f < free.size(); ++f) {
    const int i = free[f];
    rc.row(Eigen::Index(f)) = (p.node_mass[std::size_t(i)] * p.node_gravity_ratio[std::size_t(i)] * s.gravity_mm_s2 +
                               s.external_forces.col(i))
                                  .transpose();
  }
  Eigen::Matrix3Xd x = s.positions;
  ProjectiveIterations its;
  its.max_iterations = settings.max_iterations;
  its.tolerance_mm = settings.tolerance_mm;
  its.rotation = settings.rotation;
  its.threads = settings.threads;
  solver.solve(s, x, its, nullptr, rep);
  if (!x.allFinite()) {
    s.status = StepStatus::non_finite;
    s.message = "static solve: NaN/Inf in the solution; the state was not changed";
    rep.status = s.status;
    return rep;
  }
  s.positions = x;
  ++s.positions_version;
  for (int i = 0; i < s.num_nodes(); ++i)
    if (!s.node_fixed[std::size_t(i)]) s.velocities.col(i).setZero();
  return rep;
}

}  // namespace vx
