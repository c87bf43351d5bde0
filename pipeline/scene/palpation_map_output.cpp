// The files of a palpation map: map.csv, map.vtp (the pressed points on the surface, triangulated
// over the grid, with per-point stiffness and force), map.png (render/plot.h: the object seen from
// the face, the map over it, a colour bar in N/mm and a scale bar) and summary.json.
#include <fmt/format.h>
#include <vtkCellArray.h>
#include <vtkDoubleArray.h>
#include <vtkFieldData.h>
#include <vtkIntArray.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>

#include <cmath>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>

#include "base/error.h"
#include "io/surface_io.h"
#include "io/vtk_arrays.h"
#include "render/plot.h"
#include "scene/palpation_map.h"
#include "util/atomic_file.h"

namespace vx {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

const char* axis_name(int a) { return a == 0 ? "x" : a == 1 ? "y" : "z"; }

/// `x` for a 0.1 mm label: no "-0.0".
double tidy(double x) { return std::abs(x) < 0.05 ? 0.0 : x; }

/// A number for JSON: null when not finite.
json number(double x) { return std::isfinite(x) ? json(x) : json(nullptr); }

std::string map_csv(const PalpationMap& map) {
  std::ostringstream out;
  out.precision(8);
  out << "x_mm,y_mm,z_mm,force_n,stiffness_n_mm\n";
  for (const PalpationPoint& p : map.points)
    out << p.surface_mm.x() << "," << p.surface_mm.y() << "," << p.surface_mm.z() << "," << p.force_n << ","
        << p.stiffness_n_mm << "\n";
  return out.str();
}

void write_map_vtp(const PalpationMap& map, const fs::path& path) {
  const auto n = vtkIdType(map.points.size());
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(n);
  auto stiffness = make_array<vtkDoubleArray>("stiffness_n_mm", 1, n);
  auto force = make_array<vtkDoubleArray>("force_n", 1, n);
  auto grid = make_array<vtkIntArray>("grid_index", 2, n);
  std::map<std::pair<int, int>, vtkIdType> index;
  vtkNew<vtkCellArray> verts, polys;
  for (vtkIdType k = 0; k < n; ++k) {
    const PalpationPoint& p = map.points[std::size_t(k)];
    points->SetPoint(k, p.surface_mm.data());
    stiffness->SetValue(k, p.stiffness_n_mm);
    force->SetValue(k, p.force_n);
    grid->SetTypedComponent(k, 0, p.i);
    grid->SetTypedComponent(k, 1, p.j);
    index[{p.i, p.j}] = k;
    verts->InsertNextCell(1, &k);
  }
  // two triangles per grid square whose four corners were pressed, facing outward
  const bool flip = (map.outward < 0) != ((map.normal_axis + 1) % 3 != map.u_axis);
  for (const auto& [ij, a] : index) {
    const auto b = index.find({ij.first + 1, ij.second}), c = index.find({ij.first + 1, ij.second + 1}),
               d = index.find({ij.first, ij.second + 1});
    if (b == index.end() || c == index.end() || d == index.end()) continue;
    vtkIdType t0[3] = {a, b->second, c->second}, t1[3] = {a, c->second, d->second};
    if (flip) {
      std::swap(t0[1], t0[2]);
      std::swap(t1[1], t1[2]);
    }
    polys->InsertNextCell(3, t0);
    polys->InsertNextCell(3, t1);
  }
  vtkNew<vtkPolyData> pd;
  pd->SetPoints(points);
  pd->SetVerts(verts);
  pd->SetPolys(polys);
  pd->GetPointData()->AddArray(stiffness);
  pd->GetPointData()->AddArray(force);
  pd->GetPointData()->AddArray(grid);
  pd->GetPointData()->SetActiveScalars("stiffness_n_mm");
  mark_lps(pd->GetFieldData());
  save_polydata(*pd, path);
}

/// A round length for the scale bar: about a fifth of `width`, 1, 2 or 5 times a power of ten.
double scale_bar_mm(double width) {
  const double target = 0.2 * width;
  const double p = std::pow(10.0, std::floor(std::log10(target)));
  for (double m : {5.0, 2.0, 1.0})
    if (m * p <= target) return m * p;
  return p;
}

void write_map_png(const PalpationMap& map, const PalpationSummary& s, const fs::path& path) {
  PlotPanel p;
  // the object seen from the face: grey bins, lighter where higher
  double hmin = 1e300, hmax = -1e300;
  for (double h : map.bin_height_mm)
    if (std::isfinite(h)) {
      hmin = std::min(hmin, h);
      hmax = std::max(hmax, h);
    }
  for (int b = 0; b < map.bins_v; ++b)
    for (int a = 0; a < map.bins_u; ++a) {
      const double h = map.bin_height_mm[std::size_t(a + map.bins_u * b)];
      if (!std::isfinite(h)) continue;
      const int grey = int(std::lround(150 + 80 * (hmax > hmin ? (h - hmin) / (hmax - hmin) : 1.0)));
      const double u = map.bin_u0_mm + a * map.bin_mm, v = map.bin_v0_mm + b * map.bin_mm;
      p.rects.push_back({u - 0.5 * map.bin_mm, v - 0.5 * map.bin_mm, u + 0.5 * map.bin_mm, v + 0.5 * map.bin_mm,
                         fmt::format("#{0:02x}{0:02x}{0:02x}", grey)});
    }
  // the map: one box per pressed point, coloured by its stiffness
  const double half = 0.5 * map.settings.spacing_mm;
  double lo = 1e300;
  for (const PalpationPoint& q : map.points)
    if (std::isfinite(q.stiffness_n_mm)) {
      p.rects.push_back({q.u_mm - half, q.v_mm - half, q.u_mm + half, q.v_mm + half, "", q.stiffness_n_mm});
      lo = std::min(lo, q.stiffness_n_mm);
    }
  p.color_bar.label = "stiffness (force / depth), N/mm";
  p.color_bar.lo = lo < 1e300 ? lo : 0.0;
  p.color_bar.hi = std::isfinite(s.peak_n_mm) && s.peak_n_mm > p.color_bar.lo ? s.peak_n_mm : p.color_bar.lo + 1.0;
  const double u_lo = map.bin_u0_mm - map.bin_mm, u_hi = map.bin_u0_mm + map.bins_u * map.bin_mm;
  const double v_lo = map.bin_v0_mm - map.bin_mm, v_hi = map.bin_v0_mm + map.bins_v * map.bin_mm;
  const double margin = 0.12 * (v_hi - v_lo);  // room under the object for the scale bar
  const double bar = scale_bar_mm(u_hi - u_lo);
  const std::string u = axis_name(map.u_axis), v = axis_name(map.v_axis);
  const Eigen::Vector3d& e = s.lesion_estimate_mm;
  p.title = fmt::format("Palpation map of the {} face: a {:g} mm ball pressed {:g} mm at {} points {:g} mm apart",
                        face_name(map.settings.face), map.settings.probe_radius_mm, map.settings.depth_mm,
                        map.points.size(), map.settings.spacing_mm);
  p.subtitle = fmt::format(
      "contrast {:.3g} (peak {:.3g} / surroundings {:.3g} N/mm); lesion estimate ({:.1f}, {:.1f}, "
      "{:.1f}) mm",
      s.contrast, s.peak_n_mm, s.surrounding_n_mm, tidy(e.x()), tidy(e.y()), tidy(e.z()));
  p.equal_aspect = true;
  p.xlabel = u + " (mm)";
  p.ylabel = v + " (mm)";
  p.xrange = fmt::format("[{:.8g}:{:.8g}]", u_lo, u_hi);
  p.yrange = fmt::format("[{:.8g}:{:.8g}]", v_lo - margin, v_hi);
  // the scale bar, bottom left, and the estimate
  const double bx = u_lo + 0.05 * (u_hi - u_lo), by = v_lo - 0.5 * margin;
  PlotSeries scale;
  scale.x = {bx, bx + bar};
  scale.y = {by, by};
  scale.color = "black";
  scale.line_width = 4;
  p.series.push_back(scale);
  p.labels.push_back({fmt::format("{:g} mm", bar), bx + 0.5 * bar, by + 0.25 * margin});
  if (s.lesion_estimate_mm.allFinite())
    p.labels.push_back(
        {"estimate", s.lesion_estimate_mm[map.u_axis], s.lesion_estimate_mm[map.v_axis], "#e00000", true});
  const int width = 1000;
  const double aspect = (v_hi - v_lo + margin) / (u_hi - u_lo);
  plot_png({p}, path, width, std::clamp(int(std::lround(0.78 * width * aspect)) + 150, 400, 1400));
}

}  // namespace

json palpation_summary_json(const PalpationMap& map, const PalpationSummary& s) {
  const PalpationMapSettings& o = map.settings;
  json j;
  j["map"] = {{"face", face_name(o.face)},
              {"plane_axes", {axis_name(map.u_axis), axis_name(map.v_axis)}},
              {"spacing_mm", o.spacing_mm},
              {"depth_mm", o.depth_mm},
              {"probe_radius_mm", o.probe_radius_mm},
              {"speed_mm_s", o.speed_mm_s},
              {"hold_s", o.hold_s},
              {"grid", {map.grid_u, map.grid_v}},
              {"points", s.points},
              {"failed", s.failed},
              {"time_step_s", map.time_step_s},
              {"steps_per_press", map.steps_per_press},
              {"threads", map.threads},
              {"wall_s", map.wall_s},
              {"model", {{"nodes", map.nodes}, {"elements", map.elements}}}};
  j["stiffness_n_mm"] = {{"background", number(s.background_n_mm)},
                         {"peak", number(s.peak_n_mm)},
                         {"threshold", number(s.threshold_n_mm)},
                         {"surrounding", number(s.surrounding_n_mm)}};
  j["lesion_estimate_mm"] = {number(s.lesion_estimate_mm.x()), number(s.lesion_estimate_mm.y()),
                             number(s.lesion_estimate_mm.z())};
  j["extent_mm"] = {{axis_name(map.u_axis), number(s.extent_u_mm)},
                    {axis_name(map.v_axis), number(s.extent_v_mm)},
                    {"equivalent_diameter", number(s.equivalent_diameter_mm)}};
  j["points_above_threshold"] = s.points_above;
  j["contrast"] = number(s.contrast);
  return j;
}

void write_palpation_map(const PalpationMap& map, const PalpationSummary& summary, const fs::path& dir,
                         const json& extra, bool png) {
  write_text_atomically(dir / "map.csv", map_csv(map));
  write_map_vtp(map, dir / "map.vtp");
  if (png) write_map_png(map, summary, dir / "map.png");
  json j = palpation_summary_json(map, summary);
  j.update(extra);
  write_text_atomically(dir / "summary.json", j.dump(2) + "\n");
}

}  // namespace vx
