#include "io/calibration_cache.h"

#include <cmath>
#include <cstring>
#include <type_traits>
#include <utility>
#include <vector>

#include "base/huge_pages.h"
#include "io/cache_file.h"
#include "physics/calibrated_fields.h"
#include "util/log.h"

namespace vx {

namespace {

constexpr FolderCacheWords kWords{"calibration cache", "calibration", ".vxcalib",
                                  "the model is calibrated as without a cache"};
constexpr char kMagic[8] = {'V', 'X', 'C', 'A', 'L', 'I', 'B', '\n'};
constexpr std::uint32_t kFormatVersion = 1;

static_assert(sizeof(Eigen::Matrix3d) == 9 * sizeof(double), "C0 is stored as 9 doubles per element");

/// Reads one calibrated field of `count` items (-1: any) into `v` (calibrated_fields.h).
template <typename T>
void read_field(CacheFileReader& r, std::vector<T>& v, std::int64_t count, const char* what) {
  r.copy(v, count, what);
}
void read_field(CacheFileReader& r, std::vector<Eigen::Matrix3d>& v, std::int64_t count, const char* what) {
  v.clear();
  v.reserve(std::size_t(count));
  prefer_huge_pages(v.data(), std::size_t(count) * sizeof(Eigen::Matrix3d));
  v.resize(std::size_t(count));
  r.copy_to(v.data(), std::size_t(count), sizeof(Eigen::Matrix3d), what);
}
template <typename Derived>
void read_field(CacheFileReader& r, Eigen::PlainObjectBase<Derived>& m, std::int64_t count, const char* what) {
  r.matrix(m.derived(), Derived::RowsAtCompileTime, count, what);
}
template <typename T>
requires std::is_arithmetic_v<T>
void read_field(CacheFileReader& r, T& v, std::int64_t, const char* what) { r.value(v, what); }

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
  w.header(kMagic, kFormatVersion);
  w.value(std::uint32_t(p.dimensions));
  w.value(key.hash);
  w.value(std::int64_t(p.num_elements()));
  w.value(std::int64_t(p.num_vertex_entries()));
  w.value(std::int64_t(p.num_nodes()));
  w.value(std::uint32_t(p.element));
  w.value(std::uint32_t(0));
  for_each_calibrated_field(
      [&w](const char*, CalibratedCount, const auto& v) {
        if constexpr (std::is_arithmetic_v<std::decay_t<decltype(v)>>)
          w.value(v);
        else
          w.array(v);
      },
      p);
  w.finish();
}

bool read_calibration(const unsigned char* data, std::size_t bytes, const CalibrationKey& key, PhysicsModel& physics,
                      std::string* why) {
  CacheFileReader r(data, bytes);
  const std::int64_t ne = physics.num_elements(), entries = physics.num_vertex_entries(), nn = physics.num_nodes();
  r.header(kMagic, kFormatVersion, "not a voxelastic calibration file");
  std::uint32_t dimensions = 0, element = 0, reserved = 0;
  std::uint64_t hash = 0;
  std::int64_t file_ne = 0, file_entries = 0, file_nn = 0;
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
  const auto count = [&](CalibratedCount c) -> std::int64_t {
    switch (c) {
      case CalibratedCount::entries: return entries;
      case CalibratedCount::mode_entries: return physics.element == ElementKind::paper ? 0 : entries;
      case CalibratedCount::elements: return ne;
      case CalibratedCount::volume_elements: return physics.material.poisson_ratio > 0 ? ne : 0;
      case CalibratedCount::terms: return std::int64_t(t.volume_term_entry.size());
      case CalibratedCount::nodes: return nn;
      case CalibratedCount::any:
      case CalibratedCount::one: break;
    }
    return -1;
  };
  for_each_calibrated_field([&](const char* what, CalibratedCount c, auto& v) { read_field(r, v, count(c), what); }, t);
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
  for_each_calibrated_field([](const char*, CalibratedCount, auto& to, auto& from) { to = std::move(from); }, physics,
                            t);
  return true;
}

std::shared_ptr<CalibrationCache> make_calibration_cache(const std::string& option) {
  return make_folder_cache<FolderCalibrationCache>(option, &CalibrationCacheSettings::min_calibration_s,
                                                   [](CalibrationCacheSettings& s) { s.background_writes = true; });
}

FolderCalibrationCache::FolderCalibrationCache(CalibrationCacheSettings settings)
    : settings_(std::move(settings)), folder_(kWords, settings_.folder, settings_.max_bytes) {}

bool FolderCalibrationCache::load(const CalibrationKey& key, PhysicsModel& physics) {
  return folder_.load(key.name(), fmt::format("{} elements", key.elements),
                      [&](const unsigned char* data, std::size_t bytes, const std::shared_ptr<const void>&,
                          std::string& why) { return read_calibration(data, bytes, key, physics, &why); });
}

void FolderCalibrationCache::store(const CalibrationKey& key, std::shared_ptr<const PhysicsModel> physics,
                                   double seconds) {
  FolderCache::Offer offer{.name = key.name(),
                           .seconds = seconds,
                           .min_seconds = settings_.min_calibration_s,
                           .made = fmt::format("calibrated in {:.2f} s", seconds),
                           .next_start = "this model and material"};
  // reads the calibrated fields only: final while make_physics_model sets the derived ones
  FolderCache::Writer write = [key, physics = std::move(physics)](std::ostream& out) {
    write_calibration(out, key, *physics);
  };
  if (settings_.background_writes)
    folder_.store_beside(std::move(offer), std::move(write), "vx-calib-write", settings_.writer_nice);
  else
    folder_.store(offer, write);
}

}  // namespace vx
