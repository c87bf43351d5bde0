// evaluation/bench/bench.h: the Pareto front, the force-curve error, the best configuration for real
// time, the log-log slope, the CSV files, the palpation scene, and a small real bench written
// all-or-nothing.
#include "bench/bench.h"
#include "bench/scale_bench.h"
#include "sim/time_step.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "base/error.h"
#include "convert/phantom.h"
#include "scene/fast_configuration.h"
#include "scene/scene.h"
#include "support/png_stats.h"

namespace fs = std::filesystem;
using json = nlohmann::json;
using namespace vx;

namespace {

/// A usable row at (wall s per simulated s, RMS error).
BenchRow point(double wall, double err, BenchStatus status = BenchStatus::ok) {
  BenchRow r;
  r.wall_per_sim_s = wall;
  r.error.rms_rel = err;
  r.status = status;
  return r;
}

/// Splits one CSV line (double-quoted fields may hold commas and "" quotes).
std::vector<std::string> split_csv(const std::string& line) {
  std::vector<std::string> out(1);
  bool quoted = false;
  for (std::size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        out.back() += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        out.back() += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      out.emplace_back();
    } else {
      out.back() += c;
    }
  }
  return out;
}

std::vector<std::string> lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

TEST(BenchPareto, KnownPointsGiveTheFrontByWallTime) {
  std::vector<BenchRow> rows{point(1.0, 0.5),
                             point(2.0, 0.3),
                             point(3.0, 0.4),  // dominated by (2, 0.3)
                             point(0.5, 0.9),
                             point(4.0, 0.1),
                             point(4.0, 0.2),                          // dominated by (4, 0.1)
                             point(2.5, 0.3),                          // dominated: same error, slower
                             point(0.1, 0.01, BenchStatus::unstable),  // would dominate all: excluded
                             point(0.2, 0.02, BenchStatus::skipped)};
  const std::vector<std::size_t> front = mark_pareto_front(rows);
  EXPECT_EQ(front, (std::vector<std::size_t>{3, 0, 1, 4}));
  const std::vector<bool> expect{true, true, false, true, true, false, false, false, false};
  for (std::size_t i = 0; i < rows.size(); ++i) EXPECT_EQ(rows[i].pareto, expect[i]) << i;
  // the flag is recomputed, not accumulated: without (4, 0.1), (4, 0.2) joins the front
  rows[4].status = BenchStatus::unstable;
  EXPECT_EQ(mark_pareto_front(rows), (std::vector<std::size_t>{3, 0, 1, 5}));
  EXPECT_FALSE(rows[4].pareto);
  EXPECT_TRUE(rows[5].pareto);
  // a row without an error (NaN) is not usable
  rows.push_back(point(0.05, std::nan("")));
  EXPECT_EQ(mark_pareto_front(rows).size(), 4u);
  EXPECT_FALSE(rows.back().pareto);
}

TEST(BenchError, ScaledCurveGivesItsScale) {
  ForceCurve ref, curve;
  double sum2 = 0;
  for (int i = 0; i <= 100; ++i) {
    const double t = 0.003 * i, f = 0.08 * std::sin(M_PI * i / 100.0);
    ref.time_s.push_back(t);
    ref.force_n.push_back(f);
    curve.time_s.push_back(t);
    curve.force_n.push_back(1.1 * f);
    sum2 += (0.1 * f) * (0.1 * f);
  }
  EXPECT_DOUBLE_EQ(peak_force_n(ref), 0.08);
  const CurveError e = force_curve_error(curve, ref);
  EXPECT_NEAR(e.rms_rel, std::sqrt(sum2 / 101) / 0.08, 1e-12);
  EXPECT_NEAR(e.rms_rel, 0.1 / std::sqrt(2.0), 2e-3);  // RMS of a half sine is peak / sqrt(2)
  EXPECT_NEAR(e.max_abs_rel, 0.1, 1e-12);
  EXPECT_NEAR(e.peak_rel, 0.1, 1e-12);
  const CurveError self = force_curve_error(ref, ref);
  EXPECT_EQ(self.rms_rel, 0.0);
  EXPECT_EQ(self.peak_rel, 0.0);
}

TEST(BenchError, OtherSampleTimesAreInterpolated) {
  // reference f = t on [0, 1] every 0.01 s; the curve f = t + 0.05 every 0.003 s (and at 1):
  // linear interpolation is exact, so every difference is 0.05
  ForceCurve ref, curve;
  for (int i = 0; i <= 100; ++i) {
    ref.time_s.push_back(0.01 * i);
    ref.force_n.push_back(0.01 * i);
  }
  for (int i = 0; i * 0.003 < 1.0; ++i) {
    curve.time_s.push_back(0.003 * i);
    curve.force_n.push_back(0.003 * i + 0.05);
  }
  curve.time_s.push_back(1.0);
  curve.force_n.push_back(1.05);
  const CurveError e = force_curve_error(curve, ref);
  EXPECT_NEAR(e.rms_rel, 0.05, 1e-12);
  EXPECT_NEAR(e.max_abs_rel, 0.05, 1e-12);
  EXPECT_NEAR(e.peak_rel, 0.05, 1e-12);
  // a curve that stopped early is held at its last value: at t = 1 it reads 0.55, 0.45 short
  ForceCurve half{{0.0, 0.5}, {0.0, 0.5}};
  EXPECT_NEAR(force_curve_error(half, ref).max_abs_rel, 0.5, 1e-12);
  EXPECT_NEAR(force_curve_error(half, ref).peak_rel, -0.5, 1e-12);
}

TEST(BenchError, BadCurvesAreRefused) {
  const ForceCurve ref{{0.0, 1.0}, {0.0, 1.0}};
  EXPECT_THROW((void)force_curve_error(ForceCurve{}, ref), Error);
  EXPECT_THROW((void)force_curve_error(ref, ForceCurve{}), Error);
  EXPECT_THROW((void)force_curve_error(ref, ForceCurve{{0.0, 1.0}, {0.0, 0.0}}), Error);  // no positive force
  EXPECT_THROW((void)force_curve_error(ForceCurve{{0.0, 1.0}, {0.0}}, ref), Error);       // lengths differ
}

TEST(BenchBest, LowestErrorWithinRealTime) {
  std::vector<BenchRow> rows{point(0.5, 0.05), point(0.9, 0.03), point(1.5, 0.01),
                             point(0.1, 0.005, BenchStatus::unstable), point(1.0, 0.04)};
  bool rt = false;
  EXPECT_EQ(best_real_time_row(rows, rt), 1);
  EXPECT_TRUE(rt);
  // exactly 1 s per s counts as real time; a tie in error goes to the faster
  rows.push_back(point(1.0, 0.03));
  rows.push_back(point(0.7, 0.03));
  EXPECT_EQ(best_real_time_row(rows, rt), 6);
  // a stricter limit
  EXPECT_EQ(best_real_time_row(rows, rt, 0.6), 0);
  EXPECT_TRUE(rt);
}

TEST(BenchBest, NearestWhenNothingIsRealTime) {
  std::vector<BenchRow> rows{point(3.0, 0.01), point(1.5, 0.2), point(2.0, 0.1),
                             point(0.5, 0.01, BenchStatus::skipped)};
  bool rt = true;
  EXPECT_EQ(best_real_time_row(rows, rt), 1);  // the fastest stable run
  EXPECT_FALSE(rt);
  std::vector<BenchRow> none{point(0.5, 0.01, BenchStatus::unstable)};
  EXPECT_EQ(best_real_time_row(none, rt), -1);
  EXPECT_FALSE(rt);
}

TEST(BenchSlope, PowerLawsGiveTheirExponent) {
  EXPECT_NEAR(log_log_slope({32, 64, 128, 256}, {3 * 32.0 * 32, 3 * 64.0 * 64, 3 * 128.0 * 128, 3 * 256.0 * 256}), 2.0,
              1e-12);
  EXPECT_NEAR(log_log_slope({10, 20, 40}, {1e3, 8e3, 64e3}), 3.0, 1e-12);
  // points with x or y <= 0 are left out
  EXPECT_NEAR(log_log_slope({0, 10, 20, 40}, {5, 1e3, 8e3, 64e3}), 3.0, 1e-12);
  EXPECT_TRUE(std::isnan(log_log_slope({10}, {100})));
  EXPECT_TRUE(std::isnan(log_log_slope({}, {})));
}

TEST(BenchCsv, ColumnsAndRows) {
  BenchRow ok = point(0.25, 0.0123);
  ok.size = 24;
  ok.voxel_mm = 32.0 / 24;
  ok.layout = Layout::uniform;
  ok.integrator = IntegratorKind::symplectic_euler;
  ok.time_step_s = 2.5e-4;
  ok.dt_fraction = 0.5;
  ok.peak_force_n = 0.0915;
  ok.error.peak_rel = -0.02;
  ok.error.max_abs_rel = 0.03;
  ok.pareto = true;
  BenchRow bad;
  bad.size = 16;
  bad.integrator = IntegratorKind::explicit_euler;
  bad.status = BenchStatus::unstable;
  bad.note = "runaway at node 3, \"fast\"";
  const std::string csv = bench_csv({ok, bad});
  const auto l = lines(csv);
  ASSERT_EQ(l.size(), 3u);
  const auto& cols = bench_csv_columns();
  EXPECT_EQ(split_csv(l[0]), cols);
  for (const std::string want : {"size", "resolution", "integrator", "dt_s", "wall_per_sim_s", "rms_error_rel",
                                 "peak_error_rel", "status", "pareto", "real_time", "threads"})
    EXPECT_NE(std::find(cols.begin(), cols.end(), want), cols.end()) << want;
  auto field = [&](const std::vector<std::string>& row, const std::string& name) {
    return row[std::size_t(std::find(cols.begin(), cols.end(), name) - cols.begin())];
  };
  const auto r1 = split_csv(l[1]), r2 = split_csv(l[2]);
  ASSERT_EQ(r1.size(), cols.size());
  ASSERT_EQ(r2.size(), cols.size());
  EXPECT_EQ(field(r1, "size"), "24");
  EXPECT_EQ(field(r1, "resolution"), "uniform");
  EXPECT_EQ(field(r1, "integrator"), "symplectic_euler");
  EXPECT_DOUBLE_EQ(std::stod(field(r1, "dt_s")), 2.5e-4);
  EXPECT_DOUBLE_EQ(std::stod(field(r1, "wall_per_sim_s")), 0.25);
  EXPECT_DOUBLE_EQ(std::stod(field(r1, "rms_error_rel")), 0.0123);
  EXPECT_DOUBLE_EQ(std::stod(field(r1, "peak_error_rel")), -0.02);
  EXPECT_EQ(field(r1, "status"), "ok");
  EXPECT_EQ(field(r1, "pareto"), "1");
  EXPECT_EQ(field(r1, "real_time"), "1");
  EXPECT_EQ(field(r2, "status"), "unstable");
  EXPECT_EQ(field(r2, "wall_per_sim_s"), "");  // NaN: empty
  EXPECT_EQ(field(r2, "rms_error_rel"), "");
  EXPECT_EQ(field(r2, "real_time"), "0");
  EXPECT_EQ(field(r2, "note"), "runaway at node 3, \"fast\"");
}

TEST(BenchCsv, StepRowsIncludingSkipped) {
  StepBenchmarkRow run;
  run.size = 64;
  run.layout = Layout::voxel;
  run.integrator = IntegratorKind::explicit_euler;
  run.threads = 1;
  run.elements = 1000;
  run.vertex_entries = 8000;
  run.step_s = 2.5e-3;
  run.ns_per_entry = 312.5;
  StepBenchmarkRow skipped = run;
  skipped.skipped = true;
  skipped.note = "voxel models skipped above size 32 (time and memory)";
  const auto l = lines(step_csv({run, skipped}));
  ASSERT_EQ(l.size(), 3u);
  const auto header = split_csv(l[0]);
  ASSERT_EQ(split_csv(l[1]).size(), header.size());
  ASSERT_EQ(split_csv(l[2]).size(), header.size());
  const auto idx = [&](const std::string& n) {
    return std::size_t(std::find(header.begin(), header.end(), n) - header.begin());
  };
  EXPECT_EQ(split_csv(l[1])[idx("resolution")], "voxel");
  EXPECT_DOUBLE_EQ(std::stod(split_csv(l[1])[idx("step_ms")]), 2.5);
  EXPECT_DOUBLE_EQ(std::stod(split_csv(l[1])[idx("ns_per_entry")]), 312.5);
  EXPECT_EQ(split_csv(l[1])[idx("skipped")], "0");
  EXPECT_EQ(split_csv(l[2])[idx("skipped")], "1");
  EXPECT_EQ(split_csv(l[2])[idx("step_ms")], "");
  EXPECT_EQ(split_csv(l[2])[idx("note")], skipped.note);
}

TEST(BenchScene, IsAValidSceneOfTheRightGeometry) {
  PalpationSceneSettings s;
  const json j = palpation_scene_json(s, 8, Layout::gradational, IntegratorKind::implicit, 2e-3, 1);
  const Scene scene = parse_scene(j, fs::temp_directory_path(), "bench scene");
  EXPECT_EQ(scene.integrator, IntegratorKind::implicit);
  EXPECT_DOUBLE_EQ(scene.dt_s, 2e-3);
  EXPECT_DOUBLE_EQ(scene.duration_s, s.duration_s);
  ASSERT_EQ(scene.probes.size(), 1u);
  const PreparedScene p = prepare_scene(scene);
  EXPECT_DOUBLE_EQ(p.model->grid.spacing_mm.x(), 4.0);  // 32 mm / 8 voxels
  EXPECT_NEAR(p.bounds_max_mm.z() - p.bounds_min_mm.z(), s.height_mm, 1e-9);
  EXPECT_NEAR(p.bounds_max_mm.x() - p.bounds_min_mm.x(), s.block_mm, 1e-9);
  // the ball starts gap_mm above the top and its lowest point ends depth_mm below it
  const ProbeSettings& probe = p.settings.probes[0];
  EXPECT_NEAR(probe.initial_position().z() - s.probe_radius_mm, s.height_mm + s.gap_mm, 1e-9);
  EXPECT_GT(p.fixed_nodes, 0);
  // "auto" when no step is given; odd or tiny grids are refused
  EXPECT_EQ(palpation_scene_json(s, 8, Layout::voxel, IntegratorKind::symplectic_euler, 0.0, 1)["integrator"]["dt_s"],
            "auto");
  EXPECT_THROW((void)palpation_scene_json(s, 9, Layout::voxel, IntegratorKind::implicit, 1e-3, 1), Error);
  EXPECT_THROW((void)palpation_scene_json(s, 2, Layout::voxel, IntegratorKind::implicit, 1e-3, 1), Error);
}

TEST(BenchSettings, InvalidSettingsAreRefused) {
  BenchSettings s = BenchSettings::quick_settings();
  EXPECT_NO_THROW(s.validate());
  auto bad = [&](auto change) {
    BenchSettings b = BenchSettings::quick_settings();
    change(b);
    EXPECT_THROW(b.validate(), Error);
  };
  bad([](BenchSettings& b) { b.threads = 0; });
  bad([](BenchSettings& b) { b.threads = -2; });
  bad([](BenchSettings& b) { b.sizes = {15}; });
  bad([](BenchSettings& b) { b.sizes = {}; });
  bad([](BenchSettings& b) { b.reference_size = 7; });
  bad([](BenchSettings& b) { b.step_sizes = {4}; });
  bad([](BenchSettings& b) { b.explicit_fractions = {0.0}; });
  bad([](BenchSettings& b) { b.implicit_steps_s = {-1e-3}; });
  bad([](BenchSettings& b) { b.run_step = b.run_palpation = false; });
  bad([](BenchSettings& b) { b.scene.depth_mm = 20; });
}

/// A bench small enough for a unit test: the palpation part on 8- and 12-voxel grids.
BenchSettings tiny_bench() {
  BenchSettings s;
  s.run_step = false;
  s.sizes = {8};
  s.resolutions = {Layout::gradational, Layout::voxel};
  s.explicit_fractions = {
      0.5, 8.0};  // 8x the stable estimate blows up (the estimates are 1.1-3.1x below the limits): an unstable row
  s.implicit_steps_s = {2e-3};
  s.reference_size = 12;
  s.scene.duration_s = 0.12;
  s.scene.press_s = 0.06;
  s.scene.depth_mm = 2.0;
  return s;
}

TEST(BenchRun, TinyBenchMeasuresEveryRunAgainstTheReference) {
  std::vector<std::string> log;
  BenchSettings s = tiny_bench();
  s.log = [&](const std::string& l) { log.push_back(l); };
  const BenchResult res = run_bench(s);
  // the reference: a real force curve with a positive peak (Hertz for this ball and depth:
  // 4/3 E sqrt(R) d^1.5 = 0.042 N; a thin block fixed at its base is stiffer, a coarse one too)
  EXPECT_EQ(res.reference.layout, Layout::voxel);
  EXPECT_EQ(res.reference.size, 12);
  EXPECT_GT(res.reference.peak_force_n, 0.03);
  EXPECT_LT(res.reference.peak_force_n, 0.15);
  EXPECT_NEAR(res.reference.sim_time_s, 0.12, res.reference.time_step_s);
  // 2 resolutions x (2 explicit + 2 symplectic + 1 implicit)
  ASSERT_EQ(res.rows.size(), 10u);
  int unstable = 0;
  for (const BenchRow& r : res.rows) {
    EXPECT_EQ(r.size, 8);
    EXPECT_DOUBLE_EQ(r.voxel_mm, 4.0);
    EXPECT_EQ(r.threads, 1);
    if (r.dt_fraction == 8.0) {
      EXPECT_EQ(r.status, BenchStatus::unstable) << r.label();
      EXPECT_FALSE(r.note.empty());
      EXPECT_FALSE(r.pareto);
      ++unstable;
      continue;
    }
    ASSERT_EQ(r.status, BenchStatus::ok) << r.label() << ": " << r.note;
    EXPECT_GT(r.wall_per_sim_s, 0) << r.label();
    EXPECT_GT(r.peak_force_n, 0) << r.label();
    EXPECT_TRUE(std::isfinite(r.error.rms_rel)) << r.label();
    EXPECT_GE(r.error.max_abs_rel, r.error.rms_rel) << r.label();
    EXPECT_NEAR(r.sim_time_s, 0.12, r.time_step_s) << r.label();
  }
  EXPECT_EQ(unstable, 4);
  // the front and the best come from the stable rows
  ASSERT_FALSE(res.pareto.empty());
  for (std::size_t i : res.pareto) EXPECT_TRUE(res.rows[i].pareto && res.rows[i].usable());
  ASSERT_GE(res.best, 0);
  EXPECT_TRUE(res.rows[std::size_t(res.best)].usable());
  if (res.best_is_real_time) {
    EXPECT_LE(res.rows[std::size_t(res.best)].wall_per_sim_s, 1.0);
  }
  EXPECT_NE(best_statement(res).find(res.rows[std::size_t(res.best)].label()), std::string::npos);
  // progress: a line per run, "[bench i/N]"
  int progress = 0;
  for (const auto& l : log) progress += l.rfind("[bench ", 0) == 0 && l.find("/11]") != std::string::npos;
  EXPECT_EQ(progress, 11);
}

TEST(BenchRun, ReportIsWrittenAllOrNothing) {
  BenchSettings s = tiny_bench();
  s.resolutions = {Layout::gradational};
  s.explicit_fractions = {1.0};
  const BenchResult res = run_bench(s);
  const fs::path dir = fs::temp_directory_path() / ("vx_bench_test_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  const std::vector<std::string> names = write_bench_report(res, dir);
  const std::set<std::string> want{
      "bench.csv",        "bench.json",           "bench.md",       "bench_error.png", "bench_cost.png",
      "bench_curves.png", "reference_scene.json", "best_scene.json"};
  std::set<std::string> found;
  for (const auto& f : fs::directory_iterator(dir)) found.insert(f.path().filename().string());
  EXPECT_EQ(found, want);  // no staging folder left behind
  EXPECT_EQ(std::set<std::string>(names.begin(), names.end()), want);
  const json j = json::parse(slurp(dir / "bench.json"));
  EXPECT_EQ(j["rows"].size(), res.rows.size());
  EXPECT_DOUBLE_EQ(j["reference"]["peak_force_n"].get<double>(), res.reference.peak_force_n);
  EXPECT_EQ(j["reference"]["curve"]["time_s"].size(), res.reference.curve.time_s.size());
  ASSERT_TRUE(j["best"].is_object());
  EXPECT_EQ(j["best"]["index"].get<int>(), res.best);
  EXPECT_EQ(j["conclusion"].get<std::string>(), best_statement(res));
  // the best scene re-runs as a scene file
  EXPECT_NO_THROW((void)load_scene(dir / "best_scene.json"));
  EXPECT_NE(slurp(dir / "bench.md").find(best_statement(res)), std::string::npos);
  for (const char* png : {"bench_error.png", "bench_cost.png", "bench_curves.png"}) {
    const auto st = vx::testing::png_stats(dir / png);  // a real picture: drawn, with text and curves
    EXPECT_GT(st.width, 800) << png;
    EXPECT_GT(st.drawn, 10000) << png;
    EXPECT_GT(st.colours, 50) << png;
  }

  // a file in the way of the folder: an error, nothing written
  const fs::path blocked = dir / "blocked";
  std::ofstream(blocked) << "x";
  EXPECT_THROW(write_bench_report(res, blocked), Error);
  EXPECT_TRUE(fs::is_regular_file(blocked));
  fs::remove_all(dir);
}

TEST(ScaleBench, ImplicitReferenceAndTheLargeModelConfiguration) {
  // the standard suite holds the fast configuration of large models (scene/fast_configuration.h); the implicit
  // reference replaces symplectic Euler where that would take an hour
  ScaleBenchSettings s = ScaleBenchSettings::standard();
  const auto large = std::find_if(s.configs.begin(), s.configs.end(), [](const ScaleConfig& c) {
    return c.name.find("larger models") != std::string::npos;
  });
  ASSERT_NE(large, s.configs.end());
  EXPECT_DOUBLE_EQ(large->time_step_s, default_fast_configuration().large_model_time_step_s);
  EXPECT_DOUBLE_EQ(large->region_radius_mm, default_fast_configuration().large_model_region_radius_mm);
  s.use_implicit_reference();
  const auto ref = std::find_if(s.configs.begin(), s.configs.end(), [](const ScaleConfig& c) { return c.reference; });
  ASSERT_NE(ref, s.configs.end());
  EXPECT_EQ(ref->kind, IntegratorKind::implicit);
  EXPECT_GT(ref->max_iterations, 1);
  EXPECT_GT(ref->residual_tolerance_n, 0.0);

  // a tiny run: the 32 sphere pressed 2 mm and slid 2 mm in 0.2 s each; the fast configuration
  // against the implicit reference: a finite error of a few percent, the reference's own zero
  ScaleBenchSettings t = s;
  t.models = {{"sphere 32", "sphere", 32}};
  std::vector<ScaleConfig> keep;
  for (const ScaleConfig& c : s.configs)
    if (c.reference || c.name.find("fast configuration below") != std::string::npos) keep.push_back(c);
  t.configs = keep;
  t.threads = {1};
  t.depth_mm = 2.0;
  t.slide_mm = 2.0;
  t.press_s = t.slide_s = 0.2;
  const ScaleBenchResult r = run_scale_bench(t);
  ASSERT_EQ(r.rows.size(), 2u);
  EXPECT_NE(r.rows[0].config.find("reference"), std::string::npos);
  EXPECT_DOUBLE_EQ(r.rows[0].rms_error_rel, 0.0);
  EXPECT_TRUE(r.rows[1].complete);
  EXPECT_GT(r.rows[1].rms_error_rel, 0.0);
  EXPECT_LT(r.rows[1].rms_error_rel, 0.15);
  EXPECT_GT(r.rows[1].peak_force_n, 0.0);
  EXPECT_GT(r.rows[1].real_time_factor, 0.0);
  EXPECT_NEAR(r.rows[1].peak_force_n, r.rows[0].peak_force_n, 0.15 * r.rows[0].peak_force_n);
}

// A coarser grid of the same shape ("sphere 32 at 2 mm") is judged against the finer model's
// reference on the finer model's path: its own reference configuration a row like the others, errors that are finite
// and larger than the same configuration's on the fine model (the grid costs something), and the order checked (the
// finer model first)
TEST(ScaleBench, ACoarserGridIsJudgedAgainstTheFinerModelsReference) {
  ScaleBenchSettings s = ScaleBenchSettings::standard();
  s.use_implicit_reference();
  std::vector<ScaleConfig> keep;
  for (const ScaleConfig& c : s.configs)
    if (c.reference || c.name.find("fast configuration below") != std::string::npos) keep.push_back(c);
  s.configs = keep;
  ScaleModelSpec fine{"sphere 32", "sphere", 32}, coarse = fine;
  coarse.name = "sphere 32 at 2 mm";
  coarse.size = 16;
  coarse.spacing_mm = 2.0;
  coarse.judged_against = fine.name;
  s.models = {coarse, fine};
  EXPECT_THROW(s.validate(), Error);  // the finer model must come first
  s.models = {fine, coarse};
  s.threads = {1};
  s.depth_mm = 2.0;
  s.slide_mm = 2.0;
  s.press_s = s.slide_s = 0.2;
  ScaleBenchResult r = run_scale_bench(s);
  ASSERT_EQ(r.rows.size(), 4u);  // each: the reference configuration and the fast one
  EXPECT_EQ(r.rows[2].model, "sphere 32 at 2 mm");
  EXPECT_EQ(r.rows[2].config, r.rows[0].config);
  EXPECT_GT(r.rows[2].rms_error_rel, 0.05);  // the coarse grid's converged run: the grid's own error
  r.rows.erase(r.rows.begin() + 2);
  EXPECT_EQ(r.rows[2].config, r.rows[1].config);
  EXPECT_LT(r.rows[2].nodes, r.rows[1].nodes / 4);  // an eighth of the voxels, about a fifth of the nodes
  EXPECT_TRUE(r.rows[2].complete);
  EXPECT_NE(r.rows[2].note.find("sphere 32's reference"), std::string::npos);
  // on 2 mm voxels the 16-voxel sphere's top lies up to a voxel below the 32-voxel one's, so the same
  // path presses it less: measured 0.018 N at most against 0.065 N, an error of 53 % of the peak
  EXPECT_GT(r.rows[2].rms_error_rel, 2 * r.rows[1].rms_error_rel);
  EXPECT_LT(r.rows[2].rms_error_rel, 1.0);
  EXPECT_GT(r.rows[2].peak_force_n, 0.0);
  EXPECT_LT(r.rows[2].peak_force_n, r.rows[1].peak_force_n);
}

// The scale bench's supports hold what their names say, on the folded phantom at 64 voxels
// (its stem is 6 mm across there: every length is a fraction of the grid's edge)
TEST(ScaleBench, SupportsHoldWhatTheySay) {
  ScaleBenchSettings s;
  PhantomSettings ps;
  ps.name = "folded";
  ps.size = 64;
  const PhantomShape shape = phantom_shape(ps);
  const auto fixed_positions = [&](const std::string& support) {
    ScaleModelSpec m{"folded", "folded", 64};
    m.support = support;
    const PreparedScene p = prepare_scale_model(m, s);
    std::vector<Eigen::Vector3d> held;
    for (int i : p.settings.fixed_nodes) held.push_back(p.model->rest_positions.col(i));
    EXPECT_EQ(int(held.size()), p.fixed_nodes);
    // every node the rule names is held, and no other
    int named = 0;
    for (int i = 0; i < p.model->num_nodes(); ++i) {
      const Eigen::Vector3d x = p.model->rest_positions.col(i);
      if (support == "stem")  // a box round the stem's bottom 3 mm, half a voxel larger
        named += x.z() <= shape.stem_center_mm.z() + 3.5 + 1e-9 &&
                 std::abs(x.x() - shape.stem_center_mm.x()) <= shape.stem_radius_mm + 0.5 + 1e-9 &&
                 std::abs(x.y() - shape.stem_center_mm.y()) <= shape.stem_radius_mm + 0.5 + 1e-9;
      else if (support == "lower third")
        named += x.z() <= p.bounds_min_mm.z() + (p.bounds_max_mm.z() - p.bounds_min_mm.z()) / 3.0 + 1e-9;
      else
        named += x.z() <= p.bounds_min_mm.z() + 3.0 + 1e-9;
    }
    EXPECT_EQ(int(held.size()), named) << support;
    return std::make_pair(held, p);
  };
  // the stem: nodes of its bottom 3 mm only (the lowest tissue), about 4 layers of its disc
  const auto [stem, ps_stem] = fixed_positions("stem");
  ASSERT_GT(stem.size(), 20u);
  // (every node of a voxel whose centre is in the stem's disc lies within half a voxel
  // diagonal of it; the stem's bottom 3 mm are 4 layers of nodes)
  for (const auto& x : stem) {
    EXPECT_LE(std::hypot(x.x() - shape.stem_center_mm.x(), x.y() - shape.stem_center_mm.y()),
              shape.stem_radius_mm + std::sqrt(0.5));
    EXPECT_LE(x.z(), ps_stem.bounds_min_mm.z() + 3.0 + 1e-9);
  }
  EXPECT_NEAR(ps_stem.bounds_min_mm.z(), shape.stem_center_mm.z(), 1.0);
  EXPECT_LT(double(stem.size()), 0.02 * ps_stem.model->num_nodes());
  // the lower third: far more, up to a third of the height, and the stem among them
  const auto [third, ps_third] = fixed_positions("lower third");
  EXPECT_GT(third.size(), 10 * stem.size());
  double highest = -1e9;
  for (const auto& x : third) highest = std::max(highest, x.z());
  const double height = ps_third.bounds_max_mm.z() - ps_third.bounds_min_mm.z();
  EXPECT_NEAR(highest - ps_third.bounds_min_mm.z(), height / 3.0, 1.0);
  // the default: the bottom 3 mm, the stem's bottom here too (it is the lowest tissue)
  const auto [bottom, ps_bottom] = fixed_positions("bottom 3 mm");
  EXPECT_EQ(bottom.size(), stem.size());
  // stem on a phantom without one, and an unknown support: refused
  ScaleModelSpec sphere{"sphere 32", "sphere", 32};
  sphere.support = "stem";
  EXPECT_THROW((void)prepare_scale_model(sphere, s), Error);
  ScaleBenchSettings bad = ScaleBenchSettings::standard();
  bad.models[0].support = "hand";
  EXPECT_THROW(bad.validate(), Error);
}

// The standard suite's folded models press on a gyrus, off the fissure, at the top
TEST(ScaleBench, FoldedPressIsOnTissueOffTheFissure) {
  const ScaleBenchSettings s = ScaleBenchSettings::standard();
  std::vector<std::string> supports;
  for (const auto& m : s.models)
    if (m.phantom == "folded") supports.push_back(m.support);
  EXPECT_EQ(supports, (std::vector<std::string>{"stem", "lower third"}));
  const auto folded =
      std::find_if(s.models.begin(), s.models.end(), [](const auto& m) { return m.phantom == "folded"; });
  ScaleModelSpec m = *folded;
  m.size = 107;  // half the size: the offset scaled with it
  m.press_offset_mm *= 0.5;
  const PreparedScene p = prepare_scale_model(m, s);
  const auto path = scale_palpation_path(p, m, s);
  PhantomSettings ps;
  ps.name = "folded";
  ps.size = 107;
  const PhantomShape shape = phantom_shape(ps);
  // off the fissure by more than the ball's radius, and over tissue near the top: the ball's
  // lowest point at the start lies 0.5 mm above the highest node under it, within 5 mm of the top
  EXPECT_GT(std::abs(path[0].position_mm.x()) - shape.fissure_half_width_mm, s.probe_radius_mm);
  const double top = shape.center_mm.z() + shape.half_extent_mm.z();
  EXPECT_GT(path[0].position_mm.z() - s.probe_radius_mm - 0.5, top - 5.0);
  EXPECT_LT(path[0].position_mm.z() - s.probe_radius_mm - 0.5, top + 1e-9);
}
