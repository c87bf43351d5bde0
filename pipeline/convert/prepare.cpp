// From a volume in HU to the voxel grid the model is built from.

#include "convert/prepare.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>

#include "base/error.h"
#include "model/lattice_origin.h"
#include "util/log.h"

namespace vx {
namespace {

/// The input samples (and weights) that make one output sample along one axis, CSR-style.
struct Taps {
  std::vector<int> offsets{0};  ///< n_out + 1
  std::vector<int> index;       ///< input sample
  std::vector<double> weight;   ///< sums to 1 per output sample
};

/// Resampling along one axis with the centre of the axis kept: output sample o sits at input
/// index x = (n_in-1)/2 + (o-(n_out-1)/2) * step. Shrinking averages the input voxels the
/// output voxel covers (box filter, exact overlaps); growing interpolates linearly.
Taps make_taps(int n_in, int n_out, double step) {
  Taps t;
  for (int o = 0; o < n_out; ++o) {
    const double x = 0.5 * (n_in - 1) + (o - 0.5 * (n_out - 1)) * step;
    if (step > 1.0) {
      const double a = std::max(x - 0.5 * step, -0.5), b = std::min(x + 0.5 * step, n_in - 0.5);
      double total = 0.0;
      const std::size_t first = t.weight.size();
      for (int i = std::max(0, int(std::floor(a + 0.5))); i <= std::min(n_in - 1, int(std::ceil(b - 0.5))); ++i) {
        const double w = std::min(b, i + 0.5) - std::max(a, i - 0.5);
        if (w <= 0) continue;
        t.index.push_back(i);
        t.weight.push_back(w);
        total += w;
      }
      for (std::size_t q = first; q < t.weight.size(); ++q) t.weight[q] /= total;
    } else {
      const double c = std::clamp(x, 0.0, double(n_in - 1));
      const int i0 = std::min(int(std::floor(c)), std::max(n_in - 2, 0));
      const double f = c - i0;
      t.index.push_back(i0);
      t.weight.push_back(1.0 - f);
      if (f > 0 && i0 + 1 < n_in) {
        t.index.push_back(i0 + 1);
        t.weight.push_back(f);
      }
    }
    t.offsets.push_back(int(t.index.size()));
  }
  return t;
}

/// Resamples `in` (dims `d`) along `axis` to `n_out` samples; returns the new values.
std::vector<float> resample_axis(const std::vector<float>& in, const Eigen::Vector3i& d, int axis, int n_out,
                                 double step) {
  const Taps taps = make_taps(d[axis], n_out, step);
  Eigen::Vector3i od = d;
  od[axis] = n_out;
  const std::int64_t stride_in = axis == 0 ? 1 : axis == 1 ? d.x() : std::int64_t(d.x()) * d.y();
  std::vector<float> out(std::size_t(od.x()) * std::size_t(od.y()) * std::size_t(od.z()));
#pragma omp parallel for schedule(static)
  for (int k = 0; k < od.z(); ++k)
    for (int j = 0; j < od.y(); ++j)
      for (int i = 0; i < od.x(); ++i) {
        const Eigen::Vector3i o(i, j, k);
        Eigen::Vector3i base = o;
        base[axis] = 0;
        const std::int64_t b = base.x() + std::int64_t(d.x()) * (base.y() + std::int64_t(d.y()) * base.z());
        double v = 0.0;
        for (int q = taps.offsets[std::size_t(o[axis])]; q < taps.offsets[std::size_t(o[axis]) + 1]; ++q)
          v += taps.weight[std::size_t(q)] * in[std::size_t(b + stride_in * taps.index[std::size_t(q)])];
        out[std::size_t(i + std::int64_t(od.x()) * (j + std::int64_t(od.y()) * k))] = float(v);
      }
  return out;
}

/// The volume resampled to isotropic `voxel_mm` voxels, same direction, physical extent centred.
Volume resample(const Volume& volume, double voxel_mm) {
  const GridGeometry& g = volume.geometry;
  // a one-slice volume (a 2D model) keeps its slice: only the in-plane axes are resampled
  const bool slice = g.dims.z() == 1;
  Eigen::Vector3i dims;
  for (int a = 0; a < 3; ++a)
    dims[a] = slice && a == 2 ? 1 : std::max(1, int(std::lround(g.dims[a] * g.spacing_mm[a] / voxel_mm)));
  if (double(dims.x()) * dims.y() * dims.z() > 2e9)
    throw Error(fmt::format("prepare: a voxel size of {} mm makes {} x {} x {} voxels, too many; choose a larger "
                            "voxel size",
                            voxel_mm, dims.x(), dims.y(), dims.z()));
  Volume out;
  out.geometry = g;
  out.geometry.dims = dims;
  out.geometry.spacing_mm = Eigen::Vector3d::Constant(voxel_mm);
  if (slice) out.geometry.spacing_mm.z() = g.spacing_mm.z();
  // the centre of the grid stays where it was
  const Eigen::Vector3d centre = g.index_to_lps(0.5 * (g.dims.cast<double>() - Eigen::Vector3d::Ones()));
  out.geometry.origin_mm =
      centre - g.direction * (0.5 * out.geometry.spacing_mm.cwiseProduct(dims.cast<double>() - Eigen::Vector3d::Ones()));
  // one axis after the other (box and linear filters are separable); the input is never copied
  std::vector<float> values;
  const std::vector<float>* current = &volume.hu;
  Eigen::Vector3i d = g.dims;
  for (int a = 0; a < 3; ++a) {
    if (dims[a] == d[a] && std::abs(out.geometry.spacing_mm[a] - g.spacing_mm[a]) < 1e-12) continue;
    values = resample_axis(*current, d, a, dims[a], voxel_mm / g.spacing_mm[a]);
    current = &values;
    d[a] = dims[a];
  }
  out.hu = current == &volume.hu ? volume.hu : std::move(values);
  return out;
}

constexpr int kNeighbours[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};

/// The 26 neighbours of a voxel (faces, edges and corners).
constexpr auto kNeighbours26 = [] {
  std::array<std::array<int, 3>, 26> n{};
  int m = 0;
  for (int c = -1; c <= 1; ++c)
    for (int b = -1; b <= 1; ++b)
      for (int a = -1; a <= 1; ++a)
        if (a || b || c) n[std::size_t(m++)] = {a, b, c};
  return n;
}();

/// Floods the region of voxels equal to `from` that holds `seed`, setting them to `to`;
/// returns its size. Neighbours share a face (6-connected) or, with `connect26`, also an edge or
/// a corner. `queue` is scratch space.
std::int64_t flood(VoxelGrid& grid, std::int64_t seed, std::uint8_t from, std::uint8_t to,
                   std::vector<std::int64_t>& queue, bool connect26 = false) {
  const Eigen::Vector3i d = grid.dims();
  std::vector<std::uint8_t>& data = grid.data();
  std::int64_t size = 0;
  queue.assign(1, seed);
  data[std::size_t(seed)] = to;
  while (!queue.empty()) {
    const std::int64_t v = queue.back();
    queue.pop_back();
    ++size;
    const int i = int(v % d.x()), j = int((v / d.x()) % d.y()), k = int(v / (std::int64_t(d.x()) * d.y()));
    const auto visit = [&](const auto& n) {
      const int a = i + n[0], b = j + n[1], c = k + n[2];
      if (!grid.inside(a, b, c)) return;
      const std::int64_t w = grid.index(a, b, c);
      if (data[std::size_t(w)] == from) {
        data[std::size_t(w)] = to;
        queue.push_back(w);
      }
    };
    if (connect26)
      for (const auto& n : kNeighbours26) visit(n);
    else
      for (const auto& n : kNeighbours) visit(n);
  }
  return size;
}

/// Keeps the largest 6-connected tissue component; returns (components, removed voxels).
/// Works in place (visited tissue is marked 2, the kept component 3): no label array.
std::pair<int, std::int64_t> keep_largest_component(VoxelGrid& grid) {
  std::vector<std::uint8_t>& data = grid.data();
  std::vector<std::int64_t> queue;
  int components = 0;
  std::int64_t largest_seed = -1, largest_size = 0, total = 0;
  for (std::int64_t seed = 0; seed < std::int64_t(data.size()); ++seed) {
    if (data[std::size_t(seed)] != 1) continue;
    const std::int64_t size = flood(grid, seed, 1, 2, queue);
    ++components;
    total += size;
    if (size > largest_size) largest_size = size, largest_seed = seed;
  }
  if (components == 0) return {0, 0};
  flood(grid, largest_seed, 2, 3, queue);
  for (auto& v : data) v = v == 3 ? 1 : 0;
  return {components, total - largest_size};
}

/// Fills background not connected to the outside of the grid; returns the voxels added.
/// Tissue is 6-connected (keep_largest_component), so air is 26-connected: the two are the
/// complementary pair of digital topology, and air that leaves a cavity only through an edge
/// or a corner between tissue voxels (a diagonal gap) reaches the outside and is kept.
/// Works in place: background reached from the grid's faces is marked 2 while flooding.
std::int64_t fill_holes(VoxelGrid& grid) {
  const Eigen::Vector3i d = grid.dims();
  std::vector<std::uint8_t>& data = grid.data();
  std::vector<std::int64_t> queue;
  // flood from every background voxel on the grid's faces
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const bool face = i == 0 || j == 0 || k == 0 || i == d.x() - 1 || j == d.y() - 1 || k == d.z() - 1;
        if (!face) {
          i = d.x() - 2;  // jump to the far face of this row
          continue;
        }
        const std::int64_t v = grid.index(i, j, k);
        if (data[std::size_t(v)] == 0) flood(grid, v, 0, 2, queue, /*connect26=*/true);
      }
  // what the outside did not reach is a cavity
  std::int64_t filled = 0;
  for (auto& v : data) {
    if (v == 0) ++filled;
    v = v == 2 ? 0 : 1;
  }
  return filled;
}

/// The grid cut to [lo, hi) (which may reach past the grid: those voxels are air), same
/// voxel positions in patient space.
VoxelGrid crop(const VoxelGrid& grid, const Eigen::Vector3i& lo, const Eigen::Vector3i& hi) {
  GridGeometry g = grid.geometry();
  g.dims = hi - lo;
  g.origin_mm = grid.geometry().index_to_lps(lo.cast<double>());
  VoxelGrid out(g);
  for (int k = 0; k < g.dims.z(); ++k)
    for (int j = 0; j < g.dims.y(); ++j)
      for (int i = 0; i < g.dims.x(); ++i)
        if (grid.at(i + lo.x(), j + lo.y(), k + lo.z())) out.set(i, j, k, 1);
  return out;
}

std::string range_text(const HuRange& r) {
  if (std::isinf(r.hi)) return fmt::format("{:g} HU and above", r.lo);
  return fmt::format("{:g} to {:g} HU", r.lo, r.hi);
}

std::string dims_text(const Eigen::Vector3i& d) { return fmt::format("{} x {} x {}", d.x(), d.y(), d.z()); }

}  // namespace

VoxelGrid prepare_grid(const Volume& volume_in, const PrepareOptions& options, PrepareReport* report_out) {
  PrepareReport report;
  const GridGeometry& g = volume_in.geometry;
  if ((g.dims.array() <= 0).any() || std::int64_t(volume_in.hu.size()) != g.voxel_count())
    throw Error(fmt::format("prepare: the volume is empty or inconsistent ({} voxels, {} values)", dims_text(g.dims),
                            volume_in.hu.size()));
  if (!(options.range.lo <= options.range.hi) || std::isnan(options.range.lo))
    throw Error(fmt::format("prepare: the HU range {} is empty (the lower bound must not exceed the upper)",
                            range_text(options.range)));
  if (!(options.voxel_mm >= 0.0) || !std::isfinite(options.voxel_mm))
    throw Error(fmt::format("prepare: voxel size {} mm is invalid; give a positive size in mm, or 0 to keep the "
                            "volume's voxels",
                            options.voxel_mm));
  report.input_dims = g.dims;
  report.input_spacing_mm = g.spacing_mm;

  // resample the HU volume first, so thresholding sees averaged values
  Volume resampled;
  const Volume* volume = &volume_in;
  if (options.voxel_mm > 0.0) {
    resampled = resample(volume_in, options.voxel_mm);
    volume = &resampled;
  }
  report.resampled_dims = volume->geometry.dims;
  report.resampled_voxel_mm = options.voxel_mm;

  // threshold
  VoxelGrid grid = threshold(*volume, options.range);
  report.thresholded_voxels = grid.count();
  if (report.thresholded_voxels == 0) {
    const auto [lo, hi] = std::minmax_element(volume->hu.begin(), volume->hu.end());
    throw Error(fmt::format("prepare: no voxel lies in the tissue range {}; the volume's values span {:g} to {:g} HU. "
                            "Choose a threshold within that span (e.g. --threshold {:g})",
                            range_text(options.range), double(*lo), double(*hi), std::round(0.5 * (*lo + *hi))));
  }
  // every voxel tissue: a labelmap or mask read as HU passes the default window everywhere and
  // would silently become a solid box
  if (report.thresholded_voxels == volume->geometry.voxel_count() && report.thresholded_voxels > 1) {
    const auto [lo, hi] = std::minmax_element(volume->hu.begin(), volume->hu.end());
    log::warn("every voxel of the volume ({} voxels, values {:g} to {:g}) is in the tissue range {}: the model is the "
              "whole box. If this is a labelmap or segmentation, select one label (convert --label N); else choose a "
              "threshold inside the values",
              report.thresholded_voxels, double(*lo), double(*hi), range_text(options.range));
  }

  // keep the largest component
  if (options.largest_component) {
    const auto [components, removed] = keep_largest_component(grid);
    report.components = components;
    report.removed_voxels = removed;
  }

  // fill cavities
  if (options.fill_holes) report.filled_voxels = fill_holes(grid);

  // crop to the tissue with one voxel of air all round (in the slice's plane for a one-slice
  // volume: it stays one voxel thick, a 2D model)
  if (options.crop) {
    Eigen::Vector3i lo, hi;
    grid.tissue_bounds(lo, hi);
    const Eigen::Vector3i margin(1, 1, grid.dims().z() == 1 ? 0 : 1);
    report.crop_lo = lo - margin;
    report.crop_hi = hi + margin;
    grid = crop(grid, report.crop_lo, report.crop_hi);
    if (options.lattice_period > 1) {
      // docs/model.md section 3.5: the same tissue, grouped from another first voxel
      LatticeShiftReport lattice;
      BuildSettings lattice_build = options.lattice_build;
      if (grid.dims().z() == 1) lattice_build.dimensions = 2;  // a one-slice grid makes a 2D model
      const Eigen::Vector3i shift = choose_lattice_shift(grid, lattice_build, options.lattice_period, &lattice);
      report.lattice_shift = shift;
      report.entries_unshifted = lattice.entries_unshifted;
      report.entries_chosen = lattice.entries_chosen;
      report.elements_unshifted = lattice.elements_unshifted;
      report.elements_chosen = lattice.elements_chosen;
      report.lattice_s = lattice.seconds;
      if (!shift.isZero()) {
        report.crop_lo -= shift;
        grid = pad_low(grid, shift);
      }
    }
  } else {
    report.crop_lo = Eigen::Vector3i::Zero();
    report.crop_hi = grid.dims();
  }
  report.tissue_voxels = grid.count();
  if (report_out) *report_out = report;
  return grid;
}

std::string PrepareReport::summary(bool with_tissue) const {
  std::string s = fmt::format("input: {} voxels of {:.3g} x {:.3g} x {:.3g} mm\n", dims_text(input_dims),
                              input_spacing_mm.x(), input_spacing_mm.y(), input_spacing_mm.z());
  if (resampled_dims != input_dims)
    s += fmt::format("resampled: {} voxels of {:.3g} mm\n", dims_text(resampled_dims), resampled_voxel_mm);
  if (with_tissue || thresholded_voxels != tissue_voxels)
    s += fmt::format("threshold: {} tissue voxels\n", thresholded_voxels);
  if (components > 0)
    s += fmt::format("largest component: kept 1 of {} components, removed {} voxels\n", components, removed_voxels);
  if (filled_voxels > 0) s += fmt::format("holes filled: {} voxels\n", filled_voxels);
  const Eigen::Vector3i size = crop_hi - crop_lo;
  if (crop_lo != Eigen::Vector3i::Zero() || crop_hi != resampled_dims)
    s += fmt::format("cropped: voxels [{}, {}) x [{}, {}) x [{}, {}){} (1-voxel air margin{})\n", crop_lo.x(),
                     crop_hi.x(), crop_lo.y(), crop_hi.y(), crop_lo.z(), crop_hi.z(),
                     with_tissue ? " -> " + dims_text(size) : std::string(),
                     lattice_shift.isZero() ? "" : fmt::format(", {} more before, per axis", dims_text(lattice_shift)));
  // the chosen model's counts are the model's own (printed with it): here only what the choice saved
  if (entries_unshifted > 0)
    s += fmt::format(
        "lattice origin: {:+.1f} % vertex entries and {:+.1f} % elements against the 1-voxel margin "
        "({} and {} there); chosen in {:.2g} s\n",
        100.0 * (double(entries_chosen) / double(entries_unshifted) - 1.0),
        100.0 * (double(elements_chosen) / double(elements_unshifted) - 1.0), entries_unshifted, elements_unshifted,
        lattice_s);
  if (with_tissue) s += fmt::format("tissue: {} voxels\n", tissue_voxels);
  if (!s.empty() && s.back() == '\n') s.pop_back();
  return s;
}

void PrepareReport::to_json(nlohmann::json& j) const {
  auto vec = [](const auto& v) { return nlohmann::json::array({v.x(), v.y(), v.z()}); };
  j = nlohmann::json{{"input_dims", vec(input_dims)},
                     {"input_spacing_mm", vec(input_spacing_mm)},
                     {"resampled_dims", vec(resampled_dims)},
                     {"thresholded_voxels", thresholded_voxels},
                     {"components", components},
                     {"removed_voxels", removed_voxels},
                     {"filled_voxels", filled_voxels},
                     {"crop_lo", vec(crop_lo)},
                     {"crop_hi", vec(crop_hi)},
                     {"tissue_voxels", tissue_voxels}};
  if (entries_unshifted > 0)
    j["lattice_origin"] = {{"shift", vec(lattice_shift)},
                           {"entries_unshifted", entries_unshifted},
                           {"entries_chosen", entries_chosen},
                           {"elements_unshifted", elements_unshifted},
                           {"elements_chosen", elements_chosen},
                           {"seconds", lattice_s}};
}

}  // namespace vx
