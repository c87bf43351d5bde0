// The probe app's VTK window (probe_view.h): the window and its two renderers, the camera, keys
// and mouse, frames and screenshots. The scene's actors, the levels view and the HUD with the
// force plot are probe_view_actors.cpp, probe_view_levels.cpp and probe_view_hud.cpp.
#include "probe_view.h"

#include <vtkActor.h>
#include <vtkCallbackCommand.h>
#include <vtkCamera.h>
#include <vtkChartXY.h>
#include <vtkCommand.h>
#include <vtkContextActor.h>
#include <vtkLightKit.h>
#include <vtkMapper.h>
#include <vtkObjectFactory.h>
#include <vtkPNGWriter.h>
#include <vtkProperty.h>
#include <vtkRenderWindow.h>
#include <vtkRenderWindowInteractor.h>
#include <vtkRenderer.h>
#include <vtkTextActor.h>
#include <vtkWindowToImageFilter.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cctype>
#include <cmath>

#include "base/error.h"
#include "probe_view_impl.h"
#include "util/atomic_file.h"

namespace vx::probe {

vtkStandardNewMacro(ProbeInteractorStyle);

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

void on_exit(vtkObject*, unsigned long, void* client, void*) { static_cast<ProbeView::Impl*>(client)->closed = true; }

void on_input(vtkObject*, unsigned long, void* client, void*) { ++static_cast<ProbeView::Impl*>(client)->input_events; }

// a unit-ish world "toward the viewer" direction perpendicular to up
Eigen::Vector3d toward_viewer(const Eigen::Vector3d& up) {
  for (const Eigen::Vector3d& c : {Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(-1, 0, 0)}) {
    if (std::abs(c.dot(up)) < 0.7) return (c - c.dot(up) * up).normalized();
  }
  return up.unitOrthogonal();
}

}  // namespace

Eigen::Matrix3d view_basis_of(vtkCamera* cam, const Eigen::Vector3d& world_up) {
  const Eigen::Vector3d up = world_up.norm() > 0 ? Eigen::Vector3d(world_up.normalized()) : Eigen::Vector3d(0, -1, 0);
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
  // every event the window delivers (keys, mouse, resize, expose): the GUI loop redraws after one
  auto input_cb = make<vtkCallbackCommand>();
  input_cb->SetCallback(&on_input);
  input_cb->SetClientData(this);
  interactor->AddObserver(vtkCommand::AnyEvent, input_cb);

  // lights: a key/fill/back kit like a surgical lamp, plus the camera's headlight off
  auto lights = make<vtkLightKit>();
  lights->SetKeyLightIntensity(0.9);
  lights->SetKeyToFillRatio(4.0);  // more relief than VTK's default 3
  lights->SetKeyLightElevation(40.0);
  lights->SetKeyLightAzimuth(25.0);
  lights->AddLightsToRenderer(renderer);

  build_tissue();

  // the scene's size and centre from the rest surface
  const Eigen::Vector3d lo = setup.surface_vertices.rowwise().minCoeff();
  const Eigen::Vector3d hi = setup.surface_vertices.rowwise().maxCoeff();
  focus = 0.5 * (lo + hi);
  radius = std::max(1.0, 0.5 * (hi - lo).norm());
  tint_full_mm = std::max(0.5, 0.12 * (hi - lo).minCoeff());

  build_probes();
  build_walls();
  build_guides();
  build_levels();
  build_hud();
  build_plot();
  update_plot();  // the table holds a line before anything is drawn
  camera_to_start();
  interactor->Initialize();
  layout();
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
  Eigen::Vector3d dir = (-std::cos(el) * away + std::sin(el) * up).normalized();
  Eigen::Vector3d view_up = up;
  if (setup.flat) {
    // a slice: face on, its own "up" up on screen
    dir = setup.slice_normal.normalized();
    view_up = setup.world_up - dir * dir.dot(setup.world_up);
    if (view_up.norm() < 1e-9) view_up = dir.unitOrthogonal();
    view_up.normalize();
  }
  vtkCamera* cam = renderer->GetActiveCamera();
  cam->SetViewAngle(30.0);
  // frame the tissue and the probes' start positions
  double r = radius;
  for (const auto& s : setup.probe_start_mm) r = std::max(r, (s - focus).norm() * 0.8);
  const Eigen::Vector3d target = setup.flat ? focus : Eigen::Vector3d(focus + 0.15 * r * up);
  const double dist = 1.45 * r / std::sin(0.5 * 30.0 * M_PI / 180.0);
  const Eigen::Vector3d pos = target + dist * dir;
  cam->SetFocalPoint(target.data());
  cam->SetPosition(pos.data());
  cam->SetViewUp(view_up.data());
  renderer->ResetCameraClippingRange();
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
  const double mm_per_px =
      2.0 * cam->GetDistance() * std::tan(0.5 * cam->GetViewAngle() * M_PI / 180.0) / double(std::max(1, size[1]));
  Eigen::Vector3d offset(dx * mm_per_px, dy * mm_per_px, 0.0);
  if (depth) offset = Eigen::Vector3d(0.0, 0.0, dy * mm_per_px);
  keyboard->add_drag(offset);
}

bool ProbeView::process_events() {
  Impl& v = *impl_;
  if (v.closed) return false;
  v.interactor->ProcessEvents();
  if (v.interactor->GetDone()) v.closed = true;
  return !v.closed;
}

void ProbeView::replace_surface(const Eigen::Matrix3Xd& rest_vertices, const Eigen::Matrix3Xi& triangles) {
  if (rest_vertices.cols() == 0 || triangles.cols() == 0)
    throw Error("the view needs a surface (no vertices or triangles)");
  Impl& v = *impl_;
  v.setup.surface_vertices = rest_vertices;
  v.setup.surface_triangles = triangles;
  v.set_tissue_mesh();
}

void ProbeView::update_geometry(const Eigen::Matrix3Xd& surface_vertices, const Eigen::Matrix3Xd& surface_normals,
                                const Eigen::Matrix3Xd& node_positions,
                                const std::vector<Eigen::Vector3d>& probe_positions,
                                const std::vector<int>& probe_contacts) {
  Impl& v = *impl_;
  v.update_tissue(surface_vertices, surface_normals);

  // the elements follow the nodes
  if (v.level_actor && node_positions.cols() == v.last_nodes.cols()) {
    v.last_nodes = node_positions;
    if (v.levels_on) v.update_levels(false);
  }

  v.update_probes(probe_positions, probe_contacts);
}

void ProbeView::render() {
  Impl& v = *impl_;
  if (v.closed) return;
  v.layout();
  v.update_plot();
  v.update_hud_text();
  v.renderer->ResetCameraClippingRange();
  v.update_marker();
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

Eigen::Matrix3d start_view_basis(const Eigen::Vector3d& world_up) {
  const Eigen::Vector3d up = world_up.norm() > 0 ? Eigen::Vector3d(world_up.normalized()) : Eigen::Vector3d(0, -1, 0);
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
std::int64_t ProbeView::input_events() const { return impl_->input_events; }
double ProbeView::frames_per_s() const { return impl_->fps.rate(); }

bool ProbeView::software_gl() const { return impl_->frames > 0 && impl_->software_gl; }

}  // namespace vx::probe
