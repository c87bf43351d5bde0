// The probe app's defaults for an object without a scene of its own (palpation_defaults.h): the
// Scene that asks for them, and what prepare_scene places once the object is built.
#include "scene/palpation_defaults.h"

#include <fmt/core.h>

#include <algorithm>
#include <array>
#include <cmath>

#include "base/error.h"
#include "scene/fast_configuration.h"

namespace vx {

Scene default_palpation_scene(const SceneObject& object, const Material& material, const PalpationDefaults& defaults) {
  if (const std::string bad = validate(material); !bad.empty()) throw Error("material: " + bad);
  if (!(defaults.held_fraction > 0.0 && defaults.held_fraction <= 1.0))
    throw Error("the held fraction of the height must be in (0, 1]");
  Scene scene;
  scene.object = object;
  scene.material.base = material;
  scene.palpation = defaults;
  return scene;
}

std::vector<int> lower_part_nodes(const Model& model, const Eigen::Vector3d& up_in, double fraction) {
  if (!(fraction > 0.0 && fraction <= 1.0)) throw Error("the held fraction of the height must be in (0, 1]");
  const Eigen::Vector3d up = up_in.normalized();
  const Eigen::VectorXd height = model.rest_positions.transpose() * up;
  const double bottom = height.minCoeff(), top = height.maxCoeff();
  const double limit = bottom + fraction * (top - bottom) + 1e-6;
  std::vector<int> nodes;
  for (int n = 0; n < model.num_nodes(); ++n)
    if (height[n] <= limit) nodes.push_back(n);
  return nodes;
}

ToolStart default_tool_start(const Model& model, const VoxelGrid& grid, const Eigen::Vector3d& up_in, double radius_mm,
                             double press_depth_mm, double clearance_mm) {
  const GridGeometry& g = grid.geometry();
  const Eigen::Vector3d up = up_in.normalized();
  // the grid axis closest to "up", and which way along it is up
  const Eigen::Vector3d up_index = g.direction.transpose() * up;
  int ax = 0;
  up_index.cwiseAbs().maxCoeff(&ax);
  const int rise = up_index[ax] > 0 ? 1 : -1;
  const int ua = (ax + 1) % 3, wa = (ax + 2) % 3;
  const double sp = g.spacing_mm[ax];
  Eigen::Vector3i lo, hi;
  grid.tissue_bounds(lo, hi);
  const auto lateral = [&](const Eigen::Vector3d& p) -> Eigen::Vector3d { return p - up * up.dot(p); };
  const Eigen::Vector3d box_lo = model.rest_positions.rowwise().minCoeff();
  const Eigen::Vector3d box_hi = model.rest_positions.rowwise().maxCoeff();
  const Eigen::Vector3d centre = lateral(0.5 * (box_lo + box_hi));

  // each column along the up axis: its top tissue voxel and the tissue run below it
  struct Column {
    int u, w, top;            // top: voxel index along the up axis
    int run;                  // tissue voxels from the top down without a gap
    double height_mm;         // the top voxel's upper face along up
    Eigen::Vector3d lateral;  // the column's centre, across up
    double distance_mm;       // lateral distance from the centre
  };
  const int nu = std::max(0, hi[ua] - lo[ua]), nw = std::max(0, hi[wa] - lo[wa]);
  std::vector<int> column_of(std::size_t(nu) * std::size_t(nw), -1);
  std::vector<Column> columns;
  const auto voxel = [&](int u, int w, int t) {
    Eigen::Vector3i v;
    v[ua] = u;
    v[wa] = w;
    v[ax] = t;
    return v;
  };
  const auto tissue = [&](const Eigen::Vector3i& v) { return grid.at(v.x(), v.y(), v.z()) != 0; };
  for (int w = lo[wa]; w < hi[wa]; ++w)
    for (int u = lo[ua]; u < hi[ua]; ++u) {
      const int first = rise > 0 ? hi[ax] - 1 : lo[ax], last = rise > 0 ? lo[ax] - 1 : hi[ax];
      int t = first;
      while (t != last && !tissue(voxel(u, w, t))) t -= rise;
      if (t == last) continue;
      int run = 0;
      for (int s = t; s != last && tissue(voxel(u, w, s)); s -= rise) ++run;
      const Eigen::Vector3d c = g.index_to_lps(voxel(u, w, t).cast<double>());
      Column col{u, w, t, run, up.dot(c) + 0.5 * sp, lateral(c), 0.0};
      col.distance_mm = (col.lateral - centre).norm();
      column_of[std::size_t(u - lo[ua]) + std::size_t(nu) * std::size_t(w - lo[wa])] = int(columns.size());
      columns.push_back(col);
    }
  ToolStart out;
  out.start_mm = 0.5 * (box_lo + box_hi) + (up.dot(box_hi - box_lo) * 0.5 + radius_mm + clearance_mm) * up;
  if (columns.empty()) return out;

  // the columns within `reach_mm` laterally of column c
  const auto neighbours = [&](const Column& c, double reach_mm, auto&& visit) {
    const int du = int(std::ceil(reach_mm / g.spacing_mm[ua])), dw = int(std::ceil(reach_mm / g.spacing_mm[wa]));
    for (int w = std::max(lo[wa], c.w - dw); w <= std::min(hi[wa] - 1, c.w + dw); ++w)
      for (int u = std::max(lo[ua], c.u - du); u <= std::min(hi[ua] - 1, c.u + du); ++u) {
        const Eigen::Vector3d l = lateral(g.index_to_lps(voxel(u, w, c.top).cast<double>()));
        if ((l - c.lateral).norm() > reach_mm + 1e-9) continue;
        const int k = column_of[std::size_t(u - lo[ua]) + std::size_t(nu) * std::size_t(w - lo[wa])];
        visit(u, w, k < 0 ? nullptr : &columns[std::size_t(k)]);
      }
  };
  // the tool's footprint (within `patch_mm` of its axis) is tissue: every column there has its
  // top within half the press depth below c's and tissue from there down to the press depth
  const auto holds_press = [&](const Column& c, int depth_voxels, double patch_mm) {
    if (c.run < depth_voxels) return false;
    bool ok = true;
    neighbours(c, patch_mm, [&](int u, int w, const Column* q) {
      if (!ok) return;
      if (!q || q->height_mm < c.height_mm - 0.5 * depth_voxels * sp - 1e-9) {
        ok = false;
        return;
      }
      for (int k = depth_voxels / 2; k < depth_voxels && ok; ++k) ok = tissue(voxel(u, w, c.top - rise * k));
    });
    return ok;
  };
  // highest first, then nearest the centre
  std::vector<int> order(columns.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = int(i);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    const Column &x = columns[std::size_t(a)], &y = columns[std::size_t(b)];
    return x.height_mm != y.height_mm ? x.height_mm > y.height_mm : x.distance_mm < y.distance_mm;
  });
  const Eigen::Vector3d extent = box_hi - box_lo;
  const double lateral_extent = (extent - up * up.dot(extent)).cwiseAbs().maxCoeff();
  double max_distance = 0;
  for (const Column& c : columns) max_distance = std::max(max_distance, c.distance_mm);
  const int depth_voxels = std::max(1, int(std::ceil(press_depth_mm / sp - 1e-9)));
  int thickest = 1;
  for (const Column& c : columns) thickest = std::max(thickest, c.run);
  // the whole footprint first, then half of it, then the axis alone over the thickest tissue
  const std::array<std::pair<double, int>, 3> attempts{
      {{radius_mm, depth_voxels}, {0.5 * radius_mm, depth_voxels}, {0.0, std::min(depth_voxels, thickest)}}};
  const Column* chosen = nullptr;
  for (const auto& [patch_mm, depth] : attempts) {
    // widen the search around the centre until a column qualifies
    for (double reach = std::max(2.0 * radius_mm, 0.15 * lateral_extent); !chosen; reach *= 1.5) {
      for (int i : order) {
        const Column& c = columns[std::size_t(i)];
        if (c.distance_mm <= reach && holds_press(c, depth, patch_mm)) {
          chosen = &c;
          break;
        }
      }
      if (reach > max_distance) break;
    }
    if (chosen) break;
  }
  if (!chosen) return out;

  // start clear of every tissue top within the tool's radius
  double clear_top = chosen->height_mm;
  neighbours(*chosen, radius_mm + sp, [&](int, int, const Column* q) {
    if (q) clear_top = std::max(clear_top, q->height_mm);
  });
  out.found = true;
  out.surface_mm = chosen->lateral + chosen->height_mm * up;
  out.tissue_below_mm = chosen->run * sp;
  out.start_mm = chosen->lateral + (clear_top + radius_mm + clearance_mm) * up;
  return out;
}

std::vector<std::uint8_t> place_palpation_defaults(const PalpationDefaults& defaults,
                                                   const PrepareSceneOptions& options, PreparedScene& out) {
  const std::shared_ptr<const Model>& model = out.model;
  if (!model || model->num_elements() == 0) throw Error("the model has no elements");
  Eigen::Vector3d up = defaults.up.normalized();
  const bool flat = model->is_2d();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  if (flat) {
    // a 2D model: "up" in its slice plane (anterior, else superior, projected onto the plane)
    normal = model->grid.direction.col(0).cross(model->grid.direction.col(1)).normalized();
    Eigen::Vector3d in_plane = up - normal * normal.dot(up);
    if (in_plane.norm() < 0.3) in_plane = Eigen::Vector3d::UnitZ() - normal * normal.z();
    up = in_plane.normalized();
  }
  out.up = up;
  SimulationSettings& sim = out.settings;

  // the tissue is held the way the body holds an organ: over its lower part
  const Eigen::Vector3d lo = model->rest_positions.rowwise().minCoeff();
  const Eigen::Vector3d hi = model->rest_positions.rowwise().maxCoeff();
  const Eigen::Vector3d extent = hi - lo;
  sim.fixed_nodes = lower_part_nodes(*model, up, defaults.held_fraction);
  out.fixed_nodes = int(sim.fixed_nodes.size());
  std::vector<std::uint8_t> fixed(std::size_t(model->num_nodes()), 0);
  for (const int n : sim.fixed_nodes) fixed[std::size_t(n)] = 1;

  // walls: the table under the tissue, room above and around it
  int up_axis = 0;
  up.cwiseAbs().maxCoeff(&up_axis);
  sim.workspace.enabled = true;
  sim.workspace.min_mm = lo - 0.35 * extent;
  sim.workspace.max_mm = hi + 0.35 * extent;
  if (flat) {
    // the slice has no extent along its normal: walls well clear of it there
    for (int a = 0; a < 3; ++a)
      if (std::abs(normal[a]) > 0.5) {
        sim.workspace.min_mm[a] = std::min(sim.workspace.min_mm[a], lo[a] - 10.0);
        sim.workspace.max_mm[a] = std::max(sim.workspace.max_mm[a], hi[a] + 10.0);
      }
  }
  if (up[up_axis] > 0) {
    sim.workspace.min_mm[up_axis] = lo[up_axis];
    sim.workspace.max_mm[up_axis] = hi[up_axis] + 1.2 * extent[up_axis] + 10.0;
  } else {
    sim.workspace.max_mm[up_axis] = hi[up_axis];
    sim.workspace.min_mm[up_axis] = lo[up_axis] - 1.2 * extent[up_axis] - 10.0;
  }

  // one capsule tool above the top centre, pointing down
  ProbeSettings probe;
  probe.name = "probe0";
  // a 2D model: a circular tool, the paper's 2D manipulator (a sphere is a circle in the slice)
  probe.geometry.shape = flat ? ProbeShape::sphere : ProbeShape::capsule;
  double lateral = 1e30;
  for (int a = 0; a < 3; ++a)
    if (a != up_axis && !(flat && std::abs(normal[a]) > 0.5)) lateral = std::min(lateral, extent[a]);
  probe.geometry.radius_mm = std::clamp(0.06 * lateral, 1.5, 4.0);
  probe.geometry.length_mm = std::max(20.0, 0.9 * extent.maxCoeff());
  probe.geometry.axis = up;
  probe.drive = ProbeDrive::live;
  // just above tissue it will touch when pressed straight down (not above a fissure or a hole)
  const ToolStart start = default_tool_start(*model, grid_from_model(*model), up, probe.geometry.radius_mm,
                                             defaults.press_depth_mm, std::clamp(0.05 * extent[up_axis], 2.0, 8.0));
  probe.start_mm = start.start_mm;
  probe.max_speed_mm_s = 150.0;
  sim.probes.push_back(probe);

  // the fast configuration (fast_configuration.h): implicit, one iteration per step, 20 ms steps
  // (30 ms with regional solves near the tool for a large model); the paper's device shaping
  // over two steps
  const int nodes = model->num_nodes();
  const FastConfiguration fast = default_fast_configuration();
  sim.integrator = fast.integrator_for(nodes);
  if (options.threads_override >= 0) sim.integrator.threads = options.threads_override;
  sim.integrator.factor_cache = options.factor_cache;
  out.automatic_dt_s = sim.integrator.time_step_s;
  out.device_side.device = fast.device_for(nodes);
  if (std::string w = incompressible_iterations_warning(sim.integrator, out.physics->material.poisson_ratio);
      !w.empty())
    out.warnings.push_back(std::move(w));

  const Material& material = out.physics->material;
  out.log.push_back(fmt::format(
      "default palpation scene: E = {:g} kPa, Poisson ratio {:g}, damping ratio {:g}, {} nodes held (the lowest "
      "{:g} % of the height), capsule probe r = {:.1f} mm {}, the fast configuration: "
      "implicit dt = {:.3g} ms, {} iteration per step{}",
      material.youngs_modulus_kpa, material.poisson_ratio, material.damping_ratio, sim.fixed_nodes.size(),
      100.0 * defaults.held_fraction, probe.geometry.radius_mm,
      start.found ? fmt::format("above tissue {:.0f} mm deep", start.tissue_below_mm) : std::string("above the centre"),
      1e3 * sim.integrator.time_step_s, sim.integrator.max_iterations,
      sim.integrator.region_radius_mm > 0
          ? fmt::format(", regional solves within {:g} mm of the tool", sim.integrator.region_radius_mm)
          : std::string()));
  return fixed;
}

}  // namespace vx
