#pragma once
/// @file calibration_cache.h
/// The calibration cache: the calibrated part of a PhysicsModel (physics/calibration_key.h,
/// CalibrationCache: vertex weights, rest offsets, consistent gradients, bending-mode weights,
/// per-element stiffness, damping and masses, node masses) kept by the content of what it was
/// calibrated from (CalibrationKey: the model, the material, the per-element field, the options),
/// so the second start of a model loads what the first computed element by element (the folded
/// organ: 2.0 s of calibration on both cores; docs/bench.md). It lives in the factor cache's
/// folder (factor_cache.h: the same option, environment variable and size limit over both kinds
/// of file).
///
/// One file per calibration, `calibration-<elements>e-<entries>v-<hash>.vxcalib`: a header
/// (magic, format version, the key, the sizes), the arrays at 64-byte boundaries, a checksum;
/// written to a temporary name and renamed; read back through a mapping and checked (header,
/// key, every size against the model, the volume points' indices, the checksum): a damaged file
/// is removed with a warning and the model calibrated. Nothing here may stop a run.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <ostream>
#include <string>

#include "io/folder_cache.h"
#include "physics/calibration.h"
#include "physics/calibration_key.h"

namespace vx {

struct CalibrationCacheSettings {
  std::filesystem::path folder;
  /// the folder's cache files (factors and calibrations) together at most this many bytes; the
  /// least recently used go first
  std::uint64_t max_bytes{std::uint64_t(8) << 30};
  /// calibrations computed faster than this are not kept, s
  double min_calibration_s{0.25};
  /// store() writes the calibration on a thread of its own and returns at once (the folded
  /// organ's 115 MB took 0.3 to 0.45 s of its first start's path; docs/bench.md); false:
  /// store() writes it
  bool background_writes{false};
  /// that thread's nice value (a real-time run goes first)
  int writer_nice{10};
};

/// The calibration cache of a command-line option (`--factor-cache`), in the factor cache's
/// folder: "" the default folder (default_factor_cache_folder(), folder_cache.h, or none), "off" none, anything
/// else a folder (created when used). Null: no cache. $VOXELASTIC_FACTOR_CACHE_MIN_S sets
/// min_calibration_s (0: keep every calibration). Its calibrations are written in the
/// background (CalibrationCacheSettings::background_writes).
[[nodiscard]] std::shared_ptr<CalibrationCache> make_calibration_cache(const std::string& option);

/// The file form of the calibrated part of `physics` under `key` (what the folder keeps). Throws
/// vx::Error when the stream fails.
void write_calibration(std::ostream& out, const CalibrationKey& key, const PhysicsModel& physics);
/// Reads what write_calibration wrote (`bytes` bytes at `data`) into the calibrated part of
/// `physics` (its model set: every size is checked against it). False with `why` when it is not
/// a calibration of `key` for that model or is damaged; `physics` is then left as it was.
[[nodiscard]] bool read_calibration(const unsigned char* data, std::size_t bytes, const CalibrationKey& key,
                                    PhysicsModel& physics, std::string* why);

/// A CalibrationCache in a folder (folder_cache.h: the folder's bookkeeping; here what a file
/// holds: write_calibration, read_calibration). Thread-safe (one lock around each call). With
/// background writes a load first waits for the writes begun, and so does the destructor.
class FolderCalibrationCache final : public CalibrationCache {
 public:
  explicit FolderCalibrationCache(CalibrationCacheSettings settings);

  bool load(const CalibrationKey& key, PhysicsModel& physics) override;
  void store(const CalibrationKey& key, std::shared_ptr<const PhysicsModel> physics, double seconds) override;

  [[nodiscard]] const CalibrationCacheSettings& settings() const { return settings_; }
  /// The file of `key`.
  [[nodiscard]] std::filesystem::path file_of(const CalibrationKey& key) const { return folder_.file_of(key.name()); }

  /// hits: calibrations loaded; skipped: computed faster than min_calibration_s (folder_cache.h)
  using Counters = FolderCacheCounters;
  [[nodiscard]] Counters counters() const { return folder_.counters(); }

 private:
  CalibrationCacheSettings settings_;
  FolderCache folder_;
};

}  // namespace vx
