#pragma once
/// @file sim_output.h
/// What `voxelastic simulate` writes: forces.csv, summary.json, forces.png and .pvd time
/// series of the deformed model, surface and probes for ParaView. Every file is written
/// atomically (no partial output after a failure).

#include <Eigen/Core>
#include <filesystem>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "haptics/device_side.h"
#include "model/model.h"
#include "sim/simulation.h"
#include "surface/surface.h"

namespace vx {

/// One row of forces.csv.
struct ForceRow {
  double time_s{0.0};
  int probe{0};
  Eigen::Vector3d position_mm{Eigen::Vector3d::Zero()};
  Eigen::Vector3d raw_n{Eigen::Vector3d::Zero()};     ///< tissue on probe, mean over the steps since the previous row
  Eigen::Vector3d shaped_n{Eigen::Vector3d::Zero()};  ///< device force at the row's time
  int contacts{0};                                    ///< most nodes in contact during those steps
};

/// Collects force rows while a simulation runs: one row per probe at t = 0 and then every
/// `interval_s` (at least every step). The raw force of a row is the mean over the steps since
/// the previous row, so no step is lost to sampling; the device force is sampled at the row.
class ForceRecorder {
 public:
  /// `device`: the run's device side, for the device force (null: none); it must outlive the recorder.
  ForceRecorder(const Simulation& sim, const DeviceSide* device, double interval_s);
  /// Call after every step.
  void record(const Simulation& sim);
  /// Call once at the end: a last row for the steps since the previous row, if any.
  void finish(const Simulation& sim);
  /// Writes forces.csv: time_s,probe,x_mm,y_mm,z_mm,fx_n,fy_n,fz_n,dfx_n,dfy_n,dfz_n (the
  /// device columns are empty when the scene has no device). Atomic.
  void write_csv(const std::filesystem::path& path) const;

  [[nodiscard]] const std::vector<ForceRow>& rows() const { return rows_; }
  [[nodiscard]] const std::vector<std::string>& names() const { return names_; }
  [[nodiscard]] bool has_device() const { return device_; }
  /// Largest |raw force| over the rows, N (overall and per probe).
  [[nodiscard]] double max_force_n() const;
  [[nodiscard]] double max_force_n(int probe) const;
  /// Largest |raw force| of any single step, N (the jitter peaks the rows average out).
  [[nodiscard]] double max_step_force_n() const { return max_step_force_; }
  /// Largest |force| of the tissue on the walls in any step, N, and its impulse (sum F dt), N*s.
  [[nodiscard]] double max_wall_force_n() const { return max_wall_force_; }
  [[nodiscard]] const Eigen::Vector3d& wall_impulse_n_s() const { return wall_impulse_; }

 private:
  void emit(const Simulation& sim);

  std::vector<std::string> names_;
  const DeviceSide* device_side_{nullptr};
  bool device_{false};
  double interval_s_{0.0};
  double next_s_{0.0};
  std::vector<Eigen::Vector3d> sum_;
  std::vector<int> contacts_;
  int steps_{0};
  double max_step_force_{0.0};
  double max_wall_force_{0.0};
  Eigen::Vector3d wall_impulse_{Eigen::Vector3d::Zero()};
  std::vector<ForceRow> rows_;
};

/// Indentation depth of each row of one probe, mm: how far the probe has moved into the tissue
/// since its first contact, measured against the direction of its mean force (the tissue
/// pushes the probe back out). Rows before the first contact get depth <= 0. Also gives the
/// force component along that direction (N), the curve to compare with Hertz.
void indentation_curve(const std::vector<ForceRow>& rows, int probe, std::vector<double>& depth_mm,
                       std::vector<double>& force_n);

/// One press: the rows of a probe in an interval of contact (rows with contacts > 0, no more
/// than kPressGapRows rows apart), [first, last] as indices into the recorder's rows.
struct Press {
  int probe{0};
  std::size_t first{0}, last{0};
  double start_s{0.0}, end_s{0.0};
};
/// Rows without contact that end a press (shorter gaps are flicker at the contact's edge).
inline constexpr int kPressGapRows = 5;
/// The presses of every probe in time order; presses of fewer than 3 rows are left out.
[[nodiscard]] std::vector<Press> find_presses(const std::vector<ForceRow>& rows);

/// Hertz for a rigid sphere (radius r_mm) pressed d_mm into a layer h_mm thick of modulus
/// e_kpa and Poisson's ratio nu, bonded to a rigid base (Dimitriadis et al., Biophys. J. 82,
/// 2002, eq. 12), N; h -> infinity gives Hertz's half-space F = 4/3 E/(1 - nu^2) sqrt(R) d^1.5.
/// verify's Hertz cases and forces.png's analytic curve use it.
[[nodiscard]] double hertz_bonded_layer_n(double e_kpa, double nu, double r_mm, double d_mm, double h_mm);

/// An analytic force against indentation depth, drawn with the measured presses.
struct ForceReference {
  std::string title;  ///< the legend's text, e.g. "finite-layer Hertz (E 10 kPa, layer 20 mm)"
  double e_kpa{0}, nu{0}, radius_mm{0}, layer_mm{0};  ///< hertz_bonded_layer_n's parameters
};

/// Draws forces.png: the force on each probe against time (and the device force, dashed, when
/// the scene has a device), and force against indentation depth, one curve per press (depth
/// from the press's first contact along its mean force), with `references` over them. Throws
/// vx::Error when the picture cannot be written.
void plot_forces(const ForceRecorder& recorder, const std::filesystem::path& png,
                 const std::vector<ForceReference>& references = {});

/// A time series for ParaView: frames written as they come, the .pvd collection at the end.
class PvdSeries {
 public:
  /// Frames go to `dir/<name>/<name>_NNNNNN.<ext>`, the collection to `dir/<name>.pvd`.
  PvdSeries(const std::filesystem::path& dir, const std::string& name, const std::string& ext);
  /// The path of the next frame (relative names are kept in the collection).
  [[nodiscard]] std::filesystem::path next_frame_path() const;
  /// Records the frame just written at `next_frame_path()` for time t.
  void add(double time_s);
  /// Writes the .pvd collection (atomically).
  void finish() const;
  [[nodiscard]] int frames() const { return int(times_.size()); }
  [[nodiscard]] std::filesystem::path collection_path() const;

 private:
  std::filesystem::path dir_;
  std::string name_, ext_;
  std::vector<double> times_;
};

/// Per element: the Green-Lagrange strain E = (F^T F - I) / 2 of the deformation gradient F
/// that maps the element's rest vertices onto `positions` best (least squares about the
/// centroids; exact for an affine motion), 6 x elements as (xx, yy, zz, xy, yz, xz) in LPS
/// axes, tensor components (not engineering shear). A slice model's F keeps the slice normal,
/// so its strain is the in-plane strain (zz and the shears with z are 0 in the slice's frame).
/// Rigid motions give 0; a uniform stretch by s along x gives xx = (s^2 - 1) / 2.
[[nodiscard]] Eigen::Matrix<double, 6, Eigen::Dynamic> element_green_strain(const Model& model,
                                                                            const Eigen::Matrix3Xd& positions);

/// The von Mises equivalent of a strain given as (xx, yy, zz, xy, yz, xz): sqrt(2/3 e':e'), e'
/// its deviatoric part; a uniaxial strain e with no lateral strain gives 2/3 e, an
/// incompressible uniaxial one e.
[[nodiscard]] double von_mises_equivalent_strain(const Eigen::Matrix<double, 6, 1>& strain);

/// Writes deformed-model frames (.vtu): the model's polyhedron cells with points at the node
/// positions and the point array `displacement_mm` (from rest): the points are already moved,
/// so ParaView's "Warp By Vector" would move them twice (use it on the model file, convert's
/// .vtu, instead). Cell data: `level`, `green_strain` (6 components, element_green_strain)
/// and `green_strain_von_mises` (its von Mises equivalent, dimensionless). The topology is
/// built once.
class ModelFrameWriter {
 public:
  explicit ModelFrameWriter(const Model& model);
  ~ModelFrameWriter();
  void write(const Eigen::Matrix3Xd& positions, const Eigen::Matrix3Xd& velocities,
             const std::filesystem::path& path) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Writes deformed-surface frames (.vtp) with `Normals` and `displacement_mm`.
class SurfaceFrameWriter {
 public:
  explicit SurfaceFrameWriter(const EmbeddedSurface& surface);
  ~SurfaceFrameWriter();
  void write(const Eigen::Matrix3Xd& vertices, const std::filesystem::path& path) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Writes probe frames (.vtp): one point per probe (its position) with `radius_mm`,
/// `force_n` (raw) and `device_force_n` arrays, for glyphs in ParaView.
void write_probe_frame(const Simulation& sim, const DeviceSide* device, const std::filesystem::path& path);

}  // namespace vx
