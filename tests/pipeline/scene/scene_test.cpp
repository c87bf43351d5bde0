// Scene files: strict validation (JSON paths, wrong units, impossible values), building the
// object and its heterogeneous material, and the simulate outputs (forces.csv, .pvd, plot).
#include "scene/scene.h"
#include "sim/time_step.h"

#include <gtest/gtest.h>
#include <vtkDataArray.h>
#include <vtkFieldData.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPolyData.h>
#include <vtkStringArray.h>
#include <vtkUnstructuredGrid.h>
#include <vtkXMLPolyDataReader.h>
#include <vtkXMLUnstructuredGridReader.h>

#include <fmt/format.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "base/error.h"
#include "scene/fast_configuration.h"
#include "scene/run_outputs.h"
#include "scene/sim_output.h"
#include "support/png_stats.h"
#include "support/scene_helpers.h"

using namespace vx;
namespace fs = std::filesystem;
using json = nlohmann::json;

using namespace vx::testing;

TEST(Scene, ParsesAValidSceneWithDefaults) {
  const Scene s = parse_scene(base_scene(), ".", "test.json");
  EXPECT_EQ(s.object.source, ObjectSource::box);
  EXPECT_EQ(s.object.build.layout, Layout::gradational);
  EXPECT_DOUBLE_EQ(s.material.base.youngs_modulus_kpa, 10.0);
  EXPECT_EQ(s.integrator, IntegratorKind::symplectic_euler);
  EXPECT_DOUBLE_EQ(s.dt_s, 0.0);  // auto
  ASSERT_EQ(s.probes.size(), 1u);
  EXPECT_EQ(s.probes[0].geometry.shape, ProbeShape::sphere);
  EXPECT_EQ(s.probes[0].drive, ProbeDrive::path);
  EXPECT_FALSE(s.device.has_value());
  EXPECT_FALSE(s.workspace.enabled);
  EXPECT_TRUE(s.outputs.forces_csv);
  EXPECT_FALSE(s.outputs.pvd_model);
  EXPECT_DOUBLE_EQ(s.duration_s, 0.05);
  EXPECT_EQ(s.material.element, ElementKind::hourglass);
}

TEST(Scene, TheElementIsChosenByName) {
  json j = base_scene();
  j["material"]["element"] = "paper";
  const Scene s = parse_scene(j, ".", "t");
  EXPECT_EQ(s.material.element, ElementKind::paper);
  EXPECT_EQ(prepare_scene(s).physics->element, ElementKind::paper);
  j["material"]["element"] = "hourglass";
  EXPECT_TRUE(prepare_scene(parse_scene(j, ".", "t")).physics->has_bending_modes());
  j["material"]["element"] = "quadratic";
  EXPECT_CONTAINS(error_of(j), "$.material.element: unknown element \"quadratic\"");
}

TEST(Scene, EverySampleSceneLoadsAndPrepares) {
  int n = 0;
  for (const auto& e : fs::directory_iterator(fs::path(VX_SAMPLES_DIR) / "scenes")) {
    if (e.path().extension() != ".json") continue;
    ++n;
    SCOPED_TRACE(e.path().string());
    const Scene s = load_scene(e.path());
    EXPECT_FALSE(s.description.empty()) << "samples explain themselves";
    const PreparedScene p = prepare_scene(s);
    EXPECT_GT(p.model->num_elements(), 0);
    EXPECT_GT(p.settings.integrator.time_step_s, 0.0);
    for (const auto& w : p.warnings) std::printf("%s: warning: %s\n", e.path().filename().c_str(), w.c_str());
    Simulation sim(p.physics, p.settings);
    for (int k = 0; k < 5; ++k) EXPECT_EQ(sim.step(), StepStatus::ok);
  }
  EXPECT_GE(n, 5);
}

// Issue 27: every sample scene says which Poisson ratio it uses and why. Its material names the
// ratio, its description gives it ("Poisson 0.45: ...") with the reason, and the organ samples,
// palpation of an organ, use tissue's 0.45 (the probe app's default for volumes and models).
TEST(Scene, EverySampleSaysWhichPoissonRatioItUsesAndWhy) {
  int n = 0;
  for (const char* folder : {"scenes", "organ"})
    for (const auto& e : fs::directory_iterator(fs::path(VX_SAMPLES_DIR) / folder)) {
      if (e.path().extension() != ".json") continue;
      ++n;
      SCOPED_TRACE(e.path().string());
      std::ifstream in(e.path());
      const nlohmann::json j = nlohmann::json::parse(in);
      ASSERT_TRUE(j.at("material").contains("poisson_ratio")) << "the ratio named, not the core's default";
      const double nu = j.at("material").at("poisson_ratio").get<double>();
      const std::string said = fmt::format("Poisson {:g}: ", nu);
      EXPECT_NE(j.at("description").get<std::string>().find(said), std::string::npos) << "no \"" << said << "\"";
      if (std::string(folder) == "organ") {
        EXPECT_EQ(nu, 0.45);
      }
    }
  EXPECT_GE(n, 13);
}

// The palpation demo's block and lesion, its tool pressed 5 mm (more than a 4 mm surface
// element) and slid across the lesion on a path: the tissue must hold the tool up all along.
// The frictionless tip lets the surface layer fold around it at x = -7 mm; with only surface
// nodes colliding the vertical force then fell to 0.00 N for the rest of the slide (measured);
// the nodes below the surface collide too and hold it (0.29 N rising to 0.94 N over the lesion).
TEST(Scene, DeepPalpationOfTheSampleKeepsTheTissueUnderTheTool) {
  json j = json::parse(std::ifstream(fs::path(VX_SAMPLES_DIR) / "scenes" / "palpation-lesion.json"));
  json& tool = j["probes"][0];
  tool.erase("live");
  tool["path"] = {{{"t_s", 0.0}, {"position_mm", {-15, 0, 16}}},
                  {{"t_s", 0.5}, {"position_mm", {-15, 0, 16}}},
                  {{"t_s", 1.345}, {"position_mm", {-15, 0, 7.98}}},
                  {{"t_s", 2.0}, {"position_mm", {-15, 0, 7.98}}},
                  {{"t_s", 7.5}, {"position_mm", {14, 0, 7.98}}}};
  const PreparedScene p = prepare_scene(parse_scene(j, fs::path(VX_SAMPLES_DIR) / "scenes", "deep.json"));
  Simulation sim(p.physics, p.settings);
  double sum = 0, lowest = 1e9;
  int n = 0;
  while (sim.time_s() < 5.0) {
    ASSERT_EQ(sim.step(), StepStatus::ok) << sim.state().message;
    if (sim.time_s() < 2.0) continue;
    sum += sim.probe(0).raw_force_n.z();
    if (++n * sim.dt_s() >= 0.5) {  // mean over 0.5 s (about 2.6 mm of slide)
      lowest = std::min(lowest, sum / n);
      sum = 0;
      n = 0;
    }
  }
  EXPECT_GT(lowest, 0.15) << "the tool sank through the tissue surface";
}

TEST(Scene, UnknownKeysNameTheirJsonPath) {
  json j = base_scene();
  j["probes"][0]["colour"] = "red";
  const std::string m = error_of(j);
  EXPECT_CONTAINS(m, "test.json: $.probes[0].colour");
  EXPECT_CONTAINS(m, "unknown key \"colour\"");
  EXPECT_CONTAINS(m, "\"radius_mm\"");  // lists what is allowed

  j = base_scene();
  j["probes"][0]["raduis_mm"] = j["probes"][0]["radius_mm"];
  j["probes"][0].erase("radius_mm");
  EXPECT_CONTAINS(error_of(j), "did you mean \"radius_mm\"?");

  j = base_scene();
  j["durations_s"] = 1;
  EXPECT_CONTAINS(error_of(j), "$.durations_s");
}

TEST(Scene, WrongUnitsAreCaught) {
  // the modulus in Pa
  json j = base_scene();
  j["material"].erase("youngs_modulus_kpa");
  j["material"]["youngs_modulus_pa"] = 10000;
  std::string m = error_of(j);
  EXPECT_CONTAINS(m, "$.material.youngs_modulus_pa");
  EXPECT_CONTAINS(m, "given in kPa as \"youngs_modulus_kpa\"");
  // a radius without unit
  j = base_scene();
  j["probes"][0]["radius"] = 3;
  j["probes"][0].erase("radius_mm");
  EXPECT_CONTAINS(error_of(j), "radius is given in mm as \"radius_mm\"");
  // gravity in mm/s^2
  j = base_scene();
  j["gravity"] = {0, 0, -9810};
  m = error_of(j);
  EXPECT_CONTAINS(m, "$.gravity");
  EXPECT_CONTAINS(m, "m/s^2");
  j = base_scene();
  j["gravity_mm_s2"] = {0, 0, -9810};
  EXPECT_CONTAINS(error_of(j), "gravity is given in m/s^2 as \"gravity\"");
  // density in g/cm^3
  j = base_scene();
  j["material"]["density_kg_m3"] = 1.05;
  m = error_of(j);
  EXPECT_CONTAINS(m, "$.material.density_kg_m3");
  EXPECT_CONTAINS(m, "g/cm^3");
  // a time step in ms
  j = base_scene();
  j["integrator"]["dt_s"] = 0.5;
  EXPECT_CONTAINS(error_of(j), "$.integrator.dt_s");
  // units written into the value
  j = base_scene();
  j["probes"][0]["radius_mm"] = "3 mm";
  m = error_of(j);
  EXPECT_CONTAINS(m, "$.probes[0].radius_mm");
  EXPECT_CONTAINS(m, "expected a number in mm");
}

TEST(Scene, ImpossibleValuesAreCaught) {
  json j = base_scene();
  j["material"]["poisson_ratio"] = 0.5;
  EXPECT_CONTAINS(error_of(j), "$.material.poisson_ratio: must be in [0, 0.5)");
  j = base_scene();
  j["material"]["youngs_modulus_kpa"] = -3;
  EXPECT_CONTAINS(error_of(j), "$.material.youngs_modulus_kpa: must be > 0 kPa");
  j = base_scene();
  j["probes"][0]["radius_mm"] = 0;
  EXPECT_CONTAINS(error_of(j), "$.probes[0].radius_mm");
  j = base_scene();
  j["probes"][0]["path"][1]["t_s"] = 0;
  EXPECT_CONTAINS(error_of(j), "$.probes[0].path[1].t_s: keyframe times must increase");
  j = base_scene();
  j["probes"][0]["path"][1]["position_mm"] = {1, 2};
  EXPECT_CONTAINS(error_of(j), "$.probes[0].path[1].position_mm: expected 3 numbers");
  j = base_scene();
  j["contact"] = {{"restitution", 1.5}};
  EXPECT_CONTAINS(error_of(j), "$.contact.restitution");
  j = base_scene();
  j["workspace_mm"] = {{"min", {0, 0, 0}}, {"max", {10, -1, 10}}};
  EXPECT_CONTAINS(error_of(j), "$.workspace_mm: min must be below max");
  j = base_scene();
  j["duration_s"] = 0;
  EXPECT_CONTAINS(error_of(j), "$.duration_s");
  j = base_scene();
  j.erase("duration_s");
  EXPECT_CONTAINS(error_of(j), "missing \"duration_s\"");
  j = base_scene();
  j["object"]["box_mm"]["max"] = {12.5, 12, 6};
  EXPECT_CONTAINS(error_of(j), "not a whole number of 1 mm voxels");
  j = base_scene();
  j["fixed"] = {"bottom"};
  EXPECT_CONTAINS(error_of(j), "$.fixed[0]: unknown face \"bottom\"");
  j = base_scene();
  j["device"] = {{"force_shaping", "fast"}};
  EXPECT_CONTAINS(error_of(j), "$.device.force_shaping: unknown force shaping \"fast\"");
  j = base_scene();
  j["device"] = {{"device_damping_n_s_m", 0}};
  EXPECT_CONTAINS(error_of(j), "$.device.device_damping_n_s_m: must be > 0 N s/m");
}

TEST(Scene, DeviceBlockPicksTheForceShaping) {
  json j = base_scene();
  j["device"] = json::object();
  Scene s = parse_scene(j, ".", "test.json");
  ASSERT_TRUE(s.device.has_value());
  EXPECT_EQ(s.device->shaping, ForceShaping::paper);  // the paper's half sines unless asked
  EXPECT_DOUBLE_EQ(s.device->device_damping_n_s_mm, 1.5e-3);
  j["device"] = {{"force_shaping", "local"}, {"device_damping_n_s_m", 3.0}};
  s = parse_scene(j, ".", "test.json");
  EXPECT_EQ(s.device->shaping, ForceShaping::local);
  EXPECT_DOUBLE_EQ(s.device->device_damping_n_s_mm, 3e-3);
}

TEST(Scene, ShapesAndDrivesAreChecked) {
  json j = base_scene();
  j["probes"][0]["shape"] = "cube";
  EXPECT_CONTAINS(error_of(j), "$.probes[0].shape: unknown probe shape \"cube\"");
  j = base_scene();
  j["probes"][0]["shape"] = "plane";
  EXPECT_CONTAINS(error_of(j), "$.probes[0].radius_mm: a plane has no radius");
  j = base_scene();
  j["probes"][0] = {{"shape", "plane"}, {"path", {{{"t_s", 0}, {"position_mm", {0, 0, 0}}}}}};
  EXPECT_CONTAINS(error_of(j), "$.probes[0]: a plane needs \"normal\"");
  j = base_scene();
  j["probes"][0]["shape"] = "cylinder";
  EXPECT_CONTAINS(error_of(j), "missing \"length_mm\"");
  j = base_scene();
  j["probes"][0]["axis"] = {0, 0, 1};
  EXPECT_CONTAINS(error_of(j), "$.probes[0].axis: a sphere has no axis");
  j = base_scene();
  j["probes"][0]["live"] = {{"start_mm", {0, 0, 0}}};
  EXPECT_CONTAINS(error_of(j), "needs exactly one of \"path\", \"joystick\", \"live\", found \"path\" and \"live\"");
  j = base_scene();
  j["probes"][0].erase("path");
  j["probes"][0]["joystick"] = {{"start_mm", {6, 6, 9}}, {"input", {{{"t_s", 0}, {"axes", {1.5, 0}}}}}};
  EXPECT_CONTAINS(error_of(j), "$.probes[0].joystick.input[0].axes[0]: a stick deflection must be in [-1, 1]");
  j = base_scene();
  j["probes"].push_back(j["probes"][0]);
  EXPECT_CONTAINS(error_of(j), "$.probes[1].name: probe names must be unique");
  // a capsule with an axis that is not unit length is normalised
  j = base_scene();
  j["probes"][0]["shape"] = "capsule";
  j["probes"][0]["length_mm"] = 20;
  j["probes"][0]["axis"] = {0, 0, 2};
  const Scene s = parse_scene(j, ".", "test.json");
  EXPECT_NEAR(s.probes[0].geometry.axis.z(), 1.0, 1e-15);
}

TEST(Scene, ObjectSourcesAreExclusiveAndPathsChecked) {
  json j = base_scene();
  j["object"]["phantom"] = "sphere";
  EXPECT_CONTAINS(error_of(j), "$.object: the object needs exactly one of");
  j = base_scene();
  j["object"] = {{"volume", "no/such/file.nrrd"}};
  std::string m = error_of(j);
  EXPECT_CONTAINS(m, "$.object.volume");
  EXPECT_CONTAINS(m, "does not exist");
  j = base_scene();
  j["object"] = {{"phantom", "dodecahedron"}};
  EXPECT_CONTAINS(error_of(j), "unknown phantom \"dodecahedron\"");
  j = base_scene();
  j["material"]["hounsfield_table"] = {{{"hu", 0}, {"youngs_modulus_kpa", 5}},
                                       {{"hu", 100}, {"youngs_modulus_kpa", 50}}};
  EXPECT_CONTAINS(error_of(j), "$.material.hounsfield_table: needs the object's HU values");
}

TEST(Scene, InvalidJsonSaysWhere) {
  const std::string m = error_of_text("{\n  \"object\": {\"phantom\": \"sphere\"},\n  \"duration_s\": 1,,\n}");
  EXPECT_CONTAINS(m, "test.json: not valid JSON");
  EXPECT_CONTAINS(m, "line 3");
  // comments are allowed
  EXPECT_EQ(error_of_text("{ // a comment\n \"object\": {\"phantom\": \"sphere\"}, \"duration_s\": 1}"), "");
}

TEST(Scene, SliceScenesPalpateInThePlaneAndRefuseWhatHasNoCutThere) {
  // the 2D press sample: a one-slice disk-lesion phantom becomes a 2D model; the circle pressed
  // over the lesion meets 1.31 times the force of the same press on homogeneous tissue (the
  // lesion is felt); the force lies in the slice plane
  const fs::path dir = fs::path(VX_SAMPLES_DIR) / "scenes";
  json j = json::parse(std::ifstream(dir / "disk_press_2d.json"));
  j.erase("outputs");
  const auto press = [&](const json& scene) {
    PrepareSceneOptions opt;
    opt.surface = true;
    const PreparedScene p = prepare_scene(parse_scene(scene, dir, "press.json"), opt);
    EXPECT_TRUE(p.model->is_2d());
    EXPECT_EQ(p.model->grid.dims.z(), 1);
    EXPECT_EQ(p.surface->method, SurfaceMethod::slice);
    Simulation sim(p.physics, p.settings);
    while (sim.time_s() < scene.at("duration_s").get<double>() - 0.5 * sim.dt_s()) {
      EXPECT_EQ(sim.step(), StepStatus::ok);
      EXPECT_EQ(sim.probe(0).raw_force_n.z(), 0.0);
    }
    return sim.probe(0).raw_force_n.y();
  };
  const double over = press(j);
  json homogeneous = j;
  homogeneous["material"].erase("hounsfield_table");
  const double plain = press(homogeneous);
  EXPECT_GT(plain, 0.0);
  EXPECT_GT(over / plain, 1.15) << "over " << over << " N, homogeneous " << plain << " N";
  // a face across the slice would hold all of it; a capsule along the normal has no cut
  json bad = j;
  bad["fixed"] = {"z_min"};
  EXPECT_THROW(
      {
        try {
          (void)prepare_scene(parse_scene(bad, dir, "bad.json"));
        } catch (const Error& e) {
          EXPECT_NE(std::string(e.what()).find("across the slice"), std::string::npos) << e.what();
          throw;
        }
      },
      Error);
  bad = j;
  bad["probes"][0]["shape"] = "capsule";
  bad["probes"][0]["axis"] = {0, 0, 1};
  bad["probes"][0]["length_mm"] = 20;
  EXPECT_THROW(
      {
        try {
          (void)prepare_scene(parse_scene(bad, dir, "bad.json"));
        } catch (const Error& e) {
          EXPECT_NE(std::string(e.what()).find("2D model"), std::string::npos) << e.what();
          throw;
        }
      },
      Error);
  // thickness_mm belongs to the one-slice phantoms
  bad = json::parse(R"({"object": {"phantom": "sphere", "size": 20, "thickness_mm": 2}, "duration_s": 0.01})");
  EXPECT_THROW((void)parse_scene(bad, ".", "bad.json"), Error);
}

TEST(Scene, SliceGraspSampleLiftsTheDiskAndHoldsItAfterTheLift) {
  // the paper's figure 9 (samples/scenes/disk_grasp_2d.json): two circles squeeze the disk, lift
  // it 10 mm and hold it. After the lift has stopped (0.8 s) the disk hangs 8 to 10.5 mm up (the
  // mass-weighted mean of its nodes' lift) and the probes carry its weight (the mean of their
  // vertical forces over 1.0-1.4 s: the weight within 25 %: it still swings a little); without
  // friction it falls. (Gripped exactly at its middle the disk used to creep down once the
  // circles stopped and fall 0.15 s later: docs/scenes.md, "Grasping".)
  const fs::path dir = fs::path(VX_SAMPLES_DIR) / "scenes";
  json j = json::parse(std::ifstream(dir / "disk_grasp_2d.json"));
  j.erase("outputs");
  struct Lift {
    double lift_mm, carried_n, weight_n, squeeze_n;
  };
  const auto grasp = [&](const json& scene) {
    const PreparedScene p = prepare_scene(parse_scene(scene, dir, "grasp.json"));
    EXPECT_TRUE(p.model->is_2d());
    Simulation sim(p.physics, p.settings);
    const double end = scene.at("duration_s").get<double>();
    double carried = 0;
    int samples = 0;
    while (sim.time_s() < end - 0.5 * sim.dt_s()) {
      EXPECT_EQ(sim.step(), StepStatus::ok);
      if (sim.time_s() >= 1.0) {
        carried -= sim.probe(0).raw_force_n.y() + sim.probe(1).raw_force_n.y();
        ++samples;
      }
    }
    const Eigen::Matrix3Xd& x = sim.state().positions;
    double lift = 0, mass = 0;
    for (int i = 0; i < p.model->num_nodes(); ++i) {
      const double m = p.physics->node_mass_kg[std::size_t(i)];
      lift += m * (x(1, i) - p.model->rest_positions(1, i));
      mass += m;
    }
    return Lift{lift / mass, carried / std::max(samples, 1), 9.81 * p.physics->total_mass_kg(),
                std::min(-sim.probe(0).raw_force_n.x(), sim.probe(1).raw_force_n.x())};
  };
  const Lift held = grasp(j);
  EXPECT_GT(held.lift_mm, 8.0);
  EXPECT_LT(held.lift_mm, 10.5);
  EXPECT_NEAR(held.carried_n, held.weight_n, 0.25 * held.weight_n);
  EXPECT_GT(held.squeeze_n, 0.01);
  std::printf("2D grasp: lifted %.2f mm of 10; the probes carry %.4f N of the weight %.4f N; squeeze %.4f N\n",
              held.lift_mm, held.carried_n, held.weight_n, held.squeeze_n);
  j["contact"]["friction"] = 0.0;
  const Lift slipped = grasp(j);
  EXPECT_LT(slipped.lift_mm, 5.0) << "without friction the disk should fall";
}

TEST(Scene, ModelFileObjectRebuildsItsGrid) {
  // grid_from_model covers exactly the voxels of the model it came from
  const PreparedScene p = prepare_scene(parse_scene(json::parse(R"({"object": {"phantom": "torus", "size": 24},
                                                                     "duration_s": 0.01})"),
                                                    ".", "t"));
  const VoxelGrid g = grid_from_model(*p.model);
  EXPECT_EQ(g.data(), p.grid.data());
}

TEST(SimOutput, ForcesCsvPvdAndSkippingThroughAScene) {
  json j = base_scene();
  j["device"] = {{"update_interval_s", 0.004}};
  j["workspace_mm"] = {{"min", {-1, -1, -1}}, {"max", {13, 13, 20}}};
  const Scene s = parse_scene(j, ".", "test.json");
  PrepareSceneOptions lean_opt, full_opt;
  lean_opt.surface = full_opt.surface = true;
  full_opt.skip_unneeded = false;
  const PreparedScene lean_p = prepare_scene(s, lean_opt), full_p = prepare_scene(s, full_opt);
  Simulation lean(lean_p.physics, lean_p.settings), full(full_p.physics, full_p.settings);
  const DeviceSide lean_device(lean, lean_p.device_side), full_device(full, full_p.device_side);
  ForceRecorder rec(lean, &lean_device, 0.002);
  const fs::path dir = temp_dir("out");
  PvdSeries series(dir, "model", "vtu"), surf(dir, "surface", "vtp");
  ModelFrameWriter mw(*lean_p.model);
  SurfaceFrameWriter sw(*lean_p.surface);
  while (lean.time_s() < s.duration_s) {
    ASSERT_EQ(lean.step(), StepStatus::ok);
    ASSERT_EQ(full.step(), StepStatus::ok);
    ASSERT_EQ(lean.probe(0).raw_force_n, full.probe(0).raw_force_n);
    ASSERT_EQ(lean_device.output(0).shaped_force_n, full_device.output(0).shaped_force_n);
    rec.record(lean);
  }
  rec.finish(lean);
  EXPECT_EQ(lean.state().positions, full.state().positions);
  // the surface the lean run deforms on demand equals the one the full run kept up to date
  EXPECT_EQ(lean.surface_vertices(), full.surface_vertices());
  EXPECT_EQ(lean.counters().surface_updates, 1);
  EXPECT_EQ(full.counters().surface_updates, full.counters().steps);
  EXPECT_GT(lean.counters().contact.narrow_tests_skipped, 0);
  EXPECT_EQ(full.counters().contact.narrow_tests_skipped, 0);

  // forces.csv
  rec.write_csv(dir / "forces.csv");
  std::ifstream in(dir / "forces.csv");
  std::string header, line, last;
  std::getline(in, header);
  EXPECT_EQ(header, "time_s,probe,x_mm,y_mm,z_mm,fx_n,fy_n,fz_n,dfx_n,dfy_n,dfz_n");
  int rows = 0;
  while (std::getline(in, line)) ++rows, last = line;
  EXPECT_EQ(rows, int(rec.rows().size()));
  EXPECT_GE(rows, 25);  // 0.05 s every 2 ms, plus t = 0
  EXPECT_NE(last.find(",ball,6,6,8.2"), std::string::npos) << last;
  EXPECT_GT(rec.rows().back().raw_n.z(), 0.0);  // pressed: the tissue pushes the ball up
  // the rows' raw force is the mean over their steps: its time integral equals the total impulse
  double impulse_rows = 0;
  for (std::size_t r = 1; r < rec.rows().size(); ++r)
    impulse_rows += rec.rows()[r].raw_n.z() * (rec.rows()[r].time_s - rec.rows()[r - 1].time_s);
  EXPECT_GT(impulse_rows, 0.0);

  // pvd frames read back with displacement_mm
  mw.write(lean.state().positions, lean.state().velocities, series.next_frame_path());
  series.add(lean.time_s());
  series.finish();
  sw.write(lean.surface_vertices(), surf.next_frame_path());
  surf.add(lean.time_s());
  surf.finish();
  vtkNew<vtkXMLUnstructuredGridReader> r;
  r->SetFileName((dir / "model" / "model_000000.vtu").c_str());
  r->Update();
  vtkUnstructuredGrid* ug = r->GetOutput();
  ASSERT_EQ(ug->GetNumberOfPoints(), lean_p.model->num_nodes());
  EXPECT_EQ(ug->GetNumberOfCells(), lean_p.model->num_elements());
  vtkDataArray* d = ug->GetPointData()->GetArray("displacement_mm");
  ASSERT_NE(d, nullptr);
  double maxd = 0;
  for (vtkIdType i = 0; i < d->GetNumberOfTuples(); ++i) {
    const double* t = d->GetTuple3(i);
    maxd = std::max(maxd, std::sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]));
    const Eigen::Vector3d expect = lean.state().positions.col(int(i)) - lean_p.model->rest_positions.col(int(i));
    ASSERT_NEAR(t[2], expect.z(), 1e-12);
  }
  EXPECT_GT(maxd, 0.5);  // the ball pushed the surface about 1 mm
  vtkNew<vtkXMLPolyDataReader> pr;
  pr->SetFileName((dir / "surface" / "surface_000000.vtp").c_str());
  pr->Update();
  EXPECT_EQ(pr->GetOutput()->GetNumberOfPoints(), lean_p.surface->num_vertices());
  EXPECT_NE(pr->GetOutput()->GetPointData()->GetArray("displacement_mm"), nullptr);
  // frames carry their coordinate system as 3D Slicer reads it
  for (vtkDataObject* frame : {static_cast<vtkDataObject*>(ug), static_cast<vtkDataObject*>(pr->GetOutput())}) {
    auto* space = vtkStringArray::SafeDownCast(frame->GetFieldData()->GetAbstractArray("SPACE"));
    ASSERT_NE(space, nullptr);
    EXPECT_EQ(space->GetValue(0), "LPS");
  }
  std::ifstream pvd(dir / "model.pvd");
  std::stringstream text;
  text << pvd.rdbuf();
  EXPECT_NE(text.str().find("file=\"model/model_000000.vtu\""), std::string::npos);

  // the plot: a real picture, with the analytic curve of this scene (a ball into a block)
  const std::vector<ForceReference> refs = scene_force_references(s);
  ASSERT_EQ(refs.size(), 1u);
  plot_forces(rec, dir / "forces.png", refs);
  const auto png = vx::testing::png_stats(dir / "forces.png");
  EXPECT_EQ(png.width, 1000);
  EXPECT_EQ(png.height, 880);
  EXPECT_GT(png.drawn, 20000);
  EXPECT_GT(png.colours, 50);
  fs::remove_all(dir);
}

TEST(SimOutput, PressesAreIntervalsOfContact) {
  // one probe pressing twice (rows 2-9 and 16-20), a flicker of 2 rows inside the first press,
  // a one-row touch that is no press; a second probe pressing once
  std::vector<ForceRow> rows;
  auto row = [&](int probe, double t, int contacts) {
    ForceRow r;
    r.probe = probe;
    r.time_s = t;
    r.contacts = contacts;
    rows.push_back(r);
  };
  const int a[] = {0, 0, 1, 1, 1, 0, 0, 1, 1, 1, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 1, 0};
  for (int i = 0; i < int(std::size(a)); ++i) {
    row(0, i * 0.01, a[i]);
    row(1, i * 0.01, i >= 5 && i < 12 ? 3 : 0);
  }
  const std::vector<Press> p = find_presses(rows);
  ASSERT_EQ(p.size(), 3u);
  EXPECT_EQ(p[0].probe, 0);
  EXPECT_NEAR(p[0].start_s, 0.02, 1e-12);
  EXPECT_NEAR(p[0].end_s, 0.09, 1e-12);
  EXPECT_EQ(p[1].probe, 1);
  EXPECT_NEAR(p[1].start_s, 0.05, 1e-12);
  EXPECT_NEAR(p[1].end_s, 0.11, 1e-12);
  EXPECT_EQ(p[2].probe, 0);
  EXPECT_NEAR(p[2].start_s, 0.16, 1e-12);
  EXPECT_NEAR(p[2].end_s, 0.20, 1e-12);
  EXPECT_EQ(rows[p[2].first].time_s, p[2].start_s);
}

TEST(SimOutput, HertzReferenceOnlyWhereTheSceneIsHertzs) {
  // the finite-layer formula: Hertz's half-space for a thick layer, stiffer for a thin one
  EXPECT_NEAR(hertz_bonded_layer_n(10, 0, 8, 2, 1e12), 4.0 / 3.0 * 0.01 * std::sqrt(8.0) * std::pow(2.0, 1.5), 1e-12);
  EXPECT_NEAR(hertz_bonded_layer_n(10, 0, 8, 2, 20), 0.1271, 1e-4);  // samples/scenes/indent_sphere.json quotes it
  EXPECT_GT(hertz_bonded_layer_n(10, 0.3, 8, 2, 20), hertz_bonded_layer_n(10, 0, 8, 2, 20));
  const Scene indent = load_scene(fs::path(VX_SAMPLES_DIR) / "scenes" / "indent_sphere.json");
  const auto refs = scene_force_references(indent);
  ASSERT_EQ(refs.size(), 1u);
  EXPECT_EQ(refs[0].e_kpa, 10);
  EXPECT_EQ(refs[0].radius_mm, 8);
  EXPECT_EQ(refs[0].layer_mm, 20);
  EXPECT_NE(refs[0].title.find("finite-layer Hertz"), std::string::npos);
  // a lesion, a second support, a sideways path or another shape: no formula applies
  json j = base_scene();
  EXPECT_EQ(scene_force_references(parse_scene(j, ".", "t")).size(), 1u);
  j["material"]["inclusions"] = json::array({{{"center_mm", {6, 6, 3}}, {"radius_mm", 2}, {"youngs_modulus_kpa", 50}}});
  EXPECT_TRUE(scene_force_references(parse_scene(j, ".", "t")).empty());
  j = base_scene();
  j["fixed"] = {"z_min", "x_min"};
  EXPECT_TRUE(scene_force_references(parse_scene(j, ".", "t")).empty());
  j = base_scene();
  j["probes"][0]["path"][1]["position_mm"] = {7, 6, 8.2};
  EXPECT_TRUE(scene_force_references(parse_scene(j, ".", "t")).empty());
  j = base_scene();
  j["probes"][0]["shape"] = "cylinder";
  j["probes"][0]["length_mm"] = 10;
  EXPECT_TRUE(scene_force_references(parse_scene(j, ".", "t")).empty());
  for (const char* other : {"palpate_lesion.json", "tap_rebound.json", "grasp_lift.json", "compress_plate.json"})
    EXPECT_TRUE(scene_force_references(load_scene(fs::path(VX_SAMPLES_DIR) / "scenes" / other)).empty()) << other;
}

TEST(Scene, NumbersBeyondADoubleAreInvalidJsonNotAnInternalError) {
  // found by fuzzing: nlohmann's number overflow is an out_of_range, not a parse_error
  const std::string e = error_of_text(R"({"duration_s": 22e62222})");
  EXPECT_CONTAINS(e, "test.json: not valid JSON");
  EXPECT_CONTAINS(e, "number overflow");
}

TEST(Scene, RunsThatCannotFinishAreRefused) {
  // dt_s 1e-9 over a second: 1e9 steps, nothing bounded it (issue #17)
  json j = base_scene();
  j["integrator"]["dt_s"] = 1e-9;
  j["duration_s"] = 1.0;
  j["probes"][0]["path"][1]["t_s"] = 1.0;
  try {
    (void)prepare_scene(parse_scene(j, ".", "t.json"));
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_CONTAINS(e.what(), "$.integrator.dt_s");
    EXPECT_CONTAINS(e.what(), "1e+09 steps");
    EXPECT_CONTAINS(e.what(), "\"auto\" picks");
  }
  // keyframes and stick samples far in the future, and durations beyond a day
  for (const double t : {1e9, 1e308}) {
    json k = base_scene();
    k["probes"][0]["path"][1]["t_s"] = t;
    EXPECT_CONTAINS(error_of(k), "$.probes[0].path[1].t_s");
    EXPECT_CONTAINS(error_of(k), "beyond the longest scene");
  }
  json d = base_scene();
  d["duration_s"] = 2e5;
  EXPECT_CONTAINS(error_of(d), "at most 100000 s");
}

TEST(Scene, LatticeOriginKey) {
  // docs/model.md 3.5: a phantom's grid starts where the model has the fewest vertex entries,
  // unless "crop" keeps the crop's margin; a box or a model file has no crop to move
  json j = base_scene();
  j["object"] = {{"phantom", "cube"}, {"size", 24}, {"spacing_mm", 1.0}};
  j["fixed"] = json::array();
  const Scene best = parse_scene(j, ".", "t");
  EXPECT_EQ(best.object.prepare.lattice_period, 4);
  j["object"]["lattice_origin"] = "crop";
  const Scene crop = parse_scene(j, ".", "t");
  EXPECT_EQ(crop.object.prepare.lattice_period, 0);
  const PreparedScene pb = prepare_scene(best), pc = prepare_scene(crop);
  EXPECT_LT(pb.model->num_vertex_entries(), pc.model->num_vertex_entries());
  EXPECT_EQ(pb.model->covered_voxels(), pc.model->covered_voxels());
  EXPECT_TRUE(pb.bounds_min_mm.isApprox(pc.bounds_min_mm));
  EXPECT_TRUE(pb.bounds_max_mm.isApprox(pc.bounds_max_mm));
  j["object"]["lattice_origin"] = "centre";
  EXPECT_CONTAINS(error_of(j), "$.object.lattice_origin: unknown lattice origin \"centre\"");
  j = base_scene();
  j["object"]["lattice_origin"] = "best";
  EXPECT_CONTAINS(error_of(j), "lattice_origin does not apply to a box");
}

TEST(Scene, PhantomLesionPlacedAndSized) {
  // block-lesion 32: the block is 24 x 18 x 12 mm centred at the origin
  json j = base_scene();
  j["object"] = {{"phantom", "block-lesion"}, {"size", 32}, {"lesion_center_mm", {-3, 2, 1}}, {"lesion_radius_mm", 3}};
  const Scene s = parse_scene(j, ".", "test.json");
  ASSERT_TRUE(s.object.phantom.lesion_center_mm.has_value());
  EXPECT_EQ(*s.object.phantom.lesion_center_mm, Eigen::Vector3d(-3, 2, 1));
  EXPECT_EQ(s.object.phantom.lesion_radius_mm, 3.0);
  EXPECT_EQ(phantom_shape(s.object.phantom).lesion_center_mm, Eigen::Vector3d(-3, 2, 1));
  // out through the top (1 + 6 > 6), a bad radius, and the keys on objects without a lesion
  j["object"]["lesion_center_mm"] = {0, 0, 1};
  j["object"]["lesion_radius_mm"] = 6;
  EXPECT_CONTAINS(error_of(j), "$.object.lesion_center_mm: a lesion of radius 6 mm");
  EXPECT_CONTAINS(error_of(j), "does not fit inside the block");
  j["object"]["lesion_radius_mm"] = -1;
  EXPECT_CONTAINS(error_of(j), "$.object.lesion_radius_mm: must be > 0 mm");
  j["object"] = {{"phantom", "sphere"}, {"size", 32}, {"lesion_radius_mm", 3}};
  EXPECT_CONTAINS(error_of(j), "has no lesion");
  j = base_scene();
  j["object"]["lesion_radius_mm"] = 3;
  EXPECT_CONTAINS(error_of(j), "lesion_radius_mm does not apply to a box");
}
