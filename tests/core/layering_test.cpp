// The core (src/) depends on Eigen only: no VTK, SDL2, DCMTK (nor the pipeline's JSON/fmt)
// header may be included there. This test reads every source file under src/.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace {

std::vector<std::string> forbidden_includes(const fs::path& file) {
  static const std::regex include(R"(^\s*#\s*include\s*[<"]([^>"]+)[>"])");
  static const std::regex forbidden(
      R"(^(vtk|Vtk|QVTK|SDL|SDL2/|dcmtk/|dcm|ofstd|nlohmann/|fmt/|spdlog/|CLI/|gtest/|benchmark/|pipeline/|apps/))");
  std::vector<std::string> bad;
  std::ifstream in(file);
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    std::smatch m;
    if (std::regex_search(line, m, include) && std::regex_search(m[1].str(), forbidden))
      bad.push_back(file.string() + ":" + std::to_string(n) + ": " + m[1].str());
  }
  return bad;
}

}  // namespace

TEST(Layering, CoreIncludesNoVtkSdlOrDcmtk) {
  const fs::path src = fs::path(VX_SOURCE_DIR) / "src";
  ASSERT_TRUE(fs::is_directory(src));
  int files = 0;
  std::vector<std::string> bad;
  for (const auto& entry : fs::recursive_directory_iterator(src)) {
    const auto ext = entry.path().extension();
    if (ext != ".h" && ext != ".hpp" && ext != ".cpp" && ext != ".cc") continue;
    ++files;
    for (auto& b : forbidden_includes(entry.path())) bad.push_back(b);
  }
  EXPECT_GE(files, 6);
  for (const auto& b : bad) ADD_FAILURE() << "forbidden include in the core: " << b;
}

TEST(Layering, CheckerCatchesForbiddenIncludes) {
  // the checker itself must be able to fail
  const fs::path tmp = fs::temp_directory_path() / "vx_layering_probe.cpp";
  {
    std::ofstream out(tmp);
    out << "#include <Eigen/Core>\n#include <vtkPolyData.h>\n  #  include \"SDL.h\"\n#include <dcmtk/dcmdata/dctk.h>\n";
  }
  const auto bad = forbidden_includes(tmp);
  fs::remove(tmp);
  EXPECT_EQ(bad.size(), 3u);
}

TEST(Layering, CoreCMakeLinksEigenOnly) {
  std::ifstream in(fs::path(VX_SOURCE_DIR) / "src" / "CMakeLists.txt");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_FALSE(text.empty());
  for (const char* lib : {"VTK", "SDL2", "DCMTK", "nlohmann", "fmt::", "spdlog"})
    EXPECT_EQ(text.find(lib), std::string::npos) << "src/CMakeLists.txt mentions " << lib;
}
