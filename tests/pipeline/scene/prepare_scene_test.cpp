// Building a loaded scene (scene/prepare_scene.cpp): what only the built model tells (a fixed
// region that holds nothing, a probe that starts inside, a step that would tunnel), the material
// per element, the fast configuration without an integrator key (and for a large model), and
// the regional solves' error on the scene's support, before the run or beside it.
#include <gtest/gtest.h>

#include <unistd.h>
#include <cstdlib>

#include <fmt/format.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "base/error.h"
#include "io/region_check_cache.h"
#include "scene/fast_configuration.h"
#include "scene/scene.h"
#include "sim/sparse_factor.h"
#include "sim/time_step.h"
#include "support/scene_helpers.h"

using namespace vx;
using namespace vx::testing;
namespace fs = std::filesystem;
using json = nlohmann::json;

TEST(Scene, PrepareChecksWhatOnlyTheModelTells) {
  // a fixed region that holds no node
  json j = base_scene();
  j["fixed"] = {{{"box_mm", {{"min", {50, 50, 50}}, {"max", {60, 60, 60}}}}}};
  Scene s = parse_scene(j, ".", "test.json");
  try {
    (void)prepare_scene(s);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_CONTAINS(e.what(), "$.fixed[0]");
    EXPECT_CONTAINS(e.what(), "holds no node");
  }
  // a probe that would tunnel: 3 mm radius moving 1 m/s, 2 mm per step of 2 ms (implicit: stable)
  j = base_scene();
  j["integrator"] = {{"type", "implicit"}, {"dt_s", 2e-3}};
  j["probes"][0]["path"][1]["t_s"] = 0.001;
  s = parse_scene(j, ".", "test.json");
  try {
    (void)prepare_scene(s);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_CONTAINS(e.what(), "$.probes[0]");
    EXPECT_CONTAINS(e.what(), "pass through the surface");
  }
  // a time step far beyond the stable limit
  j = base_scene();
  j["integrator"]["dt_s"] = 0.05;
  s = parse_scene(j, ".", "test.json");
  try {
    (void)prepare_scene(s);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_CONTAINS(e.what(), "$.integrator.dt_s");
    EXPECT_CONTAINS(e.what(), "would blow up");
  }
  // risky but possible: warnings
  j = base_scene();
  j["integrator"]["dt_s"] = 1.1 * prepare_scene(parse_scene(base_scene(), ".", "t")).dt_stable_estimate_s;
  j["probes"][0]["path"] = {{{"t_s", 0}, {"position_mm", {6, 6, 7}}}};  // starts inside
  const PreparedScene p = prepare_scene(parse_scene(j, ".", "test.json"));
  ASSERT_EQ(p.warnings.size(), 2u);
  EXPECT_CONTAINS(p.warnings[0], "exceeds the estimated stable step");
  EXPECT_CONTAINS(p.warnings[1], "starts with");
  // friction with the implicit integrator (whose contact is frictionless): said, not silent
  j = base_scene();
  j["integrator"] = {{"type", "implicit"}, {"dt_s", 2e-3}};
  j["contact"] = {{"friction", 0.5}};
  const PreparedScene q = prepare_scene(parse_scene(j, ".", "test.json"));
  ASSERT_EQ(q.warnings.size(), 1u);
  EXPECT_CONTAINS(q.warnings[0], "friction 0.5 is ignored by the implicit integrator");
}

TEST(Scene, HounsfieldTableAndInclusionsGivePerElementModulus) {
  // table: linear between rows, constant beyond
  const std::vector<HuModulus> t = {{0, 5}, {100, 55}};
  EXPECT_DOUBLE_EQ(modulus_from_hu(t, -500), 5);
  EXPECT_DOUBLE_EQ(modulus_from_hu(t, 40), 25);
  EXPECT_DOUBLE_EQ(modulus_from_hu(t, 900), 55);

  // the block-lesion phantom: tissue 40 HU, lesion 120 HU
  json j = json::parse(R"({
    "object": {"phantom": "block-lesion", "size": 32},
    "material": {"youngs_modulus_kpa": 5,
                 "hounsfield_table": [{"hu": 40, "youngs_modulus_kpa": 5}, {"hu": 120, "youngs_modulus_kpa": 45}]},
    "duration_s": 0.01
  })");
  PreparedScene p = prepare_scene(parse_scene(j, ".", "test.json"));
  EXPECT_DOUBLE_EQ(p.min_modulus_kpa, 5.0);
  EXPECT_GT(p.max_modulus_kpa, 40.0);  // small elements inside the lesion get (nearly) its modulus
  EXPECT_LE(p.max_modulus_kpa, 45.0);
  EXPECT_GT(p.heterogeneous_elements, 0);
  // the stiffness follows: k_e scales with E
  const PhysicsModel& ph = *p.physics;
  double kmax = 0;
  for (double k : ph.element_stiffness) kmax = std::max(kmax, k);
  EXPECT_GT(kmax, 0.0);

  // an inclusion in a box: each element gets the volume fraction of the sphere it holds
  j = base_scene();
  j["material"]["inclusions"] = {{{"center_mm", {6, 6, 3}}, {"radius_mm", 2.5}, {"youngs_modulus_kpa", 100}}};
  p = prepare_scene(parse_scene(j, ".", "test.json"));
  EXPECT_DOUBLE_EQ(p.max_modulus_kpa, 100.0);  // some element lies wholly inside
  EXPECT_DOUBLE_EQ(p.min_modulus_kpa, 10.0);
  // volume-weighted mean modulus = base + (inclusion - base) * (voxels inside / all voxels)
  const Model& m = *p.model;
  const MaterialField f = material_field(m, parse_scene(j, ".", "t").material, nullptr);
  double weighted = 0, volume = 0;
  for (int e = 0; e < m.num_elements(); ++e) {
    weighted += f.youngs_modulus_kpa[std::size_t(e)] * m.element_volume_mm3[std::size_t(e)];
    volume += m.element_volume_mm3[std::size_t(e)];
  }
  int inside = 0;
  for (int k = 0; k < 6; ++k)
    for (int jj = 0; jj < 12; ++jj)
      for (int i = 0; i < 12; ++i)
        if (Eigen::Vector3d(i + 0.5 - 6, jj + 0.5 - 6, k + 0.5 - 3).norm() < 2.5) ++inside;
  EXPECT_NEAR(weighted / volume, 10.0 + 90.0 * inside / (12.0 * 12 * 6), 1e-9);
}

TEST(Scene, FixedFacesOfRoundedObjectsWithin) {
  json j = json::parse(R"({"object": {"phantom": "sphere", "size": 20}, "fixed": [{"face": "z_min", "within_mm": 2}],
                            "duration_s": 0.01})");
  const PreparedScene p = prepare_scene(parse_scene(j, ".", "test.json"));
  EXPECT_GT(p.fixed_nodes, 8);
  for (int i : p.settings.fixed_nodes) EXPECT_LE(p.model->rest_positions(2, i), p.bounds_min_mm.z() + 2.0 + 1e-9);
  j["fixed"] = {"z_min"};  // a voxel sphere touches its bounding box in a small flat patch only
  const PreparedScene q = prepare_scene(parse_scene(j, ".", "test.json"));
  EXPECT_GT(q.fixed_nodes, 0);
  EXPECT_LT(3 * q.fixed_nodes, p.fixed_nodes);
}

namespace vx {
namespace {

TEST(Scene, WithoutAnIntegratorKeyTheFastConfigurationRuns) {
  // no integrator key: implicit, the automatic step (20 ms, capped by the probe's speed), one
  // iteration; friction asks for symplectic Euler (grasping)
  nlohmann::json j = base_scene();
  j.erase("integrator");
  PreparedScene p = prepare_scene(parse_scene(j, ".", "t"));
  const FastConfiguration fast = default_fast_configuration();
  EXPECT_EQ(p.settings.integrator.kind, IntegratorKind::implicit);
  EXPECT_EQ(p.settings.integrator.max_iterations, fast.iterations);
  EXPECT_EQ(fast.iterations, 1);
  EXPECT_GT(p.settings.integrator.time_step_s, 0.0);
  EXPECT_LE(p.settings.integrator.time_step_s, fast.time_step_s);
  for (const auto& probe : p.settings.probes)
    EXPECT_LE(probe.max_scripted_speed_mm_s() * p.settings.integrator.time_step_s,
              0.25 * probe.geometry.radius_mm + 1e-12);
  j["contact"] = {{"friction", 0.5}};
  EXPECT_EQ(prepare_scene(parse_scene(j, ".", "t")).settings.integrator.kind, IntegratorKind::symplectic_euler);
  // the keys of the levers
  j = base_scene();
  j["integrator"] = {{"type", "implicit"},
                     {"dt_s", 0.002},
                     {"iterations", 3},
                     {"residual_tolerance_n", 1e-6},
                     {"region_radius_mm", 12}};
  j["material"]["mass_scaling"] = {{"factor", 2.0}};
  p = prepare_scene(parse_scene(j, ".", "t"));
  EXPECT_EQ(p.settings.integrator.max_iterations, 3);
  EXPECT_DOUBLE_EQ(p.settings.integrator.residual_tolerance_n, 1e-6);
  EXPECT_DOUBLE_EQ(p.settings.integrator.region_radius_mm, 12.0);
  EXPECT_DOUBLE_EQ(p.physics->mass_scaling.factor, 2.0);
  EXPECT_NEAR(p.physics->added_mass_kg, p.physics->total_mass_kg(), 1e-12);
  // implicit-only keys on an explicit scheme, and bad values, are errors naming the key
  j = base_scene();
  j["integrator"]["iterations"] = 2;
  EXPECT_CONTAINS(error_of(j), "settings of the implicit integrator");
  j = base_scene();
  j["material"]["mass_scaling"] = {{"factor", 0.5}};
  EXPECT_CONTAINS(error_of(j), "$.material.mass_scaling.factor");
  j = base_scene();
  j["material"]["mass_scaling"] = {{"time_step", 1e-4}};
  EXPECT_CONTAINS(error_of(j), "unknown key");
}

}  // namespace
}  // namespace vx

TEST(Scene, ANearlyIncompressibleTissueUnderFewIterationsIsWarned) {
  // the fast configuration's one iteration per step at Poisson 0.45 (docs/bench.md, "The 5 %
  // table at Poisson 0.45"): warned, with the configuration that is right; not at 0.3, nor when the steps iterate
  // to a residual, nor beyond the iterations measured, nor for an explicit scheme
  const auto warned = [](const nlohmann::json& j) {
    const PreparedScene p = prepare_scene(parse_scene(j, ".", "t"));
    for (const std::string& w : p.warnings)
      if (w.find("nearly incompressible") != std::string::npos) return w;
    return std::string();
  };
  nlohmann::json j = base_scene();
  j.erase("integrator");
  j["material"]["poisson_ratio"] = 0.45;
  const std::string w = warned(j);
  EXPECT_CONTAINS(w, "Poisson ratio 0.45 with 1 local/global iteration per step");
  EXPECT_CONTAINS(w, "\"residual_tolerance_n\": 1e-5");
  const PreparedScene p45 = prepare_scene(parse_scene(j, ".", "t"));
  EXPECT_EQ(incompressible_iterations_status(p45.settings.integrator, 0.45),
            "Poisson 0.45, 1 iteration per step: forces 8.5-13 % off a converged run (console)");
  EXPECT_EQ(incompressible_iterations_status(p45.settings.integrator, 0.4),
            "Poisson 0.4, 1 iteration per step: forces over 5 % off a converged run (console)");
  EXPECT_EQ(incompressible_iterations_status(p45.settings.integrator, 0.3), "");
  j["material"]["poisson_ratio"] = 0.3;
  EXPECT_EQ(warned(j), "");
  j["material"]["poisson_ratio"] = kSlowVolumePoissonRatio;
  EXPECT_NE(warned(j), "");
  j["integrator"] = {{"type", "implicit"}, {"dt_s", 0.01}, {"iterations", kSlowVolumeMaxIterations}};
  const std::string no_region = warned(j);
  EXPECT_CONTAINS(no_region, fmt::format("with {} local/global iterations", kSlowVolumeMaxIterations));
  EXPECT_EQ(no_region.find("regional solves"), std::string::npos) << no_region;  // this run has none
  j["integrator"]["region_radius_mm"] = 30;
  EXPECT_CONTAINS(warned(j), "the regional solves hold still the far field");
  j["integrator"]["iterations"] = kSlowVolumeMaxIterations + 1;
  EXPECT_EQ(warned(j), "");
  j["integrator"] = {{"type", "implicit"}, {"dt_s", 0.01}, {"iterations", 30}, {"residual_tolerance_n", 1e-5}};
  EXPECT_EQ(warned(j), "");
  j["integrator"] = {{"type", "symplectic_euler"}, {"dt_s", "auto"}};
  EXPECT_EQ(warned(j), "");
}

TEST(Scene, LargeModelsGetRegionalSolvesAtLongerSteps) {
  // the fast configuration (scene/fast_configuration.h): 20,000 nodes or more and no integrator key: 30 ms steps
  // (capped by the probe's speed as any automatic step) with regional solves within 60 mm
  json j = base_scene();
  j.erase("integrator");
  j["object"] = {{"phantom", "sphere"}, {"size", 80}, {"spacing_mm", 1.0}};
  j["fixed"] = json::array({{{"face", "z_min"}, {"within_mm", 3.0}}});
  j["probes"][0]["path"] =
      json::array({{{"t_s", 0}, {"position_mm", {0, 0, 45}}}, {{"t_s", 1}, {"position_mm", {0, 0, 40}}}});
  j["duration_s"] = 1.0;
  const PreparedScene p = prepare_scene(parse_scene(j, ".", "t"));
  const FastConfiguration fast = default_fast_configuration();
  EXPECT_EQ(fast.large_model_nodes, 20000);
  ASSERT_GE(p.model->num_nodes(), fast.large_model_nodes);
  EXPECT_EQ(p.settings.integrator.kind, IntegratorKind::implicit);
  EXPECT_DOUBLE_EQ(p.settings.integrator.time_step_s, fast.large_model_time_step_s);
  EXPECT_DOUBLE_EQ(p.settings.integrator.time_step_s, 0.03);
  EXPECT_DOUBLE_EQ(p.settings.integrator.region_radius_mm, fast.large_model_region_radius_mm);
  EXPECT_DOUBLE_EQ(p.settings.integrator.region_radius_mm, 60.0);
  // no iterations past the first after a release on a large model (each would be a regional or
  // full solve): its let-go tissue is brought to rest by the idle refresh
  EXPECT_EQ(p.settings.integrator.free_iterations, 0);
  EXPECT_EQ(fast.integrator_for(p.model->num_nodes()).free_iterations, 0);
  // and its factor swept in single precision (docs/bench.md, "Single-precision sweeps")
  EXPECT_TRUE(p.settings.integrator.single_precision_sweeps);
  EXPECT_TRUE(fast.integrator_for(p.model->num_nodes()).single_precision_sweeps);
  // an explicit integrator block keeps its own choices; "auto" precision is single on a large model
  j["integrator"] = {{"type", "implicit"}};
  const PreparedScene q = prepare_scene(parse_scene(j, ".", "t"));
  EXPECT_DOUBLE_EQ(q.settings.integrator.region_radius_mm, 0.0);
  EXPECT_DOUBLE_EQ(q.settings.integrator.time_step_s, fast.time_step_s);
  EXPECT_TRUE(q.settings.integrator.single_precision_sweeps);
  j["integrator"]["sweep_precision"] = "double";
  EXPECT_FALSE(prepare_scene(parse_scene(j, ".", "t")).settings.integrator.single_precision_sweeps);
  // a small model keeps 20 ms and no region
  j = base_scene();
  j.erase("integrator");
  const PreparedScene small = prepare_scene(parse_scene(j, ".", "t"));
  EXPECT_LT(small.model->num_nodes(), fast.large_model_nodes);
  EXPECT_DOUBLE_EQ(small.settings.integrator.region_radius_mm, 0.0);
  // and iterates up to 8 times in a step that leaves no tool touching (the return to rest)
  EXPECT_EQ(small.settings.integrator.free_iterations, 8);
  EXPECT_EQ(small.settings.integrator.free_iterations, fast.free_iterations);
  EXPECT_DOUBLE_EQ(small.settings.integrator.free_tolerance_mm, 1e-6);
  EXPECT_EQ(fast.integrator_for(small.model->num_nodes()).free_iterations, 8);
  // in double, unless the scene asks
  EXPECT_FALSE(small.settings.integrator.single_precision_sweeps);
  EXPECT_FALSE(fast.integrator_for(small.model->num_nodes()).single_precision_sweeps);
  j["integrator"] = {{"type", "implicit"}, {"sweep_precision", "single"}};
  if (SparseFactor::available(SparseFactor::Backend::cholmod)) {
    const PreparedScene asked = prepare_scene(parse_scene(j, ".", "t"));
    EXPECT_TRUE(asked.settings.integrator.single_precision_sweeps);
    EXPECT_TRUE(asked.warnings.empty());
  }
  // a factor of Eigen's (simplicial) sweeps in double: the run says so, and its settings too
  if (SparseFactor::available(SparseFactor::Backend::eigen_amd)) {
    ::setenv("VOXELASTIC_FACTOR", "eigen_amd", 1);
    const PreparedScene eigen = prepare_scene(parse_scene(j, ".", "t"));
    ::unsetenv("VOXELASTIC_FACTOR");
    EXPECT_FALSE(eigen.settings.integrator.single_precision_sweeps);
    ASSERT_EQ(eigen.warnings.size(), 1u);
    EXPECT_CONTAINS(eigen.warnings[0], "needs the supernodal factor of CHOLMOD");
    EXPECT_CONTAINS(eigen.warnings[0], "eigen_amd");
  }
  // a precision it does not know, or one on an explicit scheme, is an error naming the key
  j["integrator"]["sweep_precision"] = "half";
  EXPECT_CONTAINS(error_of(j), "$.integrator.sweep_precision");
  EXPECT_CONTAINS(error_of(j), "use auto");
  j["integrator"] = {{"type", "symplectic_euler"}, {"sweep_precision", "double"}};
  EXPECT_CONTAINS(error_of(j), "settings of the implicit integrator");
}

/// docs/model.md section 7: a 64 x 64 x 128 mm column (4 mm voxels) pressed at its top with regional
/// solves within 30 mm at 30 ms, held at an 8 x 8 mm stem.
json stem_held_column() {
  json j = base_scene();
  j["object"] = {{"box_mm", {{"min", {0, 0, 0}}, {"max", {64, 64, 128}}}}, {"voxel_mm", 4.0}};
  j["material"]["damping"] = 0.2;
  j["integrator"] = {{"type", "implicit"}, {"dt_s", 0.03}, {"iterations", 1}, {"region_radius_mm", 30}};
  j["probes"][0]["radius_mm"] = 4;
  j["probes"][0]["path"] =
      json::array({{{"t_s", 0}, {"position_mm", {32, 32, 132}}}, {{"t_s", 1}, {"position_mm", {32, 32, 127}}}});
  j["duration_s"] = 1.0;
  j["fixed"] = json::array({{{"box_mm", {{"min", {27.9, 27.9, -0.1}}, {"max", {36.1, 36.1, 0.1}}}}}});
  return j;
}

TEST(Scene, RegionalSolvesOnAWeakSupportSayHowWrongTheyAre) {
  // docs/model.md section 7: a 64 x 64 x 128 mm column (4 mm voxels) pressed at its top with regional
  // solves within 30 mm at 30 ms; held at an 8 x 8 mm stem the held far field makes the press too hard (a
  // warning with the estimate and the configuration that is right), held over its lower third
  // it does not (a log line only)
  json j = stem_held_column();
  const PreparedScene stem = prepare_scene(parse_scene(j, ".", "t"));
  ASSERT_TRUE(stem.region_stiffening.has_value());
  EXPECT_EQ(stem.region_stiffening_probe, "ball");
  EXPECT_GT(stem.region_stiffening->force_ratio, 1.3);
  std::string warned;
  for (const auto& w : stem.warnings)
    if (w.find("holds the far field still") != std::string::npos) warned = w;
  std::cout << "stem: " << warned << "\n";
  EXPECT_CONTAINS(warned, fmt::format("presses about {:.2g}x too hard", stem.region_stiffening->force_ratio));
  EXPECT_CONTAINS(warned, "\"integrator\": {\"type\": \"implicit\", \"dt_s\": 0.01, \"iterations\": 5}");
  // at Poisson 0.45 both warnings name the same configuration, one that iterates to a residual:
  // following the region check's advice no longer brings the Poisson warning
  json nearly = j;
  nearly["material"]["poisson_ratio"] = 0.45;
  std::string far45, poisson45;
  for (const auto& w : prepare_scene(parse_scene(nearly, ".", "t")).warnings) {
    if (w.find("holds the far field still") != std::string::npos) far45 = w;
    if (w.find("local/global iteration") != std::string::npos) poisson45 = w;
  }
  const std::string right =
      "{\"type\": \"implicit\", \"dt_s\": 0.01, \"iterations\": 30, \"residual_tolerance_n\": 1e-5}";
  EXPECT_EQ(accurate_integrator_json(0.45), right);
  EXPECT_CONTAINS(far45, "\"integrator\": " + right);
  EXPECT_CONTAINS(poisson45, "\"integrator\": " + right);
  nearly["integrator"] = json::parse(right);
  for (const auto& w : prepare_scene(parse_scene(nearly, ".", "t")).warnings) {
    EXPECT_EQ(w.find("local/global iteration"), std::string::npos) << w;
    EXPECT_EQ(w.find("holds the far field still"), std::string::npos) << w;
  }
  j["fixed"] = json::array({{{"face", "z_min"}, {"within_mm", 43.0}}});
  const PreparedScene base = prepare_scene(parse_scene(j, ".", "t"));
  ASSERT_TRUE(base.region_stiffening.has_value());
  EXPECT_LT(base.region_stiffening->force_ratio, 1.0 + kRegionStiffeningWarnRel);
  for (const auto& w : base.warnings) EXPECT_EQ(w.find("holds the far field still"), std::string::npos) << w;
  bool logged = false;
  for (const auto& l : base.log) logged = logged || l.find("regional solves within 30 mm") != std::string::npos;
  EXPECT_TRUE(logged);
  // no region, no estimate
  j["integrator"].erase("region_radius_mm");
  EXPECT_FALSE(prepare_scene(parse_scene(j, ".", "t")).region_stiffening.has_value());
}

TEST(Scene, TheRegionCheckInTheBackgroundGivesTheSameEstimate) {
  // simulate and the probe app start the run while the check runs on a thread of its own: the
  // same estimate and warning, once taken; a run that ends first cancels it without waiting
  json j = stem_held_column();
  const Scene scene = parse_scene(j, ".", "t");
  const PreparedScene now = prepare_scene(scene);
  ASSERT_TRUE(now.region_stiffening.has_value());
  EXPECT_EQ(now.pending_region_check, nullptr);
  PrepareSceneOptions background;
  background.region_check = RegionCheckTiming::background;
  PreparedScene later = prepare_scene(scene, background);
  ASSERT_NE(later.pending_region_check, nullptr);
  EXPECT_FALSE(later.region_stiffening.has_value());
  const std::size_t warnings_before = later.warnings.size();
  const std::optional<RegionCheck> c = take_region_check(later, true);
  ASSERT_TRUE(c.has_value());
  EXPECT_EQ(later.pending_region_check, nullptr);
  ASSERT_TRUE(later.region_stiffening.has_value());
  EXPECT_EQ(later.region_stiffening_probe, "ball");
  EXPECT_DOUBLE_EQ(later.region_stiffening->force_ratio, now.region_stiffening->force_ratio);
  ASSERT_EQ(c->warnings.size(), 1u);
  EXPECT_EQ(later.warnings.size(), warnings_before + 1);
  EXPECT_CONTAINS(later.warnings.back(),
                  fmt::format("presses about {:.2g}x too hard", now.region_stiffening->force_ratio));
  EXPECT_FALSE(take_region_check(later, true).has_value());  // taken once
  // the stage times name where the start-up went
  ASSERT_GE(later.stage_seconds.size(), 3u);
  EXPECT_EQ(later.stage_seconds.front().first, "object");
  for (const auto& [name, s] : later.stage_seconds) EXPECT_GE(s, 0.0) << name;
  // cancelled: the estimate stops at its next iteration and says so
  std::atomic<bool> cancel{true};
  RegionStiffeningSettings rs;
  rs.tool_mm = Eigen::Vector3d(32, 32, 132);
  rs.cancel = &cancel;
  std::vector<std::uint8_t> fixed(std::size_t(now.physics->num_nodes()), 0);
  for (int n = 0; n < now.physics->num_nodes(); ++n)
    if (now.model->rest_positions(2, n) < 0.1) fixed[std::size_t(n)] = 1;
  const RegionStiffeningEstimate e = estimate_region_stiffening(*now.physics, fixed, rs);
  EXPECT_FALSE(e.valid);
  EXPECT_EQ(e.reason, "cancelled");
  // dropped while running: joins (cancelled) instead of leaving a thread behind
  { const PreparedScene dropped = prepare_scene(scene, background); }
}

TEST(Scene, TheRegionCheckIsKeptByItsContentAndLoadedAtTheNextStart) {
  // io/region_check_cache.h: the second start on the same support loads the estimate the first
  // solved (the same numbers, bit for bit, and the same warning); another support, tool place or
  // time step is another key; a damaged file is removed and the estimate solved again
  const fs::path dir = fs::temp_directory_path() / fmt::format("vx_region_check_cache_{}", ::getpid());
  fs::remove_all(dir);
  RegionCheckCacheSettings cs;
  cs.folder = dir;
  cs.min_seconds = 0.0;  // the column's estimate takes well under the default 0.25 s
  auto cache = std::make_shared<RegionCheckCache>(cs);
  PrepareSceneOptions options;
  options.region_check_cache = cache;
  json j = stem_held_column();
  const auto prepare = [&](const json& scene) { return prepare_scene(parse_scene(scene, ".", "t"), options); };
  const auto far_warning = [](const PreparedScene& p) {
    for (const auto& w : p.warnings)
      if (w.find("holds the far field still") != std::string::npos) return w;
    return std::string();
  };
  const PreparedScene first = prepare(j);
  ASSERT_TRUE(first.region_stiffening.has_value());
  EXPECT_FALSE(first.region_stiffening->loaded);
  EXPECT_EQ(cache->counters().stored, 1);
  const PreparedScene second = prepare(j);
  ASSERT_TRUE(second.region_stiffening.has_value());
  EXPECT_TRUE(second.region_stiffening->loaded);
  EXPECT_EQ(cache->counters().hits, 1);
  const RegionStiffeningEstimate &a = *first.region_stiffening, &b = *second.region_stiffening;
  EXPECT_EQ(a.force_ratio, b.force_ratio);
  EXPECT_EQ(a.compliance_full_mm_n, b.compliance_full_mm_n);
  EXPECT_EQ(a.compliance_region_mm_n, b.compliance_region_mm_n);
  EXPECT_EQ(a.region_nodes, b.region_nodes);
  EXPECT_EQ(a.iterations_full, b.iterations_full);
  EXPECT_FALSE(far_warning(first).empty());
  EXPECT_EQ(far_warning(first), far_warning(second));
  bool said = false;
  for (const auto& l : second.log) said = said || l.find("loaded from the cache") != std::string::npos;
  EXPECT_TRUE(said);
  // another key: the tool elsewhere, the support wider, a longer step
  json moved = j;
  moved["probes"][0]["path"][0]["position_mm"] = {20, 32, 132};
  json wider = j;
  wider["fixed"][0]["box_mm"]["max"] = {40.1, 40.1, 0.1};
  json longer = j;
  longer["integrator"]["dt_s"] = 0.04;
  for (const json& other : {moved, wider, longer}) {
    const PreparedScene p = prepare(other);
    ASSERT_TRUE(p.region_stiffening.has_value());
    EXPECT_FALSE(p.region_stiffening->loaded);
  }
  EXPECT_EQ(cache->counters().hits, 1);
  EXPECT_EQ(cache->counters().stored, 4);
  // a damaged file: removed with a warning, the estimate solved and kept again
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(dir)) files.push_back(e.path());
  ASSERT_EQ(files.size(), 4u);
  for (const fs::path& f : files) {
    std::fstream s(f, std::ios::in | std::ios::out | std::ios::binary);
    s.seekp(40);
    s.put('\x7f');
  }
  const PreparedScene damaged = prepare(j);
  ASSERT_TRUE(damaged.region_stiffening.has_value());
  EXPECT_FALSE(damaged.region_stiffening->loaded);
  EXPECT_EQ(damaged.region_stiffening->force_ratio, a.force_ratio);
  EXPECT_EQ(cache->counters().damaged, 1);
  EXPECT_EQ(cache->counters().stored, 5);
  fs::remove_all(dir);
}
