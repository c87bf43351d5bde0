#pragma once
/// @file palpation_map.h
/// A palpation map: a ball pressed at a grid of points over the face of an object that looks
/// towards the probe, each press on its own from the rest state, the force read at a set depth
/// (docs/palpation.md). The map's summary estimates where a stiffer lesion lies, how large it
/// looks and how much it stands out (contrast).
///
/// The points: a square grid of `spacing_mm` in the plane of the face (for the +z face the x, y
/// plane), centred on the object's extent there. A point is pressed when the tissue lies under
/// the whole ball (every node column within one probe radius of it holds tissue) and the
/// surface under the ball rises by less than one probe radius across it (slopes below about
/// 27 degrees); the others are left out. The surface height under a point is where the ball,
/// coming down along the face's inward normal, first touches a node (contact is node-based:
/// sim/contact.h).
///
/// One press: the ball jumps through the air to `gap_mm` above its first contact, presses
/// `gap_mm + depth_mm` at `speed_mm_s`, holds `hold_s`, and the force along the face's normal is
/// averaged over the last `average_s` of the hold. Each press starts from the rest state
/// (Simulation::reset), so presses are independent and the map does not depend on the order or
/// the thread count. Stiffness = force / depth (a secant stiffness, N/mm).
///
/// Units: mm, s, N, N/mm; points in LPS mm.

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "scene/scene.h"

namespace vx {

/// How to map.
struct PalpationMapSettings {
  double spacing_mm{3.0};       ///< grid spacing in the face's plane, mm
  double depth_mm{2.0};         ///< press depth below the first contact, mm
  double probe_radius_mm{4.0};  ///< the ball (a fingertip-sized 4 mm by default), mm
  BoxFace face{BoxFace::z_max}; ///< the face pressed: z_max (+z) is pressed along -z
  double speed_mm_s{10.0};      ///< press speed (slow: quasi-static), mm/s
  double gap_mm{0.5};           ///< the press starts this far above the first contact, mm
  double hold_s{0.2};           ///< hold at depth before the force is read, s
  double average_s{0.06};       ///< the force is the mean over the last this long of the hold, s
  int threads{0};               ///< presses in parallel (0: every core); one physics thread each

  /// Empty when valid, else what is wrong (sizes > 0 and finite, average_s <= hold_s).
  [[nodiscard]] std::string validate() const;
};

/// "+z", "-x", ... for a face (the direction it looks in).
[[nodiscard]] std::string face_name(BoxFace face);
/// Parses "+z", "z", "-x", "z_max", "x_min", ...; throws vx::Error naming the choices.
[[nodiscard]] BoxFace parse_face(const std::string& text);

/// One pressed point.
struct PalpationPoint {
  int i{0}, j{0};                                   ///< grid index along the plane's first and second axis
  double u_mm{0}, v_mm{0};                          ///< in-plane coordinates (the plane axes' LPS values)
  Eigen::Vector3d surface_mm{Eigen::Vector3d::Zero()};  ///< where the ball first touches (its lowest point), LPS mm
  double depth_mm{0};                               ///< reached press depth, mm
  double force_n{0};                                ///< force along the face normal at depth, N (NaN on failure)
  double stiffness_n_mm{0};                         ///< force_n / depth_mm
  std::string failure;                              ///< "" when the press ran
};

/// A map of the face: the points and what is needed to draw it.
struct PalpationMap {
  PalpationMapSettings settings;
  int normal_axis{2};      ///< the face's axis (0 x, 1 y, 2 z)
  int u_axis{0}, v_axis{1};///< the plane's axes
  double outward{1.0};     ///< +1 for a max face, -1 for a min face
  int grid_u{0}, grid_v{0};///< grid points along u and v (pressed or not)
  double u0_mm{0}, v0_mm{0};  ///< coordinates of grid point (0, 0)
  std::vector<PalpationPoint> points;  ///< the pressed points, by j then i
  /// The object seen from the face: bins of `bin_mm` (the model's voxel) holding tissue, with
  /// the height of their top node along the outward normal (NaN: empty), bin (a, b) at
  /// (bin_u0_mm + a bin_mm, bin_v0_mm + b bin_mm), a fastest.
  int bins_u{0}, bins_v{0};
  double bin_mm{1.0}, bin_u0_mm{0}, bin_v0_mm{0};
  std::vector<double> bin_height_mm;
  int nodes{0}, elements{0};  ///< the model's size
  double time_step_s{0};      ///< the physics step of each press
  int steps_per_press{0};
  int threads{1};             ///< presses run in parallel
  double wall_s{0};           ///< time to run every press, s
};

/// What the map says about a lesion.
struct PalpationSummary {
  int points{0}, failed{0};
  double background_n_mm{0};      ///< median stiffness of the map
  double peak_n_mm{0};            ///< the stiffest point
  double threshold_n_mm{0};       ///< halfway between background and peak
  int points_above{0};            ///< points at or above the threshold
  /// stiffness-weighted (stiffness - background) centroid of the points above the threshold,
  /// on the surface, LPS mm
  Eigen::Vector3d lesion_estimate_mm{Eigen::Vector3d::Constant(std::nan(""))};
  double extent_u_mm{0}, extent_v_mm{0};  ///< extent of the points above the threshold (one spacing per point row)
  double equivalent_diameter_mm{0};       ///< diameter of the disc of the same area as those points
  double surrounding_n_mm{0};             ///< median stiffness of the points below the threshold
  double contrast{0};                     ///< peak / surrounding
};

/// The scene that maps `input`: a scene file (.json: its object, material, fixed regions and
/// contact; its probes, device, integrator and outputs are replaced), a model (.vtu) or a
/// volume (any format read_volume knows, thresholded as a scene's volume). A model or volume is
/// held at the face opposite the mapped one; a volume's voxels take their modulus from
/// `hounsfield` (HU -> kPa rows, sorted; empty: `modulus_kpa` everywhere). Throws vx::Error.
struct PalpationSceneOptions {
  BoxFace face{BoxFace::z_max};
  double modulus_kpa{5.0};
  std::vector<HuModulus> hounsfield{{40.0, 5.0}, {120.0, 50.0}};  ///< the phantoms' tissue and lesion
  double damping{0.2};
};
[[nodiscard]] Scene palpation_scene(const std::filesystem::path& input, const PalpationSceneOptions& options);

/// Presses every point of the face (see the file comment). `progress(done, total)` is called
/// from the worker threads under a lock after each press (may be empty). Throws vx::Error for
/// a 2D model, bad settings, or a face with no point to press.
[[nodiscard]] PalpationMap palpation_map(const PreparedScene& prepared, const PalpationMapSettings& settings,
                                         const std::function<void(int done, int total)>& progress = {});

/// The lesion estimate, extent and contrast of a map (see PalpationSummary).
[[nodiscard]] PalpationSummary summarize_palpation_map(const PalpationMap& map);

/// The summary as JSON (summary.json's "map" and "lesion" parts).
[[nodiscard]] nlohmann::json palpation_summary_json(const PalpationMap& map, const PalpationSummary& summary);

/// Writes DIR/map.csv, DIR/map.vtp, DIR/map.png (when `png`) and
/// DIR/summary.json (the summary with `extra` merged in), each atomically.
void write_palpation_map(const PalpationMap& map, const PalpationSummary& summary, const std::filesystem::path& dir,
                         const nlohmann::json& extra, bool png = true);

}  // namespace vx
