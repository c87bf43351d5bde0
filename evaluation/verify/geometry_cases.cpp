// The verify cases on geometry: the gradational model's element and vertex-entry counts
// against the paper, and the surfaces against the analytic phantom shapes.
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "convert/iso_surface.h"
#include "convert/phantom.h"
#include "convert/threshold.h"
#include "model/gradational_builder.h"
#include "verify/case_helpers.h"
#include "verify/cases.h"
#include "verify/surface_accuracy.h"

namespace vx::cases {

// --- model: counts against the paper -----------------------------------------------------------

namespace {

VoxelGrid full_cube(int n) {
  GridGeometry g;
  g.dims = {n, n, n};
  VoxelGrid grid(g);
  std::fill(grid.data().begin(), grid.data().end(), std::uint8_t(1));
  return grid;
}

}  // namespace

void run_model_counts(VerifyContext& ctx) {
  // the paper's 128^3 cube: its shells, level 0 outward in
  const Model m128 = build_model(full_cube(128));
  const std::vector<std::int64_t> paper = {23816, 5768, 1352, 296, 56, 8};
  const auto levels = m128.elements_per_level();
  for (std::size_t l = 0; l < paper.size(); ++l)
    ctx.check(fmt::format("cube128.level{}_elements", l), l < levels.size() ? double(levels[l]) : 0.0,
              double(paper[l]), 0.0, "elements", "the paper's shell count (3.2), exact");
  ctx.check("cube128.levels", double(levels.size()), double(paper.size()), 0.0, "levels", "six shells, exact");

  // vertex entries against 26 n^2, across sizes; the voxel-level model needs 8 n^3
  std::vector<double> ln_n, ln_grad, ln_26, ln_8, ln_sphere;
  for (int n : {16, 32, 64, 128}) {
    const Model m = n == 128 ? m128 : build_model(full_cube(n));
    const double ratio = double(m.num_vertex_entries()) / (26.0 * n * n);
    // face elements carry 13 vertices, so the entries tend to 26 n^2 from below; the edges,
    // corners and the truncated shell series of a small cube fall short by about 2/n of it
    if (n >= 32)
      ctx.check(fmt::format("cube{}.entries_over_26n2", n), ratio, 1.0, n >= 128 ? 0.05 : n >= 64 ? 0.10 : 0.20, "",
                "vertex entries / (26 n^2): the paper's cost of one step", CheckRule::within);
    else
      ctx.check(fmt::format("cube{}.entries_over_26n2", n), ratio, 1.0, 0.0, "",
                "vertex entries / (26 n^2): approached from below, never above", CheckRule::at_most);
    ctx.log(fmt::format("cube {}^3: {} elements, {} vertex entries = {:.3f} x 26 n^2, {:.1f}x fewer than 8 n^3", n,
                        m.num_elements(), m.num_vertex_entries(), ratio, 8.0 * n * n * n / double(m.num_vertex_entries())));
    ln_n.push_back(std::log10(n));
    ln_grad.push_back(std::log10(double(m.num_vertex_entries())));
    ln_26.push_back(std::log10(26.0 * n * n));
    ln_8.push_back(std::log10(8.0 * n * n * n));
  }
  ctx.check("cube128.reduction_over_n_3.25", 8.0 * 128 * 128 * 128 / double(m128.num_vertex_entries()) / (128.0 / 3.25),
            1.0, 0.05, "", "cost against the voxel-level model, 8 n^3 / entries, over its expected n / 3.25");
  // the voxel-level model: exactly 8 entries per tissue voxel
  {
    BuildSettings b;
    b.layout = Layout::voxel;
    const Model v = build_model(full_cube(32), b);
    ctx.check("cube32.voxel_entries", double(v.num_vertex_entries()), 8.0 * 32 * 32 * 32, 0.0, "entries",
              "the voxel-level model: one 8-vertex element per voxel, 8 n^3, exact");
  }
  // a sphere: the reduction grows like n (surface ~ n^2 against volume ~ n^3)
  std::vector<double> reductions;
  for (int n : {32, 64, 128}) {
    const VoxelGrid g = phantom_grid("sphere", n);
    const Model m = build_model(g);
    const double voxels = double(std::count(g.data().begin(), g.data().end(), std::uint8_t(1)));
    reductions.push_back(8.0 * voxels / double(m.num_vertex_entries()));
    ln_sphere.push_back(std::log10(double(m.num_vertex_entries())));
    ctx.log(fmt::format("sphere phantom {}^3: {} elements, {} vertex entries, {:.1f}x fewer than the voxel-level model",
                        n, m.num_elements(), m.num_vertex_entries(), reductions.back()));
  }
  // doubling n doubles the reduction; the first doublings fall short because the shells of a
  // small object are few (the finite series of 1/4 + 1/16 + ...), hence 15 %
  ctx.check("sphere.reduction_growth_64_over_32", reductions[1] / reductions[0], 2.0, 0.3, "",
            "reduction at 64 / at 32 voxels across: about 2 when cost ~ n^2 and the voxel model ~ n^3");
  ctx.check("sphere.reduction_growth_128_over_64", reductions[2] / reductions[1], 2.0, 0.3, "",
            "reduction at 128 / at 64 voxels across");
  std::vector<double> ln_ns(ln_n.begin() + 1, ln_n.end());
  ctx.plot("entries", "Vertex entries per step (the work of one step) against the object's size, log-log",
           {{"Cost of one step: gradational model against the paper's 26 n^2 and the voxel-level 8 n^3",
             "log10 n (voxels across)", "log10 vertex entries",
             {{"gradational, cube", ln_n, ln_grad, true},
              {"gradational, sphere phantom", ln_ns, ln_sphere, true},
              {"26 n^2 (paper)", ln_n, ln_26},
              {"8 n^3 (voxel-level)", ln_n, ln_8}}}});
}

// --- geometry: surfaces against the analytic shapes --------------------------------------------

void run_geometry(VerifyContext& ctx) {
  const int size = ctx.full() ? 96 : 48;
  std::vector<double> idx, iso_mean, stair_mean;
  int k = 0;
  for (const std::string name : {"sphere", "ellipsoid", "torus", "cube"}) {
    PhantomShape shape;
    const VoxelGrid grid = phantom_grid(name, size, &shape);
    const Model model = build_model(grid);
    const EmbeddedSurface iso = make_surface(model, grid, nullptr, SurfaceMethod::iso);
    const EmbeddedSurface stair = make_surface(model, grid, nullptr, SurfaceMethod::staircase);
    const SurfaceAccuracy a = measure_surface_accuracy(iso, shape, 1.0);
    const SurfaceAccuracy s = measure_surface_accuracy(stair, shape, 1.0);
    const double voxel_volume = double(model.covered_voxels());
    ctx.log(fmt::format("{} {}^3: iso {}; staircase {}", name, size, a.summary(), s.summary()));
    if (name == "cube") {
      // flat faces on voxel faces: the voxels are the shape exactly
      ctx.check(name + ".voxel_volume_error", 100.0 * (voxel_volume / shape.volume_mm3() - 1.0), 0.0, 1e-9, "%",
                "tissue voxels x voxel volume against the analytic volume: exact for a cube on the grid");
      ctx.check(name + ".staircase_volume_error", s.volume_error_percent, 0.0, 1e-6, "%",
                "enclosed volume of the voxel surface: exact for a cube on the grid");
      ctx.check(name + ".iso_volume_error", a.volume_error_percent, 0.0, 3.0, "%",
                "the smoothed iso-surface rounds the 12 edges and 8 corners off (about 1 voxel each), so a few % low");
      continue;
    }
    ctx.check(name + ".iso_mean_distance", a.mean_distance_voxels, 0.0, 0.15, "voxels",
              "mean distance of the iso-surface from the true surface: sub-voxel (a tenth of a voxel plus curvature)",
              CheckRule::at_most);
    ctx.check(name + ".iso_max_distance", a.max_distance_voxels, 0.0, 0.5, "voxels",
              "largest distance: within half a voxel, the resolution of the voxel data", CheckRule::at_most);
    ctx.check(name + ".iso_volume_error", a.volume_error_percent, 0.0, 2.0, "%",
              "enclosed volume: the smoothing shrinks curved surfaces slightly; 2 % when the thinnest part (the torus tube) is 5+ voxels in radius");
    ctx.check(name + ".staircase_mean_distance", s.mean_distance_voxels, 0.25, 0.1, "voxels",
              "the voxel staircase lies a quarter voxel off on average (uniformly distributed offsets of a half voxel)");
    ctx.check(name + ".staircase_volume_error", s.volume_error_percent, 0.0, 3.0, "%",
              "voxel volume against the analytic volume: in and out voxels cancel to a few % when the thinnest part is 5+ voxels in radius");
    idx.push_back(k);
    iso_mean.push_back(a.mean_distance_voxels);
    stair_mean.push_back(s.mean_distance_voxels);
    ++k;
  }
  ctx.plot("distance", "Mean distance from the true surface (0 sphere, 1 ellipsoid, 2 torus)",
           {{fmt::format("Surface accuracy at {} voxels across", size), "phantom (0 sphere, 1 ellipsoid, 2 torus)",
             "mean distance, voxels", {{"iso-surface", idx, iso_mean, true}, {"voxel staircase", idx, stair_mean, true}}}});
}

}  // namespace vx::cases
