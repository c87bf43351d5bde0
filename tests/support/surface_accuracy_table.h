#pragma once
// The accuracy table of the surfaces (staircase, paper, iso) on the analytic phantoms, shared
// by the surface accuracy tests (fast: size 48; slow: size 96).

#include <cstdio>
#include <string>
#include <vector>

#include "convert/iso_surface.h"
#include "convert/phantom.h"
#include "model/gradational_builder.h"
#include "surface/surface.h"
#include "verify/surface_accuracy.h"

namespace vx::testing {

struct AccuracyRow {
  std::string phantom;
  SurfaceMethod method;
  SurfaceAccuracy accuracy;
};

/// The phantom's tissue as a binary grid: voxels above the midpoint of air and tissue HU.
inline VoxelGrid phantom_tissue(const Volume& v) {
  VoxelGrid g(v.geometry);
  for (std::size_t i = 0; i < v.hu.size(); ++i) g.data()[i] = v.hu[i] > -480.0f ? 1 : 0;
  return g;
}

/// Rows for sphere, ellipsoid and torus at `size` voxels (1 mm), each as staircase, paper,
/// iso (in that order), printed as a table.
inline std::vector<AccuracyRow> accuracy_table(int size, const std::vector<std::string>& names = {"sphere", "ellipsoid", "torus"}) {
  std::vector<AccuracyRow> rows;
  std::printf("size %d, 1 mm voxels | mean mm | max mm | mean vox | max vox | bias mm | volume %% | normals deg | vertices\n", size);
  for (const std::string& name : names) {
    PhantomSettings ps;
    ps.name = name;
    ps.size = size;
    PhantomShape shape;
    const Volume volume = make_phantom(ps, &shape);
    const VoxelGrid grid = phantom_tissue(volume);
    const Model model = build_model(grid);
    for (SurfaceMethod m : {SurfaceMethod::staircase, SurfaceMethod::paper, SurfaceMethod::iso}) {
      const EmbeddedSurface s = make_surface(model, grid, nullptr, m);
      const SurfaceAccuracy a = measure_surface_accuracy(s, shape, ps.spacing_mm);
      std::printf("%-9s %-9s | %7.3f | %6.3f | %8.3f | %7.3f | %+7.3f | %+8.2f | %11.1f | %8lld\n", name.c_str(),
                  to_string(m), a.mean_distance_mm, a.max_distance_mm, a.mean_distance_voxels, a.max_distance_voxels,
                  a.mean_signed_distance_mm, a.volume_error_percent, a.mean_normal_error_deg, (long long)a.vertices);
      rows.push_back({name, m, a});
    }
  }
  return rows;
}

}  // namespace vx::testing
