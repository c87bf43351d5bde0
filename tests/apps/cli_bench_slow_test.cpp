// `voxelastic bench` through the built binary: the --quick suite end to end (files, columns and
// numbers that make sense) and clean failures for bad input (exit code, message, no report).
// Labelled slow: --quick takes 2 to 3 minutes on 2 cores.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "support/run_binary.h"

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "voxelastic" / "voxelastic";

using vx::testing::RunResult;
using vx::testing::slurp;

/// CSV text as rows of named fields (no quoted commas in the fields checked here).
std::vector<std::map<std::string, std::string>> read_csv(const std::string& text) {
  std::vector<std::map<std::string, std::string>> rows;
  std::istringstream in(text);
  std::string line;
  std::vector<std::string> header;
  auto split = [](const std::string& l) {
    std::vector<std::string> out(1);
    bool quoted = false;
    for (char c : l) {
      if (c == '"')
        quoted = !quoted;
      else if (c == ',' && !quoted)
        out.emplace_back();
      else
        out.back() += c;
    }
    return out;
  };
  while (std::getline(in, line)) {
    const auto f = split(line);
    if (header.empty()) {
      header = f;
      continue;
    }
    EXPECT_EQ(f.size(), header.size()) << line;
    std::map<std::string, std::string> row;
    for (std::size_t i = 0; i < f.size() && i < header.size(); ++i) row[header[i]] = f[i];
    rows.push_back(row);
  }
  return rows;
}

class CliBench : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_cli_bench_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "work");
  }
  void TearDown() override { fs::remove_all(dir_); }
  RunResult run(const std::string& args) const { return vx::testing::run_binary(kBinary, args, dir_ / "work", dir_); }
  fs::path dir_;
};

TEST_F(CliBench, QuickSuiteWritesASaneReport) {
  const RunResult r = run("bench --quick --out q");
  ASSERT_EQ(r.code, 0) << r.err;
  const fs::path q = dir_ / "work" / "q";
  std::set<std::string> files;
  for (const auto& f : fs::directory_iterator(q)) files.insert(f.path().filename().string());
  EXPECT_EQ(files,
            (std::set<std::string>{"step.csv", "step.png", "bench.csv", "bench.json", "bench.md", "bench_error.png",
                                   "bench_cost.png", "bench_curves.png", "reference_scene.json", "best_scene.json"}));
  for (const char* png : {"step.png", "bench_error.png", "bench_cost.png", "bench_curves.png"})
    EXPECT_GT(fs::file_size(q / png), 10000u) << png;
  // progress on stderr, the conclusion on stdout
  EXPECT_NE(r.err.find("[bench 1/55]"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("[bench 55/55]"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("[step 3/3]"), std::string::npos);
  EXPECT_TRUE(r.out.find("Best for real time") != std::string::npos ||
              r.out.find("No configuration ran in real time") != std::string::npos)
      << r.out;

  // part A: 3 resolutions x sizes 32, 64 x 3 integrators, and the 2D disk of 64 pixels x 3
  // integrators; the work grows like n^2 against n^3
  const auto steps = read_csv(slurp(q / "step.csv"));
  ASSERT_EQ(steps.size(), 21u);
  std::map<std::string, std::map<int, double>> entries, step_ms;
  for (const auto& s : steps) {
    EXPECT_EQ(s.at("threads"), "1");
    if (s.at("skipped") == "1") {
      EXPECT_EQ(s.at("integrator"), "implicit");  // only the factorisations are skipped in --quick
      EXPECT_FALSE(s.at("note").empty());
      continue;
    }
    const double ms = std::stod(s.at("step_ms")), ns = std::stod(s.at("ns_per_entry"));
    EXPECT_GT(ms, 0);
    if (s.at("integrator") == "explicit_euler") {
      EXPECT_GT(ns, 1.0) << s.at("resolution");     // a vertex entry costs nanoseconds...
      EXPECT_LT(ns, 2000.0) << s.at("resolution");  // ...not microseconds
      entries[s.at("resolution")][std::stoi(s.at("size"))] = std::stod(s.at("vertex_entries"));
      step_ms[s.at("resolution")][std::stoi(s.at("size"))] = ms;
    }
  }
  ASSERT_EQ(entries["gradational"].size(), 2u);
  ASSERT_EQ(entries["voxel"].size(), 2u);
  const double grad_growth = entries["gradational"][64] / entries["gradational"][32];
  const double voxel_growth = entries["voxel"][64] / entries["voxel"][32];
  EXPECT_GT(grad_growth, 3.5);  // ~4 = 2^2
  EXPECT_LT(grad_growth, 5.5);
  EXPECT_GT(voxel_growth, 7.5);  // ~8 = 2^3
  EXPECT_LT(voxel_growth, 9.5);
  EXPECT_LT(step_ms["gradational"][64], step_ms["voxel"][64]);
  // the 2D row: a slice of the same size has far less work than the sphere (its outline, not
  // its surface), and every integrator ran
  ASSERT_EQ(entries["gradational-2d"].size(), 1u);
  EXPECT_LT(entries["gradational-2d"][64], 0.2 * entries["gradational"][64]);
  int runs_2d = 0;
  for (const auto& s : steps) runs_2d += s.at("resolution") == "gradational-2d" && s.at("skipped") == "0";
  EXPECT_EQ(runs_2d, 3);

  // part B: 2 sizes x 3 resolutions x (3 explicit + 3 symplectic + 3 implicit) runs
  const auto rows = read_csv(slurp(q / "bench.csv"));
  ASSERT_EQ(rows.size(), 54u);
  int ok = 0, pareto = 0, close_voxel = 0;
  const json j = json::parse(slurp(q / "bench.json"));
  const double ref_peak = j["reference"]["peak_force_n"].get<double>();
  // Hertz for a 5 mm ball 3 mm deep into 5 kPa: 4/3 E sqrt(R) d^1.5 = 0.077 N; the 16 mm layer
  // fixed at its base is stiffer
  EXPECT_GT(ref_peak, 0.06);
  EXPECT_LT(ref_peak, 0.13);
  EXPECT_EQ(j["reference"]["resolution"], "voxel");
  EXPECT_EQ(j["reference"]["size"], 32);
  for (const auto& row : rows) {
    const std::string st = row.at("status");
    EXPECT_TRUE(st == "ok" || st == "unstable" || st == "skipped") << st;
    if (st != "ok") {
      EXPECT_FALSE(row.at("note").empty());
      EXPECT_EQ(row.at("pareto"), "0");
      continue;
    }
    ++ok;
    pareto += row.at("pareto") == "1";
    const double wall = std::stod(row.at("wall_per_sim_s")), err = std::stod(row.at("rms_error_rel"));
    EXPECT_GT(wall, 0);
    EXPECT_GE(err, 0);
    EXPECT_LT(err, 1.5);
    EXPECT_EQ(row.at("real_time"), wall <= 1.0 ? "1" : "0");
    // the voxel-level model with symplectic Euler at half its stable step is close to the reference
    if (row.at("resolution") == "voxel" && row.at("integrator") == "symplectic_euler" &&
        row.at("dt_fraction") == "0.5") {
      EXPECT_LT(err, 0.05) << row.at("size");
      EXPECT_NEAR(std::stod(row.at("peak_force_n")), ref_peak, 0.1 * ref_peak);
      ++close_voxel;
    }
  }
  EXPECT_EQ(close_voxel, 2);
  EXPECT_GE(ok, 20);
  EXPECT_GE(pareto, 1);
  EXPECT_EQ(j["rows"].size(), 54u);
  EXPECT_EQ(j["pareto_front"].size(), std::size_t(pareto));
  ASSERT_TRUE(j["best"].is_object());
  const json& best = j["best"];
  EXPECT_EQ(best["status"], "ok");
  if (best["real_time"].get<bool>()) {
    EXPECT_LE(best["wall_per_sim_s"].get<double>(), 1.0);
    // nothing real-time beats the best's error
    for (const auto& row : j["rows"]) {
      if (row["status"] == "ok" && row["wall_per_sim_s"].get<double>() <= 1.0) {
        EXPECT_GE(row["rms_error_rel"].get<double>(), best["rms_error_rel"].get<double>());
      }
    }
  }
  EXPECT_NE(slurp(q / "bench.md").find(j["conclusion"].get<std::string>()), std::string::npos);
  EXPECT_NE(r.out.find(j["conclusion"].get<std::string>()), std::string::npos);
}

TEST_F(CliBench, BadInputFailsCleanlyWithoutAReport) {
  struct Case {
    std::string args;
    int code;
    std::string message;
  };
  // write a file where a folder is expected
  std::ofstream(dir_ / "work" / "afile") << "x";
  const std::vector<Case> cases{
      {"bench --threads 0 --out o", 2, "--threads"},
      {"bench --threads -3 --out o", 2, "--threads"},
      {"bench --bogus --out o", 2, "--bogus"},
      {"bench --sizes 15 --skip-step --out o", 1, "even"},
      {"bench --skip-step --skip-palpation --out o", 1, "nothing to run"},
      {"bench --quick --out afile", 1, "afile"},
      {"bench --quick --out afile/sub", 1, "afile/sub"},
  };
  for (const auto& c : cases) {
    const RunResult r = run(c.args);
    EXPECT_EQ(r.code, c.code) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.message), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_EQ(r.err.find("internal error"), std::string::npos) << c.args;
    EXPECT_FALSE(fs::exists(dir_ / "work" / "o")) << c.args;
  }
  EXPECT_TRUE(fs::is_regular_file(dir_ / "work" / "afile"));
}

}  // namespace
