#pragma once
/// @file probe_view.h
/// The probe app's VTK window: the deforming smoothed tissue surface (Gouraud shading with
/// the surface's own vertex normals), the probes, the workspace walls, an optional view of
/// the elements coloured by level (the gradational structure, cut open facing the viewer),
/// a heads-up display, a live force plot (vtkChartXY in a vtkContextActor) and screenshots.
///
/// Everything here runs on the GUI (main) thread. VTK headers stay in the .cpp.
/// Create a ProbeView only after display_problem() returned empty (VTK crashes without X).

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "model/model.h"
#include "sim/contact.h"
#include "stick_control.h"

namespace vx::probe {

/// The elements of a model as polygons for the level view: one point per element vertex
/// entry (so each element can be shrunk on its own), polygons from the element faces.
struct LevelCells {
  std::vector<std::int32_t> point_node;       ///< points: model node id
  std::vector<std::int32_t> element_offsets;  ///< elements + 1: points of element e
  std::vector<std::int32_t> element_polys;    ///< elements + 1: polygons of element e
  std::vector<std::int32_t> poly_offsets{0};  ///< polygons + 1
  std::vector<std::int32_t> poly_points;      ///< point ids
  std::vector<std::int8_t> poly_level;        ///< polygons: level of their element
  Eigen::Matrix3Xd rest_centroids;            ///< 3 x elements, mm
  Eigen::Matrix3Xd rest_nodes;                ///< 3 x nodes, the model's rest positions, mm
  std::vector<double> level_size_mm;          ///< levels: element edge, mm (Model::element_size_mm)
  std::vector<int> level_voxels;              ///< levels: element edge, voxels (Model::element_edge_voxels)
  int levels{0};
};
/// Builds the level cells of `model`; throws vx::Error for an inconsistent model.
[[nodiscard]] LevelCells make_level_cells(const Model& model);

/// Unit vertex normals (3 x V) of a triangle mesh (3 x V vertices, 3 x T triangles), as the
/// deforming surface computes them (surface.h: the mean of the unit normals of the triangles
/// around a vertex). The view lights its rest surface with them until the first frame arrives.
[[nodiscard]] Eigen::Matrix3Xd vertex_normals(const Eigen::Matrix3Xd& vertices, const Eigen::Matrix3Xi& triangles);

/// What the view shows that does not change during a run.
struct ViewSetup {
  std::string title;                         ///< shown in the HUD and the window title
  Eigen::Matrix3Xd surface_vertices;         ///< 3 x V at rest, LPS mm
  Eigen::Matrix3Xi surface_triangles;        ///< 3 x T, counter-clockwise seen from outside
  std::shared_ptr<const LevelCells> levels;  ///< optional: the elements view, made now
  /// optional: the elements view's cells, made the first time it is shown (a second on an organ,
  /// which a session that never shows it does not pay before its first frame); `levels` first
  std::function<std::shared_ptr<const LevelCells>()> make_levels;
  std::vector<ProbeGeometry> probes;            ///< one per probe
  std::vector<std::string> probe_names;         ///< one per probe (HUD)
  std::vector<Eigen::Vector3d> probe_start_mm;  ///< where each probe starts
  bool walls{false};
  Box workspace;                       ///< the walls (when `walls`)
  Eigen::Vector3d world_up{0, -1, 0};  ///< "up" on screen (LPS; default anterior)
  /// a 2D (slice) model: the flat view, the camera on the side of `slice_normal` looking at the
  /// slice face on, `world_up` (in the slice plane) up on screen
  bool flat{false};
  Eigen::Vector3d slice_normal{0, 0, 1};
  int width{1280};
  int height{800};
  double plot_window_s{5.0};  ///< time shown by the force plot
  std::string input_line;     ///< HUD: e.g. "rate control: joystick 'X'"
  std::string output_line;    ///< HUD: e.g. "force out: haptic 'X' + log f.csv"
  bool local_shaping{false};  ///< the device force is the local contact model's (HUD, plot)
  std::string physics_line;   ///< HUD: the configuration the physics runs, e.g. "implicit 20 ms, 1 iteration"
};

/// Numbers for the heads-up display.
struct HudInfo {
  double sim_s{0.0};  ///< paper: simulated time; local: the device's clock
  double physics_steps_per_s{0.0};
  double physics_updates_per_s{0.0};  ///< local: local contact models published per second (measured)
  double real_time_factor{1.0};       ///< simulated seconds per wall second
  /// The physics' rate as the app words it (real_time_meter.h): "34 steps/s (0.52x real time,
  /// last 1 s)", or during the start-up "preparing the solver (3.2 s)"; empty: from the numbers
  std::string physics_rate;
  /// While the solver is factored in the background: a line under the solver's configuration
  /// (GuiLoop::solver_note); empty: none.
  std::string solver_note;
  /// While the display surface is a preview, decimated in the background: a line saying so
  /// (GuiLoop::surface_note); empty: none.
  std::string surface_note;
  bool behind_real_time{false};  ///< physics cannot keep up
  /// The threads the physics steps on now, of those it was given (thread_share.h)
  int physics_threads{1};
  int physics_threads_given{1};
  double device_hz{0.0};
  double device_target_hz{1000.0};  ///< the device thread's rate; below 90% of it the HUD warns
  int probes{0};
  std::array<double, 2> force_N{};  ///< per probe: paper, |the current update's mean|; local, |the force played|
  std::array<int, 2> contacts{};
  std::array<int, 2> model_nodes{};  ///< local: nodes of the probe's local contact model
  int active_probe{0};               ///< the keyboard's probe
  bool paused{false};
  std::string status;  ///< an extra line (errors, disconnects), shown in red
};

/// One point of the force plot (the paper's fig. 10: the raw reaction sum jitters from step to
/// step; the device plays one half sine per update whose mean is the update's averaged force;
/// local shaping: the local model's force, and the physics' force at its anchor).
struct PlotSample {
  double t_s{0.0};                  ///< paper: simulated time; local: the device's clock
  std::array<float, 2> device_N{};  ///< |device force| played now (the half sine; the local model) per probe
  std::array<float, 2> mean_N{};    ///< |the current update's force| (the half sine's mean; the anchor's) per probe
  std::array<float, 2> raw_N{};     ///< |raw reaction sum of the last physics step| per probe
};

/// The view basis of the start camera (columns right, up, away; world, unit) for `world_up`:
/// the camera looks at the tissue from the front, 30 degrees above the horizon. Headless runs
/// use it too, so a scripted palpation moves the probe the same way with or without a window.
[[nodiscard]] Eigen::Matrix3d start_view_basis(const Eigen::Vector3d& world_up);

/// What a key asks the app to do (view-only toggles are handled by the view itself).
enum class ViewAction : std::uint8_t { quit, pause, reset_scene, screenshot, next_probe };

class ProbeView {
 public:
  /// Opens the window. `keyboard` receives the motion keys and mouse drags (may be null);
  /// `on_action` the keys for the app. Throws vx::Error when the window cannot be made.
  ProbeView(const ViewSetup& setup, KeyboardStick* keyboard, std::function<void(ViewAction)> on_action);
  ~ProbeView();
  ProbeView(const ProbeView&) = delete;
  ProbeView& operator=(const ProbeView&) = delete;

  /// Handles pending window events (keys, mouse, resize, close). False once the window closed.
  bool process_events();
  /// New deformed surface (3 x V vertices and unit normals), node positions (3 x nodes, for
  /// the elements view; may be empty) and probe positions.
  void update_geometry(const Eigen::Matrix3Xd& surface_vertices, const Eigen::Matrix3Xd& surface_normals,
                       const Eigen::Matrix3Xd& node_positions, const std::vector<Eigen::Vector3d>& probe_positions,
                       const std::vector<int>& probe_contacts);
  /// Another tissue surface at rest (3 x V vertices, 3 x T triangles), drawn from now on in
  /// place of the first (the camera, the tint and the views stay): the physics deforms a refined
  /// display surface once it is ready. The next update_geometry must have V vertices. Throws
  /// vx::Error when it has no vertices or triangles.
  void replace_surface(const Eigen::Matrix3Xd& rest_vertices, const Eigen::Matrix3Xi& triangles);
  /// Appends samples to the force plot (times increasing; older than the window are dropped).
  void add_plot_samples(const std::vector<PlotSample>& samples);
  /// Clears the force plot (after a reset).
  void clear_plot();
  /// Sets the HUD numbers (frames/s is measured by the view).
  void set_hud(const HudInfo& hud);
  /// Draws one frame.
  void render();
  /// Writes the last frame as PNG (atomically); throws vx::Error on failure.
  void save_screenshot(const std::filesystem::path& png);
  /// Camera back to the start view.
  void reset_camera();
  /// Shows or hides the element levels view (the `l` key).
  void toggle_levels();
  /// True while the element levels view is shown: the only part of the view that draws the
  /// nodes (update_geometry's node positions are not needed otherwise).
  [[nodiscard]] bool shows_levels() const;
  /// The view basis for the sticks: columns right, up, away (world, unit).
  [[nodiscard]] Eigen::Matrix3d view_basis() const;
  /// Frames rendered so far and the measured rate.
  [[nodiscard]] std::int64_t frames() const;
  /// Window events handled so far (keys, mouse, resize, expose): what the user did to the view.
  [[nodiscard]] std::int64_t input_events() const;
  [[nodiscard]] double frames_per_s() const;
  /// The OpenGL renderer is a software one (llvmpipe, softpipe, swrast), known after the first frame.
  [[nodiscard]] bool software_gl() const;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace vx::probe
