#include "probe_view.h"

#include <fmt/core.h>
#include <vtkActor.h>
#include <vtkAxis.h>
#include <vtkBrush.h>
#include <vtkCallbackCommand.h>
#include <vtkCamera.h>
#include <vtkCapsuleSource.h>
#include <vtkCellArray.h>
#include <vtkCellData.h>
#include <vtkChartLegend.h>
#include <vtkChartXY.h>
#include <vtkContextActor.h>
#include <vtkContextScene.h>
#include <vtkCoordinate.h>
#include <vtkCubeSource.h>
#include <vtkCylinderSource.h>
#include <vtkDoubleArray.h>
#include <vtkFloatArray.h>
#include <vtkIdTypeArray.h>
#include <vtkInteractorStyleTrackballCamera.h>
#include <vtkLightKit.h>
#include <vtkLookupTable.h>
#include <vtkObjectFactory.h>
#include <vtkOutlineSource.h>
#include <vtkPNGWriter.h>
#include <vtkPen.h>
#include <vtkPlane.h>
#include <vtkPlaneSource.h>
#include <vtkPlot.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataMapper.h>
#include <vtkProperty.h>
#include <vtkRenderWindow.h>
#include <vtkRenderWindowInteractor.h>
#include <vtkRenderer.h>
#include <vtkSmartPointer.h>
#include <vtkSphereSource.h>
#include <vtkTable.h>
#include <vtkTextActor.h>
#include <vtkTextProperty.h>
#include <vtkTransform.h>
#include <vtkTransformPolyDataFilter.h>
#include <vtkUnsignedCharArray.h>
#include <vtkWindowToImageFilter.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <deque>

#include "base/error.h"
#include "io/element_faces.h"
#include "render/palette.h"
#include "rate_thread.h"
#include "util/atomic_file.h"

namespace vx::probe {

template <class T>
using Ptr = vtkSmartPointer<T>;
template <class T>
Ptr<T> make() {
  return Ptr<T>::New();
}

// ---------------------------------------------------------------- level cells

LevelCells make_level_cells(const Model& model) {
  LevelCells cells;
  const int ne = model.num_elements();
  cells.element_offsets.reserve(std::size_t(ne) + 1);
  cells.element_offsets.push_back(0);
  cells.element_polys.push_back(0);
  FacePolygons faces;
  for (int e = 0; e < ne; ++e) {
    const int b = model.element_offsets[std::size_t(e)], n = model.num_vertices(e);
    const auto first_point = std::int32_t(cells.point_node.size());
    for (int i = 0; i < n; ++i) cells.point_node.push_back(model.element_vertices[std::size_t(b + i)]);
    cells.element_offsets.push_back(std::int32_t(cells.point_node.size()));
    faces.clear();
    append_element_faces(model, e, faces);
    for (int f = 0; f < faces.size(); ++f) {
      for (int k = faces.offsets[std::size_t(f)]; k < faces.offsets[std::size_t(f) + 1]; ++k) {
        // the face's node as one of this element's points
        const std::int32_t node = faces.nodes[std::size_t(k)];
        int local = -1;
        for (int i = 0; i < n; ++i)
          if (model.element_vertices[std::size_t(b + i)] == node) local = i;
        if (local < 0) throw Error("element " + std::to_string(e) + ": a face node is not a vertex");
        cells.poly_points.push_back(first_point + local);
      }
      cells.poly_offsets.push_back(std::int32_t(cells.poly_points.size()));
      cells.poly_level.push_back(model.element_level[std::size_t(e)]);
    }
    cells.element_polys.push_back(std::int32_t(cells.poly_level.size()));
  }
  cells.levels = model.num_levels();
  cells.rest_centroids = model.rest_centroids;
  cells.rest_nodes = model.rest_positions;
  // the element edge of each level, as the model has it (one voxel in the voxel layout)
  cells.level_size_mm.assign(std::size_t(cells.levels), 0.0);
  cells.level_voxels.assign(std::size_t(cells.levels), 0);
  for (int e = 0; e < ne; ++e) {
    const auto l = std::size_t(model.element_level[std::size_t(e)]);
    cells.level_size_mm[l] = model.element_size_mm[std::size_t(e)];
    cells.level_voxels[l] = model.element_edge_voxels(e);
  }
  return cells;
}

// ---------------------------------------------------------------- colours

namespace {

struct Rgb {
  double r, g, b;
};
constexpr Rgb kTissue{0.86, 0.56, 0.50};
constexpr Rgb kTool{0.78, 0.80, 0.84};
constexpr Rgb kToolContact{0.66, 0.77, 0.93};
constexpr Rgb kBackgroundTop{0.10, 0.12, 0.16};
constexpr Rgb kBackgroundBottom{0.28, 0.31, 0.36};
constexpr std::array<Rgb, 2> kProbeColour{Rgb{1.0, 0.62, 0.15}, Rgb{0.30, 0.80, 1.0}};
/// The colour of element level `level` (render/palette.h: the same as in pictures).
Rgb level_rgb(int level) {
  const std::array<double, 3> c = level_colour(level);
  return Rgb{c[0], c[1], c[2]};
}

constexpr const char* kHelp =
    "keys and mouse\n"
    "  arrows       move the probe (screen plane)\n"
    "  PgUp / PgDn  move it away / towards you\n"
    "  right-drag   move it (shift: depth)\n"
    "  left-drag    rotate the view, wheel: zoom\n"
    "  Tab          switch probe (keyboard)\n"
    "  l  element levels    t  see-through\n"
    "  d  displacement tint\n"
    "  w  walls             g  force plot\n"
    "  c  reset camera      r  reset scene\n"
    "  space  pause         s  screenshot\n"
    "  h  hide this help    q / Esc  quit";

// the right-hand panel takes this fraction of the window's width
constexpr double kPanel = 0.32;

void set_text_style(vtkTextProperty* p, int size, const Rgb& c) {
  p->SetFontFamilyToCourier();
  p->SetFontSize(size);
  p->SetColor(c.r, c.g, c.b);
  p->SetBackgroundColor(0.0, 0.0, 0.0);
  p->SetBackgroundOpacity(0.45);
  p->SetShadow(false);
}

}  // namespace

// ---------------------------------------------------------------- interactor style

class ProbeInteractorStyle : public vtkInteractorStyleTrackballCamera {
 public:
  static ProbeInteractorStyle* New();
  vtkTypeMacro(ProbeInteractorStyle, vtkInteractorStyleTrackballCamera)
  void OnChar() override {}  // no built-in VTK keys (e/q quit, w wireframe, 3 stereo, ...)
  void OnKeyPress() override;
  void OnKeyRelease() override;
  void OnRightButtonDown() override;
  void OnRightButtonUp() override;
  void OnMouseMove() override;
  ProbeView::Impl* view{nullptr};

 private:
  bool dragging_{false};
  int last_x_{0}, last_y_{0};
};
vtkStandardNewMacro(ProbeInteractorStyle);

// ---------------------------------------------------------------- the view

struct ProbeView::Impl {
  ViewSetup setup;
  KeyboardStick* keyboard{nullptr};
  std::function<void(ViewAction)> on_action;

  Ptr<vtkRenderWindow> window;
  Ptr<vtkRenderer> renderer;  // the 3D view (left)
  Ptr<vtkRenderer> panel;     // force plot and help (right)
  Ptr<vtkRenderWindowInteractor> interactor;
  Ptr<ProbeInteractorStyle> style;
  bool closed{false};
  bool software_gl{true};

  // tissue
  Ptr<vtkPolyData> surface;
  Ptr<vtkActor> surface_actor;
  int tissue_mode{0};  // 0 solid, 1 see-through
  bool tint_on{true};  // tissue tinted by its displacement (where it is pressed)
  double tint_full_mm{4.0};
  Ptr<vtkUnsignedCharArray> tint;
  Ptr<vtkTextActor> tint_legend;

  // elements by level
  Ptr<vtkPolyData> level_poly;
  Ptr<vtkActor> level_actor;
  Ptr<vtkPlane> level_cut;               // the cut-away plane (surface clipped, elements culled)
  Eigen::Vector3d cut_away{0, 0, 0};      // "away" direction the current cut was made for
  Eigen::Matrix3Xd last_nodes;            // node positions of the last frame
  std::vector<Ptr<vtkTextActor>> level_legend;  // one line per level, in its colour
  Eigen::Matrix3Xd level_points;  // scratch
  bool levels_on{false};

  // probes and walls
  std::vector<Ptr<vtkActor>> probe_actors;
  std::vector<Ptr<vtkActor>> wall_actors;
  bool walls_on{true};

  // HUD and help
  Ptr<vtkTextActor> hud;
  Ptr<vtkTextActor> status;
  Ptr<vtkTextActor> help;
  bool help_on{true};
  HudInfo hud_info;

  // force plot
  Ptr<vtkChartXY> chart;
  Ptr<vtkContextActor> chart_actor;
  Ptr<vtkTable> table;
  std::deque<PlotSample> plot;
  bool plot_on{true};

  // rates
  std::int64_t frames{0};
  RateMeter fps{0.5};

  // camera
  Eigen::Vector3d focus{0, 0, 0};
  double radius{50.0};

  void build_scene();
  void build_probes();
  void build_walls();
  void build_levels();
  void update_levels(bool force_cut);
  void set_levels(bool on);
  void build_hud();
  void build_plot();
  void layout();
  void update_plot();
  void update_hud_text();
  void key(const std::string& sym, bool down);
  void drag(int dx, int dy, bool depth);
  void camera_to_start();
};

void ProbeInteractorStyle::OnKeyPress() {
  if (view && this->Interactor && this->Interactor->GetKeySym()) view->key(this->Interactor->GetKeySym(), true);
}
void ProbeInteractorStyle::OnKeyRelease() {
  if (view && this->Interactor && this->Interactor->GetKeySym()) view->key(this->Interactor->GetKeySym(), false);
}
void ProbeInteractorStyle::OnRightButtonDown() {
  dragging_ = true;
  this->Interactor->GetEventPosition(last_x_, last_y_);
}
void ProbeInteractorStyle::OnRightButtonUp() { dragging_ = false; }
void ProbeInteractorStyle::OnMouseMove() {
  if (!dragging_) {
    vtkInteractorStyleTrackballCamera::OnMouseMove();
    return;
  }
  int x = 0, y = 0;
  this->Interactor->GetEventPosition(x, y);
  if (view) view->drag(x - last_x_, y - last_y_, this->Interactor->GetShiftKey() != 0);
  last_x_ = x;
  last_y_ = y;
}

namespace {

void on_exit(vtkObject*, unsigned long, void* client, void*) {
  static_cast<ProbeView::Impl*>(client)->closed = true;
}

// a unit-ish world "toward the viewer" direction perpendicular to up
Eigen::Vector3d toward_viewer(const Eigen::Vector3d& up) {
  for (const Eigen::Vector3d& c : {Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(-1, 0, 0)}) {
    if (std::abs(c.dot(up)) < 0.7) return (c - c.dot(up) * up).normalized();
  }
  return up.unitOrthogonal();
}

// columns right, up, away: "away" is the viewing direction made horizontal (looking straight
// down: the camera's up), "up" the world's
Eigen::Matrix3d view_basis_of(vtkCamera* cam, const Eigen::Vector3d& world_up) {
  const Eigen::Vector3d up =
      world_up.norm() > 0 ? Eigen::Vector3d(world_up.normalized()) : Eigen::Vector3d(0, -1, 0);
  double dop[3];
  cam->GetDirectionOfProjection(dop);
  const Eigen::Vector3d d(dop[0], dop[1], dop[2]);
  Eigen::Vector3d away = d - d.dot(up) * up;
  if (away.norm() < 1e-3) {
    double vu[3];
    cam->GetViewUp(vu);
    away = Eigen::Vector3d(vu[0], vu[1], vu[2]);
    away -= away.dot(up) * up;
  }
  if (away.norm() < 1e-9) away = up.unitOrthogonal();
  away.normalize();
  Eigen::Matrix3d basis;
  basis.col(0) = away.cross(up).normalized();
  basis.col(1) = up;
  basis.col(2) = away;
  return basis;
}

// the polydata of a probe's shape, in its own frame (tip / centre at the origin)
Ptr<vtkPolyData> probe_shape(const ProbeGeometry& g, double scene_size) {
  Ptr<vtkPolyData> out;
  const Eigen::Vector3d axis = g.axis.norm() > 0 ? Eigen::Vector3d(g.axis.normalized()) : Eigen::Vector3d(0, 0, 1);
  // VTK's sources are along +y; rotate +y onto the axis
  const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d(0, 1, 0), axis);
  const Eigen::AngleAxisd aa(q);
  auto transform = make<vtkTransform>();
  switch (g.shape) {
    case ProbeShape::sphere: {
      auto s = make<vtkSphereSource>();
      s->SetRadius(g.radius_mm);
      s->SetThetaResolution(48);
      s->SetPhiResolution(32);
      s->Update();
      return s->GetOutput();
    }
    case ProbeShape::cylinder: {
      auto c = make<vtkCylinderSource>();
      c->SetRadius(g.radius_mm);
      c->SetHeight(std::max(g.length_mm, 1e-3));
      c->SetResolution(48);
      c->Update();
      out = c->GetOutput();
      break;
    }
    case ProbeShape::capsule: {
      // the tip sphere's centre is the probe position; the rod runs length_mm along the axis
      auto c = make<vtkCapsuleSource>();
      c->SetRadius(g.radius_mm);
      c->SetCylinderLength(std::max(g.length_mm, 1e-3));
      c->SetCenter(0.0, 0.5 * g.length_mm, 0.0);
      c->SetThetaResolution(48);
      c->SetPhiResolution(24);
      c->Update();
      out = c->GetOutput();
      break;
    }
    case ProbeShape::plane: {
      // a square plate of the scene's size, its normal along the axis, surface at the origin
      auto p = make<vtkCubeSource>();
      const double half = 0.5 * scene_size;
      p->SetBounds(-half, half, -0.04 * scene_size, 0.0, -half, half);
      p->Update();
      out = p->GetOutput();
      break;
    }
  }
  transform->RotateWXYZ(aa.angle() * 180.0 / M_PI, aa.axis().x(), aa.axis().y(), aa.axis().z());
  auto tf = make<vtkTransformPolyDataFilter>();
  tf->SetInputData(out);
  tf->SetTransform(transform);
  tf->Update();
  return tf->GetOutput();
}

}  // namespace

ProbeView::ProbeView(const ViewSetup& setup, KeyboardStick* keyboard, std::function<void(ViewAction)> on_action)
    : impl_(std::make_unique<Impl>()) {
  Impl& v = *impl_;
  v.setup = setup;
  v.keyboard = keyboard;
  v.on_action = std::move(on_action);
  if (setup.surface_vertices.cols() == 0 || setup.surface_triangles.cols() == 0)
    throw Error("the view needs a surface (no vertices or triangles)");
  v.build_scene();
}

ProbeView::~ProbeView() {
  if (impl_ && impl_->window) {
    impl_->window->Finalize();
  }
}

void ProbeView::Impl::build_scene() {
  renderer = make<vtkRenderer>();
  renderer->GradientBackgroundOn();
  renderer->SetBackground(kBackgroundBottom.r, kBackgroundBottom.g, kBackgroundBottom.b);
  renderer->SetBackground2(kBackgroundTop.r, kBackgroundTop.g, kBackgroundTop.b);
  renderer->SetViewport(0.0, 0.0, 1.0 - kPanel, 1.0);
  // anti-aliasing: FXAA on a GPU (switched on after the first frame); none in software GL
  // (llvmpipe under Xvfb), where it would cost two thirds of the frame rate
  panel = make<vtkRenderer>();
  panel->SetViewport(1.0 - kPanel, 0.0, 1.0, 1.0);
  panel->SetBackground(0.07, 0.08, 0.10);
  panel->InteractiveOff();
  window = make<vtkRenderWindow>();
  window->SetSize(setup.width, setup.height);
  window->SetWindowName(("voxelastic-probe: " + setup.title).c_str());
  window->SetMultiSamples(0);
  window->AddRenderer(renderer);
  window->AddRenderer(panel);
  interactor = make<vtkRenderWindowInteractor>();
  interactor->SetRenderWindow(window);
  style = make<ProbeInteractorStyle>();
  style->view = this;
  interactor->SetInteractorStyle(style);
  auto exit_cb = make<vtkCallbackCommand>();
  exit_cb->SetCallback(&on_exit);
  exit_cb->SetClientData(this);
  interactor->AddObserver(vtkCommand::ExitEvent, exit_cb);

  // lights: a key/fill/back kit like a surgical lamp, plus the camera's headlight off
  auto lights = make<vtkLightKit>();
  lights->SetKeyLightIntensity(0.9);
  lights->SetKeyToFillRatio(4.0);  // more relief than VTK's default 3
  lights->SetKeyLightElevation(40.0);
  lights->SetKeyLightAzimuth(25.0);
  lights->AddLightsToRenderer(renderer);

  // the tissue surface (points and normals replaced every frame)
  surface = make<vtkPolyData>();
  {
    const auto nv = setup.surface_vertices.cols();
    auto pts = make<vtkPoints>();
    pts->SetDataTypeToDouble();
    pts->SetNumberOfPoints(nv);
    std::copy_n(setup.surface_vertices.data(), 3 * nv, static_cast<double*>(pts->GetVoidPointer(0)));
    surface->SetPoints(pts);
    auto normals = make<vtkDoubleArray>();
    normals->SetName("Normals");
    normals->SetNumberOfComponents(3);
    normals->SetNumberOfTuples(nv);
    std::fill_n(normals->GetPointer(0), 3 * nv, 0.0);
    surface->GetPointData()->SetNormals(normals);
    auto offsets = make<vtkIdTypeArray>();
    auto conn = make<vtkIdTypeArray>();
    const auto nt = setup.surface_triangles.cols();
    offsets->SetNumberOfValues(nt + 1);
    conn->SetNumberOfValues(3 * nt);
    for (vtkIdType t = 0; t <= nt; ++t) offsets->SetValue(t, 3 * t);
    for (vtkIdType i = 0; i < 3 * nt; ++i) conn->SetValue(i, setup.surface_triangles.data()[i]);
    auto tris = make<vtkCellArray>();
    tris->SetData(offsets, conn);
    surface->SetPolys(tris);
  }
  // the displacement tint: per-vertex colours, the tissue colour deepening where it is pressed
  tint = make<vtkUnsignedCharArray>();
  tint->SetName("tint");
  tint->SetNumberOfComponents(3);
  tint->SetNumberOfTuples(setup.surface_vertices.cols());
  for (vtkIdType i = 0; i < setup.surface_vertices.cols(); ++i)
    tint->SetTypedTuple(i, std::array<unsigned char, 3>{static_cast<unsigned char>(255 * kTissue.r),
                                                        static_cast<unsigned char>(255 * kTissue.g),
                                                        static_cast<unsigned char>(255 * kTissue.b)}
                               .data());
  surface->GetPointData()->SetScalars(tint);
  auto surface_mapper = make<vtkPolyDataMapper>();
  surface_mapper->SetInputData(surface);
  surface_mapper->SetColorModeToDirectScalars();
  surface_mapper->SetScalarModeToUsePointData();
  surface_mapper->ScalarVisibilityOn();
  surface_actor = make<vtkActor>();
  surface_actor->SetMapper(surface_mapper);
  {
    vtkProperty* p = surface_actor->GetProperty();
    p->SetInterpolationToGouraud();
    p->SetColor(kTissue.r, kTissue.g, kTissue.b);
    p->SetAmbient(0.12);
    p->SetDiffuse(0.85);
    p->SetSpecular(0.25);
    p->SetSpecularPower(25.0);
    p->SetSpecularColor(1.0, 0.95, 0.9);
  }
  renderer->AddActor(surface_actor);

  // the scene's size and centre from the rest surface
  const Eigen::Vector3d lo = setup.surface_vertices.rowwise().minCoeff();
  const Eigen::Vector3d hi = setup.surface_vertices.rowwise().maxCoeff();
  focus = 0.5 * (lo + hi);
  radius = std::max(1.0, 0.5 * (hi - lo).norm());
  tint_full_mm = std::max(0.5, 0.12 * (hi - lo).minCoeff());

  build_probes();
  build_walls();
  build_levels();
  build_hud();
  build_plot();
  update_plot();  // the table holds a line before anything is drawn
  camera_to_start();
  interactor->Initialize();
  layout();
}

void ProbeView::Impl::build_probes() {
  for (std::size_t p = 0; p < setup.probes.size(); ++p) {
    auto mapper = make<vtkPolyDataMapper>();
    mapper->SetInputData(probe_shape(setup.probes[p], 2.0 * radius));
    auto actor = make<vtkActor>();
    actor->SetMapper(mapper);
    vtkProperty* prop = actor->GetProperty();
    prop->SetInterpolationToGouraud();
    prop->SetColor(kTool.r, kTool.g, kTool.b);
    prop->SetAmbient(0.15);
    prop->SetDiffuse(0.6);
    prop->SetSpecular(0.8);
    prop->SetSpecularPower(60.0);
    if (setup.probes[p].shape == ProbeShape::plane) prop->SetOpacity(0.5);
    const Eigen::Vector3d s = p < setup.probe_start_mm.size() ? setup.probe_start_mm[p] : Eigen::Vector3d::Zero();
    actor->SetPosition(s.x(), s.y(), s.z());
    renderer->AddActor(actor);
    probe_actors.push_back(actor);
  }
}

void ProbeView::Impl::build_walls() {
  if (!setup.walls || !setup.workspace.valid()) return;
  const Box& b = setup.workspace;
  auto outline = make<vtkOutlineSource>();
  outline->SetBounds(b.lo.x(), b.hi.x(), b.lo.y(), b.hi.y(), b.lo.z(), b.hi.z());
  auto om = make<vtkPolyDataMapper>();
  om->SetInputConnection(outline->GetOutputPort());
  auto oa = make<vtkActor>();
  oa->SetMapper(om);
  oa->GetProperty()->SetColor(0.65, 0.70, 0.78);
  oa->GetProperty()->SetLineWidth(1.5);
  oa->GetProperty()->LightingOff();
  renderer->AddActor(oa);
  wall_actors.push_back(oa);
  // the floor: the wall at the bottom (against "up"), drawn as a dark table top
  const Eigen::Vector3d up = setup.world_up.normalized();
  int axis = 0;
  up.cwiseAbs().maxCoeff(&axis);
  const double at = up[axis] > 0 ? b.lo[axis] : b.hi[axis];
  Eigen::Vector3d o = b.lo, p1 = b.lo, p2 = b.lo;
  const int u = (axis + 1) % 3, w = (axis + 2) % 3;
  o[axis] = p1[axis] = p2[axis] = at;
  p1[u] = b.hi[u];
  p2[w] = b.hi[w];
  auto floor = make<vtkPlaneSource>();
  floor->SetOrigin(o.data());
  floor->SetPoint1(p1.data());
  floor->SetPoint2(p2.data());
  auto fm = make<vtkPolyDataMapper>();
  fm->SetInputConnection(floor->GetOutputPort());
  auto fa = make<vtkActor>();
  fa->SetMapper(fm);
  fa->GetProperty()->SetColor(0.32, 0.36, 0.42);
  fa->GetProperty()->SetAmbient(0.3);
  fa->GetProperty()->SetDiffuse(0.6);
  fa->GetProperty()->SetSpecular(0.05);
  renderer->AddActor(fa);
  wall_actors.push_back(fa);
}

void ProbeView::Impl::build_levels() {
  if (!setup.levels) return;
  const LevelCells& c = *setup.levels;
  level_poly = make<vtkPolyData>();
  auto pts = make<vtkPoints>();
  pts->SetDataTypeToDouble();
  pts->SetNumberOfPoints(vtkIdType(c.point_node.size()));
  level_poly->SetPoints(pts);
  level_poly->SetPolys(make<vtkCellArray>());
  last_nodes = c.rest_nodes;

  auto lut = make<vtkLookupTable>();
  const int n = std::max(1, c.levels);
  lut->SetNumberOfTableValues(n);
  for (int l = 0; l < n; ++l) {
    const Rgb col = level_rgb(l);
    lut->SetTableValue(l, col.r, col.g, col.b, 1.0);
  }
  lut->SetRange(0, n - 1);
  lut->Build();
  auto mapper = make<vtkPolyDataMapper>();
  mapper->SetInputData(level_poly);
  mapper->SetLookupTable(lut);
  mapper->SetScalarModeToUseCellData();
  mapper->SetScalarRange(0, n - 1);
  mapper->SetColorModeToMapScalars();
  level_cut = make<vtkPlane>();
  level_actor = make<vtkActor>();
  level_actor->SetMapper(mapper);
  level_actor->GetProperty()->SetEdgeVisibility(true);
  level_actor->GetProperty()->SetEdgeColor(0.15, 0.15, 0.18);
  level_actor->GetProperty()->SetLineWidth(1.0);
  level_actor->GetProperty()->SetAmbient(0.25);
  level_actor->SetVisibility(false);
  renderer->AddActor(level_actor);

  for (int l = 0; l < c.levels; ++l) {
    auto t = make<vtkTextActor>();
    t->SetInput(fmt::format("level {}: elements {:g} mm ({} voxels) wide", l, c.level_size_mm[std::size_t(l)],
                            c.level_voxels[std::size_t(l)])
                    .c_str());
    set_text_style(t->GetTextProperty(), 14, level_rgb(l));
    t->SetVisibility(false);
    renderer->AddViewProp(t);
    level_legend.push_back(t);
  }
}

void ProbeView::Impl::build_hud() {
  tint_legend = make<vtkTextActor>();
  set_text_style(tint_legend->GetTextProperty(), 13, Rgb{0.95, 0.80, 0.76});
  tint_legend->SetInput(fmt::format("deeper red: tissue displaced (full at {:.1f} mm); d toggles", tint_full_mm).c_str());
  renderer->AddViewProp(tint_legend);
  hud = make<vtkTextActor>();
  set_text_style(hud->GetTextProperty(), 15, Rgb{0.95, 0.97, 1.0});
  hud->GetTextProperty()->SetVerticalJustificationToTop();
  renderer->AddViewProp(hud);
  status = make<vtkTextActor>();
  set_text_style(status->GetTextProperty(), 15, Rgb{1.0, 0.45, 0.40});
  status->GetTextProperty()->SetVerticalJustificationToTop();
  renderer->AddViewProp(status);
  help = make<vtkTextActor>();
  set_text_style(help->GetTextProperty(), 13, Rgb{0.85, 0.88, 0.92});
  help->GetTextProperty()->SetBackgroundOpacity(0.0);
  help->GetTextProperty()->SetVerticalJustificationToTop();
  help->SetInput(kHelp);
  help->GetPositionCoordinate()->SetCoordinateSystemToViewport();
  panel->AddViewProp(help);
}

void ProbeView::Impl::build_plot() {
  // per probe three columns: raw sum, half sine played, update mean
  table = make<vtkTable>();
  auto t = make<vtkFloatArray>();
  t->SetName("time (s)");
  table->AddColumn(t);
  const int np = std::min(2, std::max<int>(1, int(setup.probes.size())));
  for (int p = 0; p < np; ++p) {
    const std::string name =
        p < int(setup.probe_names.size()) ? setup.probe_names[std::size_t(p)] : std::to_string(p);
    const std::string who = np > 1 ? " (" + name + ")" : "";
    for (const char* name : {"raw sum per step", "half sines played", "device update mean"}) {
      auto col = make<vtkFloatArray>();
      col->SetName((name + who).c_str());
      table->AddColumn(col);
    }
  }
  chart = make<vtkChartXY>();
  chart->SetAutoSize(false);
  chart->SetTitle("probe force |F| (N)");
  chart->GetTitleProperties()->SetColor(0.95, 0.95, 0.95);
  chart->GetTitleProperties()->SetFontSize(14);
  chart->GetBackgroundBrush()->SetColorF(0.05, 0.06, 0.08, 1.0);
  chart->SetShowLegend(true);
  chart->GetLegend()->GetLabelProperties()->SetColor(0.95, 0.95, 0.95);
  chart->GetLegend()->GetLabelProperties()->SetFontSize(11);
  chart->GetLegend()->GetBrush()->SetColorF(0.1, 0.1, 0.12, 0.75);
  chart->GetLegend()->SetInline(true);
  chart->GetLegend()->SetHorizontalAlignment(vtkChartLegend::LEFT);
  chart->GetLegend()->SetVerticalAlignment(vtkChartLegend::TOP);
  for (int a : {vtkAxis::LEFT, vtkAxis::BOTTOM}) {
    vtkAxis* axis = chart->GetAxis(a);
    axis->GetLabelProperties()->SetColor(0.9, 0.9, 0.9);
    axis->GetTitleProperties()->SetColor(0.9, 0.9, 0.9);
    axis->GetTitleProperties()->SetFontSize(12);
    axis->GetLabelProperties()->SetFontSize(12);
    axis->GetPen()->SetColorF(0.8, 0.8, 0.8);
    axis->GetGridPen()->SetColorF(0.25, 0.27, 0.31);
    axis->SetBehavior(vtkAxis::AUTO);
  }
  chart->GetAxis(vtkAxis::LEFT)->SetTitle("N");
  chart->GetAxis(vtkAxis::BOTTOM)->SetTitle("simulated time (s)");
  for (int p = 0; p < np; ++p) {
    const Rgb& c = kProbeColour[std::size_t(p)];
    vtkPlot* played = chart->AddPlot(vtkChart::LINE);
    played->SetInputData(table, 0, 2 + 3 * p);
    played->SetColor(c.r, c.g, c.b);
    played->GetPen()->SetOpacityF(0.35);
    played->SetWidth(1.0);
    vtkPlot* raw = chart->AddPlot(vtkChart::LINE);
    raw->SetInputData(table, 0, 1 + 3 * p);
    raw->SetColor(0.85, 0.87, 0.90);
    raw->GetPen()->SetOpacityF(0.7);
    raw->SetWidth(1.0);
    vtkPlot* mean = chart->AddPlot(vtkChart::LINE);
    mean->SetInputData(table, 0, 3 + 3 * p);
    mean->SetColor(c.r, c.g, c.b);
    mean->SetWidth(3.0);
  }
  auto scene = make<vtkContextScene>();
  scene->AddItem(chart);
  chart_actor = make<vtkContextActor>();
  chart_actor->SetScene(scene);
  panel->AddActor(chart_actor);
  scene->SetRenderer(panel);
}

void ProbeView::Impl::layout() {
  const int* size = window->GetSize();
  const int w = std::max(size[0], 320), h = std::max(size[1], 240);
  const int pw = int(kPanel * w);
  hud->SetDisplayPosition(10, h - 10);
  // the panel: force plot on top, help below (coordinates relative to the panel's viewport)
  const float ph = float(h) * 0.52f;
  chart->SetSize(vtkRectf(6.0f, float(h) - ph - 6.0f, float(pw) - 12.0f, ph));
  help->SetPosition(14.0, double(h) - ph - 30.0);
  for (std::size_t l = 0; l < level_legend.size(); ++l)
    level_legend[l]->SetDisplayPosition(10, 12 + int(level_legend.size() - 1 - l) * 20);
  tint_legend->SetDisplayPosition(10, 12 + (levels_on ? int(level_legend.size()) * 20 : 0));
}

void ProbeView::Impl::camera_to_start() {
  const Eigen::Matrix3d basis = start_view_basis(setup.world_up);
  const Eigen::Vector3d up = basis.col(1), away = basis.col(2);
  // look from the front (against "away"), 50 degrees above the horizon: the tissue around the
  // tool tip stays in sight
  const double el = 50.0 * M_PI / 180.0;
  const Eigen::Vector3d dir = (-std::cos(el) * away + std::sin(el) * up).normalized();
  vtkCamera* cam = renderer->GetActiveCamera();
  cam->SetViewAngle(30.0);
  // frame the tissue and the probes' start positions
  double r = radius;
  for (const auto& s : setup.probe_start_mm) r = std::max(r, (s - focus).norm() * 0.8);
  const Eigen::Vector3d target = focus + 0.15 * r * up;
  const double dist = 1.45 * r / std::sin(0.5 * 30.0 * M_PI / 180.0);
  const Eigen::Vector3d pos = target + dist * dir;
  cam->SetFocalPoint(target.data());
  cam->SetPosition(pos.data());
  cam->SetViewUp(up.data());
  renderer->ResetCameraClippingRange();
}

void ProbeView::Impl::update_plot() {
  const int np = std::min(2, std::max<int>(1, int(setup.probes.size())));
  // a line needs two points: before the first samples, a flat zero line over the window
  std::deque<PlotSample> pad;
  if (plot.size() < 2) {
    PlotSample a, b;
    b.t_s = plot.empty() ? setup.plot_window_s : std::max(plot.back().t_s, 1e-3);
    pad = {a, b};
  }
  const std::deque<PlotSample>& data = plot.size() < 2 ? pad : plot;
  const auto n = vtkIdType(data.size());
  table->SetNumberOfRows(n);
  auto* t = vtkFloatArray::SafeDownCast(table->GetColumn(0));
  for (vtkIdType i = 0; i < n; ++i) {
    const PlotSample& s = data[std::size_t(i)];
    t->SetValue(i, float(s.t_s));
    for (int p = 0; p < np; ++p) {
      vtkFloatArray::SafeDownCast(table->GetColumn(1 + 3 * p))->SetValue(i, s.raw_N[std::size_t(p)]);
      vtkFloatArray::SafeDownCast(table->GetColumn(2 + 3 * p))->SetValue(i, s.device_N[std::size_t(p)]);
      vtkFloatArray::SafeDownCast(table->GetColumn(3 + 3 * p))->SetValue(i, s.mean_N[std::size_t(p)]);
    }
  }
  for (vtkIdType c = 0; c < table->GetNumberOfColumns(); ++c) table->GetColumn(c)->Modified();
  table->Modified();
  chart->RecalculateBounds();
  // a steady window: the last plot_window_s seconds, force from 0 with headroom
  vtkAxis* x = chart->GetAxis(vtkAxis::BOTTOM);
  vtkAxis* y = chart->GetAxis(vtkAxis::LEFT);
  const double t1 = plot.empty() ? setup.plot_window_s : std::max(setup.plot_window_s, plot.back().t_s);
  x->SetBehavior(vtkAxis::FIXED);
  x->SetRange(t1 - setup.plot_window_s, t1);
  float fmax = 0.0f;
  for (const auto& s : plot)
    for (int p = 0; p < np; ++p)
      fmax = std::max({fmax, s.device_N[std::size_t(p)], s.raw_N[std::size_t(p)], s.mean_N[std::size_t(p)]});
  // a range that only grows in steps, so the plot does not breathe every frame
  double top = 0.5;
  while (top < 1.1 * fmax) top *= 2.0;
  y->SetBehavior(vtkAxis::FIXED);
  y->SetRange(0.0, top);
  chart_actor->SetVisibility(plot_on);
}

void ProbeView::Impl::update_hud_text() {
  const HudInfo& h = hud_info;
  std::string text = fmt::format("{}   t = {:.2f} s{}\n", setup.title, h.sim_s, h.paused ? "   [PAUSED]" : "");
  text += fmt::format("physics {:.0f} steps/s ({:.2f}x real time)\n", h.physics_steps_per_s, h.real_time_factor);
  text += fmt::format("device {:.0f} updates/s   display {:.1f} frames/s\n", h.device_hz, fps.rate());
  for (int p = 0; p < h.probes && p < 2; ++p) {
    const std::string name = std::size_t(p) < setup.probe_names.size() ? setup.probe_names[std::size_t(p)]
                                                                         : fmt::format("probe {}", p);
    text += fmt::format("{}{}: force {:.3f} N  ({} nodes in contact)\n", name,
                        h.probes > 1 && p == h.active_probe ? " [keys]" : "", h.force_N[std::size_t(p)],
                        h.contacts[std::size_t(p)]);
  }
  text += setup.input_line;
  if (!setup.output_line.empty()) text += "\n" + setup.output_line;
  hud->SetInput(text.c_str());
  std::string warn;
  if (h.behind_real_time)
    warn = fmt::format("physics cannot keep real time: {:.2f}x (slow motion)", h.real_time_factor);
  if (h.device_hz > 0 && h.device_hz < 0.9 * h.device_target_hz) {
    if (!warn.empty()) warn += "\n";
    warn += fmt::format("device thread late: {:.0f} of {:.0f} updates/s", h.device_hz, h.device_target_hz);
  }
  if (!h.status.empty()) {
    if (!warn.empty()) warn += "\n";
    warn += h.status;
  }
  status->SetInput(warn.c_str());
  status->SetVisibility(!warn.empty());
  // the warnings go under the HUD's lines
  const int* size = window->GetSize();
  const int lines = 4 + std::min(h.probes, 2) + (setup.output_line.empty() ? 0 : 1);
  status->SetDisplayPosition(10, std::max(240, size[1]) - 10 - lines * 19 - 8);
}

void ProbeView::Impl::key(const std::string& sym_in, bool down) {
  std::string sym = sym_in;
  if (sym.size() == 1) sym[0] = char(std::tolower(static_cast<unsigned char>(sym[0])));
  // motion keys go to the keyboard stick while held
  const auto motion = [&](KeyboardStick::Key k) {
    if (!keyboard) return;
    if (down)
      keyboard->press(k);
    else
      keyboard->release(k);
  };
  if (sym == "Left" || sym == "KP_Left") return motion(KeyboardStick::left);
  if (sym == "Right" || sym == "KP_Right") return motion(KeyboardStick::right);
  if (sym == "Up" || sym == "KP_Up") return motion(KeyboardStick::up);
  if (sym == "Down" || sym == "KP_Down") return motion(KeyboardStick::down);
  if (sym == "Prior" || sym == "KP_Prior" || sym == "Page_Up") return motion(KeyboardStick::away);
  if (sym == "Next" || sym == "KP_Next" || sym == "Page_Down") return motion(KeyboardStick::toward);
  if (!down) return;
  if (sym == "q" || sym == "Escape") {
    if (on_action) on_action(ViewAction::quit);
  } else if (sym == "space" || sym == "p") {
    if (on_action) on_action(ViewAction::pause);
  } else if (sym == "r") {
    if (on_action) on_action(ViewAction::reset_scene);
  } else if (sym == "s") {
    if (on_action) on_action(ViewAction::screenshot);
  } else if (sym == "Tab") {
    if (on_action) on_action(ViewAction::next_probe);
  } else if (sym == "l") {
    set_levels(!levels_on);
  } else if (sym == "d") {
    tint_on = !tint_on;
    tint_legend->SetVisibility(tint_on);
    surface_actor->GetMapper()->SetScalarVisibility(tint_on);
  } else if (sym == "t") {
    tissue_mode = (tissue_mode + 1) % 2;
    surface_actor->GetProperty()->SetOpacity(tissue_mode == 1 ? 0.35 : 1.0);
  } else if (sym == "w") {
    walls_on = !walls_on;
    for (auto& a : wall_actors) a->SetVisibility(walls_on);
  } else if (sym == "g") {
    plot_on = !plot_on;
    chart_actor->SetVisibility(plot_on);
  } else if (sym == "h") {
    help_on = !help_on;
    help->SetVisibility(help_on);
  } else if (sym == "c") {
    camera_to_start();
  }
}

void ProbeView::Impl::drag(int dx, int dy, bool depth) {
  if (!keyboard) return;
  // pixels to mm at the focal distance
  vtkCamera* cam = renderer->GetActiveCamera();
  const int* size = window->GetSize();
  const double mm_per_px = 2.0 * cam->GetDistance() * std::tan(0.5 * cam->GetViewAngle() * M_PI / 180.0) /
                           double(std::max(1, size[1]));
  Eigen::Vector3d offset(dx * mm_per_px, dy * mm_per_px, 0.0);
  if (depth) offset = Eigen::Vector3d(0.0, 0.0, dy * mm_per_px);
  keyboard->add_drag(offset);
}

void ProbeView::Impl::set_levels(bool on) {
  levels_on = on && level_actor;
  if (!level_actor) return;
  level_actor->SetVisibility(levels_on);
  for (auto& t : level_legend) t->SetVisibility(levels_on);
  // a cut-away: the near half of the tissue is removed, the elements behind it show
  vtkMapper* m = surface_actor->GetMapper();
  m->RemoveAllClippingPlanes();
  if (levels_on) {
    m->AddClippingPlane(level_cut);
    update_levels(true);
  }
}

void ProbeView::Impl::update_levels(bool force_cut) {
  const LevelCells& c = *setup.levels;
  // the cut: a vertical plane through the tissue's centre, facing the viewer; the elements
  // whose rest centroid is behind it are drawn whole (remade when the view turns)
  const Eigen::Vector3d away = view_basis_of(renderer->GetActiveCamera(), setup.world_up).col(2);
  if (force_cut || away.dot(cut_away) < std::cos(10.0 * M_PI / 180.0)) {
    cut_away = away;
    level_cut->SetOrigin(focus.data());
    level_cut->SetNormal(away.data());
    auto offsets = make<vtkIdTypeArray>();
    auto conn = make<vtkIdTypeArray>();
    auto level = make<vtkUnsignedCharArray>();
    level->SetName("level");
    offsets->InsertNextValue(0);
    const int ne = int(c.element_offsets.size()) - 1;
    for (int e = 0; e < ne; ++e) {
      if ((c.rest_centroids.col(e) - focus).dot(away) < 0) continue;
      for (int f = c.element_polys[std::size_t(e)]; f < c.element_polys[std::size_t(e) + 1]; ++f) {
        for (int k = c.poly_offsets[std::size_t(f)]; k < c.poly_offsets[std::size_t(f) + 1]; ++k)
          conn->InsertNextValue(c.poly_points[std::size_t(k)]);
        offsets->InsertNextValue(conn->GetNumberOfValues());
        level->InsertNextValue(std::uint8_t(c.poly_level[std::size_t(f)]));
      }
    }
    auto polys = make<vtkCellArray>();
    polys->SetData(offsets, conn);
    level_poly->SetPolys(polys);
    level_poly->GetCellData()->SetScalars(level);
  }
  // the points: each element shrunk towards its centroid so the levels read as separate cells
  vtkPoints* lp = level_poly->GetPoints();
  auto* out = static_cast<double*>(lp->GetVoidPointer(0));
  const int ne = int(c.element_offsets.size()) - 1;
  for (int e = 0; e < ne; ++e) {
    const int b = c.element_offsets[std::size_t(e)], n = c.element_offsets[std::size_t(e) + 1] - b;
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (int i = 0; i < n; ++i) centroid += last_nodes.col(c.point_node[std::size_t(b + i)]);
    centroid /= double(std::max(1, n));
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector3d p = centroid + 0.9 * (last_nodes.col(c.point_node[std::size_t(b + i)]) - centroid);
      std::copy_n(p.data(), 3, out + 3 * (b + i));
    }
  }
  lp->Modified();
  level_poly->Modified();
}

bool ProbeView::process_events() {
  Impl& v = *impl_;
  if (v.closed) return false;
  v.interactor->ProcessEvents();
  if (v.interactor->GetDone()) v.closed = true;
  return !v.closed;
}

void ProbeView::update_geometry(const Eigen::Matrix3Xd& surface_vertices, const Eigen::Matrix3Xd& surface_normals,
                                const Eigen::Matrix3Xd& node_positions,
                                const std::vector<Eigen::Vector3d>& probe_positions,
                                const std::vector<int>& probe_contacts) {
  Impl& v = *impl_;
  // the tissue surface: new points and normals, same triangles
  vtkPoints* pts = v.surface->GetPoints();
  if (surface_vertices.cols() == pts->GetNumberOfPoints()) {
    std::copy_n(surface_vertices.data(), 3 * surface_vertices.cols(), static_cast<double*>(pts->GetVoidPointer(0)));
    pts->Modified();
  }
  auto* normals = vtkDoubleArray::SafeDownCast(v.surface->GetPointData()->GetNormals());
  if (normals && surface_normals.cols() == normals->GetNumberOfTuples()) {
    std::copy_n(surface_normals.data(), 3 * surface_normals.cols(), normals->GetPointer(0));
    normals->Modified();
  }
  if (v.tint_on && surface_vertices.cols() == v.setup.surface_vertices.cols()) {
    // deeper, darker red with the displacement from rest (smoothstep up to tint_full_mm)
    const Rgb deep{0.62, 0.20, 0.22};
    auto* c = v.tint->GetPointer(0);
    for (Eigen::Index i = 0; i < surface_vertices.cols(); ++i) {
      const double d = (surface_vertices.col(i) - v.setup.surface_vertices.col(i)).norm() / v.tint_full_mm;
      const double t0 = std::clamp(d, 0.0, 1.0), t = t0 * t0 * (3.0 - 2.0 * t0);
      c[3 * i + 0] = static_cast<unsigned char>(255.0 * (kTissue.r + t * (deep.r - kTissue.r)));
      c[3 * i + 1] = static_cast<unsigned char>(255.0 * (kTissue.g + t * (deep.g - kTissue.g)));
      c[3 * i + 2] = static_cast<unsigned char>(255.0 * (kTissue.b + t * (deep.b - kTissue.b)));
    }
    v.tint->Modified();
  }
  v.surface->Modified();

  // the elements follow the nodes
  if (v.level_actor && node_positions.cols() == v.last_nodes.cols()) {
    v.last_nodes = node_positions;
    if (v.levels_on) v.update_levels(false);
  }

  // the probes; a probe in contact lights up
  for (std::size_t p = 0; p < v.probe_actors.size() && p < probe_positions.size(); ++p) {
    const Eigen::Vector3d& x = probe_positions[p];
    v.probe_actors[p]->SetPosition(x.x(), x.y(), x.z());
    const bool touching = p < probe_contacts.size() && probe_contacts[p] > 0;
    const Rgb& c = touching ? kToolContact : kTool;
    v.probe_actors[p]->GetProperty()->SetColor(c.r, c.g, c.b);
  }
}

void ProbeView::add_plot_samples(const std::vector<PlotSample>& samples) {
  Impl& v = *impl_;
  for (const auto& s : samples) {
    if (!v.plot.empty() && s.t_s < v.plot.back().t_s) v.plot.clear();  // time went back: a reset
    v.plot.push_back(s);
  }
  while (!v.plot.empty() && v.plot.back().t_s - v.plot.front().t_s > v.setup.plot_window_s) v.plot.pop_front();
}

void ProbeView::clear_plot() { impl_->plot.clear(); }

void ProbeView::set_hud(const HudInfo& hud) { impl_->hud_info = hud; }

void ProbeView::render() {
  Impl& v = *impl_;
  if (v.closed) return;
  v.layout();
  v.update_plot();
  v.update_hud_text();
  v.renderer->ResetCameraClippingRange();
  v.window->Render();
  if (v.frames == 0) {
    const char* caps = v.window->ReportCapabilities();
    const std::string c = caps ? caps : "";
    v.software_gl = c.find("llvmpipe") != std::string::npos || c.find("softpipe") != std::string::npos ||
                    c.find("swrast") != std::string::npos || c.empty();
    if (!v.software_gl) v.renderer->UseFXAAOn();
  }
  ++v.frames;
  v.fps.sample(v.frames);
}

void ProbeView::save_screenshot(const std::filesystem::path& png) {
  Impl& v = *impl_;
  if (png.extension() != ".png" && png.extension() != ".PNG")
    throw Error("screenshot '" + png.string() + "': give a .png path");
  check_output_path(png);
  write_atomically(png, [&](const std::filesystem::path& tmp) {
    auto grab = make<vtkWindowToImageFilter>();
    grab->SetInput(v.window);
    grab->SetInputBufferTypeToRGB();
    grab->ReadFrontBufferOff();
    grab->Modified();
    grab->Update();
    auto writer = make<vtkPNGWriter>();
    writer->SetFileName(tmp.string().c_str());
    writer->SetInputConnection(grab->GetOutputPort());
    writer->Write();
    if (writer->GetErrorCode() != 0) throw Error("cannot write screenshot '" + png.string() + "'");
  });
}

void ProbeView::reset_camera() { impl_->camera_to_start(); }

void ProbeView::toggle_levels() { impl_->set_levels(!impl_->levels_on); }

Eigen::Matrix3d start_view_basis(const Eigen::Vector3d& world_up) {
  const Eigen::Vector3d up =
      world_up.norm() > 0 ? Eigen::Vector3d(world_up.normalized()) : Eigen::Vector3d(0, -1, 0);
  const Eigen::Vector3d away = -toward_viewer(up);
  Eigen::Matrix3d basis;
  basis.col(0) = away.cross(up).normalized();
  basis.col(1) = up;
  basis.col(2) = away;
  return basis;
}

Eigen::Matrix3d ProbeView::view_basis() const {
  return view_basis_of(impl_->renderer->GetActiveCamera(), impl_->setup.world_up);
}

std::int64_t ProbeView::frames() const { return impl_->frames; }
double ProbeView::frames_per_s() const { return impl_->fps.rate(); }

}  // namespace vx::probe
