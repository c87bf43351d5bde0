// The calibration cache in a folder (io/calibration_cache.h): a model loaded from it has the
// calibrated model's arrays bit for bit and steps the same; another model, material or option is
// another key; a damaged file is removed and the model calibrated; quick calibrations are not
// kept; the folder's size limit counts factors and calibrations together; the option and the
// environment pick the factor cache's folder or none; a calibration written in the background is
// the file written in place and is found at once.
#include "io/calibration_cache.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "io/factor_cache.h"
#include "scene/scene.h"
#include "sim/simulation.h"

namespace vx {
namespace {
namespace fs = std::filesystem;

/// A small folded phantom (the folded organ's shape at 48 voxels of 1 mm: partly filled surface
/// elements, extra face vertices, larger elements inside) held at its bottom and sagging under
/// gravity; `extra` is merged into the scene (another material, an inclusion).
Scene folded_scene(const nlohmann::json& extra = nlohmann::json::object()) {
  nlohmann::json j = nlohmann::json::parse(R"({
    "object": {"phantom": "folded", "size": 48, "spacing_mm": 1.0, "resolution": "gradational"},
    "material": {"youngs_modulus_kpa": 10, "damping": 0.2, "density_kg_m3": 1000, "poisson_ratio": 0},
    "fixed": [{"face": "z_min", "within_mm": 3}],
    "gravity": [0, 0, -9.81],
    "integrator": {"type": "symplectic_euler", "dt_s": "auto"},
    "duration_s": 0.01,
    "outputs": {"plot": false}
  })");
  j.merge_patch(extra);
  return parse_scene(j, fs::temp_directory_path(), "folded48.json");
}

PreparedScene prepare_with(const Scene& scene, const std::shared_ptr<CalibrationCache>& cache) {
  PrepareSceneOptions o;
  o.calibration_cache = cache;
  return prepare_scene(scene, o);
}

/// Every array of two physics models, bit for bit: the calibrated part, the part derived from it,
/// the packed entries and the batches of the element pass.
void expect_same_physics(const PhysicsModel& a, const PhysicsModel& b) {
  EXPECT_EQ(a.entry_weight, b.entry_weight);
  EXPECT_EQ(a.entry_rest, b.entry_rest);
  EXPECT_EQ(a.entry_rest_weighted, b.entry_rest_weighted);
  EXPECT_EQ(a.entry_gradient, b.entry_gradient);
  EXPECT_EQ(a.entry_modes, b.entry_modes);
  EXPECT_EQ(a.element_stiffness, b.element_stiffness);
  EXPECT_EQ(a.element_damping, b.element_damping);
  EXPECT_EQ(a.element_volume_stiffness, b.element_volume_stiffness);
  EXPECT_EQ(a.element_mass_kg, b.element_mass_kg);
  EXPECT_EQ(a.element_spread_mm2, b.element_spread_mm2);
  EXPECT_EQ(a.element_fit_scale, b.element_fit_scale);
  EXPECT_EQ(a.element_affine_stiffness, b.element_affine_stiffness);
  ASSERT_EQ(a.element_spread.size(), b.element_spread.size());
  for (std::size_t e = 0; e < a.element_spread.size(); ++e) ASSERT_EQ(a.element_spread[e], b.element_spread[e]) << e;
  EXPECT_EQ(a.volume_point_offsets, b.volume_point_offsets);
  EXPECT_EQ(a.volume_point_stiffness, b.volume_point_stiffness);
  EXPECT_EQ(a.volume_point_term_offsets, b.volume_point_term_offsets);
  EXPECT_EQ(a.volume_term_entry, b.volume_term_entry);
  EXPECT_EQ(a.volume_term_delta, b.volume_term_delta);
  EXPECT_EQ(a.bending_relief_clamped, b.bending_relief_clamped);
  EXPECT_EQ(a.gradient_fallback_elements, b.gradient_fallback_elements);
  EXPECT_EQ(a.anisotropic_elements, b.anisotropic_elements);
  EXPECT_EQ(a.max_anisotropy, b.max_anisotropy);
  EXPECT_EQ(a.node_mass_kg, b.node_mass_kg);
  EXPECT_EQ(a.node_mass, b.node_mass);
  EXPECT_EQ(a.node_inv_mass, b.node_inv_mass);
  EXPECT_EQ(a.node_gravity_ratio, b.node_gravity_ratio);
  EXPECT_EQ(a.added_mass_kg, b.added_mass_kg);
  EXPECT_EQ(a.scaled_nodes, b.scaled_nodes);
  EXPECT_EQ(a.node_entry_offsets, b.node_entry_offsets);
  EXPECT_EQ(a.node_entries, b.node_entries);
  EXPECT_EQ(a.entry_slot, b.entry_slot);
  EXPECT_EQ(a.damped, b.damped);
  EXPECT_EQ(a.rest_diagonal_mm, b.rest_diagonal_mm);
  ASSERT_EQ(a.entry_packed.size(), b.entry_packed.size());
  EXPECT_EQ(std::memcmp(a.entry_packed.data(), b.entry_packed.data(), a.entry_packed.size() * sizeof(PackedEntry)), 0);
  const ElementBatches &ba = a.element_batches, &bb = b.element_batches;
  ASSERT_EQ(ba.rows.size(), bb.rows.size());
  EXPECT_EQ(std::memcmp(ba.rows.data(), bb.rows.data(), ba.rows.size() * sizeof(BatchRow)), 0);
  ASSERT_EQ(ba.mode_rows.size(), bb.mode_rows.size());
  EXPECT_EQ(std::memcmp(ba.mode_rows.data(), bb.mode_rows.data(), ba.mode_rows.size() * sizeof(ModeRow)), 0);
  EXPECT_EQ(ba.window_offsets, bb.window_offsets);
  EXPECT_EQ(ba.unbatched, bb.unbatched);
  ASSERT_EQ(ba.batches.size(), bb.batches.size());
  for (std::size_t i = 0; i < ba.batches.size(); ++i) {
    const ElementBatch &x = ba.batches[i], &y = bb.batches[i];
    ASSERT_EQ(std::memcmp(x.stiffness, y.stiffness, sizeof x.stiffness), 0) << i;
    ASSERT_EQ(std::memcmp(x.affine_stiffness, y.affine_stiffness, sizeof x.affine_stiffness), 0) << i;
    ASSERT_EQ(std::memcmp(x.damping, y.damping, sizeof x.damping), 0) << i;
    ASSERT_EQ(std::memcmp(x.spread, y.spread, sizeof x.spread), 0) << i;
    ASSERT_EQ(std::memcmp(x.element, y.element, sizeof x.element), 0) << i;
    ASSERT_EQ(std::memcmp(x.count, y.count, sizeof x.count), 0) << i;
    ASSERT_EQ(x.first_row, y.first_row) << i;
    ASSERT_EQ(x.rows, y.rows) << i;
  }
}

/// The node positions after `steps` steps of `prepared`.
Eigen::Matrix3Xd positions_after(const PreparedScene& prepared, int steps) {
  Simulation sim(prepared.physics, prepared.settings);
  for (int k = 0; k < steps; ++k) EXPECT_EQ(sim.step(), StepStatus::ok);
  return sim.state().positions;
}

class CalibrationCacheTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_calibration_cache_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  [[nodiscard]] CalibrationCacheSettings settings() const {
    CalibrationCacheSettings s;
    s.folder = dir_ / "cache";  // created when the first calibration is kept
    s.min_calibration_s = 0.0;
    return s;
  }
  [[nodiscard]] std::shared_ptr<FolderCalibrationCache> cache() const {
    return std::make_shared<FolderCalibrationCache>(settings());
  }
  static std::vector<fs::path> files(const fs::path& folder) {
    std::vector<fs::path> out;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(folder, ec)) out.push_back(e.path());
    return out;
  }
  fs::path dir_;
};

TEST_F(CalibrationCacheTest, AModelLoadedFromTheCacheHasTheCalibratedArraysBitForBitAndStepsTheSame) {
  const Scene scene = folded_scene();
  const PreparedScene plain = prepare_with(scene, nullptr);
  ASSERT_GT(plain.physics->num_elements(), 500);
  EXPECT_GT(plain.physics->entry_modes.cols(), 0);  // the hourglass element: its relief weights too

  const auto first_cache = cache();
  const PreparedScene first = prepare_with(scene, first_cache);
  EXPECT_EQ(first_cache->counters().misses, 1);
  EXPECT_EQ(first_cache->counters().stored, 1);
  const std::vector<fs::path> kept = files(settings().folder);
  ASSERT_EQ(kept.size(), 1u);  // no temporary file left beside it
  EXPECT_EQ(kept[0].extension(), ".vxcalib");
  EXPECT_EQ(kept[0], first_cache->file_of(calibration_key(*plain.model, scene.material.base, {}, [&] {
    CalibrationOptions o;
    o.element = scene.material.element;
    return o;
  }())));

  // a second start (another cache object on the same folder, as another process would)
  const auto second_cache = cache();
  const PreparedScene second = prepare_with(scene, second_cache);
  EXPECT_EQ(second_cache->counters().hits, 1);
  EXPECT_EQ(second_cache->counters().stored, 0);
  expect_same_physics(*plain.physics, *first.physics);
  expect_same_physics(*plain.physics, *second.physics);
  // and the same steps: the held phantom sags under gravity the same to the bit
  const Eigen::Matrix3Xd x_plain = positions_after(plain, 20);
  EXPECT_GT((x_plain - plain.model->rest_positions).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_EQ(x_plain, positions_after(second, 20));
}

TEST_F(CalibrationCacheTest, VolumePointsMassScalingAndAMaterialFieldComeBackBitForBit) {
  // Poisson 0.3 with volume points, a floor of the masses, a stiff inclusion: every optional array
  const Scene scene = folded_scene(nlohmann::json::parse(R"({
    "material": {"poisson_ratio": 0.3, "mass_scaling": {"factor": 2, "time_step_s": 0.0005},
                 "inclusions": [{"center_mm": [0, 0, 0], "radius_mm": 8, "youngs_modulus_kpa": 40}]}
  })"));
  const PreparedScene prepared = prepare_with(scene, nullptr);
  const MaterialField field = material_field(*prepared.model, scene.material, nullptr);
  ASSERT_FALSE(field.youngs_modulus_kpa.empty());
  CalibrationOptions o;
  o.element = scene.material.element;
  o.mass_scaling = scene.material.mass_scaling;
  o.volume_mean_fraction = 0.5;
  const auto plain = make_physics_model(prepared.model, scene.material.base, field, o);
  ASSERT_TRUE(plain->has_volume_points());
  ASSERT_GT(plain->scaled_nodes, 0);
  const auto c1 = cache();
  const auto computed = make_physics_model(prepared.model, scene.material.base, field, o, c1.get());
  const auto c2 = cache();
  const auto loaded = make_physics_model(prepared.model, scene.material.base, field, o, c2.get());
  EXPECT_EQ(c1->counters().stored, 1);
  EXPECT_EQ(c2->counters().hits, 1);
  expect_same_physics(*plain, *computed);
  expect_same_physics(*plain, *loaded);
}

TEST_F(CalibrationCacheTest, AnotherModelMaterialFieldOrOptionIsAnotherKey) {
  const PreparedScene prepared = prepare_with(folded_scene(), nullptr);
  const Model& m = *prepared.model;
  const Material mat = prepared.physics->material;
  const CalibrationKey key = calibration_key(m, mat, {}, {});
  EXPECT_EQ(key, calibration_key(m, mat, {}, {}));  // the same inputs, the same key
  EXPECT_EQ(key.elements, m.num_elements());
  EXPECT_EQ(key.entries, m.num_vertex_entries());
  EXPECT_EQ(key.name().rfind("calibration-" + std::to_string(m.num_elements()) + "e-", 0), 0u) << key.name();
  // one node moved by one unit in the last place
  Model moved = m;
  moved.rest_positions(0, 7) = std::nextafter(moved.rest_positions(0, 7), 1e9);
  EXPECT_NE(key.hash, calibration_key(moved, mat, {}, {}).hash);
  Material softer = mat;
  softer.youngs_modulus_kpa *= 0.5;
  EXPECT_NE(key.hash, calibration_key(m, softer, {}, {}).hash);
  Material damped = mat;
  damped.damping_ratio += 0.1;
  EXPECT_NE(key.hash, calibration_key(m, damped, {}, {}).hash);
  MaterialField field;
  field.youngs_modulus_kpa.assign(std::size_t(m.num_elements()), mat.youngs_modulus_kpa);
  EXPECT_NE(key.hash, calibration_key(m, mat, field, {}).hash);  // a field, even an even one, is another input
  CalibrationOptions paper;
  paper.element = ElementKind::paper;
  EXPECT_NE(key.hash, calibration_key(m, mat, {}, paper).hash);
  CalibrationOptions scaled;
  scaled.mass_scaling.factor = 2.0;
  EXPECT_NE(key.hash, calibration_key(m, mat, {}, scaled).hash);

  // a file of one key is not read for another model
  const auto c = cache();
  (void)make_physics_model(prepared.model, mat, {}, {}, c.get());
  const fs::path file = c->file_of(key);
  ASSERT_TRUE(fs::exists(file));
  std::ifstream in(file, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  PhysicsModel other;
  other.model = std::make_shared<const Model>(moved);
  other.material = mat;
  other.element = ElementKind::hourglass;
  std::string why;
  EXPECT_FALSE(read_calibration(reinterpret_cast<const unsigned char*>(bytes.data()), bytes.size(),
                                calibration_key(moved, mat, {}, {}), other, &why));
  EXPECT_NE(why.find("another model"), std::string::npos) << why;
  EXPECT_TRUE(other.entry_weight.empty());  // left as it was
}

TEST_F(CalibrationCacheTest, ADamagedFileIsRemovedWithAWarningAndTheModelCalibrated) {
  const Scene scene = folded_scene();
  const PreparedScene plain = prepare_with(scene, nullptr);
  const auto c1 = cache();
  (void)prepare_with(scene, c1);
  const std::vector<fs::path> kept = files(settings().folder);
  ASSERT_EQ(kept.size(), 1u);
  // one flipped byte in the middle of the arrays
  {
    std::fstream f(kept[0], std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(std::streamoff(fs::file_size(kept[0]) / 2));
    char b = 0;
    f.read(&b, 1);
    b = char(b ^ 0x10);
    f.seekp(std::streamoff(fs::file_size(kept[0]) / 2));
    f.write(&b, 1);
  }
  const auto c2 = cache();
  ::testing::internal::CaptureStderr();
  const PreparedScene again = prepare_with(scene, c2);
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find("could not be read"), std::string::npos) << err;
  EXPECT_NE(err.find("checksum"), std::string::npos) << err;
  EXPECT_EQ(c2->counters().damaged, 1);
  EXPECT_EQ(c2->counters().hits, 0);
  EXPECT_EQ(c2->counters().stored, 1);  // calibrated and kept anew
  expect_same_physics(*plain.physics, *again.physics);
  // a truncated file likewise
  fs::resize_file(kept[0], fs::file_size(kept[0]) / 3);
  const auto c3 = cache();
  const PreparedScene third = prepare_with(scene, c3);
  EXPECT_EQ(c3->counters().damaged, 1);
  expect_same_physics(*plain.physics, *third.physics);
}

TEST_F(CalibrationCacheTest, ACalibrationWrittenInTheBackgroundIsTheFileWrittenInPlaceAndIsFoundAtOnce) {
  // the write reads the calibrated part while make_physics_model sets the derived part (here the
  // scaled masses too) beside it: the file is the one written in place, byte for byte, and the
  // same cache's next lookup waits for it and loads it
  const Scene scene = folded_scene(nlohmann::json::parse(R"({
    "material": {"poisson_ratio": 0.3, "mass_scaling": {"factor": 2, "time_step_s": 0.0005}}
  })"));
  const PreparedScene prepared = prepare_with(scene, nullptr);
  CalibrationOptions o;
  o.element = scene.material.element;
  o.mass_scaling = scene.material.mass_scaling;
  o.volume_mean_fraction = 0.5;
  const auto plain = make_physics_model(prepared.model, scene.material.base, {}, o);
  const auto in_place = cache();
  (void)make_physics_model(prepared.model, scene.material.base, {}, o, in_place.get());
  ASSERT_EQ(in_place->counters().stored, 1);
  const auto read_bytes = [](const fs::path& file) {
    std::ifstream in(file, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  const std::string expected = read_bytes(files(settings().folder).at(0));
  ASSERT_GT(expected.size(), 100000u);

  CalibrationCacheSettings s = settings();
  s.folder = dir_ / "beside";
  s.background_writes = true;
  s.writer_nice = 0;
  const auto beside = std::make_shared<FolderCalibrationCache>(s);
  const auto computed = make_physics_model(prepared.model, scene.material.base, {}, o, beside.get());
  const auto loaded = make_physics_model(prepared.model, scene.material.base, {}, o, beside.get());
  EXPECT_EQ(beside->counters().stored, 1);  // the lookup waited for the write ...
  EXPECT_EQ(beside->counters().hits, 1);    // ... and found it
  expect_same_physics(*plain, *computed);
  expect_same_physics(*plain, *loaded);
  const std::vector<fs::path> kept = files(s.folder);
  ASSERT_EQ(kept.size(), 1u);  // no temporary file left beside it
  EXPECT_EQ(read_bytes(kept[0]) == expected, true);

  // a lookup right after the store, before its thread has begun to write: found every time
  const CalibrationKey key = calibration_key(*prepared.model, scene.material.base, {}, o);
  int found = 0;
  for (std::uint64_t i = 1; i <= 50; ++i) {
    CalibrationKey k = key;
    k.hash ^= i;  // another name, another file
    beside->store(k, computed, 1.0);
    PhysicsModel t = *plain;
    t.node_mass_kg.assign(t.node_mass_kg.size(), 0.0);
    found += beside->load(k, t) && t.node_mass_kg == plain->node_mass_kg;
  }
  EXPECT_EQ(found, 50);
}

TEST_F(CalibrationCacheTest, QuickCalibrationsAreNotKept) {
  CalibrationCacheSettings s = settings();
  s.min_calibration_s = 1e9;
  const auto c = std::make_shared<FolderCalibrationCache>(s);
  (void)prepare_with(folded_scene(), c);
  EXPECT_EQ(c->counters().skipped, 1);
  EXPECT_EQ(c->counters().stored, 0);
  EXPECT_TRUE(files(s.folder).empty());
}

TEST_F(CalibrationCacheTest, TheFolderLimitCountsFactorsAndCalibrationsTogether) {
  const Scene scene = folded_scene();
  // the size of the phantom's calibration file
  CalibrationCacheSettings probe = settings();
  probe.folder = dir_ / "probe";
  const auto measure = std::make_shared<FolderCalibrationCache>(probe);
  (void)prepare_with(scene, measure);
  ASSERT_EQ(files(probe.folder).size(), 1u);
  const std::uintmax_t calibration_bytes = fs::file_size(files(probe.folder)[0]);

  // an old factor of 2 MB and a file that is not the cache's, beside
  fs::create_directories(settings().folder);
  const fs::path factor = settings().folder / "cholmod-1n-1nz-0000000000000000.vxfactor";
  const fs::path other = settings().folder / "notes.txt";
  std::ofstream(factor, std::ios::binary) << std::string(2'000'000, 'x');
  std::ofstream(other) << std::string(5'000'000, 'y');
  fs::last_write_time(factor, fs::file_time_type::clock::now() - std::chrono::hours(1));
  CalibrationCacheSettings s = settings();
  s.max_bytes = calibration_bytes + 1'000'000;  // the calibration fits, not with the factor
  const auto c = std::make_shared<FolderCalibrationCache>(s);
  (void)prepare_with(scene, c);
  ASSERT_EQ(c->counters().stored, 1);
  EXPECT_EQ(c->counters().evicted, 1);
  EXPECT_FALSE(fs::exists(factor));
  EXPECT_TRUE(fs::exists(other));  // not counted, not removed

  // and the factor cache's limit counts the calibration: a factor kept now drops it
  FactorCacheSettings fs_settings;
  fs_settings.folder = s.folder;
  fs_settings.max_bytes = 100'000;  // the small factor below fits, the calibration does not
  fs_settings.min_factor_s = 0.0;
  ASSERT_GT(calibration_bytes, fs_settings.max_bytes);
  FolderFactorCache factors(fs_settings);
  SparseFactor::Matrix a(2, 2);
  a.insert(0, 0) = 2.0;
  a.insert(1, 1) = 3.0;
  SparseFactor f;
  ASSERT_TRUE(f.compute(a));
  FactorKey k;
  k.rows = 2;
  k.nonzeros = 2;
  k.backend = std::uint8_t(SparseFactor::best_backend());
  factors.store(k, f);
  ASSERT_EQ(factors.counters().stored, 1);
  EXPECT_EQ(factors.counters().evicted, 1);
  EXPECT_TRUE(fs::exists(factors.file_of(k)));
  EXPECT_TRUE(fs::exists(other));
  int calibrations = 0;
  for (const fs::path& p : files(s.folder)) calibrations += p.extension() == ".vxcalib" ? 1 : 0;
  EXPECT_EQ(calibrations, 0);
}

TEST_F(CalibrationCacheTest, TheOptionAndTheEnvironmentPickTheFactorCachesFolder) {
  EXPECT_EQ(make_calibration_cache("off"), nullptr);
  const auto explicit_folder =
      std::dynamic_pointer_cast<FolderCalibrationCache>(make_calibration_cache((dir_ / "x").string()));
  ASSERT_NE(explicit_folder, nullptr);
  EXPECT_EQ(explicit_folder->settings().folder, dir_ / "x");
  ::setenv("VOXELASTIC_FACTOR_CACHE", "off", 1);
  EXPECT_EQ(make_calibration_cache(""), nullptr);
  ::setenv("VOXELASTIC_FACTOR_CACHE", (dir_ / "env").c_str(), 1);
  ::setenv("VOXELASTIC_FACTOR_CACHE_MIN_S", "0.5", 1);
  const auto from_env = std::dynamic_pointer_cast<FolderCalibrationCache>(make_calibration_cache(""));
  ASSERT_NE(from_env, nullptr);
  EXPECT_EQ(from_env->settings().folder, dir_ / "env");
  EXPECT_EQ(from_env->settings().min_calibration_s, 0.5);
  ::unsetenv("VOXELASTIC_FACTOR_CACHE_MIN_S");
  ::unsetenv("VOXELASTIC_FACTOR_CACHE");
}

}  // namespace
}  // namespace vx
