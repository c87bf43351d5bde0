#pragma once
/// @file phantom.h
/// Synthetic CT-like volumes with a known analytic shape, for tests, demos and verification.

#include <Eigen/Core>
#include <string>
#include <vector>

#include "volume.h"

namespace vx {

/// Settings of a phantom. Sizes are in voxels of the grid; the shape is centred in the grid.
struct PhantomSettings {
  std::string name{"sphere"};  ///< sphere, cube, ellipsoid, cylinder, torus, block, block-lesion
  int size{64};                ///< grid voxels along each axis
  double spacing_mm{1.0};      ///< isotropic voxel size, mm
  double tissue_hu{40.0};      ///< soft tissue
  double air_hu{-1000.0};      ///< outside
  double lesion_hu{120.0};     ///< block-lesion: the stiffer inclusion
  double noise_hu{0.0};        ///< standard deviation of Gaussian noise added, HU
  unsigned seed{1};            ///< noise seed
};

/// The analytic shape of a phantom in patient coordinates (LPS mm).
struct PhantomShape {
  std::string name;
  Eigen::Vector3d center_mm{0, 0, 0};
  Eigen::Vector3d half_extent_mm{0, 0, 0};  ///< semi-axes (sphere/ellipsoid), half sizes (cube/block)
  double major_radius_mm{0};                ///< torus
  double minor_radius_mm{0};                ///< torus; cylinder radius
  Eigen::Vector3d lesion_center_mm{0, 0, 0};///< block-lesion
  double lesion_radius_mm{0};               ///< block-lesion

  /// Signed distance from the surface, mm (negative inside); exact for sphere, cube, block,
  /// cylinder and torus, a close approximation for the ellipsoid.
  [[nodiscard]] double signed_distance_mm(const Eigen::Vector3d& p_mm) const;
  [[nodiscard]] bool inside(const Eigen::Vector3d& p_mm) const { return signed_distance_mm(p_mm) < 0; }
  /// Exact enclosed volume, mm^3.
  [[nodiscard]] double volume_mm3() const;
  /// Exact surface area, mm^2.
  [[nodiscard]] double area_mm2() const;
};

/// Names of the phantoms `make_phantom` knows.
[[nodiscard]] std::vector<std::string> phantom_names();

/// Makes a phantom volume (voxel centres inside the shape get tissue_hu, else air_hu) and,
/// if `shape` is given, its analytic shape. Throws vx::Error for an unknown name or a bad size.
[[nodiscard]] Volume make_phantom(const PhantomSettings& settings, PhantomShape* shape = nullptr);

}  // namespace vx
