#pragma once
/// @file calibration_key.h
/// The core's half of the calibration cache (the folder and the file form are
/// pipeline/io/calibration_cache.h, as the factor cache is split between sim/sparse_factor.h and
/// pipeline/io/factor_cache.h): what a calibration is the calibration of (CalibrationKey), the
/// store that keeps calibrations by it (CalibrationCache; make_physics_model takes one,
/// calibration.h). The calibration (calibration.h) is the same per-element work at every start of the
/// same model and material: 2.0 s on both cores for the folded organ (docs/bench.md).

#include <cstdint>
#include <memory>
#include <string>

namespace vx {

class ContentHash;
struct Model;
struct Material;
struct MaterialField;
struct CalibrationOptions;
struct PhysicsModel;

/// What a calibration is the calibration of (the calibration cache's key, as FactorKey is the
/// factor cache's): a 64-bit hash of everything the calibrated part of a PhysicsModel depends
/// on: the model's content (every array of Model, bit for bit), the material, the per-element
/// field, the calibration options, a version (physics_model_key.cpp), and the calibration of a
/// small reference object built like the model with the same material and options by this
/// build (so a change of the calibration's code that shows there changes the key, and a file
/// written by an older build is not used).
struct CalibrationKey {
  std::uint64_t hash{0};     ///< ContentHash (base/content_hash.h)
  std::int64_t elements{0};  ///< sizes of the model (for the file name; the hash holds the content)
  std::int64_t entries{0};   ///< vertex entries
  /// A file-name-safe name: "calibration-43616e-1302388v-0123456789abcdef".
  [[nodiscard]] std::string name() const;
  [[nodiscard]] bool operator==(const CalibrationKey&) const = default;
};

/// The key of calibrating `model` with `material`, `field` and `options` (make_physics_model's
/// arguments). Hashes the model at about 6 GB/s and calibrates the reference object (a few ms).
/// Throws vx::Error where make_physics_model would (an invalid material or options).
[[nodiscard]] CalibrationKey calibration_key(const Model& model, const Material& material, const MaterialField& field,
                                             const CalibrationOptions& options);

/// Feeds every array of `model` to `h`, bit for bit (the key's model part; the display surface
/// cache keys by it too: pipeline/io/surface_cache.h).
void add_model_content(ContentHash& h, const Model& model);

/// A store of calibrations by key (pipeline/io/calibration_cache.h keeps one in a folder, beside
/// the factors). make_physics_model asks it before calibrating and offers it the result after.
/// It holds the calibrated part of a PhysicsModel, the per-element work: the fields that
/// calibrated_fields.h lists (the vertex entries' weights, rest offsets, gradients and
/// bending-mode weights, the elements' stiffness, damping, masses and spreads, the volume
/// points, the node masses and four counts).
/// The rest (the inertial masses and their scaling, the node -> entry index, the packed entries
/// and the batches of the element pass) is derived from these at every start.
class CalibrationCache {
 public:
  virtual ~CalibrationCache() = default;
  /// Fills the calibrated part of `physics` (its model, material, element and dimensions set)
  /// with the stored calibration of `key`; false when there is none or it cannot be read (then
  /// `physics` is as it was).
  virtual bool load(const CalibrationKey& key, PhysicsModel& physics) = 0;
  /// Offers the calibration of `key`, just computed in `seconds` (wall time). The calibrated
  /// part of `physics` is final from here on (make_physics_model then sets the derived part, in
  /// other fields), so a store may write it on a thread of its own while the model is finished
  /// and used, holding `physics` till then.
  virtual void store(const CalibrationKey& key, std::shared_ptr<const PhysicsModel> physics, double seconds) = 0;
};

}  // namespace vx
