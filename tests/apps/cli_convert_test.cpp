// `voxelastic convert` through the built binary: outputs, statistics, and clean failures.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>
#include <vtkCellData.h>
#include <vtkDataArray.h>
#include <vtkNew.h>
#include <vtkUnstructuredGrid.h>
#include <vtkXMLUnstructuredGridReader.h>

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
#include "io/segmentation_io.h"
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
  for (const char* word : {"elements", "nodes", "vertex entries", "reduction", "model.vtu"})
    EXPECT_NE(r.out.find(word), std::string::npos) << word << "\n" << r.out;
  // each figure once: the tissue count, the element count and the grid appear once each
  const auto times = [&](const std::string& figure) {
    int n = 0;
    for (auto p = r.out.find(figure); p != std::string::npos; p = r.out.find(figure, p + 1)) ++n;
    return n;
  };
  EXPECT_EQ(times(" " + std::to_string(phantom_tissue()) + " "), 1) << r.out;
  const nlohmann::json js = nlohmann::json::parse(slurp(out_ / "stats.json"));
  EXPECT_EQ(times(" " + std::to_string(js.at("elements").get<std::int64_t>()) + " "), 1) << r.out;

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
  // (exit 2, as a segment name that is not there: the argument does not fit the input)
  r = run("convert labels.nrrd --label 7 -o none.vtu");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("its labels are 0, 1, 2"), std::string::npos) << r.err;
  r = run("convert " + input("sphere.vti") + " --label 1 -o none.vtu");
  EXPECT_EQ(r.code, 2);  // the sphere phantom holds 40 and -1000 HU: no label 1
  EXPECT_NE(r.err.find("its labels are -1000, 40"), std::string::npos) << r.err;
  write_volume([] {
    Volume v = make_phantom(PhantomSettings{});
    v.hu[0] = 0.5f;
    return v;
  }(), out_ / "ct.nrrd");
  r = run("convert ct.nrrd --label 1 -o none.vtu");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("holds the value 0.5, so it is not a labelmap"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out_ / "none.vtu"));
  // --label with an HU window or resampling: a command-line mistake
  EXPECT_EQ(run("convert labels.nrrd --label 1 --threshold bone -o x.vtu").code, 2);
  EXPECT_EQ(run("convert labels.nrrd --label 1 --voxel 2 -o x.vtu").code, 2);
  EXPECT_EQ(run("convert labels.nrrd --label 1 --threshold tissue -o t.vtu -q").code, 0);  // Slicer passes the default
}

// A 3D Slicer segmentation in its layered form (the first axis the layer, "kinds: list domain
// domain domain"), written here as Slicer writes one: layer 0 "block" (the block-lesion
// phantom's block, lesion included), layer 1 "lesion" (its lesion), both label 1, overlapping.
// --label NAME makes the model of one segment; --mask writes the model's voxels as a segmentation
// that reads back on the input's grid and converts to the same model.
TEST_F(CliConvert, SlicerSegmentationByNameAndTheModelsVoxelsAsASegmentation) {
  PhantomSettings s;
  s.name = "block-lesion";
  s.size = 24;
  s.air_hu = 0;
  s.tissue_hu = 1;
  s.lesion_hu = 2;
  PhantomShape shape;
  const Volume labels = make_phantom(s, &shape);
  ASSERT_GT(shape.lesion_voxels, 0);
  const GridGeometry& g = labels.geometry;
  std::string header = "NRRD0004\ntype: unsigned char\ndimension: 4\nspace: left-posterior-superior\n";
  header += fmt::format("sizes: 2 {} {} {}\n", g.dims.x(), g.dims.y(), g.dims.z());
  const Eigen::Matrix3d A = g.direction * g.spacing_mm.asDiagonal();
  header += fmt::format("space directions: none ({},{},{}) ({},{},{}) ({},{},{})\n", A(0, 0), A(1, 0), A(2, 0), A(0, 1),
                        A(1, 1), A(2, 1), A(0, 2), A(1, 2), A(2, 2));
  header += fmt::format("kinds: list domain domain domain\nencoding: raw\nspace origin: ({},{},{})\n", g.origin_mm.x(),
                        g.origin_mm.y(), g.origin_mm.z());
  header += "Segment0_ID:=Segment_1\nSegment0_Name:=block\nSegment0_LabelValue:=1\nSegment0_Layer:=0\n";
  header += "Segment1_ID:=Segment_2\nSegment1_Name:=lesion\nSegment1_LabelValue:=1\nSegment1_Layer:=1\n\n";
  {
    std::ofstream out(out_ / "two.seg.nrrd", std::ios::binary);
    out << header;
    for (const float v : labels.hu) out << char(v >= 1 ? 1 : 0) << char(v == 2 ? 1 : 0);
  }
  const auto json = [&](const char* name) { return nlohmann::json::parse(slurp(out_ / name)); };

  // the lesion by its name: its voxels, exactly; the mask holds the model's voxels on the input's grid
  RunResult r = run("convert two.seg.nrrd --label lesion -o lesion.vtu --stats lesion.json --mask lesion.seg.nrrd");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("segment:        lesion (label 1)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("lesion.seg.nrrd"), std::string::npos) << r.out;
  const nlohmann::json j = json("lesion.json");
  EXPECT_EQ(j.at("voxels").get<std::int64_t>(), shape.lesion_voxels);
  EXPECT_EQ(j.at("segment"), "lesion");
  EXPECT_EQ(j.at("outputs").at("mask"), "lesion.seg.nrrd");
  const Segmentation mask = read_segmentation(out_ / "lesion.seg.nrrd");
  EXPECT_EQ(mask.geometry.dims, g.dims);  // uncropped: the input's grid
  EXPECT_LT((mask.geometry.origin_mm - g.origin_mm).norm(), 1e-9) << mask.geometry.origin_mm.transpose();
  EXPECT_TRUE(mask.geometry.spacing_mm.isApprox(g.spacing_mm));
  EXPECT_TRUE(mask.geometry.direction.isApprox(g.direction));
  ASSERT_EQ(mask.segments.size(), 1u);
  EXPECT_EQ(mask.segments[0].name, "lesion");
  EXPECT_EQ(mask.count(mask.segments[0]), j.at("voxels").get<std::int64_t>());
  const Volume m = mask.mask(mask.segments[0]);
  std::int64_t same = 0;
  for (std::size_t i = 0; i < m.hu.size(); ++i) same += (m.hu[i] == 1.0f) == (labels.hu[i] == 2.0f);
  EXPECT_EQ(same, std::int64_t(m.hu.size()));  // voxel by voxel, in place
  EXPECT_EQ(load_model(out_ / "lesion.vtu").covered_voxels(), shape.lesion_voxels);

  // a segmentation of one segment needs no --label: the mask converts to the same model
  r = run("convert lesion.seg.nrrd -o again.vtu --stats again.json -q");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(json("again.json").at("elements"), j.at("elements"));
  EXPECT_EQ(json("again.json").at("voxels"), j.at("voxels"));

  // the block, lesion included, by its name in either case
  r = run("convert two.seg.nrrd --label BLOCK -o block.vtu --stats block.json -q");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(json("block.json").at("voxels").get<std::int64_t>(), shape.tissue_voxels);

  // a mistyped name, no name for two segments, a label number in two layers: exit 2, the segments listed
  const std::string listed = "its segments are 'block' (label 1, layer 0), 'lesion' (label 1, layer 1)";
  r = run("convert two.seg.nrrd --label lesoin -o x.vtu");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("no segment named 'lesoin' (did you mean 'lesion'?)"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(listed), std::string::npos) << r.err;
  r = run("convert two.seg.nrrd -o x.vtu");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("a segmentation of 2 segments: choose one with --label NAME"), std::string::npos) << r.err;
  r = run("convert two.seg.nrrd --label 1 -o x.vtu");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("label 1 is in 2 layers"), std::string::npos) << r.err;
  EXPECT_EQ(run("convert two.seg.nrrd --label lesion --threshold bone -o x.vtu").code, 2);
  EXPECT_FALSE(fs::exists(out_ / "x.vtu"));
  // a name for a labelmap without names; a mask that is not a .seg.nrrd
  write_volume(labels, out_ / "labels.nrrd");
  r = run("convert labels.nrrd --label lesion -o x.vtu");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("names are the segments of a 3D Slicer segmentation"), std::string::npos) << r.err;
  r = run("convert labels.nrrd --label 2 -o x.vtu --mask m.nrrd");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("m.seg.nrrd"), std::string::npos) << r.err;
}

// --mask on a CT volume: the tissue voxels the model covers, on the volume's own grid, though
// the model's grid was cropped and its lattice origin moved.
TEST_F(CliConvert, MaskOfACtVolumeIsTheModelsVoxelsOnTheInputsGrid) {
  const RunResult r = run("convert " + input("sphere.vti") + " -o m.vtu --stats m.json --mask m.seg.nrrd -q");
  ASSERT_EQ(r.code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(slurp(out_ / "m.json"));
  ASSERT_NE(j.at("grid"), nlohmann::json::array({32, 32, 32}));  // cropped
  const Segmentation mask = read_segmentation(out_ / "m.seg.nrrd");
  EXPECT_EQ(mask.geometry.dims, volume_->geometry.dims);
  EXPECT_LT((mask.geometry.origin_mm - volume_->geometry.origin_mm).norm(), 1e-9);
  EXPECT_TRUE(mask.geometry.spacing_mm.isApprox(volume_->geometry.spacing_mm));
  EXPECT_EQ(mask.count(mask.segments.at(0)), j.at("voxels").get<std::int64_t>());
  EXPECT_EQ(mask.count(mask.segments.at(0)), phantom_tissue());
  EXPECT_EQ(mask.segments.at(0).name, "voxelastic model");
  const Volume m = mask.mask(mask.segments[0]);
  for (std::size_t i = 0; i < m.hu.size(); ++i) ASSERT_EQ(m.hu[i] == 1.0f, volume_->hu[i] >= -200.0f) << "voxel " << i;
}

// The model file's per-element youngs_modulus_kpa and mean_hu: a lesion of 100 HU in tissue of
// 40 HU shows in both (a table linear between the two makes each element's averaged modulus the
// table's value at its mean HU); without a table the modulus is the one given.
TEST_F(CliConvert, ModelFileCarriesEachElementsModulusAndMeanHu) {
  PhantomSettings s;
  s.name = "block-lesion";
  s.size = 24;
  s.tissue_hu = 40;
  s.lesion_hu = 100;
  PhantomShape shape;
  write_volume(make_phantom(s, &shape), out_ / "lesion.nrrd");
  ASSERT_GT(shape.lesion_voxels, 0);
  const auto cell_array = [&](const char* file, const char* name) {
    vtkNew<vtkXMLUnstructuredGridReader> reader;
    reader->SetFileName((out_ / file).c_str());
    reader->Update();
    std::vector<double> v;
    vtkDataArray* a = reader->GetOutput()->GetCellData()->GetArray(name);
    if (a)
      for (vtkIdType i = 0; i < a->GetNumberOfTuples(); ++i) v.push_back(a->GetTuple1(i));
    return v;
  };
  RunResult r = run("convert lesion.nrrd -o table.vtu --hounsfield-table 40:10,100:50 -q");
  ASSERT_EQ(r.code, 0) << r.err;
  const std::vector<double> hu = cell_array("table.vtu", "mean_hu"), e = cell_array("table.vtu", "youngs_modulus_kpa");
  ASSERT_EQ(hu.size(), e.size());
  ASSERT_GT(hu.size(), 10u);
  const std::vector<double> volume = cell_array("table.vtu", "volume_mm3");
  ASSERT_EQ(volume.size(), hu.size());
  int with_lesion = 0, in_tissue = 0;
  double excess = 0, total = 0;  // the lesion's HU above the tissue's, summed over the elements' volumes
  for (std::size_t i = 0; i < hu.size(); ++i) {
    ASSERT_GE(hu[i], 40.0 - 1e-9);
    ASSERT_LE(hu[i], 100.0 + 1e-9);
    ASSERT_NEAR(e[i], 10.0 + (hu[i] - 40.0) * 40.0 / 60.0, 1e-9) << i;
    with_lesion += hu[i] > 40.0 + 1e-9;
    in_tissue += hu[i] == 40.0;
    excess += (hu[i] - 40.0) * volume[i];
    total += volume[i];
  }
  EXPECT_GT(with_lesion, 0);  // the lesion shows
  EXPECT_GT(in_tissue, with_lesion);
  // the means are volume averages: over the model, the lesion's share of the voxels times 60 HU
  EXPECT_NEAR(excess / total, 60.0 * double(shape.lesion_voxels) / double(shape.tissue_voxels), 1e-9);
  // without a table: the modulus given, everywhere; the same mean HU
  r = run("convert lesion.nrrd -o plain.vtu --youngs-modulus-kpa 7.5 -q");
  ASSERT_EQ(r.code, 0) << r.err;
  for (const double x : cell_array("plain.vtu", "youngs_modulus_kpa")) ASSERT_EQ(x, 7.5);
  EXPECT_EQ(cell_array("plain.vtu", "mean_hu"), hu);
  // table mistakes are command-line mistakes
  EXPECT_EQ(run("convert lesion.nrrd -o x.vtu --hounsfield-table 100:5,40:10").code, 2);
  EXPECT_EQ(run("convert lesion.nrrd -o x.vtu --hounsfield-table 40:10").code, 2);
  EXPECT_EQ(run("convert lesion.nrrd -o x.vtu --youngs-modulus-kpa 0").code, 2);
}
