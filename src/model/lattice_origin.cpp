/// @file lattice_origin.cpp
/// The builder's lattice origin, chosen to minimise vertex entries (docs/model.md section 3.5).

#include "model/lattice_origin.h"

#include <chrono>

#include "base/error.h"

namespace vx {

VoxelGrid pad_low(const VoxelGrid& grid, const Eigen::Vector3i& shift) {
  if ((shift.array() < 0).any()) throw Error("pad_low: the shift must not be negative");
  if (shift.isZero()) return grid;
  GridGeometry g = grid.geometry();
  g.dims = grid.dims() + shift;
  g.origin_mm = grid.geometry().index_to_lps(-shift.cast<double>());
  VoxelGrid out(g);
  const Eigen::Vector3i& d = grid.dims();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j) {
      const std::uint8_t* src = grid.data().data() + grid.index(0, j, k);
      std::uint8_t* dst = out.data().data() + out.index(shift.x(), j + shift.y(), k + shift.z());
      std::copy(src, src + d.x(), dst);
    }
  return out;
}

Eigen::Vector3i choose_lattice_shift(const VoxelGrid& grid, const BuildSettings& settings, int period,
                                     LatticeShiftReport* report) {
  if (period < 1 || (period & (period - 1)) != 0)
    throw Error("choose_lattice_shift: the period must be a power of two (1, 2, 4, 8 ...)");
  const auto t0 = std::chrono::steady_clock::now();
  BuildSettings quiet = settings;
  quiet.progress = nullptr;
  LatticeShiftReport r;
  auto measure = [&](const Eigen::Vector3i& s) {
    ++r.builds;
    const Model m = build_model(pad_low(grid, s), quiet);
    return std::pair<std::int64_t, std::int64_t>{m.num_vertex_entries(), m.num_elements()};
  };
  const auto [entries0, elements0] = measure(Eigen::Vector3i::Zero());
  r.entries_unshifted = r.entries_chosen = entries0;
  r.elements_unshifted = r.elements_chosen = elements0;
  Eigen::Vector3i best = Eigen::Vector3i::Zero();
  if (settings.layout != Layout::voxel) {
    const int axes = settings.dimensions == 2 ? 2 : 3;
    for (int a = 0; a < axes; ++a)
      for (int s = 1; s < period; ++s) {
        Eigen::Vector3i trial = best;
        trial[a] = s;
        const auto [entries, elements] = measure(trial);
        if (entries < r.entries_chosen) {
          r.entries_chosen = entries;
          r.elements_chosen = elements;
          best = trial;
        }
      }
  }
  r.shift = best;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (report) *report = r;
  return best;
}

}  // namespace vx
