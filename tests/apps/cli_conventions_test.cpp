// What users expect of the command line (issues #17, #29), through the built binaries: -q keeps
// warnings on stderr and hides notes and progress everywhere (the DICOM reader too), wherever
// it is written; the exit codes of the shared table (util/exit_codes.h), every command-line
// mistake exit 2 with the nearest correct word; Ctrl-C in `simulate` leaving a usable .pvd
// and a summary.json that says where it stopped; stdout and stderr in one file in the order printed.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <string>

#include "convert/phantom.h"
#include "io/dicom_series.h"
#include "io/volume_io.h"
#include "sim/sparse_factor.h"
#include "support/run_binary.h"
#include "util/exit_codes.h"

namespace fs = std::filesystem;
using vx::testing::RunResult;
using vx::testing::slurp;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "voxelastic" / "voxelastic";

class CliConventions : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_cli_conventions_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  RunResult run(const std::string& args, const std::string& env = "") const {
    return vx::testing::run_binary(kBinary, args, dir_, dir_, env);
  }
  fs::path dir_;
};

/// A box pressed by a ball for `duration_s`, with .pvd output every `pvd_s`.
std::string box_scene(double duration_s, double pvd_s, double ball_z_mm = 9.2) {
  nlohmann::json j = nlohmann::json::parse(R"({
    "object": {"box_mm": {"min": [0, 0, 0], "max": [12, 12, 6]}, "voxel_mm": 1.0},
    "material": {"youngs_modulus_kpa": 10, "poisson_ratio": 0, "density_kg_m3": 1000, "damping": 0.1},
    "fixed": ["z_min"],
    "probes": [{"name": "ball", "shape": "sphere", "radius_mm": 3, "path": [{"t_s": 0, "position_mm": [6, 6, 9.2]}]}],
    "outputs": {"plot": false}
  })");
  j["duration_s"] = duration_s;
  j["probes"][0]["path"][0]["position_mm"][2] = ball_z_mm;
  j["outputs"]["pvd"] = {{"model", true}, {"surface", false}, {"interval_s", pvd_s}};
  return j.dump(2);
}

}  // namespace

TEST_F(CliConventions, TheSecondRunOfAnImplicitSceneLoadsItsFactorAndCalibrationAndGivesTheSameForces) {
  nlohmann::json j = nlohmann::json::parse(box_scene(0.1, 0.05));
  j["integrator"] = {{"type", "implicit"}, {"dt_s", 0.01}, {"iterations", 3}};
  j["outputs"].erase("pvd");
  j["outputs"]["forces_csv"] = true;
  std::ofstream(dir_ / "implicit.json") << j.dump(2);
  // every factor kept (a box's takes milliseconds: below the default 1 s)
  const std::string keep_all = "env VOXELASTIC_FACTOR_CACHE_MIN_S=0";
  const RunResult first = run("simulate implicit.json --out a --factor-cache fc", keep_all);
  ASSERT_EQ(first.code, 0) << first.err;
  EXPECT_NE(first.err.find("factor cache: kept the factor"), std::string::npos) << first.err;
  EXPECT_NE(first.out.find("factoring took"), std::string::npos) << first.out;
  EXPECT_NE(first.err.find("calibration cache: kept the calibration"), std::string::npos) << first.err;
  const bool orders = vx::SparseFactor::best_backend() == vx::SparseFactor::Backend::cholmod;
  if (orders) {  // METIS's order, kept by the pattern
    EXPECT_NE(first.err.find("factor cache: kept the order"), std::string::npos) << first.err;
  }
  const RunResult second = run("simulate implicit.json --out b --factor-cache fc", keep_all);
  ASSERT_EQ(second.code, 0) << second.err;
  EXPECT_NE(second.err.find("factor cache: loaded the factor"), std::string::npos) << second.err;
  EXPECT_NE(second.out.find("the factor loaded from the cache"), std::string::npos) << second.out;
  EXPECT_NE(second.err.find("calibration cache: loaded the calibration"), std::string::npos) << second.err;
  EXPECT_NE(second.out.find("the calibration loaded from the cache"), std::string::npos) << second.out;
  const nlohmann::json sa = nlohmann::json::parse(slurp(dir_ / "a" / "summary.json"));
  const nlohmann::json sb = nlohmann::json::parse(slurp(dir_ / "b" / "summary.json"));
  EXPECT_EQ(sa.at("factorisations"), 1);
  EXPECT_EQ(sa.at("factors_from_cache"), 0);
  EXPECT_EQ(sb.at("factors_from_cache"), 1);
  // which BLAS factored it (the run's process loads the libblas.so.3 this one does)
  EXPECT_EQ(sa.at("blas").get<std::string>(), vx::SparseFactor::blas_library());
  if (vx::SparseFactor::available(vx::SparseFactor::Backend::cholmod)) {
    EXPECT_NE(sa.at("blas"), "none");
  }
  // the same bits: the forces written are the same text
  const std::string fa = slurp(dir_ / "a" / "forces.csv");
  EXPECT_GT(fa.size(), 100u);
  EXPECT_EQ(fa, slurp(dir_ / "b" / "forces.csv"));
  int files = 0, calibrations = 0;
  for (const auto& e : fs::directory_iterator(dir_ / "fc")) {
    files += e.path().extension() == ".vxfactor" ? 1 : 0;
    calibrations += e.path().extension() == ".vxcalib" ? 1 : 0;
  }
  EXPECT_EQ(files, 1);
  EXPECT_EQ(calibrations, 1);
  // another step: another matrix, factored anew and kept beside
  j["integrator"]["dt_s"] = 0.02;
  std::ofstream(dir_ / "implicit.json") << j.dump(2);
  const RunResult third = run("simulate implicit.json --out c --factor-cache fc", keep_all);
  ASSERT_EQ(third.code, 0) << third.err;
  EXPECT_EQ(nlohmann::json::parse(slurp(dir_ / "c" / "summary.json")).at("factors_from_cache"), 0);
  // the calibration does not depend on the step: loaded
  EXPECT_NE(third.err.find("calibration cache: loaded the calibration"), std::string::npos) << third.err;
  // nor does the matrix's pattern: METIS's order loaded, not found again
  if (orders) {
    EXPECT_NE(third.err.find("factor cache: loaded the order"), std::string::npos) << third.err;
    EXPECT_NE(third.out.find("METIS's order loaded from the cache"), std::string::npos) << third.out;
    EXPECT_EQ(nlohmann::json::parse(slurp(dir_ / "c" / "summary.json")).at("orders_from_cache"), 1);
    EXPECT_EQ(sa.at("orders_from_cache"), 0);
  }
  // off: nothing looked up
  const RunResult off = run("simulate implicit.json --out d --factor-cache off", keep_all);
  ASSERT_EQ(off.code, 0) << off.err;
  EXPECT_EQ(off.err.find("factor cache"), std::string::npos) << off.err;
  EXPECT_EQ(off.err.find("calibration cache"), std::string::npos) << off.err;
  // the order loaded is the order METIS finds: the same factor, the same forces as text
  const std::string fc = slurp(dir_ / "c" / "forces.csv");
  EXPECT_GT(fc.size(), 100u);
  EXPECT_EQ(fc, slurp(dir_ / "d" / "forces.csv"));
}

TEST_F(CliConventions, CtrlCInSimulateKeepsAUsablePvdAndSaysWhereItStopped) {
  std::ofstream(dir_ / "long.json") << box_scene(1000.0, 0.05);
  // SIGINT after 6 s (the box is built in well under a second, then it runs)
  const RunResult r = run("simulate long.json --out out", "timeout --preserve-status -s INT 6");
  EXPECT_EQ(r.code, vx::exit_code::interrupted) << r.err;
  EXPECT_NE(r.err.find("interrupted at t = "), std::string::npos) << r.err;
  // summary.json: interrupted, the time reached
  const nlohmann::json s = nlohmann::json::parse(slurp(dir_ / "out" / "summary.json"));
  EXPECT_EQ(s.at("interrupted"), true);
  EXPECT_EQ(s.at("status"), "interrupted");
  const double reached = s.at("sim_time_s").get<double>();
  EXPECT_GT(reached, 0.0);
  EXPECT_LT(reached, 1000.0);
  EXPECT_EQ(s.at("duration_s"), 1000.0);
  // model.pvd lists frames that all exist, the last at (about) the time reached
  const std::string pvd = slurp(dir_ / "out" / "model.pvd");
  const std::regex entry(R"re(timestep="([0-9.eE+-]+)"[^>]*file="([^"]+)")re");
  int frames = 0;
  double last = -1;
  for (auto it = std::sregex_iterator(pvd.begin(), pvd.end(), entry); it != std::sregex_iterator(); ++it) {
    ++frames;
    last = std::stod((*it)[1]);
    EXPECT_TRUE(fs::exists(dir_ / "out" / (*it)[2].str())) << (*it)[2];
  }
  EXPECT_GE(frames, 2) << pvd;
  EXPECT_NEAR(last, reached, 1e-7 * (1 + reached));  // the series ends where the run stopped (9 digits)
  // forces.csv is complete too (header and rows up to the time reached)
  EXPECT_EQ(slurp(dir_ / "out" / "forces.csv").rfind("time_s,probe,", 0), 0u);
}

TEST_F(CliConventions, QuietKeepsWarningsOnStderrAndHidesNotes) {
  // the ball starts inside the box: prepare_scene warns
  std::ofstream(dir_ / "inside.json") << box_scene(0.002, 0.001, 5.0);
  RunResult r = run("simulate inside.json --out out -q");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out, "");
  EXPECT_NE(r.err.find("warning: probes[0] \"ball\" starts with"), std::string::npos) << r.err;
  r = run("simulate inside.json --out out2");
  EXPECT_NE(r.out.find("simulating"), std::string::npos);

  // the DICOM reader's notes: shown without -q, hidden with -q (here: a file that is not DICOM)
  vx::PhantomSettings ps;
  ps.name = "cube";
  ps.size = 8;
  vx::write_dicom_series(vx::make_phantom(ps), dir_ / "series");
  std::ofstream(dir_ / "series" / "README.txt") << "notes\n";
  r = run("convert series -o m.vtu");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("DICOM: skipped 1 file that is not DICOM"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("README.txt"), std::string::npos) << r.err;
  r = run("convert series -o m.vtu -q");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err, "");
  EXPECT_EQ(r.out, "");
  // -v: the same run says more than without it, never less
  r = run("convert series -o m.vtu -v");
  EXPECT_EQ(r.code, 0) << r.err;
}

// stdout a line at a time: in one file with stderr (a pipe, a log, `2>&1 | tee`), the notes come
// where they were printed, between the progress lines, not all at the exit.
TEST_F(CliConventions, StdoutAndStderrInOneFileKeepTheirOrder) {
  // a run of a few seconds (progress lines on a pipe come only for work over a second)
  nlohmann::json j = nlohmann::json::parse(box_scene(6.0, 6.0, 15.0));
  j["object"]["box_mm"]["max"] = {24, 24, 12};
  j["integrator"] = {{"type", "symplectic_euler"}};
  j["outputs"].erase("pvd");
  std::ofstream(dir_ / "long.json") << j.dump(2);
  const std::string cmd = "cd '" + dir_.string() + "' && timeout 300 '" + kBinary.string() +
                          "' simulate long.json --out out > both.txt 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << slurp(dir_ / "both.txt");
  const std::string both = slurp(dir_ / "both.txt");
  // the first progress line ("simulate: 40%": the deciles after the run's first second)
  const std::size_t simulating = both.find("simulating 6 s"), first = both.find("\nsimulate: "),
                    done = both.find("simulate: done in"), result = both.find(" s simulated in ");
  ASSERT_NE(done, std::string::npos) << "no progress lines: the run took under a second?\n" << both;
  ASSERT_NE(first, std::string::npos) << both;
  ASSERT_NE(simulating, std::string::npos) << both;
  ASSERT_NE(result, std::string::npos) << both;
  EXPECT_LT(simulating, first) << both;  // the note before the progress, as printed
  EXPECT_GT(result, done) << both;       // the result after it
}

TEST_F(CliConventions, ExitCodesFollowTheSharedTable) {
  EXPECT_EQ(run("--version").code, vx::exit_code::ok);
  EXPECT_EQ(run("convert --no-such-option").code, vx::exit_code::usage);
  EXPECT_EQ(run("convert").code, vx::exit_code::usage);  // INPUT and -o missing
  const RunResult r = run("convert missing.nrrd -o m.vtu");
  EXPECT_EQ(r.code, vx::exit_code::error);
  EXPECT_NE(r.err.find("missing.nrrd"), std::string::npos) << r.err;
  // a scene that cannot finish is refused up front, with the reason
  std::ofstream(dir_ / "forever.json") << box_scene(1.0, 0.5);
  nlohmann::json j = nlohmann::json::parse(slurp(dir_ / "forever.json"));
  j["integrator"] = {{"type", "symplectic_euler"}, {"dt_s", 1e-9}};
  std::ofstream(dir_ / "forever.json") << j.dump();
  const RunResult f = run("simulate forever.json --out out");
  EXPECT_EQ(f.code, vx::exit_code::error) << f.err;
  EXPECT_NE(f.err.find("1e+09 steps"), std::string::npos) << f.err;
}

// A step far below the stable one is said before the run, with the steps and the time they take
// (measured on trial steps); the summary keeps the internal counters for -v and summary.json.
TEST_F(CliConventions, AStepFarBelowTheStableStepIsSaidBeforeTheRun) {
  nlohmann::json j = nlohmann::json::parse(box_scene(2e-6, 1.0));
  j["integrator"] = {{"type", "symplectic_euler"}, {"dt_s", 1e-9}};
  j["outputs"]["pvd"]["model"] = false;
  std::ofstream(dir_ / "tiny.json") << j.dump();
  RunResult r = run("simulate tiny.json --out out");
  ASSERT_EQ(r.code, 0) << r.err;
  const std::regex said(
      R"re(integrator\.dt_s 1e-09 s is ([0-9.e+]+) times below the estimated stable step ([0-9.e+-]+) s: 2000 steps, about ([0-9.e+-]+) s at ([0-9.e+-]+) ms per step \(measured on trial steps\); "dt_s": "auto")re");
  std::smatch m;
  ASSERT_TRUE(std::regex_search(r.err, m, said)) << r.err;
  const double ratio = std::stod(m[1]), stable_s = std::stod(m[2]), per_step_ms = std::stod(m[4]);
  EXPECT_NEAR(ratio, stable_s / 1e-9, 0.01 * ratio);  // the two figures agree
  EXPECT_GT(ratio, 100.0);
  EXPECT_GT(per_step_ms, 0.0);
  EXPECT_NEAR(std::stod(m[3]), 2000 * per_step_ms * 1e-3, 0.06 * std::stod(m[3]) + 0.01);  // steps x per step
  const nlohmann::json s = nlohmann::json::parse(slurp(dir_ / "out" / "summary.json"));
  // no internal counters in the user summary; they are in summary.json, and on the console with -v
  EXPECT_EQ(r.out.find("narrow-phase"), std::string::npos) << r.out;
  EXPECT_TRUE(s.at("skipped").contains("narrow_phase_tests"));
  r = run("-v simulate tiny.json --out out2");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("skipped: "), std::string::npos) << r.err;
  // the automatic step: nothing said
  std::ofstream(dir_ / "auto.json") << box_scene(0.002, 0.001);
  r = run("simulate auto.json --out out3");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err.find("times below"), std::string::npos) << r.err;
}

TEST_F(CliConventions, QuietWorksBeforeAndAfterTheSubcommand) {
  vx::PhantomSettings ps;
  ps.name = "sphere";
  ps.size = 12;
  vx::write_volume(vx::make_phantom(ps), dir_ / "s.nrrd");
  // without -q: the summary on stdout; no progress lines on stderr for work under a second that
  // is not shown on a terminal (pipeline/util/progress.cpp)
  RunResult r = run("convert s.nrrd -o m.vtu");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("threshold:"), std::string::npos) << r.out;
  EXPECT_EQ(r.err.find("reading s.nrrd"), std::string::npos) << r.err;
  for (const std::string args : {"-q convert s.nrrd -o m.vtu", "convert s.nrrd -o m.vtu -q",
                                 "--quiet convert s.nrrd -o m.vtu", "convert -q s.nrrd -o m.vtu"}) {
    r = run(args);
    EXPECT_EQ(r.code, 0) << args << "\n" << r.err;
    EXPECT_EQ(r.out, "") << args;
    EXPECT_EQ(r.err, "") << args;
  }
  // simulate too: -q before the subcommand hides the set-up lines and the summary
  std::ofstream(dir_ / "box.json") << box_scene(0.002, 0.001);
  r = run("-q simulate box.json --out out");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out, "");
}

TEST_F(CliConventions, EveryCommandLineMistakeExitsTwoWithTheNearestWord) {
  vx::PhantomSettings ps;
  ps.name = "sphere";
  ps.size = 12;
  vx::write_volume(vx::make_phantom(ps), dir_ / "s.nrrd");
  std::ofstream(dir_ / "box.json") << box_scene(0.002, 0.001);
  struct Case {
    const char* args;
    const char* says;
  };
  const Case cases[] = {
      {"conver s.nrrd -o m.vtu", "unknown command 'conver' (did you mean 'convert'?)"},
      {"-q simulat box.json --out out", "unknown command 'simulat' (did you mean 'simulate'?)"},
      {"frobnicate", "the commands are: phantom, convert, simulate"},
      {"convert s.nrrd -o m.vtu --threshold sofft-tissue", "did you mean 'soft-tissue'?"},
      {"convert s.nrrd -o m.vtu --threshold 300:100", "the lower bound 300 is above the upper bound 100"},
      {"convert s.nrrd -o x.stl", "the model must be a .vtu file (for example x.vtu)"},
      {"convert s.nrrd -o m.vtu --stats s.txt", "must be a .json file"},
      {"convert s.nrrd -o m.vtu --surface s.stl", "must be a .vtp file"},
      {"convert s.nrrd -o m.vtu --threshhold 3", "unknown option '--threshhold'; did you mean '--threshold'?"},
      {"convert s.nrrd -o m.vtu --resolution gradationl", "gradational"},
      {"convert s.nrrd", "--output is required"},
      {"phantom sphre -o p.nrrd", "unknown phantom 'sphre'; did you mean 'sphere'?"},
      {"phantom sphere -o p.stl", "cannot write a phantom as '.stl'"},
      {"phantom sphere -o p.nrrd --sise 8", "did you mean '--size'?"},
      {"simulate box.json --out out --thread 2", "did you mean '--threads'?"},
  };
  for (const Case& c : cases) {
    const RunResult r = run(c.args);
    EXPECT_EQ(r.code, vx::exit_code::usage) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.says), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "m.vtu") || fs::exists(dir_ / "p.nrrd") || fs::exists(dir_ / "out"))
        << c.args << ": nothing is written";
  }
  // bad input found by the work is not a command-line mistake: exit 1
  const RunResult r = run("convert s.nrrd -o m.vtu --threshold 3000");
  EXPECT_EQ(r.code, vx::exit_code::error) << r.err;
}

TEST_F(CliConventions, MessagesNameOptionsNotInternalApi) {
  // every string the programs print, searched for the C++ names of their settings
  for (const char* binary : {"apps/voxelastic/voxelastic", "apps/probe/voxelastic-probe"}) {
    const std::string bytes = slurp(fs::path(VX_BINARY_DIR) / binary);
    for (const char* api :
         {"ReadOptions::", "PrepareOptions::", "BuildSettings::", "PhantomSettings::", "SceneOutputs::"})
      EXPECT_EQ(bytes.find(api), std::string::npos) << binary << " prints " << api;
  }
}
