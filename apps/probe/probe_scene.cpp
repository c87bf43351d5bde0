#include "probe_scene.h"

#include <fmt/core.h>

#include <algorithm>
#include <array>
#include <cmath>

#include "base/error.h"
#include "convert/decimate_surface.h"
#include "convert/iso_surface.h"
#include "convert/prepare.h"
#include "convert/threshold.h"
#include "io/model_io.h"
#include "io/surface_io.h"
#include "io/volume_io.h"
#include "model/gradational_builder.h"
#include "scene/fast_configuration.h"
#include "scene/scene.h"
#include "sim/state.h"
#include "sim/time_step.h"
#include "util/text.h"

namespace vx::probe {

namespace {

std::string lower_extension(const std::filesystem::path& p) {
  const std::string name = lower(p.filename().string());
  if (name.size() > 7 && name.ends_with(".nii.gz")) return ".nii.gz";
  const auto dot = name.rfind('.');
  return dot == std::string::npos ? std::string() : name.substr(dot);
}

// the axis from the held nodes' centroid towards the model's (the side away from the support)
Eigen::Vector3d away_from_support(const Model& model, const std::vector<int>& fixed_nodes) {
  Eigen::Vector3d held = Eigen::Vector3d::Zero();
  for (const int n : fixed_nodes) held += model.rest_positions.col(n);
  held /= double(fixed_nodes.size());
  const Eigen::Vector3d all = model.rest_positions.rowwise().mean();
  const Eigen::Vector3d d = all - held;
  Eigen::Index axis = 0;
  if (d.cwiseAbs().maxCoeff(&axis) < 1e-9) return Eigen::Vector3d(0, -1, 0);
  Eigen::Vector3d up = Eigen::Vector3d::Zero();
  up[axis] = d[axis] > 0 ? 1.0 : -1.0;
  return up;
}

// "up" for the view: against gravity; else away from the face the tissue is held by (a
// specimen fixed at z_min sits on a table below it); else along the first probe's tool axis
// (tip -> handle); else away from any other
// support (a box or sphere selector: an organ on its stem); else anterior (LPS -y: a patient lying on the table)
Eigen::Vector3d scene_up(const Scene& file, const Model& model, const SimulationSettings& s) {
  if (s.gravity_mm_s2.norm() > 0) return -s.gravity_mm_s2.normalized();
  for (const auto& f : file.fixed) {
    if (!f.is_face) continue;
    switch (f.face) {
      case BoxFace::x_min: return Eigen::Vector3d(1, 0, 0);
      case BoxFace::x_max: return Eigen::Vector3d(-1, 0, 0);
      case BoxFace::y_min: return Eigen::Vector3d(0, 1, 0);
      case BoxFace::y_max: return Eigen::Vector3d(0, -1, 0);
      case BoxFace::z_min: return Eigen::Vector3d(0, 0, 1);
      case BoxFace::z_max: return Eigen::Vector3d(0, 0, -1);
    }
  }
  for (const auto& p : s.probes)
    if (p.geometry.shape == ProbeShape::capsule || p.geometry.shape == ProbeShape::cylinder ||
        p.geometry.shape == ProbeShape::plane)
      return p.geometry.axis.normalized();
  // held by a box or sphere selector (an organ on its stem): up points from the held nodes to
  // the rest, along the nearest axis (a stem below the organ gives +z, as the body would)
  if (!s.fixed_nodes.empty()) return away_from_support(model, s.fixed_nodes);
  return Eigen::Vector3d(0, -1, 0);
}

ProbeScene load_scene_file(const std::filesystem::path& path, const DefaultSceneOptions& options) {
  const Scene file = load_scene(path);
  PrepareSceneOptions prep;
  prep.surface = options.surface_method != SurfaceMethod::iso;  // the scene's own (paper) surface
  prep.region_check = RegionCheckTiming::background;            // seconds on a large organ: not before the run
  prep.calibration_cache = options.calibration_cache;
  PreparedScene built = prepare_scene(file, prep);
  ProbeScene scene;
  scene.name = path.stem().string();
  scene.model = built.model;
  scene.physics = built.physics;
  scene.simulation = built.settings;
  scene.device_side = built.device_side;
  scene.region_check = built.pending_region_check;
  if (scene.simulation.probes.empty()) throw Error(path.string() + ": $.probes: the scene has no probe to palpate with");
  if (options.surface_method == SurfaceMethod::iso) {
    // a smoothed iso-surface of the model's voxels, embedded in its elements
    scene.surface =
        std::make_shared<const EmbeddedSurface>(make_surface(*built.model, built.grid, nullptr, SurfaceMethod::iso));
    scene.simulation.surface = scene.surface;
  } else {
    scene.surface = built.surface;
  }
  scene.world_up = scene_up(file, *scene.model, scene.simulation);
  if (!file.description.empty()) scene.notes.push_back(file.description);
  for (const auto& l : built.log) scene.notes.push_back(l);
  scene.notes.push_back(fmt::format("surface: {} ({} triangles)", to_string(scene.surface->method),
                                    scene.surface->num_triangles()));
  scene.notes.push_back(fmt::format("physics: {}{}", physics_configuration(scene.simulation.integrator, *scene.physics),
                                    !scene.device_side.device ? std::string(", no device shaping (raw force)")
                                    : scene.device_side.device->shaping == ForceShaping::local
                                        ? std::string(", device force from the local contact model")
                                        : fmt::format(", device updates every {:g} ms (half sines)",
                                                      1e3 * scene.device_side.device->update_interval_s)));
  for (const auto& w : built.warnings) scene.notes.push_back("warning: " + w);
  make_probes_live(scene);
  use_display_surface(scene, options);
  return scene;
}

}  // namespace

void use_display_surface(ProbeScene& scene, const DefaultSceneOptions& options) {
  if (!scene.surface || !scene.model) return;
  DecimationSettings settings;
  settings.target_triangles = options.display_triangles;
  DecimationReport report;
  EmbeddedSurface shown = decimate_surface(*scene.model, *scene.surface, settings, &report);
  if (!report.decimated) return;
  // the physics deforms the surface it publishes: the decimated one only
  scene.surface = std::make_shared<const EmbeddedSurface>(std::move(shown));
  scene.simulation.surface = scene.surface;
  scene.notes.push_back(report.summary());
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

ProbeScene make_default_scene(std::shared_ptr<const Model> model, std::shared_ptr<const EmbeddedSurface> surface,
                              const DefaultSceneOptions& options, const Eigen::Vector3d& up_in,
                              const std::string& name) {
  if (!model || model->num_elements() == 0) throw Error("the model has no elements");
  Eigen::Vector3d up = up_in.normalized();
  const bool flat = model->is_2d();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  if (flat) {
    // a 2D model: "up" in its slice plane (anterior, else superior, projected onto the plane)
    normal = model->grid.direction.col(0).cross(model->grid.direction.col(1)).normalized();
    Eigen::Vector3d in_plane = up - normal * normal.dot(up);
    if (in_plane.norm() < 0.3) in_plane = Eigen::Vector3d::UnitZ() - normal * normal.z();
    up = in_plane.normalized();
  }
  ProbeScene scene;
  scene.name = name;
  scene.model = model;
  scene.surface = surface;
  scene.world_up = up;

  // material
  Material material;
  material.youngs_modulus_kpa = options.youngs_modulus_kpa;
  material.damping_ratio = options.damping_ratio;
  if (const std::string bad = validate(material); !bad.empty()) throw Error("material: " + bad);
  scene.physics = make_physics_model(model, material, {}, {}, options.calibration_cache.get());

  SimulationSettings& sim = scene.simulation;
  sim.surface = surface;

  // the tissue is held the way the body holds an organ: over its lower part
  const Eigen::Vector3d lo = model->rest_positions.rowwise().minCoeff();
  const Eigen::Vector3d hi = model->rest_positions.rowwise().maxCoeff();
  const Eigen::Vector3d extent = hi - lo;
  sim.fixed_nodes = lower_part_nodes(*model, up, options.held_fraction);

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
                                             options.press_depth_mm, std::clamp(0.05 * extent[up_axis], 2.0, 8.0));
  probe.start_mm = start.start_mm;
  probe.max_speed_mm_s = 150.0;
  sim.probes.push_back(probe);

  // the fast configuration (time_step.h): implicit, one iteration per step, 20 ms steps (30 ms
  // with regional solves near the tool for a large model); the paper's device shaping over two
  // steps
  const int nodes = scene.model->num_nodes();
  const FastConfiguration fast = default_fast_configuration();
  sim.integrator = fast.integrator_for(nodes);
  scene.device_side.device = fast.device_for(nodes);

  scene.notes.push_back(fmt::format("default palpation scene: E = {:g} kPa, damping ratio {:g}, {} nodes held (the lowest "
                                    "{:g} % of the height), capsule probe r = {:.1f} mm {}, the fast configuration: "
                                    "implicit dt = {:.3g} ms, {} iteration per step{}",
                                    material.youngs_modulus_kpa, material.damping_ratio, sim.fixed_nodes.size(),
                                    100.0 * options.held_fraction, probe.geometry.radius_mm,
                                    start.found ? fmt::format("above tissue {:.0f} mm deep", start.tissue_below_mm)
                                                : std::string("above the centre"),
                                    1e3 * sim.integrator.time_step_s,
                                    sim.integrator.max_iterations,
                                    sim.integrator.region_radius_mm > 0
                                        ? fmt::format(", regional solves within {:g} mm of the tool",
                                                      sim.integrator.region_radius_mm)
                                        : std::string()));
  make_probes_live(scene);
  return scene;
}

std::string physics_configuration(const IntegratorSettings& in, const PhysicsModel& p) {
  std::string s = in.kind == IntegratorKind::implicit         ? "implicit"
                  : in.kind == IntegratorKind::symplectic_euler ? "symplectic Euler"
                                                                : "explicit Euler";
  s += in.time_step_s >= 1e-3 ? fmt::format(" {:.3g} ms", 1e3 * in.time_step_s) : fmt::format(" {:.3g} us", 1e6 * in.time_step_s);
  if (in.kind == IntegratorKind::implicit) {
    s += fmt::format(", {} iteration{}", in.max_iterations, in.max_iterations == 1 ? "" : "s");
    if (in.residual_tolerance_n > 0) s += fmt::format(" (to {:.2g} N)", in.residual_tolerance_n);
    if (in.region_radius_mm > 0) s += fmt::format(", region {:g} mm", in.region_radius_mm);
  }
  if (p.mass_scaling.factor != 1.0) s += fmt::format(", mass x{:g}", p.mass_scaling.factor);
  if (p.mass_scaling.time_step_s > 0) s += fmt::format(", mass floor for {:.3g} ms", 1e3 * p.mass_scaling.time_step_s);
  return s;
}

void make_probes_live(ProbeScene& scene) {
  SimulationSettings& sim = scene.simulation;
  const Eigen::Vector3d lo = scene.model->rest_positions.rowwise().minCoeff();
  const Eigen::Vector3d hi = scene.model->rest_positions.rowwise().maxCoeff();
  const Eigen::Vector3d extent = hi - lo;
  scene.probe_allowed.clear();
  bool first_live = true;
  for (auto& p : sim.probes) {
    const Eigen::Vector3d start = p.initial_position();
    if (p.drive == ProbeDrive::live && first_live) {
      // the scene's stick mapping of its first live probe sets the app's defaults
      first_live = false;
      scene.control_from_scene = true;
      scene.control.mapping = p.mapping;
    }
    if (p.drive != ProbeDrive::live) {
      p.drive = ProbeDrive::live;
      p.start_mm = start;
      p.path.clear();
      p.joystick.clear();
    }
    if (!(p.max_speed_mm_s > 0)) p.max_speed_mm_s = 150.0;
    Box allowed;
    const double r = p.geometry.shape == ProbeShape::plane ? 0.0 : p.geometry.radius_mm;
    if (sim.workspace.enabled) {
      allowed.lo = sim.workspace.min_mm + Eigen::Vector3d::Constant(r);
      allowed.hi = sim.workspace.max_mm - Eigen::Vector3d::Constant(r);
      allowed.lo = allowed.lo.cwiseMin(start);
      allowed.hi = allowed.hi.cwiseMax(start);
    } else {
      allowed.lo = (lo - 0.5 * extent).cwiseMin(start);
      allowed.hi = (hi + 0.5 * extent).cwiseMax(start);
    }
    scene.probe_allowed.push_back(allowed);
  }
}

ProbeScene load_probe_scene(const std::filesystem::path& input, const DefaultSceneOptions& options) {
  namespace fs = std::filesystem;
  if (!fs::exists(input)) throw Error("input '" + input.string() + "' does not exist");
  const std::string ext = lower_extension(input);
  const std::string name = input.filename().string();

  if (ext == ".json") return load_scene_file(input, options);

  if (ext == ".vtu") {
    // a model written by `voxelastic convert`, with its surface if given
    auto model = std::make_shared<const Model>(load_model(input));
    std::shared_ptr<const EmbeddedSurface> surface;
    std::string how;
    if (!options.surface.empty()) {
      surface = std::make_shared<const EmbeddedSurface>(load_surface(options.surface, model.get()));
      how = "surface " + options.surface.string();
    } else {
      const VoxelGrid grid = grid_from_model(*model);
      surface = std::make_shared<const EmbeddedSurface>(make_surface(*model, grid, nullptr, options.surface_method));
      how = std::string(to_string(options.surface_method)) + " surface of the model's voxels";
    }
    ProbeScene scene = make_default_scene(model, surface, options, Eigen::Vector3d(0, -1, 0), name);
    scene.notes.insert(scene.notes.begin(),
                       fmt::format("model {}: {} nodes, {} elements in {} levels; {} ({} triangles)", input.string(),
                                   model->num_nodes(), model->num_elements(), model->num_levels(), how,
                                   surface->num_triangles()));
    use_display_surface(scene, options);
    return scene;
  }

  if (fs::is_directory(input) || !volume_format(input).empty()) {
    // a CT-like volume: threshold, largest component, fill holes, build the gradational model
    const Volume volume = read_volume(input);
    PrepareOptions prep;
    prep.range = parse_threshold(options.threshold);
    prep.largest_component = true;
    prep.fill_holes = true;
    prep.voxel_mm = options.voxel_mm;
    prep.lattice_period = 4;  // the fewest vertex entries (docs/model.md section 3.5)
    PrepareReport report;
    const VoxelGrid grid = prepare_grid(volume, prep, &report);
    BuildReport build;
    BuildSettings settings;
    if (grid.dims().z() == 1) settings.dimensions = 2;  // one slice: the 2D model
    auto model = std::make_shared<const Model>(build_model(grid, settings, &build));
    auto surface = std::make_shared<const EmbeddedSurface>(make_surface(*model, grid, nullptr, options.surface_method));
    ProbeScene scene = make_default_scene(model, surface, options, Eigen::Vector3d(0, -1, 0), name);
    scene.notes.insert(scene.notes.begin(),
                       fmt::format("volume {}: {} tissue voxels -> {} nodes, {} elements in {} levels; "
                                   "{} surface ({} triangles)",
                                   input.string(), report.tissue_voxels, model->num_nodes(), model->num_elements(),
                                   model->num_levels(), to_string(surface->method), surface->num_triangles()));
    use_display_surface(scene, options);
    return scene;
  }
  throw Error("input '" + input.string() +
              "': not a scene (.json), a volume (.vti .mha .mhd .nii .nii.gz .nrrd .nhdr, DICOM folder) "
              "or a model (.vtu)");
}

}  // namespace vx::probe
