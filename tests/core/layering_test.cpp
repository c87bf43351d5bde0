// The layers and their folders. Data flows one way: apps -> evaluation -> pipeline -> core, and
// inside the core base -> model -> physics -> sim (surface beside physics). Includes name the
// folder ("sim/state.h"), so a reader knows from the line where a header lives; this test reads
// every source file and forbids every include that runs back up:
// - the core (src/) includes Eigen and the standard library only (and, in sim/sparse_factor.cpp,
//   the sparse Cholesky's CHOLMOD and METIS when the build has them): no VTK, SDL2, DCMTK, JSON,
//   fmt, nor any pipeline, evaluation or app header;
// - inside the core, a stage includes only the stages below it;
// - the pipeline never includes evaluation or app headers;
// - evaluation never includes app headers.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace {

/// Quoted and angle includes of a file: (line number, header).
std::vector<std::pair<int, std::string>> includes_of(const fs::path& file) {
  static const std::regex include(R"(^\s*#\s*include\s*[<"]([^>"]+)[>"])");
  std::vector<std::pair<int, std::string>> out;
  std::ifstream in(file);
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    std::smatch m;
    if (std::regex_search(line, m, include)) out.emplace_back(n, m[1].str());
  }
  return out;
}

const std::regex kThirdPartyOutsideCore(
    R"(^(vtk|Vtk|QVTK|SDL|SDL2/|dcmtk/|dcm|ofstd|nlohmann/|fmt/|spdlog/|CLI/|gtest/|benchmark/))");

const std::set<std::string> kCoreStages{"base", "model", "physics", "sim", "surface"};
const std::set<std::string> kPipelineStages{"util", "io", "convert", "scene", "render"};
const std::set<std::string> kEvaluationStages{"verify", "bench"};

/// The stages of the core each stage may include (itself included).
const std::map<std::string, std::set<std::string>> kCoreAllowed{
    {"base", {"base"}},
    {"model", {"base", "model"}},
    {"physics", {"base", "model", "physics"}},
    {"surface", {"base", "model", "surface"}},
    {"sim", {"base", "model", "physics", "sim", "surface"}},
};

std::string first_folder(const std::string& header) {
  const auto slash = header.find('/');
  return slash == std::string::npos ? std::string() : header.substr(0, slash);
}

/// The forbidden includes of `file`, which lives in `layer` ("core", "pipeline", "evaluation")
/// and in the stage folder `stage` of that layer.
std::vector<std::string> forbidden_includes(const fs::path& file, const std::string& layer,
                                            const std::string& stage) {
  std::vector<std::string> bad;
  for (const auto& [line, header] : includes_of(file)) {
    const std::string folder = first_folder(header);
    bool forbidden = false;
    if (layer == "core") {
      forbidden = std::regex_search(header, kThirdPartyOutsideCore) || kPipelineStages.count(folder) ||
                  kEvaluationStages.count(folder) || folder == "pipeline" || folder == "apps" ||
                  (kCoreStages.count(folder) && kCoreAllowed.count(stage) &&
                   !kCoreAllowed.at(stage).count(folder));
    } else if (layer == "pipeline") {
      forbidden = kEvaluationStages.count(folder) || folder == "apps" || folder == "evaluation";
    } else if (layer == "evaluation") {
      forbidden = folder == "apps";
    }
    if (forbidden) bad.push_back(file.string() + ":" + std::to_string(line) + ": " + header);
  }
  return bad;
}

/// Checks every source file under `dir` (layer `layer`); returns the number of files read.
int check_layer(const fs::path& dir, const std::string& layer, std::vector<std::string>& bad) {
  int files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    const auto ext = entry.path().extension();
    if (ext != ".h" && ext != ".hpp" && ext != ".cpp" && ext != ".cc" && ext != ".in") continue;
    ++files;
    const std::string stage = fs::relative(entry.path(), dir).begin()->string();
    for (auto& b : forbidden_includes(entry.path(), layer, stage)) bad.push_back(b);
  }
  return files;
}

}  // namespace

TEST(Layering, CoreIncludesNoVtkSdlOrDcmtkAndStagesLookDown) {
  const fs::path src = fs::path(VX_SOURCE_DIR) / "src";
  ASSERT_TRUE(fs::is_directory(src));
  std::vector<std::string> bad;
  EXPECT_GE(check_layer(src, "core", bad), 30);
  for (const auto& b : bad) ADD_FAILURE() << "forbidden include in the core: " << b;
}

TEST(Layering, CoreFilesLiveInStageFolders) {
  // a file directly under src/ (or in an unknown folder) would escape the stage rules
  const fs::path src = fs::path(VX_SOURCE_DIR) / "src";
  for (const auto& entry : fs::directory_iterator(src)) {
    if (entry.is_directory()) {
      EXPECT_TRUE(kCoreStages.count(entry.path().filename().string()))
          << "src/" << entry.path().filename().string() << " is not a stage of the core";
    } else {
      EXPECT_EQ(entry.path().filename(), "CMakeLists.txt") << entry.path() << " lies outside the stage folders";
    }
  }
}

TEST(Layering, PipelineIncludesNoEvaluationOrApps) {
  std::vector<std::string> bad;
  EXPECT_GE(check_layer(fs::path(VX_SOURCE_DIR) / "pipeline", "pipeline", bad), 30);
  for (const auto& b : bad) ADD_FAILURE() << "forbidden include in the pipeline: " << b;
}

TEST(Layering, EvaluationIncludesNoApps) {
  std::vector<std::string> bad;
  EXPECT_GE(check_layer(fs::path(VX_SOURCE_DIR) / "evaluation", "evaluation", bad), 8);
  for (const auto& b : bad) ADD_FAILURE() << "forbidden include in evaluation: " << b;
}

TEST(Layering, CheckerCatchesForbiddenIncludes) {
  // the checker itself must be able to fail
  const fs::path tmp = fs::temp_directory_path() / "vx_layering_probe.cpp";
  {
    std::ofstream out(tmp);
    out << "#include <Eigen/Core>\n#include <vtkPolyData.h>\n  #  include \"SDL.h\"\n"
           "#include <dcmtk/dcmdata/dctk.h>\n#include \"sim/state.h\"\n#include \"io/volume_io.h\"\n"
           "#include \"model/model.h\"\n#include \"verify/verify.h\"\n";
  }
  // a model-stage file: the third-party headers, the sim stage, the pipeline and evaluation
  EXPECT_EQ(forbidden_includes(tmp, "core", "model").size(), 6u);
  // a sim-stage file may include the model stage and sim itself
  EXPECT_EQ(forbidden_includes(tmp, "core", "sim").size(), 5u);
  // the pipeline may include the core and third-party headers, not evaluation
  EXPECT_EQ(forbidden_includes(tmp, "pipeline", "io").size(), 1u);
  EXPECT_EQ(forbidden_includes(tmp, "evaluation", "verify").size(), 0u);
  fs::remove(tmp);
}

TEST(Layering, CoreCMakeLinksEigenOnly) {
  std::ifstream in(fs::path(VX_SOURCE_DIR) / "src" / "CMakeLists.txt");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_FALSE(text.empty());
  for (const char* lib : {"VTK", "SDL2", "DCMTK", "nlohmann", "fmt::", "spdlog"})
    EXPECT_EQ(text.find(lib), std::string::npos) << "src/CMakeLists.txt mentions " << lib;
}
