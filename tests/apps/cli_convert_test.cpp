// `voxelastic convert` through the built binary: outputs, statistics, and clean failures.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <numeric>
#include <set>
#include <sstream>
#include <string>

#include "convert/phantom.h"
#include "io/model_io.h"
#include "io/volume_io.h"
#include "render/render.h"
#include "support/run_binary.h"

namespace fs = std::filesystem;
using namespace vx;

namespace {

const fs::path kBinary = fs::path(VX_BINARY_DIR) / "apps" / "voxelastic" / "voxelastic";

using vx::testing::RunResult;
using vx::testing::slurp;

class CliConvert : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("vx_cli_convert_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "in");
    // a sphere phantom, radius 12 mm in a 32^3 grid of 1 mm voxels; tissue 40 HU, air -1000 HU
    PhantomSettings s;
    s.name = "sphere";
    s.size = 32;
    volume_ = new Volume(make_phantom(s));
    write_volume(*volume_, dir_ / "in" / "sphere.vti");
    std::ofstream(dir_ / "in" / "notes.txt") << "not a volume\n";
  }
  static void TearDownTestSuite() {
    fs::remove_all(dir_);
    delete volume_;
  }
  void SetUp() override {
    out_ = dir_ / ::testing::UnitTest::GetInstance()->current_test_info()->name();
    fs::remove_all(out_);
    fs::create_directories(out_);
  }
  /// Runs `voxelastic ARGS` in the output folder; `env` is put in front (e.g. "env -u DISPLAY").
  RunResult run(const std::string& args, const std::string& env = "") const {
    return vx::testing::run_binary(kBinary, args, out_, dir_, env);
  }
  [[nodiscard]] std::set<std::string> outputs() const {
    std::set<std::string> names;
    for (const auto& f : fs::directory_iterator(out_)) names.insert(f.path().filename().string());
    return names;
  }
  [[nodiscard]] static std::string input(const char* name) { return (dir_ / "in" / name).string(); }
  /// Tissue voxels of the phantom at the default threshold (HU >= -200), counted here.
  [[nodiscard]] static std::int64_t phantom_tissue() {
    std::int64_t n = 0;
    for (float v : volume_->hu) n += v >= -200.0f;
    return n;
  }

  static inline fs::path dir_;
  static inline Volume* volume_ = nullptr;
  fs::path out_;
};

/// Expects a failed run with a message containing `needle` and nothing written.
#define EXPECT_FAILS_CLEANLY(run_result, needle)                                                    \
  do {                                                                                             \
    const RunResult& r_ = (run_result);                                                                  \
    EXPECT_NE(r_.code, 0) << r_.err;                                                               \
    EXPECT_NE(r_.err.find(needle), std::string::npos) << "stderr: " << r_.err;                    \
    EXPECT_TRUE(outputs().empty()) << "left behind: " << *outputs().begin();                       \
  } while (0)

}  // namespace

TEST_F(CliConvert, SphereModelAndStats) {
  ASSERT_TRUE(fs::exists(kBinary)) << kBinary;
  const RunResult r = run("convert " + input("sphere.vti") + " -o model.vtu --stats stats.json");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(outputs(), (std::set<std::string>{"model.vtu", "stats.json"}));
  // the console summary names the numbers
  for (const char* word : {"elements", "nodes", "vertex entries", "reduction", "build time", "model.vtu"})
    EXPECT_NE(r.out.find(word), std::string::npos) << word << "\n" << r.out;

  const nlohmann::json j = nlohmann::json::parse(slurp(out_ / "stats.json"));
  for (const char* key : {"input", "grid", "spacing_mm", "voxels", "elements", "elements_per_level", "nodes",
                          "surface_nodes", "vertex_entries", "voxel_model_vertex_entries", "reduction", "build_s",
                          "bounds_mm", "resolution", "threshold_hu", "prepare"})
    EXPECT_TRUE(j.contains(key)) << key;
  const auto per_level = j["elements_per_level"].get<std::vector<std::int64_t>>();
  EXPECT_EQ(j["elements"].get<std::int64_t>(), std::accumulate(per_level.begin(), per_level.end(), std::int64_t(0)));
  EXPECT_GE(per_level.size(), 3u);  // a 24 mm ball: shells of levels 0, 1, 2 at least
  EXPECT_EQ(j["voxels"].get<std::int64_t>(), phantom_tissue());
  EXPECT_EQ(j["prepare"]["tissue_voxels"].get<std::int64_t>(), phantom_tissue());
  EXPECT_EQ(j["voxel_model_vertex_entries"].get<std::int64_t>(), 8 * phantom_tissue());
  EXPECT_NEAR(j["reduction"].get<double>(),
              8.0 * double(phantom_tissue()) / j["vertex_entries"].get<double>(), 1e-9);
  EXPECT_GT(j["reduction"].get<double>(), 1.0);
  EXPECT_EQ(j["resolution"], "gradational");
  EXPECT_EQ(j["threshold_hu"][0].get<double>(), -200.0);
  EXPECT_EQ(j["spacing_mm"], nlohmann::json::array({1.0, 1.0, 1.0}));
  // cropped to the ball with a 1-voxel margin, plus the lattice origin's shift on the low side
  // (docs/model.md 3.5): as wide as the tissue box + 2 + shift
  const auto grid = j["grid"].get<std::vector<int>>();
  const auto shift = j["prepare"]["lattice_origin"]["shift"].get<std::vector<int>>();
  const auto lo = j["bounds_mm"]["min"].get<std::vector<double>>(), hi = j["bounds_mm"]["max"].get<std::vector<double>>();
  for (int a = 0; a < 3; ++a) {
    EXPECT_GE(shift[std::size_t(a)], 0);
    EXPECT_LE(shift[std::size_t(a)], 3);
    EXPECT_NEAR(hi[std::size_t(a)] - lo[std::size_t(a)] + 2.0 + shift[std::size_t(a)], grid[std::size_t(a)], 1e-9) << a;
  }
  EXPECT_LE(j["prepare"]["lattice_origin"]["entries_chosen"].get<std::int64_t>(),
            j["prepare"]["lattice_origin"]["entries_unshifted"].get<std::int64_t>());
  EXPECT_EQ(j["prepare"]["lattice_origin"]["entries_chosen"], j["vertex_entries"]);

  // the file holds the model the numbers describe
  const Model m = load_model(out_ / "model.vtu");
  EXPECT_EQ(m.num_elements(), j["elements"].get<std::int64_t>());
  EXPECT_EQ(m.num_nodes(), j["nodes"].get<std::int64_t>());
  EXPECT_EQ(m.num_vertex_entries(), j["vertex_entries"].get<std::int64_t>());
  EXPECT_EQ(m.covered_voxels(), phantom_tissue());
  EXPECT_EQ(m.grid.dims, Eigen::Vector3i(grid[0], grid[1], grid[2]));
}

TEST_F(CliConvert, UniformAndVoxelResolutions) {
  const RunResult u = run("convert " + input("sphere.vti") + " -o u.vtu --resolution uniform --stats u.json -q");
  ASSERT_EQ(u.code, 0) << u.err;
  EXPECT_TRUE(u.out.empty()) << u.out;  // --quiet
  const RunResult v = run("convert " + input("sphere.vti") + " -o v.vtu --resolution voxel --stats v.json -q");
  ASSERT_EQ(v.code, 0) << v.err;
  const auto ju = nlohmann::json::parse(slurp(out_ / "u.json")), jv = nlohmann::json::parse(slurp(out_ / "v.json"));
  EXPECT_EQ(ju["elements_per_level"].size(), 1u);
  EXPECT_EQ(jv["elements"].get<std::int64_t>(), phantom_tissue());  // one element per voxel
  EXPECT_EQ(jv["vertex_entries"].get<std::int64_t>(), 8 * phantom_tissue());
  EXPECT_DOUBLE_EQ(jv["reduction"].get<double>(), 1.0);
  const RunResult g = run("convert " + input("sphere.vti") + " -o g.vtu --max-level 1 --stats g.json -q");
  ASSERT_EQ(g.code, 0) << g.err;
  EXPECT_EQ(nlohmann::json::parse(slurp(out_ / "g.json"))["elements_per_level"].size(), 2u);
}

TEST_F(CliConvert, PictureUnderXvfb) {
  if (!display_available()) GTEST_SKIP() << "no X display (run under xvfb-run)";
  const RunResult r = run("convert " + input("sphere.vti") + " -o m.vtu --png m.png -q");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(outputs(), (std::set<std::string>{"m.png", "m.vtu"}));
  EXPECT_GT(fs::file_size(out_ / "m.png"), 10000u);
}

TEST_F(CliConvert, PictureWithoutDisplayFailsBeforeWork) {
  EXPECT_FAILS_CLEANLY(run("convert " + input("sphere.vti") + " -o m.vtu --png m.png", "env -u DISPLAY"), "xvfb-run");
  // exit 4, as voxelastic-probe without a display (util/exit_codes.h)
  EXPECT_EQ(run("convert " + input("sphere.vti") + " -o m.vtu --png m.png", "env -u DISPLAY").code, 4);
}

TEST_F(CliConvert, BadInputsFailCleanly) {
  const std::string in = input("sphere.vti");
  EXPECT_FAILS_CLEANLY(run("convert " + input("missing.nrrd") + " -o m.vtu"), "does not exist");
  EXPECT_FAILS_CLEANLY(run("convert " + input("notes.txt") + " -o m.vtu"), "unknown volume format");
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o m.vtk"), ".vtu");
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o nowhere/m.vtu"), "does not exist");
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o m.vtu --stats s.txt"), ".json");
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o m.vtu --png m.jpg"), ".png");
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o m.vtu --max-level -2"), "max-level");
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o m.vtu --resolution fine"), "resolution");
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o m.vtu --resolution voxel --max-level 2"), "--max-level");
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o m.vtu --voxel -1"), "voxel");  // 0: no resampling (the default)
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o m.vtu --threshold banana"), "banana");
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o m.vtu --modality pet"), "modality");
  EXPECT_FAILS_CLEANLY(run("convert " + in), "--output");
  // a threshold that leaves no tissue: the work starts, fails, and writes nothing
  EXPECT_FAILS_CLEANLY(run("convert " + in + " -o m.vtu --stats s.json --threshold 3000"), "3000");
}

TEST_F(CliConvert, FailureKeepsEarlierOutputs) {
  std::ofstream(out_ / "m.vtu") << "an older model";
  const RunResult r = run("convert " + input("sphere.vti") + " -o m.vtu --threshold 3000");
  EXPECT_NE(r.code, 0);
  EXPECT_EQ(slurp(out_ / "m.vtu"), "an older model");
  EXPECT_EQ(outputs(), (std::set<std::string>{"m.vtu"}));
}

// A labelmap (a block with a spherical lesion: labels 0 air, 1 tissue, 2 lesion), as Slicer
// writes one: --label N makes the model of one label; read as HU it is all tissue, and says so.
TEST_F(CliConvert, LabelmapSelectsOneLabelAndAllTissueWarns) {
  PhantomSettings s;
  s.name = "block-lesion";
  s.size = 24;
  s.air_hu = 0;
  s.tissue_hu = 1;
  s.lesion_hu = 2;
  PhantomShape shape;
  write_volume(make_phantom(s, &shape), out_ / "labels.nrrd");
  ASSERT_GT(shape.lesion_voxels, 0);
  const auto tissue_of = [&](const char* stats) {
    return nlohmann::json::parse(slurp(out_ / stats)).at("prepare").at("tissue_voxels").get<std::int64_t>();
  };
  // label 2: the lesion's voxels, exactly; label 1: the block without them
  RunResult r = run("convert labels.nrrd --label 2 -o lesion.vtu --stats lesion.json --no-crop");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("label:          2"), std::string::npos) << r.out;
  EXPECT_EQ(tissue_of("lesion.json"), shape.lesion_voxels);
  EXPECT_EQ(nlohmann::json::parse(slurp(out_ / "lesion.json")).at("label"), 2);
  r = run("convert labels.nrrd --label 1 -o block.vtu --stats block.json --no-crop");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(tissue_of("block.json"), shape.tissue_voxels - shape.lesion_voxels);
  EXPECT_EQ(r.err.find("warning"), std::string::npos) << r.err;
  // read as HU with the default window (>= -200): every voxel is tissue, a warning says so (even with -q)
  r = run("convert labels.nrrd -o box.vtu -q");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("warning: every voxel of the volume (13824 voxels, values 0 to 2)"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("--label N"), std::string::npos) << r.err;
  // a label that is not there: the labels that are; a volume that is not a labelmap: said so
  r = run("convert labels.nrrd --label 7 -o none.vtu");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("its labels are 0, 1, 2"), std::string::npos) << r.err;
  r = run("convert " + input("sphere.vti") + " --label 1 -o none.vtu");
  EXPECT_EQ(r.code, 1);  // the sphere phantom holds 40 and -1000 HU: no label 1
  EXPECT_NE(r.err.find("its labels are -1000, 40"), std::string::npos) << r.err;
  write_volume([] {
    Volume v = make_phantom(PhantomSettings{});
    v.hu[0] = 0.5f;
    return v;
  }(), out_ / "ct.nrrd");
  r = run("convert ct.nrrd --label 1 -o none.vtu");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("holds the value 0.5, so it is not a labelmap"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out_ / "none.vtu"));
  // --label with an HU window or resampling: a command-line mistake
  EXPECT_EQ(run("convert labels.nrrd --label 1 --threshold bone -o x.vtu").code, 2);
  EXPECT_EQ(run("convert labels.nrrd --label 1 --voxel 2 -o x.vtu").code, 2);
  EXPECT_EQ(run("convert labels.nrrd --label 1 --threshold tissue -o t.vtu -q").code, 0);  // Slicer passes the default
}
