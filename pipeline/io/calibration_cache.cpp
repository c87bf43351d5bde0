#include "io/calibration_cache.h"

#include <cmath>
#include <cstring>
#include <utility>
#include <vector>

#include "base/huge_pages.h"
#include "io/cache_file.h"
#include "util/log.h"

namespace vx {

namespace {

constexpr FolderCacheWords kWords{"calibration cache", "calibration", ".vxcalib",
                                  "the model is calibrated as without a cache"};
constexpr char kMagic[8] = {'V', 'X', 'C', 'A', 'L', 'I', 'B', '\n'};
constexpr std::uint32_t kFormatVersion = 1;

static_assert(sizeof(Eigen::Matrix3d) == 9 * sizeof(double), "C0 is stored as 9 doubles per element");

/// True when `offsets` is empty or starts at 0, never falls and ends at `last`.
bool good_offsets(const std::vector<std::int32_t>& offsets, std::size_t last) {
  if (offsets.empty()) return true;
  if (offsets.front() != 0 || std::size_t(offsets.back()) != last) return false;
  for (std::size_t i = 1; i < offsets.size(); ++i)
    if (offsets[i] < offsets[i - 1]) return false;
  return true;
}

}  // namespace

void write_calibration(std::ostream& out, const CalibrationKey& key, const PhysicsModel& p) {
  CacheFileWriter w(out);
  w.bytes(kMagic, sizeof kMagic);
  w.value(kFormatVersion);
  w.value(std::uint32_t(p.dimensions));
  w.value(key.hash);
  w.value(std::int64_t(p.num_elements()));
  w.value(std::int64_t(p.num_vertex_entries()));
  w.value(std::int64_t(p.num_nodes()));
  w.value(std::uint32_t(p.element));
  w.value(std::uint32_t(0));
  // vertex entries
  w.array(p.entry_weight);
  w.array(p.entry_rest);
  w.array(p.entry_rest_weighted);
  w.array(p.entry_gradient);
  w.array(p.entry_modes);
  // elements
  w.array(p.element_stiffness);
  w.array(p.element_damping);
  w.array(p.element_volume_stiffness);
  w.array(p.element_mass_kg);
  w.array(p.element_spread_mm2);
  w.array(p.element_fit_scale);
  w.array(p.element_affine_stiffness);
  w.array(p.element_spread.data(), p.element_spread.size(), sizeof(Eigen::Matrix3d));
  // volume points
  w.array(p.volume_point_offsets);
  w.array(p.volume_point_stiffness);
  w.array(p.volume_point_term_offsets);
  w.array(p.volume_term_entry);
  w.array(p.volume_term_delta);
  // nodes, counts
  w.array(p.node_mass_kg);
  w.value(p.bending_relief_clamped);
  w.value(p.gradient_fallback_elements);
  w.value(p.anisotropic_elements);
  w.value(p.max_anisotropy);
  w.finish();
}

bool read_calibration(const unsigned char* data, std::size_t bytes, const CalibrationKey& key, PhysicsModel& physics,
                      std::string* why) {
  CacheFileReader r(data, bytes);
  const std::int64_t ne = physics.num_elements(), entries = physics.num_vertex_entries(), nn = physics.num_nodes();
  if (const unsigned char* magic = r.bytes(sizeof kMagic, "the header");
      magic && std::memcmp(magic, kMagic, sizeof kMagic) != 0)
    r.fail("not a voxelastic calibration file");
  std::uint32_t version = 0, dimensions = 0, element = 0, reserved = 0;
  std::uint64_t hash = 0;
  std::int64_t file_ne = 0, file_entries = 0, file_nn = 0;
  r.value(version, "the header");
  if (r.ok() && version != kFormatVersion)
    r.fail("format version " + std::to_string(version) + ", this build reads " + std::to_string(kFormatVersion));
  r.value(dimensions, "the header");
  r.value(hash, "the header");
  r.value(file_ne, "the header");
  r.value(file_entries, "the header");
  r.value(file_nn, "the header");
  r.value(element, "the header");
  r.value(reserved, "the header");
  if (r.ok() && (hash != key.hash || file_ne != ne || file_entries != entries || file_nn != nn ||
                 int(dimensions) != physics.dimensions || element != std::uint32_t(physics.element)))
    r.fail("the calibration of another model or material");
  // into a scratch model first: `physics` changes only when all of it is read
  PhysicsModel t;
  r.copy(t.entry_weight, entries, "the vertex weights");
  r.matrix(t.entry_rest, 3, entries, "the rest offsets");
  r.matrix(t.entry_rest_weighted, 3, entries, "the weighted rest offsets");
  r.matrix(t.entry_gradient, 3, entries, "the gradients");
  r.matrix(t.entry_modes, kBendingModes, physics.element == ElementKind::paper ? 0 : entries,
           "the bending-mode weights");
  r.copy(t.element_stiffness, ne, "the element stiffness");
  r.copy(t.element_damping, ne, "the element damping");
  r.copy(t.element_volume_stiffness, physics.material.poisson_ratio > 0 ? ne : 0, "the volume stiffness");
  r.copy(t.element_mass_kg, ne, "the element masses");
  r.copy(t.element_spread_mm2, ne, "the element spreads");
  r.copy(t.element_fit_scale, ne, "the fit scales");
  r.copy(t.element_affine_stiffness, ne, "the affine stiffness");
  t.element_spread.reserve(std::size_t(ne));
  prefer_huge_pages(t.element_spread.data(), std::size_t(ne) * sizeof(Eigen::Matrix3d));
  t.element_spread.resize(std::size_t(ne));
  r.copy_to(t.element_spread.data(), std::size_t(ne), sizeof(Eigen::Matrix3d), "the spread matrices");
  r.copy(t.volume_point_offsets, -1, "the volume point offsets");
  r.copy(t.volume_point_stiffness, -1, "the volume point stiffness");
  r.copy(t.volume_point_term_offsets, -1, "the volume point term offsets");
  r.copy(t.volume_term_entry, -1, "the volume point terms");
  r.matrix(t.volume_term_delta, 3, std::int64_t(t.volume_term_entry.size()), "the volume point deltas");
  r.copy(t.node_mass_kg, nn, "the node masses");
  r.value(t.bending_relief_clamped, "the counts");
  r.value(t.gradient_fallback_elements, "the counts");
  r.value(t.anisotropic_elements, "the counts");
  r.value(t.max_anisotropy, "the counts");
  r.finish();
  // the structure: whatever a step indexes must be in range
  if (r.ok()) {
    const std::size_t points = t.volume_point_stiffness.size(), terms = t.volume_term_entry.size();
    bool good = t.volume_point_offsets.empty() ? points == 0 && t.volume_point_term_offsets.empty() && terms == 0
                                               : t.volume_point_offsets.size() == std::size_t(ne) + 1 &&
                                                     good_offsets(t.volume_point_offsets, points) &&
                                                     t.volume_point_term_offsets.size() == points + 1 &&
                                                     good_offsets(t.volume_point_term_offsets, terms);
    for (std::size_t k = 0; good && k < terms; ++k)
      good = t.volume_term_entry[k] >= 0 && t.volume_term_entry[k] < entries;
    if (!good) r.fail("the volume points do not index the model's vertex entries");
  }
  if (r.ok()) {
    for (const double m : t.node_mass_kg)
      if (!(m > 0) || !std::isfinite(m)) {
        r.fail("a node mass is not positive");
        break;
      }
  }
  if (!r.ok()) {
    if (why) *why = r.error();
    return false;
  }
  physics.entry_weight = std::move(t.entry_weight);
  physics.entry_rest = std::move(t.entry_rest);
  physics.entry_rest_weighted = std::move(t.entry_rest_weighted);
  physics.entry_gradient = std::move(t.entry_gradient);
  physics.entry_modes = std::move(t.entry_modes);
  physics.element_stiffness = std::move(t.element_stiffness);
  physics.element_damping = std::move(t.element_damping);
  physics.element_volume_stiffness = std::move(t.element_volume_stiffness);
  physics.element_mass_kg = std::move(t.element_mass_kg);
  physics.element_spread_mm2 = std::move(t.element_spread_mm2);
  physics.element_fit_scale = std::move(t.element_fit_scale);
  physics.element_affine_stiffness = std::move(t.element_affine_stiffness);
  physics.element_spread = std::move(t.element_spread);
  physics.volume_point_offsets = std::move(t.volume_point_offsets);
  physics.volume_point_stiffness = std::move(t.volume_point_stiffness);
  physics.volume_point_term_offsets = std::move(t.volume_point_term_offsets);
  physics.volume_term_entry = std::move(t.volume_term_entry);
  physics.volume_term_delta = std::move(t.volume_term_delta);
  physics.node_mass_kg = std::move(t.node_mass_kg);
  physics.bending_relief_clamped = t.bending_relief_clamped;
  physics.gradient_fallback_elements = t.gradient_fallback_elements;
  physics.anisotropic_elements = t.anisotropic_elements;
  physics.max_anisotropy = t.max_anisotropy;
  return true;
}

std::shared_ptr<CalibrationCache> make_calibration_cache(const std::string& option) {
  return make_folder_cache<FolderCalibrationCache>(option, &CalibrationCacheSettings::min_calibration_s);
}

FolderCalibrationCache::FolderCalibrationCache(CalibrationCacheSettings settings)
    : settings_(std::move(settings)), folder_(kWords, settings_.folder, settings_.max_bytes) {}

bool FolderCalibrationCache::load(const CalibrationKey& key, PhysicsModel& physics) {
  return folder_.load(key.name(), fmt::format("{} elements", key.elements),
                      [&](const unsigned char* data, std::size_t bytes, const std::shared_ptr<const void>&,
                          std::string& why) { return read_calibration(data, bytes, key, physics, &why); });
}

void FolderCalibrationCache::store(const CalibrationKey& key, const PhysicsModel& physics, double seconds) {
  folder_.store({.name = key.name(),
                 .seconds = seconds,
                 .min_seconds = settings_.min_calibration_s,
                 .made = fmt::format("calibrated in {:.2f} s", seconds),
                 .next_start = "this model and material"},
                [&](std::ostream& out) { write_calibration(out, key, physics); });
}

}  // namespace vx
