// The 2D (slice) physics (docs/model.md section 12.2) against references: the closed-form
// rotation against the 2D SVD, the in-plane closest matrix with a given determinant against its
// optimality conditions, the consistent gradient's exactness and balance, forces = -dE/dx by
// finite differences, rigid motions cost nothing, plate compression against plane stress
// (stress = E strain, lateral strain = -nu strain), and a simulation that keeps the slice in
// its plane. The slices are oblique (not an LPS plane) where it matters, so that nothing
// relies on z being the normal.

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <cmath>
#include <iostream>
#include <random>

#include "base/error.h"
#include "model/gradational_builder.h"
#include "physics/calibration.h"
#include "physics/element_gradient.h"
#include "physics/elements.h"
#include "sim/simulation.h"
#include "sim/static_solver.h"
#include "sim/time_step.h"
#include "support/physics_helpers.h"

namespace vx {
namespace {

/// An oblique orthonormal frame (columns: the slice's index axes x, y and its normal).
Eigen::Matrix3d oblique_frame() {
  return (Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 1, 0).normalized()))
      .toRotationMatrix();
}

/// A one-slice grid of nx x ny pixels of `pixel` mm, `thickness` mm deep, in `direction`,
/// with tissue where inside(i, j).
VoxelGrid slice(int nx, int ny, const std::function<bool(int, int)>& inside, double pixel = 1.0,
                double thickness = 2.0, const Eigen::Matrix3d& direction = Eigen::Matrix3d::Identity()) {
  GridGeometry g;
  g.dims = {nx, ny, 1};
  g.spacing_mm = {pixel, pixel, thickness};
  g.direction = direction;
  g.origin_mm = {10.0, -5.0, 30.0};
  VoxelGrid grid(g);
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) grid.set(i, j, 0, inside(i, j) ? 1 : 0);
  return grid;
}

Model build_2d(const VoxelGrid& grid, Layout layout = Layout::gradational) {
  BuildSettings b;
  b.layout = layout;
  b.dimensions = 2;
  return build_model(grid, b);
}

VoxelGrid disk(int n, const Eigen::Matrix3d& direction = Eigen::Matrix3d::Identity()) {
  const double c = 0.5 * n, r = 0.5 * n - 0.5;
  return slice(n, n, [=](int i, int j) { return (i + 0.5 - c) * (i + 0.5 - c) + (j + 0.5 - c) * (j + 0.5 - c) <= r * r; },
               1.0, 2.0, direction);
}

/// The 2D proper rotation maximising tr(Q^T a) by SVD (the reference).
Eigen::Matrix2d svd_rotation_2d(const Eigen::Matrix2d& a) {
  const Eigen::JacobiSVD<Eigen::Matrix2d> svd(a, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix2d u = svd.matrixU();
  if ((u * svd.matrixV().transpose()).determinant() < 0) u.col(1) *= -1.0;
  return u * svd.matrixV().transpose();
}

TEST(PlaneModel, ClosedFormRotationIsTheSvdRotationEvenInverted) {
  const Eigen::Matrix3d frame = oblique_frame();
  const auto e = frame.leftCols<2>();
  std::mt19937 rng(7);
  std::normal_distribution<double> nd;
  int inverted = 0;
  for (int t = 0; t < 200; ++t) {
    Eigen::Matrix2d a2;
    a2 << nd(rng), nd(rng), nd(rng), nd(rng);
    inverted += a2.determinant() < 0;
    const Eigen::Matrix3d a = e * a2 * e.transpose();
    Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
    Eigen::Matrix3d rot;
    bool conv = false;
    fit_plane_rotation(a, frame, q, &conv, &rot);
    EXPECT_TRUE(conv);
    const Eigen::Matrix2d q2 = e.transpose() * rot * e;
    EXPECT_LT((q2 - svd_rotation_2d(a2)).norm(), 1e-10) << a2;
    EXPECT_NEAR(q2.determinant(), 1.0, 1e-12);
    EXPECT_LT((rot * frame.col(2)).norm(), 1e-12) << "no normal block";
    // the quaternion is the same rotation about the normal
    const Eigen::Matrix3d full = q.toRotationMatrix();
    EXPECT_LT((full * frame.col(2) - frame.col(2)).norm(), 1e-12);
    EXPECT_LT((e.transpose() * full * e - q2).norm(), 1e-12);
  }
  EXPECT_GT(inverted, 50);
}

TEST(PlaneModel, ClosestMatrixWithDeterminantIsOnTheConstraintAndLocallyClosest) {
  const Eigen::Matrix3d frame = oblique_frame();
  const auto e = frame.leftCols<2>();
  std::mt19937 rng(11);
  std::normal_distribution<double> nd;
  for (int t = 0; t < 100; ++t) {
    Eigen::Matrix2d b2;
    b2 << 1 + 0.3 * nd(rng), 0.3 * nd(rng), 0.3 * nd(rng), 1 + 0.3 * nd(rng);
    const double det = 0.5 + std::abs(nd(rng));
    const Eigen::Matrix2d x2 = e.transpose() * closest_with_determinant_in_plane(e * b2 * e.transpose(), det, frame) * e;
    EXPECT_NEAR(x2.determinant(), det, 1e-10 * det);
    // no matrix with the same determinant nearby is closer to b2
    const double d0 = (x2 - b2).squaredNorm();
    for (int k = 0; k < 50; ++k) {
      Eigen::Matrix2d y = x2;
      y += 1e-3 * Eigen::Matrix2d::Random();
      if (!(y.determinant() > 0)) continue;
      y *= std::sqrt(det / y.determinant());
      EXPECT_GE((y - b2).squaredNorm(), d0 - 1e-12) << "t " << t;
    }
  }
}

TEST(PlaneModel, ConsistentGradientIsExactAndBalancesAtInteriorNodes) {
  const Model m = build_2d(disk(40, oblique_frame()));
  ASSERT_TRUE(m.is_2d());
  const ElementGradients g = compute_element_gradients(m);
  EXPECT_EQ(g.fallback_elements, 0);
  const Eigen::Matrix3d frame = oblique_frame();
  const Eigen::Matrix3d in_plane = frame.leftCols<2>() * frame.leftCols<2>().transpose();
  Eigen::Matrix3Xd node_area = Eigen::Matrix3Xd::Zero(3, m.num_nodes());
  for (int e = 0; e < m.num_elements(); ++e) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    Eigen::Matrix3d f = Eigen::Matrix3d::Zero();
    for (int j = m.element_offsets[e]; j < m.element_offsets[e + 1]; ++j) {
      sum += g.entry_gradient.col(j);
      f += m.rest_positions.col(m.element_vertices[j]) * g.entry_gradient.col(j).transpose();
      node_area.col(m.element_vertices[j]) += m.element_volume_mm3[std::size_t(e)] * g.entry_gradient.col(j);
      EXPECT_LT(std::abs(frame.col(2).dot(g.entry_gradient.col(j))), 1e-12);
    }
    EXPECT_LT(sum.norm(), 1e-12) << "element " << e;
    EXPECT_LT((f - in_plane).norm(), 1e-10) << "element " << e << ": F of the rest shape is the plane's identity";
  }
  // the shares of neighbouring elements cancel at every interior node; the outline's nodes
  // carry the outward normal of the boundary (its area vectors sum to zero around the disk)
  int interior = 0;
  for (int i = 0; i < m.num_nodes(); ++i)
    if (!m.node_surface[std::size_t(i)]) {
      ++interior;
      EXPECT_LT(node_area.col(i).norm(), 1e-9) << "node " << i;
    }
  EXPECT_GT(interior, 50);
  EXPECT_LT(node_area.rowwise().sum().norm(), 1e-9);
}

/// A 2D disk calibrated with `nu`, its element forces and energy at positions x.
struct PlaneForces {
  std::shared_ptr<const PhysicsModel> p;
  Eigen::Matrix3Xd node_forces;
  double energy{0};
};

PlaneForces plane_forces(std::shared_ptr<const PhysicsModel> p, const Eigen::Matrix3Xd& x) {
  PlaneForces out{p, {}, 0};
  std::vector<Eigen::Quaterniond> rot(std::size_t(p->num_elements()), Eigen::Quaterniond::Identity());
  Eigen::Matrix3Xd entry;
  std::vector<double> energy;
  ElementPassScratch scratch;
  ElementPassOptions o;
  o.damping = false;
  o.energy = true;
  const ElementPassStats st = compute_element_forces(*p, x, nullptr, rot, entry, &energy, o, 1, scratch);
  gather_node_forces(*p, entry, out.node_forces, 1);
  out.energy = st.elastic_energy;
  return out;
}

double total_energy(const PhysicsModel& p, const Eigen::Matrix3Xd& x) {
  double e = 0;
  for (int el = 0; el < p.num_elements(); ++el) {
    Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
    e += element_energy(p, el, x, q, RotationFitSettings{});
  }
  return e;
}

TEST(PlaneModel, ForcesAreMinusTheEnergyGradientAndStayInThePlane) {
  const Eigen::Matrix3d frame = oblique_frame();
  for (const double nu : {0.0, 0.3, 0.45}) {
    Material mat;
    mat.youngs_modulus_kpa = 10.0;
    mat.poisson_ratio = nu;
    auto p = make_physics_model(build_2d(disk(16, frame)), mat);
    ASSERT_TRUE(p->is_2d());
    ASSERT_TRUE(p->has_bending_modes());
    EXPECT_LT((p->plane_frame - frame).norm(), 1e-12);
    // a large in-plane deformation: a shear, a turn of 50 degrees and noise
    std::mt19937 rng(3);
    std::normal_distribution<double> nd(0.0, 0.2);
    const auto e = frame.leftCols<2>();
    Eigen::Matrix2d def;
    def << 1.1, 0.25, -0.05, 0.9;
    def = Eigen::Rotation2Dd(0.87).toRotationMatrix() * def;
    const Eigen::Vector3d c = p->plane_point_mm;
    Eigen::Matrix3Xd x = p->model->rest_positions;
    for (int i = 0; i < p->num_nodes(); ++i) {
      const Eigen::Vector2d u = e.transpose() * (x.col(i) - c);
      x.col(i) = c + e * (def * u + Eigen::Vector2d(nd(rng), nd(rng)));
    }
    const PlaneForces f = plane_forces(p, x);
    EXPECT_NEAR(f.energy, total_energy(*p, x), 1e-9 * f.energy);
    double fmax = 0;
    for (int i = 0; i < p->num_nodes(); ++i) {
      fmax = std::max(fmax, f.node_forces.col(i).norm());
      EXPECT_LT(std::abs(frame.col(2).dot(f.node_forces.col(i))), 1e-12 * (1 + f.node_forces.col(i).norm()));
    }
    ASSERT_GT(fmax, 0);
    const double h = 1e-6;
    for (int i = 0; i < p->num_nodes(); i += 7)
      for (int d = 0; d < 2; ++d) {
        Eigen::Matrix3Xd xp = x, xm = x;
        xp.col(i) += h * e.col(d);
        xm.col(i) -= h * e.col(d);
        const double fd = -(total_energy(*p, xp) - total_energy(*p, xm)) / (2 * h);
        EXPECT_NEAR(f.node_forces.col(i).dot(e.col(d)), fd, 1e-5 * fmax) << "nu " << nu << " node " << i;
      }
  }
}

TEST(PlaneModel, RigidInPlaneMotionCostsNothingAndAnInvertedShapeIsPushedBack) {
  Material mat;
  mat.youngs_modulus_kpa = 10.0;
  mat.poisson_ratio = 0.3;
  const Eigen::Matrix3d frame = oblique_frame();
  auto p = make_physics_model(build_2d(disk(16, frame)), mat);
  const auto e = frame.leftCols<2>();
  const Eigen::Vector3d c = p->plane_point_mm;
  for (const double angle : {0.3, 2.0, 3.1}) {
    Eigen::Matrix3Xd x = p->model->rest_positions;
    const Eigen::Matrix2d r = Eigen::Rotation2Dd(angle).toRotationMatrix();
    for (int i = 0; i < p->num_nodes(); ++i) x.col(i) = c + e * (r * (e.transpose() * (x.col(i) - c))) + 3.0 * e.col(0);
    const PlaneForces f = plane_forces(p, x);
    EXPECT_LT(f.node_forces.cwiseAbs().maxCoeff(), 1e-10) << angle;
    EXPECT_LT(std::abs(f.energy), 1e-12) << angle;
  }
  // mirrored across the plane's y axis: every element inverted; the forces push it back, i.e.
  // do negative work along the path back towards the rest shape
  Eigen::Matrix3Xd x = p->model->rest_positions;
  for (int i = 0; i < p->num_nodes(); ++i) {
    Eigen::Vector2d u = e.transpose() * (x.col(i) - c);
    u.x() = -0.5 * u.x();
    x.col(i) = c + e * u;
  }
  std::vector<Eigen::Quaterniond> rot(std::size_t(p->num_elements()), Eigen::Quaterniond::Identity());
  Eigen::Matrix3Xd entry;
  ElementPassScratch scratch;
  ElementPassOptions o;
  o.damping = false;
  const ElementPassStats st = compute_element_forces(*p, x, nullptr, rot, entry, nullptr, o, 1, scratch);
  EXPECT_EQ(st.inverted, p->num_elements());
  Eigen::Matrix3Xd nf;
  gather_node_forces(*p, entry, nf, 1);
  double towards = 0;
  for (int i = 0; i < p->num_nodes(); ++i) towards += nf.col(i).dot(p->model->rest_positions.col(i) - x.col(i));
  EXPECT_GT(towards, 0.0);
}

struct PlaneCompression {
  double modulus_kpa;     ///< (reaction / (width * thickness)) / strain
  double lateral_strain;  ///< mid-height width change / width
};

/// A W x H pixel rectangle (thickness t) in `frame`, the bottom row of nodes clamped, the top
/// row moved down by strain * H, solved statically.
PlaneCompression compress_plane(Layout layout, int w, int h, double nu, double strain, const Eigen::Matrix3d& frame) {
  const double pixel = 0.5, thickness = 3.0;
  const Model m = build_2d(slice(w, h, [](int, int) { return true; }, pixel, thickness, frame), layout);
  Material mat;
  mat.youngs_modulus_kpa = 10.0;
  mat.poisson_ratio = nu;
  auto p = make_physics_model(m, mat);
  SimState s = make_state(p);
  const auto e = frame.leftCols<2>();
  Eigen::Matrix2Xd u(2, m.num_nodes());
  for (int i = 0; i < m.num_nodes(); ++i) u.col(i) = e.transpose() * (m.rest_positions.col(i) - p->plane_point_mm);
  const double ymin = u.row(1).minCoeff(), ymax = u.row(1).maxCoeff(), xmin = u.row(0).minCoeff(),
               xmax = u.row(0).maxCoeff();
  std::vector<int> bottom, top;
  for (int i = 0; i < m.num_nodes(); ++i) {
    if (std::abs(u(1, i) - ymin) < 1e-9) bottom.push_back(i);
    if (std::abs(u(1, i) - ymax) < 1e-9) top.push_back(i);
  }
  s.fix_nodes(bottom);
  s.fix_nodes(top);
  const double height = ymax - ymin;
  for (int i : top) s.positions.col(i) -= strain * height * e.col(1);
  StaticSolveSettings ss;
  ss.max_iterations = 3000;
  ss.tolerance_mm = 1e-11;
  solve_static(s, ss);
  EXPECT_FALSE(s.failed()) << s.message;
  const double reaction = elastic_force_on(s, top).dot(e.col(1));
  double left = 0, right = 0;
  int nl = 0, nr = 0;
  for (int i = 0; i < m.num_nodes(); ++i) {
    if (std::abs(u(1, i) - 0.5 * (ymin + ymax)) > 1e-9) continue;
    const double x = e.col(0).dot(s.positions.col(i) - p->plane_point_mm);
    if (std::abs(u(0, i) - xmin) < 1e-9) left += x, ++nl;
    if (std::abs(u(0, i) - xmax) < 1e-9) right += x, ++nr;
  }
  EXPECT_GT(nl, 0);
  EXPECT_GT(nr, 0);
  const double width = xmax - xmin;
  return {reaction / (width * thickness) / strain / kKpaToNPerMm2, (right / nr - left / nl) / width - 1.0};
}

TEST(PlaneModel, PlateCompressionIsPlaneStress) {
  // nu = 0: the patch test makes the state exactly uniform, stress = E strain on the area
  // width x thickness, in every layout and in an oblique slice
  for (const Layout layout : {Layout::voxel, Layout::uniform, Layout::gradational})
    for (const Eigen::Matrix3d& frame : {Eigen::Matrix3d(Eigen::Matrix3d::Identity()), oblique_frame()}) {
      const PlaneCompression c = compress_plane(layout, 32, 32, 0.0, 0.01, frame);
      std::cout << to_string(layout) << ": E_measured / E = " << c.modulus_kpa / 10.0 << ", lateral " << c.lateral_strain
                << "\n";
      EXPECT_NEAR(c.modulus_kpa / 10.0, 1.0, 1e-6) << to_string(layout);
      EXPECT_NEAR(c.lateral_strain, 0.0, 1e-6) << to_string(layout);
    }
  // nu > 0: a bar 4x as tall as wide; plane stress: lateral strain -nu * axial (plane strain
  // would give -nu / (1 - nu)), stress = E strain (plane strain: E / (1 - nu^2)); the clamped
  // ends stiffen it a little
  for (const Layout layout : {Layout::voxel, Layout::gradational})
    for (const double nu : {0.3, 0.45}) {
      const PlaneCompression c = compress_plane(layout, 16, 64, nu, 0.01, Eigen::Matrix3d::Identity());
      std::cout << to_string(layout) << " nu " << nu << ": E_measured / E = " << c.modulus_kpa / 10.0
                << ", lateral / (nu axial) = " << c.lateral_strain / (nu * 0.01) << "\n";
      EXPECT_NEAR(c.lateral_strain / (nu * 0.01), 1.0, 0.12) << to_string(layout) << " nu " << nu;
      EXPECT_NEAR(c.modulus_kpa / 10.0, 1.0, 0.12) << to_string(layout) << " nu " << nu;
      EXPECT_LT(c.modulus_kpa / 10.0, 1.0 / (1.0 - nu * nu)) << "softer than plane strain";
    }
}

/// Tip deflection (mm) of a cantilever of L x H pixels (1 mm, thickness 2 mm, E 10 kPa, nu 0)
/// clamped at x = 0 under a tip load F (N) spread over the nodes of the free end.
double cantilever_tip(Layout layout, ElementKind element, int l, int h, double force_n) {
  const Model m = build_2d(slice(l, h, [](int, int) { return true; }, 1.0, 2.0), layout);
  Material mat;
  mat.youngs_modulus_kpa = 10.0;
  CalibrationOptions co;
  co.element = element;
  auto p = make_physics_model(std::make_shared<const Model>(m), mat, {}, co);
  SimState s = make_state(p);
  const double xmin = m.rest_positions.row(0).minCoeff(), xmax = m.rest_positions.row(0).maxCoeff();
  std::vector<int> clamped, tip;
  for (int i = 0; i < m.num_nodes(); ++i) {
    if (std::abs(m.rest_positions(0, i) - xmin) < 1e-9) clamped.push_back(i);
    if (std::abs(m.rest_positions(0, i) - xmax) < 1e-9) tip.push_back(i);
  }
  s.fix_nodes(clamped);
  // the tip load as a parabolic shear traction would be ideal; equal shares per unit length
  // (each node its half-edges) are the usual choice
  std::vector<double> share(tip.size(), 0.0);
  std::vector<std::pair<double, int>> ys;
  for (std::size_t k = 0; k < tip.size(); ++k) ys.emplace_back(m.rest_positions(1, tip[k]), int(k));
  std::sort(ys.begin(), ys.end());
  for (std::size_t k = 0; k + 1 < ys.size(); ++k) {
    const double half = 0.5 * (ys[k + 1].first - ys[k].first);
    share[std::size_t(ys[k].second)] += half;
    share[std::size_t(ys[k + 1].second)] += half;
  }
  const double height = ys.back().first - ys.front().first;
  for (std::size_t k = 0; k < tip.size(); ++k) s.external_forces(1, tip[k]) = -force_n * share[k] / height;
  StaticSolveSettings ss;
  ss.max_iterations = 20000;
  ss.tolerance_mm = 1e-12;
  solve_static(s, ss);
  EXPECT_FALSE(s.failed()) << s.message;
  double d = 0;
  for (int i : tip) d += m.rest_positions(1, i) - s.positions(1, i);
  return d / double(tip.size());
}

TEST(PlaneModel, CantileverBendsLikeTimoshenkosBeam) {
  // plane stress, nu = 0: delta = F L^3 / (3 E I) + F L / (kappa G A), I = t H^3 / 12, A = t H,
  // G = E / 2, kappa = 5/6 (the clamped end adds a little: the formula is the reference)
  const int l = 64, h = 8;
  const double t = 2.0, e = 10.0 * kKpaToNPerMm2, f = 1e-4;
  const double inertia = t * h * h * h / 12.0;
  const double want = f * l * l * l / (3 * e * inertia) + f * l / (5.0 / 6.0 * 0.5 * e * t * h);
  for (const Layout layout : {Layout::voxel, Layout::gradational}) {
    const double hourglass = cantilever_tip(layout, ElementKind::hourglass, l, h, f);
    const double paper = cantilever_tip(layout, ElementKind::paper, l, h, f);
    std::cout << to_string(layout) << ": tip deflection / Timoshenko: hourglass " << hourglass / want << ", paper "
              << paper / want << "\n";
    EXPECT_NEAR(hourglass / want, 1.0, 0.05) << to_string(layout);
    EXPECT_LT(paper, hourglass) << "the paper's element locks in bending";
  }
}

TEST(PlaneModel, SimulationKeepsTheSliceInItsPlane) {
  // a disk of 20 mm in an oblique slice, pressed by a sphere whose path leaves the plane by
  // 3 mm, under a gravity with a normal component: every node stays on the plane and the
  // probe's force lies in it; a capsule along the normal is refused
  const Eigen::Matrix3d frame = oblique_frame();
  Material mat;
  mat.youngs_modulus_kpa = 10.0;
  mat.poisson_ratio = 0.3;
  mat.damping_ratio = 0.2;
  auto p = make_physics_model(build_2d(disk(20, frame)), mat);
  const Eigen::Vector3d c = p->plane_point_mm, n = frame.col(2), ex = frame.col(0), ey = frame.col(1);
  SimulationSettings s;
  s.integrator.kind = IntegratorKind::implicit;
  s.integrator.time_step_s = 1e-3;
  s.gravity_mm_s2 = 9810.0 * (0.6 * n - 0.8 * ey);
  // the bottom quarter of the disk held
  const auto e2 = frame.leftCols<2>();
  for (int i = 0; i < p->num_nodes(); ++i)
    if ((e2.transpose() * (p->model->rest_positions.col(i) - c)).y() < -6.0) s.fixed_nodes.push_back(i);
  ProbeSettings probe;
  probe.name = "finger";
  probe.geometry.shape = ProbeShape::sphere;
  probe.geometry.radius_mm = 4.0;
  probe.path = {{0.0, c + (10.0 + 4.0 + 0.5) * ey + 3.0 * n}, {0.2, c + (10.0 + 4.0 - 2.0) * ey - 3.0 * n}};
  s.probes = {probe};
  {
    SimulationSettings bad = s;
    bad.probes[0].geometry.shape = ProbeShape::capsule;
    bad.probes[0].geometry.length_mm = 10.0;
    bad.probes[0].geometry.axis = n;
    EXPECT_THROW(Simulation(p, bad), Error);
  }
  Simulation sim(p, s);
  double force = 0;
  while (sim.time_s() < 0.2 - 0.5 * sim.dt_s()) {
    ASSERT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
    force = sim.probe(0).raw_force_n.dot(ey);
    EXPECT_LT(std::abs(sim.probe(0).raw_force_n.dot(n)), 1e-9 * (1 + sim.probe(0).raw_force_n.norm()));
  }
  double off = 0;
  for (int i = 0; i < p->num_nodes(); ++i) off = std::max(off, std::abs(n.dot(sim.state().positions.col(i) - c)));
  EXPECT_LT(off, 1e-9);
  EXPECT_GT(force, 0.0) << "the tissue pushes the probe back up";
  // the probe's circle is in the plane: the top node moved down by about the 2 mm press
  double top_y = -1e9;
  for (int i = 0; i < p->num_nodes(); ++i) top_y = std::max(top_y, ey.dot(sim.state().positions.col(i) - c));
  EXPECT_NEAR(top_y, 10.0 - 2.0, 0.6);
  (void)ex;
}

}  // namespace
}  // namespace vx
