#pragma once
/// @file probe_view_impl.h
/// Private to the probe app's view (probe_view.h): the view's state, shared by its files:
/// probe_view.cpp (the window, camera, keys, frames, screenshots), probe_view_actors.cpp (the
/// tissue surface, the probes, the walls), probe_view_levels.cpp (the elements by level) and
/// probe_view_hud.cpp (the HUD, help and force plot). VTK headers stay out of probe_view.h.

#include <vtkInteractorStyleTrackballCamera.h>
#include <vtkSmartPointer.h>

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <deque>
#include <functional>
#include <string>
#include <vector>

#include "probe_view.h"
#include "rate_thread.h"

class vtkActor;
class vtkAxesActor;
class vtkBillboardTextActor3D;
class vtkCamera;
class vtkChartXY;
class vtkContextActor;
class vtkPlane;
class vtkPolyData;
class vtkRenderWindow;
class vtkRenderWindowInteractor;
class vtkRenderer;
class vtkTable;
class vtkTextActor;
class vtkTextProperty;
class vtkUnsignedCharArray;

namespace vx::probe {

template <class T>
using Ptr = vtkSmartPointer<T>;
template <class T>
Ptr<T> make() {
  return Ptr<T>::New();
}

// ---------------------------------------------------------------- colours

/// A colour, each component in [0, 1].
struct Rgb {
  double r, g, b;
};
inline constexpr Rgb kTissue{0.86, 0.56, 0.50};
inline constexpr Rgb kTool{0.78, 0.80, 0.84};
inline constexpr Rgb kToolContact{0.66, 0.77, 0.93};
inline constexpr Rgb kBackgroundTop{0.10, 0.12, 0.16};
inline constexpr Rgb kBackgroundBottom{0.28, 0.31, 0.36};
inline constexpr std::array<Rgb, 2> kProbeColour{Rgb{1.0, 0.62, 0.15}, Rgb{0.30, 0.80, 1.0}};
/// The colour of element level `level` (render/palette.h: the same as in pictures).
[[nodiscard]] Rgb level_rgb(int level);

/// The right-hand panel takes this fraction of the window's width.
inline constexpr double kPanel = 0.32;

/// Courier text of `size` points in colour `c` on a dark translucent box.
void set_text_style(vtkTextProperty* p, int size, const Rgb& c);

/// Columns right, up, away for the camera: "away" is the viewing direction made horizontal
/// (looking straight down: the camera's up), "up" the world's.
[[nodiscard]] Eigen::Matrix3d view_basis_of(vtkCamera* cam, const Eigen::Vector3d& world_up);

// ---------------------------------------------------------------- interactor style

class ProbeInteractorStyle : public vtkInteractorStyleTrackballCamera {
 public:
  static ProbeInteractorStyle* New();
  vtkTypeMacro(ProbeInteractorStyle, vtkInteractorStyleTrackballCamera) void OnChar() override {
  }  // no built-in VTK keys (e/q quit, w wireframe, 3 stereo, ...)
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
  Ptr<vtkPlane> level_cut;                      // the cut-away plane (surface clipped, elements culled)
  Eigen::Vector3d cut_away{0, 0, 0};            // "away" direction the current cut was made for
  Eigen::Matrix3Xd last_nodes;                  // node positions of the last frame
  std::vector<Ptr<vtkTextActor>> level_legend;  // one line per level, in its colour
  bool levels_on{false};

  // probes and walls
  std::vector<Ptr<vtkActor>> probe_actors;
  std::vector<Ptr<vtkActor>> wall_actors;
  bool walls_on{true};

  // guides: a scale bar on the table in front of the tissue, and the model's axes (LPS) in
  // the 3D view's bottom right corner, turning with the camera
  Ptr<vtkActor> scale_bar;
  Ptr<vtkBillboardTextActor3D> scale_label;
  double scale_bar_mm{10.0};
  Ptr<vtkRenderer> marker;  // layer 1, over the 3D view
  Ptr<vtkAxesActor> axes;
  double marker_distance{10.0};

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
  std::int64_t input_events{0};  // window events (keys, mouse, resize, expose) so far
  RateMeter fps{0.5};

  // camera
  Eigen::Vector3d focus{0, 0, 0};
  double radius{50.0};

  void build_scene();
  void build_tissue();
  void build_probes();
  void build_walls();
  void build_guides();
  void update_marker();
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
  void update_tissue(const Eigen::Matrix3Xd& surface_vertices, const Eigen::Matrix3Xd& surface_normals);
  /// The tissue's polydata from setup.surface_vertices and setup.surface_triangles.
  void set_tissue_mesh();
  void update_probes(const std::vector<Eigen::Vector3d>& probe_positions, const std::vector<int>& probe_contacts);
};

}  // namespace vx::probe
