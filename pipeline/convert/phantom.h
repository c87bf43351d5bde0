#pragma once
/// @file phantom.h
/// Synthetic CT-like volumes with a known analytic shape, for tests, demos and verification.

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "io/volume.h"

namespace vx {

/// Settings of a phantom. Sizes are in voxels of the grid; the shape is centred in the grid,
/// whose centre is at LPS (0,0,0) (identity direction), with at least 2 voxels of air around
/// it (1 voxel for sizes below 6).
///
/// Proportions, as fractions of the grid's edge L = size * spacing (for sizes below 25, of a
/// slightly smaller length so the margin holds): sphere radius 0.4; cube edge 0.7; ellipsoid
/// semi-axes 0.42 x 0.30 x 0.22 (x, y, z); cylinder along z, radius 0.3, length 0.8; torus in
/// the xy plane, radii 0.28 and 0.12; block 0.8 x 0.6 x 0.4; block-lesion the block with a
/// spherical lesion of radius about 0.15 centred off-axis at 60% of the block's height; organ an
/// ellipsoid of semi-axes 0.327 x 0.42 x 0.35 (an organ-sized stand-in: 140 x 180 x 150 mm at
/// size 214 and 1 mm voxels, about 2 M tissue voxels); folded a brain-like stand-in (below).
///
/// folded, in mm at size 214 and 1 mm voxels (every length scales with the grid's edge like the
/// others'): two hemispheres, 140 x 180 x 136 mm (x, y, z), an ellipsoid centred at z = +7 with
/// a longitudinal fissure 4 mm wide (|x| < 2) from its top down to z = -5, below which they are
/// joined; the cortex folded into gyri by sulci 3 mm wide and 10 mm deep (10 to 13 mm below the
/// ellipsoid along its normal), traced by the sheet of a gyroid of period 30 mm pushed along rays
/// from the centre (so every sulcal wall runs inwards and no gyrus is cut off); and a stem, a
/// vertical cylinder of radius 10 mm at x = y = 0 from the lowest tissue, z = -75, up into the
/// body (z = -30; 14 mm of it stand out below the body). Overall 140 x 180 x 150 mm, one
/// connected piece.
/// Flat faces (cube, block, cylinder caps) lie on voxel faces (rounded inwards), so their
/// voxel counts are exact.
///
/// One-slice (2D) phantoms, the paper's 2D case (docs/model.md section 12): a size x size x 1
/// grid whose slice is `thickness_mm` deep (0: the pixel spacing), the shape in its plane z = 0:
/// disk radius 0.4; rectangle 0.8 x 0.5 (x, y); disk-lesion the disk with a round lesion of a
/// quarter of its radius centred halfway from the centre to the top (+y).
struct PhantomSettings {
  std::string name{"sphere"};  ///< sphere, cube, ellipsoid, cylinder, torus, block, block-lesion, organ, folded
                               ///< one slice (2D): disk, rectangle, disk-lesion
  int size{64};                ///< grid voxels along each axis
  double spacing_mm{1.0};      ///< isotropic voxel size, mm
  double tissue_hu{40.0};      ///< soft tissue
  double air_hu{-1000.0};      ///< outside
  double lesion_hu{120.0};     ///< block-lesion, disk-lesion: the stiffer inclusion
  /// block-lesion, disk-lesion: the lesion's centre, LPS mm (absent: the default placement
  /// above; disk-lesion: z must be 0, the slice plane). The whole lesion must lie inside the
  /// block (disk): phantom_shape() throws otherwise.
  std::optional<Eigen::Vector3d> lesion_center_mm;
  double lesion_radius_mm{0.0};  ///< block-lesion, disk-lesion: the lesion's radius, mm (0: the default)
  double thickness_mm{0.0};    ///< one-slice phantoms: the slice thickness, mm (0: spacing_mm)
  double noise_hu{0.0};        ///< standard deviation of Gaussian noise added, HU; noisy values
                               ///< are rounded to whole HU, as CT stores them
  unsigned seed{1};            ///< noise seed (std::mt19937; the same seed gives the same volume)
};

/// The analytic shape of a phantom in patient coordinates (LPS mm).
struct PhantomShape {
  std::string name;
  Eigen::Vector3d center_mm{0, 0, 0};
  Eigen::Vector3d half_extent_mm{0, 0, 0};  ///< semi-axes (sphere/ellipsoid), half sizes (cube/block)
  double major_radius_mm{0};                ///< torus
  double minor_radius_mm{0};                ///< torus; cylinder radius
  double half_length_mm{0};                 ///< cylinder: half its length along z
  Eigen::Vector3d lesion_center_mm{0, 0, 0};///< block-lesion
  double lesion_radius_mm{0};               ///< block-lesion
  // folded (brain-like): the body is the ellipsoid center_mm, half_extent_mm
  double fold_period_mm{0};                 ///< folded: period of the gyroid whose sheet traces the sulci
  double fold_half_width_mm{0};             ///< folded: half the width of a sulcus
  double fold_depth_mm{0};                  ///< folded: depth of the sulci below the ellipsoid (its distance bound)
  double fissure_half_width_mm{0};          ///< folded: half the width of the longitudinal fissure (|x| <)
  double fissure_bottom_z_mm{0};            ///< folded: the fissure's floor; the hemispheres join below it
  Eigen::Vector3d stem_center_mm{0, 0, 0};  ///< folded: centre of the stem's bottom face (the lowest tissue)
  double stem_radius_mm{0};                 ///< folded: the stem, a vertical cylinder of this radius
  double stem_length_mm{0};                 ///< folded: from its bottom face up into the body
  std::int64_t tissue_voxels{0};            ///< make_phantom: voxels whose centre is inside (lesion included)
  std::int64_t lesion_voxels{0};            ///< make_phantom: voxels whose centre is inside the lesion

  /// Signed distance from the surface, mm (negative inside); exact for every shape but folded
  /// (the ellipsoid's by root finding on the closest-point equation, to about 1e-9 mm). The
  /// block-lesion's surface is the block's (the lesion is inside the tissue).
  /// folded: an approximate distance, a max/min of 1-Lipschitz bounds of its pieces (body,
  /// sulci, fissure, stem). Its sign is exact (make_phantom fills the voxels by it), it is zero
  /// on the surface and 1-Lipschitz, so |d| never exceeds the true distance (tested: no voxel
  /// centre of the other side lies within |d| of a point). It can understate it: within 4 mm
  /// of the surface its gradient norm has a median of 0.79 but falls to 0.05 where a sulcus
  /// crosses the cortex obliquely, and the nearest voxel of the other side was found up to 4x
  /// |d| (+ half a voxel diagonal) away. Use it for inside/outside and "within d of the
  /// surface", not to measure surface errors.
  [[nodiscard]] double signed_distance_mm(const Eigen::Vector3d& p_mm) const;
  [[nodiscard]] bool inside(const Eigen::Vector3d& p_mm) const { return signed_distance_mm(p_mm) < 0; }
  /// Exact enclosed volume, mm^3 (block-lesion: the whole block, lesion included). Throws
  /// vx::Error for a shape without a closed form (folded: count its voxels).
  [[nodiscard]] double volume_mm3() const;
  /// Exact surface area, mm^2 (the ellipsoid's from Legendre's elliptic-integral formula); for a
  /// one-slice shape the area of the shape in its plane. Throws vx::Error like volume_mm3().
  [[nodiscard]] double area_mm2() const;
  /// The signed distance is exact and volume and area have closed forms (all but folded).
  [[nodiscard]] bool has_closed_form() const { return name != "folded"; }
  /// A one-slice (2D) shape: disk, rectangle, disk-lesion.
  [[nodiscard]] bool is_2d() const { return name == "disk" || name == "rectangle" || name == "disk-lesion"; }
};

/// What is wrong with the lesion settings (`lesion_center_mm`, `lesion_radius_mm`) for the
/// shape they would go into, or "" when they fit: a lesion needs block-lesion or disk-lesion, a
/// positive finite radius, and must lie wholly inside the block (disk). phantom_shape() throws
/// this message as a vx::Error; the command line reports it as a usage error.
[[nodiscard]] std::string lesion_settings_error(const PhantomSettings& settings);

/// Names of the phantoms `make_phantom` knows.
[[nodiscard]] std::vector<std::string> phantom_names();

/// The analytic shape `make_phantom` would make for these settings, without the voxels
/// (tissue_voxels and lesion_voxels 0): where a scene or a bench finds the folded phantom's
/// stem. Throws vx::Error for settings make_phantom refuses (but not for a shape too small
/// to hold a voxel, which only the voxels tell).
[[nodiscard]] PhantomShape phantom_shape(const PhantomSettings& settings);

/// Makes a phantom volume (voxel centres inside the shape get tissue_hu, inside the lesion
/// lesion_hu, else air_hu) and, if `shape` is given, its analytic shape. Throws vx::Error for
/// an unknown name, a size outside 4..1024, a spacing that is not positive and finite, a
/// negative noise, or a shape too small to hold a single voxel.
[[nodiscard]] Volume make_phantom(const PhantomSettings& settings, PhantomShape* shape = nullptr);

}  // namespace vx
