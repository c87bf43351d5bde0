#pragma once
/// @file sim_helpers.h
/// Test helpers for whole simulations (sim/simulation.h, haptics/device_side.h): a block of
/// tissue, its physics, a symplectic step and a probe on a path.
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "model/gradational_builder.h"
#include "physics/calibration.h"
#include "physics/physics_model.h"
#include "sim/simulation.h"
#include "sim/time_step.h"

namespace vx::testing {

/// An all-tissue block of nx x ny x nz voxels of 1 mm spanning [0, n] mm on each axis.
inline std::shared_ptr<const Model> block_model(int nx, int ny, int nz, Layout r = Layout::gradational) {
  GridGeometry g;
  g.dims = {nx, ny, nz};
  g.origin_mm = {0.5, 0.5, 0.5};
  VoxelGrid grid(g);
  for (auto& v : grid.data()) v = 1;
  BuildSettings b;
  b.layout = r;
  return std::make_shared<const Model>(build_model(grid, b));
}

inline std::shared_ptr<const PhysicsModel> physics_of(std::shared_ptr<const Model> m, double e_kpa,
                                                      double damping = 0.1) {
  Material mat;
  mat.youngs_modulus_kpa = e_kpa;
  mat.density_kg_m3 = 1000;
  mat.damping_ratio = damping;
  mat.poisson_ratio = 0.0;
  return make_physics_model(std::move(m), mat);
}

inline IntegratorSettings symplectic(const PhysicsModel& p, double fraction = 0.5) {
  IntegratorSettings s;
  s.kind = IntegratorKind::symplectic_euler;
  s.time_step_s = fraction * stable_time_step(p, s.kind);
  s.threads = 1;  // the tests share the machine; SameResultsOnOneAndTwoThreads checks threads
  return s;
}

inline ProbeSettings path_probe(const std::string& name, ProbeShape shape, double radius, std::vector<PathKey> path) {
  ProbeSettings p;
  p.name = name;
  p.geometry.shape = shape;
  p.geometry.radius_mm = radius;
  p.drive = ProbeDrive::path;
  p.path = std::move(path);
  return p;
}

/// A block held at its z_min face under a live ball "hand" (radius 3 mm, starting at (6, 6, 9.5)
/// mm, at most 50 mm/s) and a path probe "still" far away: a live press, on a symplectic step.
inline SimulationSettings live_press_settings(const PhysicsModel& phys) {
  SimulationSettings s;
  s.integrator = symplectic(phys);
  s.fixed_nodes = nodes_on_face(*phys.model, BoxFace::z_min);
  ProbeSettings live;
  live.name = "hand";
  live.drive = ProbeDrive::live;
  live.geometry.radius_mm = 3;
  live.start_mm = {6, 6, 9.5};
  live.max_speed_mm_s = 50;
  s.probes = {live, path_probe("still", ProbeShape::sphere, 1, {{0.0, {30, 30, 30}}})};
  return s;
}

}  // namespace vx::testing
