// A palpation map: the grid of points over a face, one press per point from rest, in parallel;
// its summary (lesion estimate, extent, contrast). The files it writes are palpation_map_output.cpp.
#include "scene/palpation_map.h"

#include <fmt/format.h>
#include <omp.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <numbers>
#include <nlohmann/json.hpp>

#include "base/error.h"
#include "base/parallel.h"
#include "io/volume_io.h"
#include "sim/simulation.h"

namespace vx {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// A finite positive number.
bool positive(double x) { return std::isfinite(x) && x > 0; }

/// The median of `x` (NaN when empty); x is reordered.
double median(std::vector<double> x) {
  if (x.empty()) return kNaN;
  const std::size_t m = x.size() / 2;
  std::nth_element(x.begin(), x.begin() + std::ptrdiff_t(m), x.end());
  const double hi = x[m];
  if (x.size() % 2 == 1) return hi;
  return 0.5 * (hi + *std::max_element(x.begin(), x.begin() + std::ptrdiff_t(m)));
}

/// The top node of each bin of the face's plane: its in-plane position and its height.
struct TopNode {
  double u{0}, v{0}, h{-std::numeric_limits<double>::infinity()};
  bool occupied() const { return std::isfinite(h); }
};

/// The face's frame and the bins of the object seen from it.
struct FaceView {
  int axis{2}, ua{0}, va{1};
  double outward{1.0};
  double bin{1.0}, u0{0}, v0{0};  ///< bin (a, b) is centred at (u0 + a bin, v0 + b bin)
  int nu{0}, nv{0};
  std::vector<TopNode> top;       ///< nu x nv, a fastest
  double highest{0};              ///< the highest node along the outward normal

  [[nodiscard]] const TopNode& at(int a, int b) const { return top[std::size_t(a + nu * b)]; }
  /// LPS point of in-plane (u, v) at height h.
  [[nodiscard]] Eigen::Vector3d point(double u, double v, double h) const {
    Eigen::Vector3d p;
    p[axis] = outward * h;
    p[ua] = u;
    p[va] = v;
    return p;
  }
};

FaceView face_view(const Model& model, BoxFace face) {
  FaceView f;
  f.axis = int(face) / 2;
  f.outward = int(face) % 2 == 1 ? 1.0 : -1.0;
  f.ua = (f.axis + 1) % 3;
  f.va = (f.axis + 2) % 3;
  f.bin = model.grid.spacing_mm.minCoeff();
  const Eigen::Matrix3Xd& x = model.rest_positions;
  const double umin = x.row(f.ua).minCoeff(), umax = x.row(f.ua).maxCoeff();
  const double vmin = x.row(f.va).minCoeff(), vmax = x.row(f.va).maxCoeff();
  f.u0 = umin;
  f.v0 = vmin;
  f.nu = int(std::floor((umax - umin) / f.bin + 0.5)) + 1;
  f.nv = int(std::floor((vmax - vmin) / f.bin + 0.5)) + 1;
  f.top.assign(std::size_t(f.nu) * std::size_t(f.nv), TopNode{});
  f.highest = -std::numeric_limits<double>::infinity();
  for (Eigen::Index n = 0; n < x.cols(); ++n) {
    const double u = x(f.ua, n), v = x(f.va, n), h = f.outward * x(f.axis, n);
    const int a = std::clamp(int(std::floor((u - f.u0) / f.bin + 0.5)), 0, f.nu - 1);
    const int b = std::clamp(int(std::floor((v - f.v0) / f.bin + 0.5)), 0, f.nv - 1);
    TopNode& t = f.top[std::size_t(a + f.nu * b)];
    if (h > t.h) t = {u, v, h};
    f.highest = std::max(f.highest, h);
  }
  return f;
}

/// Whether the ball can press at (u, v), and the height of its lowest point at first contact.
bool first_contact(const FaceView& f, double u, double v, double radius, double& contact_h) {
  const int a0 = int(std::floor((u - radius - f.u0) / f.bin)), a1 = int(std::ceil((u + radius - f.u0) / f.bin));
  const int b0 = int(std::floor((v - radius - f.v0) / f.bin)), b1 = int(std::ceil((v + radius - f.v0) / f.bin));
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  contact_h = -std::numeric_limits<double>::infinity();
  for (int b = b0; b <= b1; ++b)
    for (int a = a0; a <= a1; ++a) {
      const double du = f.u0 + a * f.bin - u, dv = f.v0 + b * f.bin - v;
      const bool under = du * du + dv * dv <= radius * radius;  // the bin's centre is under the ball
      if (a < 0 || b < 0 || a >= f.nu || b >= f.nv || !f.at(a, b).occupied()) {
        if (under) return false;  // air under the ball: not a point of this face
        continue;
      }
      const TopNode& t = f.at(a, b);
      if (under) {
        lo = std::min(lo, t.h);
        hi = std::max(hi, t.h);
      }
      const double d2 = (t.u - u) * (t.u - u) + (t.v - v) * (t.v - v);
      if (d2 < radius * radius) contact_h = std::max(contact_h, t.h + std::sqrt(radius * radius - d2) - radius);
    }
  return std::isfinite(contact_h) && hi - lo < radius;
}

}  // namespace

std::string PalpationMapSettings::validate() const {
  std::string e;
  if (!positive(spacing_mm)) e += fmt::format("spacing {} mm must be > 0; ", spacing_mm);
  if (!positive(depth_mm)) e += fmt::format("depth {} mm must be > 0; ", depth_mm);
  if (!positive(probe_radius_mm)) e += fmt::format("probe radius {} mm must be > 0; ", probe_radius_mm);
  if (!positive(speed_mm_s)) e += fmt::format("press speed {} mm/s must be > 0; ", speed_mm_s);
  if (!(std::isfinite(gap_mm) && gap_mm >= 0)) e += fmt::format("gap {} mm must be >= 0; ", gap_mm);
  if (!positive(hold_s)) e += fmt::format("hold {} s must be > 0; ", hold_s);
  if (!positive(average_s) || average_s > hold_s)
    e += fmt::format("the force's averaging time {} s must be > 0 and at most the hold ({} s); ", average_s, hold_s);
  if (depth_mm >= probe_radius_mm) e += fmt::format("depth {} mm must be less than the probe radius {} mm; ", depth_mm, probe_radius_mm);
  if (threads < 0) e += fmt::format("threads {} must be >= 0 (0: every core); ", threads);
  return e;
}

std::string face_name(BoxFace face) {
  static const char* names[] = {"-x", "+x", "-y", "+y", "-z", "+z"};
  return names[int(face)];
}

BoxFace parse_face(const std::string& text) {
  static const char* signs[] = {"-x", "+x", "-y", "+y", "-z", "+z"};
  static const char* words[] = {"x_min", "x_max", "y_min", "y_max", "z_min", "z_max"};
  for (int k = 0; k < 6; ++k)
    if (text == signs[k] || text == words[k]) return BoxFace(k);
  if (text == "x" || text == "y" || text == "z") return BoxFace(2 * (text[0] - 'x') + 1);
  throw Error(fmt::format("face '{}' is not one of +x, -x, +y, -y, +z, -z (the direction the face looks in; "
                          "x_max, x_min, ... are accepted too)",
                          text));
}

Scene palpation_scene(const fs::path& input, const PalpationSceneOptions& o) {
  if (!fs::exists(input)) throw Error(fmt::format("'{}' does not exist", input.string()));
  const std::string ext = input.extension().string();
  Scene scene;
  if (ext == ".json") {
    scene = load_scene(input);
  } else {
    static const char* fixed_face[] = {"x_max", "x_min", "y_max", "y_min", "z_max", "z_min"};  // the opposite one
    json j;
    const bool model = ext == ".vtu";
    if (!model && volume_format(input).empty())
      throw Error(fmt::format("'{}': not a scene (.json), a model (.vtu) or a volume voxelastic reads (.vti, .nrrd, "
                              ".nii(.gz), .mha, .mhd, a DICOM folder or file)",
                              input.string()));
    j["description"] = fmt::format("palpation map of {}", input.filename().string());
    j["object"] = model ? json{{"model", fs::absolute(input).string()}} : json{{"volume", fs::absolute(input).string()}};
    j["material"] = {{"youngs_modulus_kpa", o.modulus_kpa}, {"damping", o.damping}};
    if (!model && !o.hounsfield.empty()) {
      json rows = json::array();
      for (const HuModulus& r : o.hounsfield) rows.push_back({{"hu", r.hu}, {"youngs_modulus_kpa", r.youngs_modulus_kpa}});
      j["material"]["hounsfield_table"] = rows;
    }
    j["fixed"] = {fixed_face[int(o.face)]};
    j["duration_s"] = 1.0;
    scene = parse_scene(j, fs::current_path(), input.filename().string());
    scene.file = input;
  }
  // the map's own probe, the fast configuration, one physics thread per press, no outputs
  scene.probes.clear();
  scene.device.reset();
  scene.integrator = IntegratorKind::implicit;
  scene.integrator_given = false;
  scene.dt_s = 0.0;
  scene.iterations = 0;
  scene.region_radius_mm = 0.0;
  scene.duration_s = 1.0;
  scene.threads = 1;
  scene.outputs = SceneOutputs{};
  scene.outputs.forces_csv = false;
  scene.outputs.plot = false;
  return scene;
}

PalpationMap palpation_map(const PreparedScene& prepared, const PalpationMapSettings& settings,
                           const std::function<void(int, int)>& progress) {
  if (const std::string e = settings.validate(); !e.empty()) throw Error("palpation map: " + e);
  const Model& model = *prepared.model;
  if (model.is_2d())
    throw Error("palpation map: the object is one slice (a 2D model); map a volume (3D) object instead");
  PalpationMap map;
  map.settings = settings;
  const FaceView f = face_view(model, settings.face);
  map.normal_axis = f.axis;
  map.u_axis = f.ua;
  map.v_axis = f.va;
  map.outward = f.outward;
  map.bins_u = f.nu;
  map.bins_v = f.nv;
  map.bin_mm = f.bin;
  map.bin_u0_mm = f.u0;
  map.bin_v0_mm = f.v0;
  map.bin_height_mm.resize(f.top.size());
  for (std::size_t k = 0; k < f.top.size(); ++k) map.bin_height_mm[k] = f.top[k].occupied() ? f.top[k].h : kNaN;
  map.nodes = model.num_nodes();
  map.elements = model.num_elements();

  // the grid, centred on the object's extent in the plane; the points the ball can press
  const double R = settings.probe_radius_mm, s = settings.spacing_mm;
  const double width_u = (f.nu - 1) * f.bin, width_v = (f.nv - 1) * f.bin;
  map.grid_u = int(std::floor(width_u / s + 1e-9)) + 1;
  map.grid_v = int(std::floor(width_v / s + 1e-9)) + 1;
  map.u0_mm = f.u0 + 0.5 * (width_u - (map.grid_u - 1) * s);
  map.v0_mm = f.v0 + 0.5 * (width_v - (map.grid_v - 1) * s);
  for (int j = 0; j < map.grid_v; ++j)
    for (int i = 0; i < map.grid_u; ++i) {
      PalpationPoint p;
      p.i = i;
      p.j = j;
      p.u_mm = map.u0_mm + i * s;
      p.v_mm = map.v0_mm + j * s;
      double h = 0;
      if (!first_contact(f, p.u_mm, p.v_mm, R, h)) continue;
      p.surface_mm = f.point(p.u_mm, p.v_mm, h);
      map.points.push_back(p);
    }
  if (map.points.empty())
    throw Error(fmt::format("palpation map: no point of the {} face has tissue under the whole {:g} mm ball; map "
                            "another face (--face) or use a smaller probe",
                            face_name(settings.face), R));

  // the press, in steps of the fast configuration (shortened so the ball moves at most a
  // quarter of its radius per step, as a scene's automatic step is)
  SimulationSettings ss = prepared.settings;
  ss.integrator.threads = 1;
  ss.surface.reset();
  ss.integrator.time_step_s = std::min(ss.integrator.time_step_s, 0.25 * R / settings.speed_mm_s);
  const double dt = ss.integrator.time_step_s;
  const Eigen::Vector3d inward = -f.outward * Eigen::Vector3d::Unit(f.axis);
  const double safe_h = f.highest + R + settings.gap_mm + 1.0;  // above every node: the ball travels in the air
  ProbeSettings probe;
  probe.name = "palpation";
  probe.geometry.shape = ProbeShape::sphere;
  probe.geometry.radius_mm = R;
  probe.drive = ProbeDrive::live;
  probe.start_mm = f.point(map.points.front().u_mm, map.points.front().v_mm, safe_h);
  probe.max_speed_mm_s = 1e12;  // it jumps through the air; the press itself is scripted step by step
  ss.probes = {probe};
  const int press_steps = std::max(1, int(std::ceil((settings.gap_mm + settings.depth_mm) / (settings.speed_mm_s * dt) - 1e-9)));
  const int hold_steps = std::max(1, int(std::ceil(settings.hold_s / dt - 1e-9)));
  const int average_steps = std::clamp(int(std::lround(settings.average_s / dt)), 1, hold_steps);
  map.time_step_s = dt;
  map.steps_per_press = 2 + press_steps + hold_steps;

  const int total = int(map.points.size());
  const int threads = int(std::min<std::int64_t>(resolve_threads(settings.threads), total));
  map.threads = threads;
  std::vector<std::unique_ptr<Simulation>> sims(static_cast<std::size_t>(threads));
  std::vector<std::string> setup_error(static_cast<std::size_t>(threads));
  std::mutex lock;
  int done = 0;
  const auto start = std::chrono::steady_clock::now();
  parallel_for(total, 1, threads, [&](std::int64_t b, std::int64_t e) {
    const std::size_t t = std::size_t(std::max(0, omp_get_thread_num()));
    if (!sims[t] && setup_error[t].empty()) {
      try {
        sims[t] = std::make_unique<Simulation>(prepared.physics, ss);
      } catch (const std::exception& ex) {
        setup_error[t] = ex.what();
      }
    }
    for (std::int64_t k = b; k < e; ++k) {
      PalpationPoint& p = map.points[std::size_t(k)];
      if (!sims[t]) {
        p.failure = setup_error[t];
        p.force_n = p.stiffness_n_mm = kNaN;
      } else try {
        Simulation& sim = *sims[t];
        sim.reset();
        const double h0 = f.outward * p.surface_mm[f.axis];
        const auto go = [&](double centre_h) {
          sim.set_live(0, {LiveCommand::Kind::position, f.point(p.u_mm, p.v_mm, centre_h)});
          return sim.step() == StepStatus::ok;
        };
        // through the air to above the point, down to the gap, then the press and the hold
        bool ok = go(safe_h) && go(h0 + R + settings.gap_mm);
        for (int n = 1; ok && n <= press_steps; ++n)
          ok = go(h0 + R + settings.gap_mm - (settings.gap_mm + settings.depth_mm) * n / press_steps);
        double sum = 0;
        for (int n = 1; ok && n <= hold_steps; ++n) {
          ok = go(h0 + R - settings.depth_mm);
          if (ok && n > hold_steps - average_steps) sum += -sim.probe(0).raw_force_n.dot(inward);
        }
        if (!ok || sim.failed()) {
          p.failure = sim.state().message.empty() ? std::string("the press stopped") : sim.state().message;
          p.force_n = p.stiffness_n_mm = kNaN;
        } else {
          p.depth_mm = settings.depth_mm;
          p.force_n = sum / average_steps;
          p.stiffness_n_mm = p.force_n / p.depth_mm;
        }
      } catch (const std::exception& ex) {  // nothing may leave the parallel loop
        p.failure = ex.what();
        p.force_n = p.stiffness_n_mm = kNaN;
      }
      std::lock_guard<std::mutex> g(lock);
      ++done;
      if (progress) progress(done, total);
    }
  });
  map.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return map;
}

PalpationSummary summarize_palpation_map(const PalpationMap& map) {
  PalpationSummary s;
  std::vector<double> k;
  for (const PalpationPoint& p : map.points) {
    if (!p.failure.empty() || !std::isfinite(p.stiffness_n_mm)) {
      ++s.failed;
      continue;
    }
    k.push_back(p.stiffness_n_mm);
  }
  s.points = int(map.points.size());
  if (k.empty()) return s;
  s.background_n_mm = median(k);
  s.peak_n_mm = *std::max_element(k.begin(), k.end());
  s.threshold_n_mm = s.background_n_mm + 0.5 * (s.peak_n_mm - s.background_n_mm);
  // the points above the threshold: weighted centroid, extent; the rest: the surroundings
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  double weight = 0;
  double umin = 1e300, umax = -1e300, vmin = 1e300, vmax = -1e300;
  std::vector<double> below;
  for (const PalpationPoint& p : map.points) {
    if (!p.failure.empty() || !std::isfinite(p.stiffness_n_mm)) continue;
    if (p.stiffness_n_mm < s.threshold_n_mm || s.peak_n_mm == s.background_n_mm) {
      below.push_back(p.stiffness_n_mm);
      if (s.peak_n_mm > s.background_n_mm) continue;
    }
    ++s.points_above;
    const double w = std::max(p.stiffness_n_mm - s.background_n_mm, 1e-300);
    centroid += w * p.surface_mm;
    weight += w;
    umin = std::min(umin, p.u_mm);
    umax = std::max(umax, p.u_mm);
    vmin = std::min(vmin, p.v_mm);
    vmax = std::max(vmax, p.v_mm);
  }
  const double sp = map.settings.spacing_mm;
  if (weight > 0) {
    s.lesion_estimate_mm = centroid / weight;
    s.extent_u_mm = umax - umin + sp;
    s.extent_v_mm = vmax - vmin + sp;
    s.equivalent_diameter_mm = 2.0 * std::sqrt(double(s.points_above) * sp * sp / std::numbers::pi);
  }
  s.surrounding_n_mm = below.empty() ? s.background_n_mm : median(below);
  s.contrast = s.surrounding_n_mm > 0 ? s.peak_n_mm / s.surrounding_n_mm : kNaN;
  return s;
}

}  // namespace vx
