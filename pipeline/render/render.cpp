#include "render/render.h"

#include <dlfcn.h>
#include <vtkActor.h>
#include <vtkActor2D.h>
#include <vtkAxesActor.h>
#include <vtkCamera.h>
#include <vtkCaptionActor2D.h>
#include <vtkCellArray.h>
#include <vtkCellData.h>
#include <vtkCoordinate.h>
#include <vtkIntArray.h>
#include <vtkLookupTable.h>
#include <vtkNew.h>
#include <vtkPNGWriter.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataMapper.h>
#include <vtkPolyDataMapper2D.h>
#include <vtkProperty.h>
#include <vtkProperty2D.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkTextActor.h>
#include <vtkTextProperty.h>
#include <vtkWindowToImageFilter.h>

#include <fmt/core.h>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <mutex>
#include <string>
#include <vector>

#include "base/error.h"
#include "io/element_faces.h"
#include "render/palette.h"
#include "util/atomic_file.h"
#include "util/vtk_messages.h"

namespace vx {
namespace fs = std::filesystem;

namespace {

/// Opens the X display named by DISPLAY and checks it offers GLX (OpenGL), through libX11
/// loaded at run time: no X11 link dependency, and no VTK window (which would crash without X).
/// The first connection that passes stays open for the life of the process: an X server resets
/// when its last client leaves (Xvfb under xvfb-run does), a connection opened during the reset
/// fails, and VTK then aborts. Closing this one let VTK's own connection land in that reset (a
/// rare abort of the render tests, 6 in 100 pairs under load; docs/robustness.md).
bool probe_x_display() {
  static std::mutex mutex;
  static void* kept = nullptr;
  const std::lock_guard lock(mutex);
  if (kept) return true;
  const char* name = std::getenv("DISPLAY");
  if (!name || !*name) return false;
  void* x11 = ::dlopen("libX11.so.6", RTLD_LAZY | RTLD_LOCAL);
  if (!x11) return false;
  using OpenDisplay = void* (*)(const char*);
  using CloseDisplay = int (*)(void*);
  using QueryExtension = int (*)(void*, const char*, int*, int*, int*);
  auto open = reinterpret_cast<OpenDisplay>(::dlsym(x11, "XOpenDisplay"));
  auto close = reinterpret_cast<CloseDisplay>(::dlsym(x11, "XCloseDisplay"));
  auto query = reinterpret_cast<QueryExtension>(::dlsym(x11, "XQueryExtension"));
  bool ok = false;
  if (open && close && query) {
    if (void* display = open(name)) {
      int opcode = 0, event = 0, error = 0;
      ok = query(display, "GLX", &opcode, &event, &error) != 0;
      if (ok)
        kept = display;
      else
        close(display);
    }
  }
  // libX11 stays loaded: it registers handlers at load time, and VTK uses it anyway
  return ok;
}

/// A length with 1, 2 or 5 as its leading digit, at most `mm`.
double round_length(double mm) {
  const double p = std::pow(10.0, std::floor(std::log10(mm)));
  for (double f : {5.0, 2.0, 1.0})
    if (f * p <= mm) return f * p;
  return p;
}

std::string format_mm(double mm) {
  return mm >= 10 ? fmt::format("{:.0f} mm", mm)
                  : (mm >= 1 ? fmt::format("{:.1f} mm", mm) : fmt::format("{:.2f} mm", mm));
}

vtkSmartPointer<vtkTextActor> make_text(const std::string& text, int size, double x, double y, int justify,
                                        bool bold = false, double grey = 0.1) {
  auto t = vtkSmartPointer<vtkTextActor>::New();
  t->SetInput(text.c_str());
  t->GetPositionCoordinate()->SetCoordinateSystemToNormalizedViewport();
  t->SetPosition(x, y);
  vtkTextProperty* p = t->GetTextProperty();
  p->SetFontFamilyToArial();
  p->SetFontSize(size);
  p->SetBold(bold);
  p->SetColor(grey, grey, grey);
  p->SetJustification(justify);
  p->SetVerticalJustificationToCentered();
  return t;
}

/// A 2D shape in normalized viewport coordinates: a filled polygon, or an open polyline.
vtkSmartPointer<vtkActor2D> make_shape(const std::vector<std::array<double, 2>>& xy, bool filled,
                                       const std::array<double, 3>& colour, double line_width = 1.0) {
  vtkNew<vtkPoints> pts;
  for (const auto& p : xy) pts->InsertNextPoint(p[0], p[1], 0.0);
  vtkNew<vtkCellArray> cells;
  cells->InsertNextCell(vtkIdType(xy.size()));
  for (vtkIdType i = 0; i < vtkIdType(xy.size()); ++i) cells->InsertCellPoint(i);
  vtkNew<vtkPolyData> pd;
  pd->SetPoints(pts);
  if (filled)
    pd->SetPolys(cells);
  else
    pd->SetLines(cells);
  vtkNew<vtkCoordinate> coord;
  coord->SetCoordinateSystemToNormalizedViewport();
  vtkNew<vtkPolyDataMapper2D> mapper;
  mapper->SetInputData(pd);
  mapper->SetTransformCoordinate(coord);
  auto actor = vtkSmartPointer<vtkActor2D>::New();
  actor->SetMapper(mapper);
  actor->GetProperty()->SetColor(colour[0], colour[1], colour[2]);
  actor->GetProperty()->SetLineWidth(float(line_width));
  return actor;
}

/// Where the model is and how it is seen: the box of its nodes (LPS mm), and the direction
/// towards the camera (from the patient's front-left and above: LPS -y anterior, +x left, +z
/// superior).
/// A 2D (slice) model is seen face on, from the side opposite its normal e1 x e2 (an axial
/// slice from the feet, as radiology shows it), superior up (anterior for an axial slice).
struct ModelView {
  Eigen::Vector3d lo, hi, centre, extent;
  Eigen::Vector3d view{Eigen::Vector3d(0.9, -1.5, 0.85).normalized()};
  Eigen::Vector3d up{Eigen::Vector3d::UnitZ()};  ///< screen up (before removing its part along view)
  explicit ModelView(const Model& model)
      : lo(model.rest_positions.rowwise().minCoeff()),
        hi(model.rest_positions.rowwise().maxCoeff()),
        centre(0.5 * (lo + hi)),
        extent(hi - lo) {
    if (model.is_2d()) {
      view = -model.grid.direction.col(0).cross(model.grid.direction.col(1)).normalized();
      up = std::abs(view.z()) > 0.9 ? Eigen::Vector3d(0, -1, 0) : Eigen::Vector3d::UnitZ();
    }
  }
};

/// The elements' faces with their level as cell data, without those whose centroid lies in the
/// octant facing the camera when `settings.cutaway` (and that leaves some but not all);
/// `cutaway` says whether it was cut.
vtkSmartPointer<vtkPolyData> level_faces(const Model& model, const ModelView& mv, const RenderSettings& settings,
                                         bool& cutaway) {
  const auto cut = [&](int e) {
    if (!settings.cutaway) return false;
    const Eigen::Vector3d d = model.rest_centroids.col(e) - mv.centre;
    return d.x() * mv.view.x() > 0 && d.y() * mv.view.y() > 0 && d.z() * mv.view.z() > 0;
  };
  int kept_elements = 0;
  for (int e = 0; e < model.num_elements(); ++e) kept_elements += !cut(e);
  cutaway = settings.cutaway && !model.is_2d() && kept_elements > 0 && kept_elements < model.num_elements();

  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(model.num_nodes());
  for (int i = 0; i < model.num_nodes(); ++i) points->SetPoint(i, model.rest_positions.col(i).data());
  vtkNew<vtkCellArray> polys;
  vtkNew<vtkIntArray> levels;
  levels->SetName("level");
  FacePolygons faces;
  std::vector<vtkIdType> ids;
  for (int e = 0; e < model.num_elements(); ++e) {
    if (cutaway && cut(e)) continue;
    if (model.is_2d()) {
      // a 2D element is one polygon: its vertex list goes round it
      const int b = model.element_offsets[std::size_t(e)], n = model.num_vertices(e);
      ids.assign(model.element_vertices.begin() + b, model.element_vertices.begin() + b + n);
      polys->InsertNextCell(vtkIdType(ids.size()), ids.data());
      levels->InsertNextValue(model.element_level[std::size_t(e)]);
      continue;
    }
    faces.clear();
    append_element_faces(model, e, faces);
    for (int f = 0; f < faces.size(); ++f) {
      ids.assign(faces.nodes.begin() + faces.offsets[std::size_t(f)],
                 faces.nodes.begin() + faces.offsets[std::size_t(f) + 1]);
      polys->InsertNextCell(vtkIdType(ids.size()), ids.data());
      levels->InsertNextValue(model.element_level[std::size_t(e)]);
    }
  }
  auto surface = vtkSmartPointer<vtkPolyData>::New();
  surface->SetPoints(points);
  surface->SetPolys(polys);
  surface->GetCellData()->SetScalars(levels);
  return surface;
}

/// The faces coloured by level (palette.h), flat, with element outlines (thinner when there
/// are many faces per pixel, so they do not blacken the picture).
vtkSmartPointer<vtkActor> level_actor(vtkPolyData* surface, int num_levels, const RenderSettings& settings) {
  vtkNew<vtkLookupTable> lut;
  lut->SetNumberOfTableValues(num_levels);
  lut->SetTableRange(0, std::max(num_levels - 1, 1));
  for (int l = 0; l < num_levels; ++l) {
    const auto c = level_colour(l);
    lut->SetTableValue(l, c[0], c[1], c[2], 1.0);
  }
  lut->Build();
  vtkNew<vtkPolyDataMapper> mapper;
  mapper->SetInputData(surface);
  mapper->SetLookupTable(lut);
  mapper->SetScalarModeToUseCellData();
  mapper->SetScalarRange(0, std::max(num_levels - 1, 1));
  if (num_levels == 1) mapper->SetScalarRange(0, 1);
  mapper->SetColorModeToMapScalars();
  auto actor = vtkSmartPointer<vtkActor>::New();
  actor->SetMapper(mapper);
  vtkProperty* prop = actor->GetProperty();
  prop->SetInterpolationToFlat();
  prop->SetAmbient(0.3);
  prop->SetDiffuse(0.75);
  prop->SetSpecular(0.0);
  const double faces_per_pixel =
      double(surface->GetPolys()->GetNumberOfCells()) / (double(settings.width) * settings.height);
  prop->SetEdgeVisibility(true);
  const double edge_grey = faces_per_pixel > 0.02 ? 0.35 : 0.15;
  prop->SetEdgeColor(edge_grey, edge_grey, edge_grey);
  prop->SetLineWidth(1.0f);
  return actor;
}

/// The picture's parts: a title band on top, the legend on the right, the model in the rest,
/// the orientation marker in its corner; sizes in pixels of the model's part.
struct PictureLayout {
  double legend_x{0.74}, title_y{0.93};
  double scene_w{0}, scene_h{0};
  double font_scale{1.0};  ///< text sizes follow the picture size (designed for 1200 x 900)
  vtkNew<vtkRenderer> scene, band, legend, axes;

  explicit PictureLayout(const RenderSettings& settings) {
    title_y = settings.title.empty() ? 0.93 : 0.88;
    scene_w = settings.width * legend_x;
    scene_h = settings.height * title_y;
    font_scale = std::clamp(std::min(settings.width / 1200.0, settings.height / 900.0), 0.5, 4.0);
    scene->SetViewport(0.0, 0.0, legend_x, title_y);
    band->SetViewport(0.0, title_y, 1.0, 1.0);
    legend->SetViewport(legend_x, 0.0, 1.0, title_y);
    axes->SetViewport(0.0, 0.0, 0.14 * legend_x, 0.17 * title_y);
    for (vtkRenderer* r : {scene.Get(), band.Get(), legend.Get()}) r->SetBackground(1.0, 1.0, 1.0);
    scene->SetBackground(0.97, 0.97, 0.98);
    scene->SetBackground2(0.86, 0.88, 0.92);
    scene->GradientBackgroundOn();
    axes->SetLayer(1);
    axes->InteractiveOff();
  }
  [[nodiscard]] int font(int points) const { return std::max(8, int(std::lround(points * font_scale))); }
};

/// Parallel projection (so the scale bar is exact), framing the model's projection with
/// margins: 12 % of the height, and room for the axes and the scale bar at the bottom.
void frame_camera(vtkCamera* camera, const Model& model, const ModelView& mv, const PictureLayout& layout) {
  const Eigen::Vector3d up = (mv.up - mv.up.dot(mv.view) * mv.view).normalized();  // superior up (2D: see ModelView)
  const Eigen::Vector3d right = (-mv.view).cross(up);
  Eigen::Vector2d plo(1e300, 1e300), phi(-1e300, -1e300);
  for (int i = 0; i < model.num_nodes(); ++i) {
    const Eigen::Vector3d d = model.rest_positions.col(i) - mv.centre;
    const Eigen::Vector2d q(d.dot(right), d.dot(up));
    plo = plo.cwiseMin(q);
    phi = phi.cwiseMax(q);
  }
  const Eigen::Vector2d pmid = 0.5 * (plo + phi), phalf = 0.5 * (phi - plo);
  const double radius = 0.5 * mv.extent.norm() + 1e-6;
  const Eigen::Vector3d focal = mv.centre + pmid.x() * right + pmid.y() * up;
  const Eigen::Vector3d eye = focal + mv.view * (4.0 * radius);
  camera->ParallelProjectionOn();
  camera->SetFocalPoint(focal.data());
  camera->SetPosition(eye.data());
  camera->SetViewUp(up.data());
  camera->SetParallelScale(std::max({phalf.y(), phalf.x() * layout.scene_h / layout.scene_w, 1e-6}) * 1.22);
  camera->SetClippingRange(radius, 7.0 * radius);
}

/// The orientation marker: L, P, S axes turning with the camera.
void add_orientation_marker(const ModelView& mv, PictureLayout& layout) {
  vtkNew<vtkAxesActor> triad;
  triad->SetXAxisLabelText("L");
  triad->SetYAxisLabelText("P");
  triad->SetZAxisLabelText("S");
  triad->SetShaftTypeToCylinder();
  triad->SetTotalLength(1.0, 1.0, 1.0);
  for (vtkCaptionActor2D* c :
       {triad->GetXAxisCaptionActor2D(), triad->GetYAxisCaptionActor2D(), triad->GetZAxisCaptionActor2D()}) {
    c->GetCaptionTextProperty()->SetColor(0.1, 0.1, 0.1);
    c->GetCaptionTextProperty()->ShadowOff();
    c->GetCaptionTextProperty()->ItalicOff();
    c->GetCaptionTextProperty()->SetFontSize(layout.font(14));
    c->GetTextActor()->SetTextScaleModeToNone();
  }
  layout.axes->AddActor(triad);
  vtkCamera* axes_camera = layout.axes->GetActiveCamera();
  axes_camera->SetFocalPoint(0, 0, 0);
  const Eigen::Vector3d axes_eye = mv.view * 10.0;
  axes_camera->SetPosition(axes_eye.data());
  axes_camera->SetViewUp(mv.up.data());
  layout.axes->ResetCamera();
  axes_camera->Zoom(1.3);
}

/// A scale bar: a round length about a fifth of the model's view, at the bottom right.
void add_scale_bar(PictureLayout& layout) {
  const double px_per_mm = layout.scene_h / (2.0 * layout.scene->GetActiveCamera()->GetParallelScale());
  const double bar_mm = round_length(0.2 * layout.scene_w / px_per_mm);
  const double bar_w = bar_mm * px_per_mm / layout.scene_w;  // normalized viewport
  const double bx1 = 0.95, bx0 = bx1 - bar_w, by = 0.06, tick = 0.015;
  layout.scene->AddActor2D(
      make_shape({{bx0, by + tick}, {bx0, by}, {bx1, by}, {bx1, by + tick}}, false, {0.1, 0.1, 0.1}, 2.0));
  layout.scene->AddActor2D(
      make_text(format_mm(bar_mm), layout.font(16), 0.5 * (bx0 + bx1), by + 0.035, VTK_TEXT_CENTERED));
}

/// The title band: the title (when given) over the model's layout and size.
void add_title(const Model& model, const RenderSettings& settings, PictureLayout& layout) {
  const int num_levels = model.num_levels();
  const std::string what = fmt::format("{}{} model: {} elements in {} level{}, {} nodes",
                                       model.is_2d() ? "2D (slice) " : "", to_string(model.layout),
                                       model.num_elements(), num_levels, num_levels == 1 ? "" : "s", model.num_nodes());
  if (!settings.title.empty()) {
    layout.band->AddActor2D(make_text(settings.title, layout.font(24), 0.5, 0.66, VTK_TEXT_CENTERED, true));
    layout.band->AddActor2D(make_text(what, layout.font(16), 0.5, 0.24, VTK_TEXT_CENTERED, false, 0.3));
  } else {
    layout.band->AddActor2D(make_text(what, layout.font(18), 0.5, 0.5, VTK_TEXT_CENTERED, true));
  }
}

/// The legend: one swatch per level with its element count and element size, then the
/// tissue's extent, the voxel size and how the model is seen.
void add_legend(const Model& model, const ModelView& mv, bool cutaway, const RenderSettings& settings,
                PictureLayout& layout) {
  vtkRenderer* legend = layout.legend;
  const auto font = [&](int points) { return layout.font(points); };
  const int num_levels = model.num_levels();
  const std::vector<std::int64_t> per_level = model.elements_per_level();
  std::vector<double> size_mm(std::size_t(num_levels), 0.0);
  for (int e = 0; e < model.num_elements(); ++e)
    size_mm[std::size_t(model.element_level[std::size_t(e)])] = model.element_size_mm[std::size_t(e)];
  const double line = std::min(0.065, 0.62 / (num_levels + 2));
  double y = 0.95;
  legend->AddActor2D(make_text("element level", font(18), 0.08, y, VTK_TEXT_LEFT, true));
  legend->AddActor2D(make_text("(count, element edge)", font(14), 0.08, y - 0.035, VTK_TEXT_LEFT, false, 0.35));
  y -= 0.035 + line;
  // square swatches: half height in the legend's normalized height, width converted by its aspect
  const double half = 0.28 * line, sw = 2.0 * half * layout.scene_h / (settings.width * (1.0 - layout.legend_x));
  for (int l = 0; l < num_levels; ++l, y -= line) {
    legend->AddActor2D(make_shape({{0.08, y - half}, {0.08 + sw, y - half}, {0.08 + sw, y + half}, {0.08, y + half}},
                                  true, level_colour(l)));
    legend->AddActor2D(
        make_shape({{0.08, y - half}, {0.08 + sw, y - half}, {0.08 + sw, y + half}, {0.08, y + half}, {0.08, y - half}},
                   false, {0.2, 0.2, 0.2}));
    legend->AddActor2D(make_text(
        fmt::format("level {}: {} elements, {}", l, per_level[std::size_t(l)], format_mm(size_mm[std::size_t(l)])),
        font(15), 0.08 + sw + 0.04, y, VTK_TEXT_LEFT));
  }
  // size and view notes under the legend
  y -= 0.5 * line;
  legend->AddActor2D(make_text("tissue extent (mm)", font(15), 0.08, y, VTK_TEXT_LEFT, true));
  y -= 0.04;
  legend->AddActor2D(
      make_text(fmt::format("R-L {:.1f}, A-P {:.1f}, I-S {:.1f}", mv.extent.x(), mv.extent.y(), mv.extent.z()),
                font(14), 0.08, y, VTK_TEXT_LEFT));
  y -= 0.04;
  if (model.is_2d())
    legend->AddActor2D(make_text(fmt::format("pixel {:.3g} x {:.3g} mm, slice {:.3g} mm", model.grid.spacing_mm.x(),
                                             model.grid.spacing_mm.y(), model.grid.spacing_mm.z()),
                                 font(14), 0.08, y, VTK_TEXT_LEFT));
  else
    legend->AddActor2D(make_text(fmt::format("voxel {:.3g} x {:.3g} x {:.3g} mm", model.grid.spacing_mm.x(),
                                             model.grid.spacing_mm.y(), model.grid.spacing_mm.z()),
                                 font(14), 0.08, y, VTK_TEXT_LEFT));
  y -= 0.06;
  legend->AddActor2D(make_text(model.is_2d() ? "view: the slice face on" : "view: from front-left, above", font(14),
                               0.08, y, VTK_TEXT_LEFT, false, 0.35));
  if (cutaway) {
    y -= 0.04;
    legend->AddActor2D(make_text("front-left-top octant cut away", font(14), 0.08, y, VTK_TEXT_LEFT, false, 0.35));
    y -= 0.04;
    legend->AddActor2D(make_text("to show the inner levels", font(14), 0.08, y, VTK_TEXT_LEFT, false, 0.35));
  }
}

/// Renders the picture's parts off screen and writes the PNG atomically.
void save_picture(PictureLayout& layout, const RenderSettings& settings, const fs::path& png) {
  const VtkMessageCapture vtk_messages;
  vtkNew<vtkRenderWindow> window;
  window->SetOffScreenRendering(1);
  window->SetMultiSamples(8);
  window->SetNumberOfLayers(2);
  window->SetSize(settings.width, settings.height);
  for (vtkRenderer* r : {layout.scene.Get(), layout.band.Get(), layout.legend.Get(), layout.axes.Get()})
    window->AddRenderer(r);
  window->Render();
  vtkNew<vtkWindowToImageFilter> grab;
  grab->SetInput(window);
  grab->SetInputBufferTypeToRGB();
  grab->ReadFrontBufferOff();
  grab->Update();
  if (!vtk_messages.errors().empty())
    throw Error("rendering '" + png.string() + "' failed (VTK: " + vtk_messages.errors().front() +
                "); check the X display (" + std::string(std::getenv("DISPLAY") ? std::getenv("DISPLAY") : "") + ")");
  write_atomically(png, [&](const fs::path& tmp) {
    vtkNew<vtkPNGWriter> writer;
    writer->SetInputConnection(grab->GetOutputPort());
    writer->SetFileName(tmp.c_str());
    writer->Write();
    if (!vtk_messages.errors().empty()) throw Error("VTK could not write the PNG: " + vtk_messages.errors().front());
  });
}

}  // namespace

bool display_available() {
  static const bool available = probe_x_display();
  return available;
}

void render_model_png(const Model& model, const fs::path& png, const RenderSettings& settings) {
  if (png.extension() != ".png") throw Error("cannot write the picture '" + png.string() + "': use a .png file name");
  if (settings.width < 200 || settings.height < 150 || settings.width > 8192 || settings.height > 8192)
    throw Error(fmt::format("picture size {} x {} px is out of range: use 200..8192 x 150..8192", settings.width,
                            settings.height));
  if (model.num_elements() == 0) throw Error("cannot draw '" + png.string() + "': the model has no elements");
  check_output_path(png);
  if (!display_available())
    throw Error(
        "no X display: pictures need an X server (VTK 9.1 on Debian renders through X11 only). Run under "
        "xvfb-run, e.g. `xvfb-run -a -s \"-screen 0 1280x1024x24\" voxelastic ...`, or leave out the picture "
        "(--png)");

  const ModelView mv(model);
  bool cutaway = false;
  const vtkSmartPointer<vtkPolyData> faces = level_faces(model, mv, settings, cutaway);
  PictureLayout layout(settings);
  layout.scene->AddActor(level_actor(faces, model.num_levels(), settings));
  frame_camera(layout.scene->GetActiveCamera(), model, mv, layout);
  add_orientation_marker(mv, layout);
  add_scale_bar(layout);
  add_title(model, settings, layout);
  add_legend(model, mv, cutaway, settings, layout);
  save_picture(layout, settings, png);
}

}  // namespace vx
