// `voxelastic phantom` through the built binary: every output format, the summary line, and
// clean failures (non-zero exit, a message, no file).
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>

#include "convert/phantom.h"
#include "io/model_io.h"
#include "io/surface_io.h"
#include <nlohmann/json.hpp>
#include "io/volume_io.h"
#include "support/run_binary.h"

namespace fs = std::filesystem;
using namespace vx;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "voxelastic" / "voxelastic";

using vx::testing::RunResult;
using vx::testing::slurp;

class CliPhantom : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_cli_phantom_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "out");
  }
  void TearDown() override { fs::remove_all(dir_); }
  /// Runs `voxelastic ARGS` inside dir_/out.
  RunResult run(const std::string& args) const { return vx::testing::run_binary(kBinary, args, dir_ / "out", dir_); }

 public:
  [[nodiscard]] std::set<std::string> outputs() const {
    std::set<std::string> names;
    for (const auto& f : fs::directory_iterator(dir_ / "out")) names.insert(f.path().filename().string());
    return names;
  }

 protected:
  fs::path dir_;
};

TEST_F(CliPhantom, SphereVtiMatchesTheLibrary) {
  const RunResult r = run("phantom sphere -o x.vti --size 32 --spacing 0.5");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(outputs(), std::set<std::string>{"x.vti"});
  PhantomSettings s;
  s.name = "sphere";
  s.size = 32;
  s.spacing_mm = 0.5;
  PhantomShape shape;
  const Volume expected = make_phantom(s, &shape);
  const Volume got = read_volume(dir_ / "out" / "x.vti");
  EXPECT_EQ(got.hu, expected.hu);
  EXPECT_EQ(got.geometry, expected.geometry);
  // one summary line: shape, dims, spacing, tissue voxels, analytic volume
  EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1) << r.out;
  EXPECT_NE(r.out.find("sphere"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("32x32x32"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("0.5 mm"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(std::to_string(shape.tissue_voxels) + " tissue voxels"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(fmt::format("analytic {:.4g} cm^3", shape.volume_mm3() / 1000.0)), std::string::npos) << r.out;
}

TEST_F(CliPhantom, EveryFormatAndTheLesionOptions) {
  PhantomSettings s;
  s.name = "block-lesion";
  s.size = 24;
  s.lesion_hu = 200;
  s.noise_hu = 10;
  s.seed = 5;
  const Volume expected = make_phantom(s);
  for (const std::string out : {"b.mha", "b.nii.gz", "b.nii", "b.nrrd", "b.vti", "series/"}) {
    SCOPED_TRACE(out);
    const RunResult r = run("phantom block-lesion --size 24 --lesion-hu 200 --noise 10 --seed 5 -o " + out);
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.out.find("lesion"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("noise 10 HU (seed 5)"), std::string::npos) << r.out;
    const Volume got = read_volume(dir_ / "out" / out);
    EXPECT_EQ(got.hu, expected.hu);
    EXPECT_LT((got.geometry.origin_mm - expected.geometry.origin_mm).norm(), 1e-5);
    EXPECT_LT((got.geometry.spacing_mm - expected.geometry.spacing_mm).norm(), 1e-6);
  }
}

TEST_F(CliPhantom, SlicePhantomsConvertToTheSame2DModelFromEveryFormat) {
  // the paper's 2D case end to end: a one-slice disk with a lesion in every format (a one-file
  // DICOM series too) reads back as one slice 2 mm thick and converts to the same 2D model
  PhantomSettings s;
  s.name = "disk-lesion";
  s.size = 48;
  s.spacing_mm = 0.5;
  s.thickness_mm = 2.0;
  PhantomShape shape;
  const Volume expected = make_phantom(s, &shape);
  EXPECT_EQ(expected.geometry.dims, Eigen::Vector3i(48, 48, 1));
  EXPECT_NEAR(double(shape.tissue_voxels) * 0.25, shape.area_mm2(), 0.02 * shape.area_mm2());
  EXPECT_GT(shape.lesion_voxels, 20);
  std::set<long> element_counts;
  for (const std::string out : {"d.mha", "d.nii.gz", "d.nrrd", "d.vti", "series/"}) {
    SCOPED_TRACE(out);
    RunResult r = run("phantom disk-lesion --size 48 --spacing 0.5 --thickness 2 -o " + out);
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.out.find("one slice, a 2D model"), std::string::npos) << r.out;
    const Volume got = read_volume(dir_ / "out" / out);
    EXPECT_EQ(got.geometry.dims, Eigen::Vector3i(48, 48, 1));
    EXPECT_NEAR(got.geometry.spacing_mm.z(), 2.0, 1e-6);
    EXPECT_EQ(got.hu, expected.hu);
    r = run("convert " + out + " -o m.vtu --stats m.json --surface m.vtp");
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.out.find("2D (slice, plane stress)"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("slice surface"), std::string::npos) << r.out;
    std::ifstream in(dir_ / "out" / "m.json");
    const nlohmann::json stats = nlohmann::json::parse(in);
    EXPECT_EQ(stats.at("dimensions"), 2);
    EXPECT_EQ(stats.at("grid")[2], 1);
    EXPECT_NEAR(stats.at("spacing_mm")[2].get<double>(), 2.0, 1e-6);
    EXPECT_EQ(stats.at("surface").at("method"), "slice");
    element_counts.insert(stats.at("elements").get<long>());
    const Model m = load_model(dir_ / "out" / "m.vtu");
    EXPECT_EQ(m.dimensions, 2);
    const EmbeddedSurface surface = load_surface(dir_ / "out" / "m.vtp", &m);
    EXPECT_EQ(surface.method, SurfaceMethod::slice);
    EXPECT_EQ(surface.model_nodes, m.num_nodes());
    EXPECT_EQ(m.covered_voxels(), shape.tissue_voxels);
  }
  EXPECT_EQ(element_counts.size(), 1u) << "every format gives the same model";
  // a volume model says 3
  ASSERT_EQ(run("phantom sphere --size 16 -o s.nrrd").code, 0);
  ASSERT_EQ(run("convert s.nrrd -o s.vtu --stats s.json").code, 0);
  std::ifstream in(dir_ / "out" / "s.json");
  EXPECT_EQ(nlohmann::json::parse(in).at("dimensions"), 3);
}

TEST_F(CliPhantom, FoldedConvertsToAModelMostlyOfSurface) {
  // the folded phantom at half its default size (107 voxels of 1 mm: a brain of 70 x 90 x 75
  // mm); the full size's counts are in cli_phantom_slow_test.cpp
  RunResult r = run("phantom folded --size 107 -o f.nii.gz");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("phantom folded: 107x107x107 voxels"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("stem r 5 mm"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("analytic"), std::string::npos) << r.out;  // no closed-form volume
  r = run("convert f.nii.gz -o m.vtu --stats m.json --surface m.vtp --largest-component");
  ASSERT_EQ(r.code, 0) << r.err;
  std::ifstream in(dir_ / "out" / "m.json");
  const nlohmann::json stats = nlohmann::json::parse(in);
  const double elements = stats.at("elements").get<double>(), nodes = stats.at("nodes").get<double>();
  const double surface = stats.at("surface_nodes").get<double>();
  const double triangles = stats.at("surface").at("triangles").get<double>();
  // measured: 14,025 elements, 75,142 nodes (88 % on the surface), 133,784 triangles
  EXPECT_GT(elements, 12000);
  EXPECT_GT(nodes, 65000);
  EXPECT_GT(surface / nodes, 0.80);
  EXPECT_GT(triangles, 115000);
  // one piece: the largest component is all of the phantom's tissue
  EXPECT_EQ(stats.at("prepare").at("components").get<int>(), 1) << stats.at("prepare").dump();
  PhantomSettings s;
  s.name = "folded";
  s.size = 107;
  PhantomShape shape;
  (void)make_phantom(s, &shape);
  EXPECT_EQ(stats.at("voxels").get<std::int64_t>(), shape.tissue_voxels);
}

/// Expects a failed run with a message containing each needle, and nothing written.
void expect_clean_failure(const CliPhantom& t, const RunResult& r, std::initializer_list<const char*> needles) {
  EXPECT_NE(r.code, 0) << r.out;
  for (const char* n : needles) EXPECT_NE(r.err.find(n), std::string::npos) << "stderr: " << r.err;
  EXPECT_TRUE(t.outputs().empty()) << "left behind: " << *t.outputs().begin();
}

TEST_F(CliPhantom, LesionCentreAndRadius) {
  // the lesion where the user puts it, the same volume as the library's
  const RunResult r = run("phantom block-lesion --size 32 --lesion-center-mm -4,2.5,1 --lesion-radius-mm 3 -o l.vti");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("lesion r 3 mm at (-4, 2.5, 1) mm"), std::string::npos) << r.out;
  PhantomSettings s;
  s.name = "block-lesion";
  s.size = 32;
  s.lesion_center_mm = Eigen::Vector3d(-4.0, 2.5, 1.0);
  s.lesion_radius_mm = 3.0;
  EXPECT_EQ(read_volume(dir_ / "out" / "l.vti").hu, make_phantom(s).hu);
  ASSERT_EQ(run("phantom disk-lesion --size 32 --lesion-center-mm 3,-3,0 --lesion-radius-mm 2 -o d.vti").code, 0);

  // a lesion that does not fit, or a malformed value: a usage error (exit 2), no file
  for (const std::string bad : {"--lesion-center-mm 0,0,6 --lesion-radius-mm 3",  // block half height 6: out the top
                                "--lesion-center-mm 0,0 --lesion-radius-mm 1", "--lesion-center-mm a,b,c",
                                "--lesion-center-mm 0,0,0,0", "--lesion-radius-mm 0", "--lesion-radius-mm -2",
                                "--lesion-radius-mm 40"}) {
    SCOPED_TRACE(bad);
    const RunResult e = run("phantom block-lesion --size 32 -o bad.vti " + bad);
    EXPECT_EQ(e.code, 2) << e.err;
    EXPECT_NE(e.err.find("lesion"), std::string::npos) << e.err;
    EXPECT_FALSE(fs::exists(dir_ / "out" / "bad.vti"));
  }
  const RunResult outside = run("phantom block-lesion --size 32 -o bad.vti --lesion-center-mm 0,0,6 --lesion-radius-mm 3");
  EXPECT_NE(outside.err.find("does not fit inside the block"), std::string::npos) << outside.err;
  const RunResult no_lesion = run("phantom block -o bad.vti --lesion-radius-mm 3");
  EXPECT_EQ(no_lesion.code, 2);
  EXPECT_NE(no_lesion.err.find("has no lesion"), std::string::npos) << no_lesion.err;
  EXPECT_EQ(run("phantom disk-lesion --size 32 -o bad.vti --lesion-center-mm 0,0,1 --lesion-radius-mm 2").code, 2);
}

TEST_F(CliPhantom, BadInputFailsCleanly) {
  expect_clean_failure(*this, run("phantom pyramid -o x.vti"),
                       {"unknown phantom 'pyramid'", "sphere", "ellipsoid", "block-lesion"});
  expect_clean_failure(*this, run("phantom sphere -o x.vti --size 2"), {"size 2", "4 to 1024"});
  expect_clean_failure(*this, run("phantom sphere -o x.vti --size 2000"), {"size 2000", "4 to 1024"});
  expect_clean_failure(*this, run("phantom sphere -o x.vti --spacing 0"), {"spacing"});
  expect_clean_failure(*this, run("phantom sphere -o x.vti --spacing -2"), {"spacing"});
  expect_clean_failure(*this, run("phantom sphere -o x.vti --noise -5"), {"noise"});
  expect_clean_failure(*this, run("phantom sphere -o x.png"), {"x.png", ".vti", ".nii.gz"});
  expect_clean_failure(*this, run("phantom sphere -o x.mhd"), {"x.mhd", ".mha"});
  expect_clean_failure(*this, run("phantom sphere -o missing/x.vti"), {"missing", "does not exist"});
  expect_clean_failure(*this, run("phantom sphere"), {"--output"});
  expect_clean_failure(*this, run("phantom sphere -o x.vti --size abc"), {"size"});
  // a mistaken command line exits 2 (the name is checked while parsing); bad input found by
  // the work says 'error' and exits 1
  EXPECT_EQ(run("phantom pyramid -o x.vti").code, 2);
  EXPECT_EQ(run("phantom sphere -o missing/x.vti").code, 1);
  EXPECT_NE(run("phantom sphere -o missing/x.vti").err.find("voxelastic: error:"), std::string::npos);
}

}  // namespace
