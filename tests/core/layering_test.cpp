// The layers and their folders. Data flows one way: apps -> evaluation -> pipeline -> core, and
// inside the core base -> model -> physics -> sim -> haptics (surface beside physics). Includes name the
// folder ("sim/state.h"), so a reader knows from the line where a header lives; this test reads
// every source file and forbids every include that runs back up:
// - the core (src/) includes Eigen and the standard library only (and, in sim/sparse_factor.cpp,
//   the sparse Cholesky's CHOLMOD and METIS when the build has them; in base/huge_pages.cpp, Linux's
//   madvise; in base/pi_mutex.cpp, POSIX threads' priority-inheritance mutex): no VTK, SDL2, DCMTK, JSON,
//   fmt, nor any pipeline, evaluation or app header;
// - inside the core, a stage includes only the stages below it;
// - the pipeline never includes evaluation or app headers;
// - evaluation never includes app headers;
// - inside a folder of the core, the pipeline, evaluation and the apps, the files form rooms (a
//   header and its source; a few files that make one unit share a room) in a declared order, the
//   lowest first (kRoomOrder): a file includes only headers of its own room and of rooms listed
//   before it, so no arrow runs back up inside a folder either. A new file needs its place in that
//   list. The apps include their own headers without the folder ("probe_scene.h").
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
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

const std::set<std::string> kCoreStages{"base", "model", "physics", "sim", "haptics", "surface"};
const std::set<std::string> kPipelineStages{"util", "io", "convert", "scene", "render"};
const std::set<std::string> kEvaluationStages{"verify", "bench"};

/// The stages of the core each stage may include (itself included).
const std::map<std::string, std::set<std::string>> kCoreAllowed{
    {"base", {"base"}},
    {"model", {"base", "model"}},
    {"physics", {"base", "model", "physics"}},
    {"surface", {"base", "model", "surface"}},
    {"sim", {"base", "model", "physics", "sim", "surface"}},
    {"haptics", {"base", "model", "physics", "sim", "surface", "haptics"}},
};

std::string first_folder(const std::string& header) {
  const auto slash = header.find('/');
  return slash == std::string::npos ? std::string() : header.substr(0, slash);
}

/// The forbidden includes of `file`, which lives in `layer` ("core", "pipeline", "evaluation")
/// and in the stage folder `stage` of that layer.
std::vector<std::string> forbidden_includes(const fs::path& file, const std::string& layer, const std::string& stage) {
  std::vector<std::string> bad;
  for (const auto& [line, header] : includes_of(file)) {
    const std::string folder = first_folder(header);
    bool forbidden = false;
    if (layer == "core") {
      forbidden = std::regex_search(header, kThirdPartyOutsideCore) || kPipelineStages.count(folder) ||
                  kEvaluationStages.count(folder) || folder == "pipeline" || folder == "apps" ||
                  (kCoreStages.count(folder) && kCoreAllowed.count(stage) && !kCoreAllowed.at(stage).count(folder));
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

/// The rooms of each folder, the lowest first; a room is the files named `stem.h`, `stem.cpp`
/// (any extension after the first dot), several stems separated by spaces sharing one room.
/// Shared rooms are knots still to untie: the 3D and 2D builders call each other; in
/// src/physics the element pass, the calibration and the SIMD kernels call each other (issue
/// 26's one element law; the batches' data is below them in element_batch_layout.h);
/// bench_parts.h is the private half of bench.h, probe_view_impl.h of probe_view.h (the view's
/// parts in several files).
// (kept by hand: one folder a paragraph)
// clang-format off
const std::map<std::string, std::vector<std::string>> kRoomOrder{
    {"src/base", {"error", "content_hash", "huge_pages", "simd", "cache_file_format", "parallel", "pi_mutex", "triple_buffer", "version"}},
    {"src/model", {"voxel_grid", "model", "voxel_shapes", "gradational_builder gradational_builder_2d", "lattice_origin"}},
    {"src/physics",
     {"rigid_sums", "element_gradient", "element_modes", "element_batch_layout", "material", "vertex_weights",
      "calibration_key", "physics_model", "calibrated_fields", "rotation_fit", "element_pass", "element_law", "element_batches",
      "elements", "calibration", "physics_model_key"}},
    {"src/surface", {"lattice_lookup", "surface embed_surface", "slice_surface"}},
    {"src/sim",
     {"integrator_kind", "time_step", "state", "step_report", "contact_constraint",
      "sparse_factor sparse_factor_solve sparse_factor_sweeps sparse_factor_file", "contact_active_set", "projective_solver",
      "region_stiffening", "static_solver", "integrators", "probe", "contact", "simulation"}},
    {"src/haptics", {"device_force", "local_compliance", "local_contact", "device_side"}},
    {"pipeline/util", {"system_memory", "thread_priority", "exit_codes", "text", "log", "progress", "atomic_file", "vtk_messages"}},
    {"pipeline/io",
     {"read_options", "volume", "compression", "jpeg2000", "dicom_common", "dicom_series_parts", "dicom_header",
      "dicom_slice_layout", "dicom_pixels", "dicom_series", "dicom_writer", "volume_formats", "vti_check",
      "element_faces", "vtk_arrays", "vti_io", "metaimage_io", "nifti_io", "nrrd_io", "raw_io", "volume_io",
      "segmentation_io", "model_io", "surface_io", "cache_file", "folder_cache", "factor_cache", "calibration_cache", "surface_cache",
      "region_check_cache"}},
    {"pipeline/convert", {"threshold", "stats", "phantom", "iso_surface", "decimate_surface", "prepare"}},
    {"pipeline/scene", {"strict_json", "fast_configuration", "sim_output", "scene", "run_outputs", "material_field", "palpation_defaults", "prepare_scene", "palpation_map", "palpation_map_output"}},
    {"pipeline/render", {"palette", "plot", "plot_spec", "render"}},
    {"evaluation/verify",
     {"finite_brick_reference", "case_helpers", "static_newton", "surface_accuracy", "verify", "cases", "statics_cases", "dynamics_cases", "geometry_cases",
      "plane_cases", "robustness_cases", "verify_cases"}},
    {"evaluation/bench",
     {"step_benchmark", "haptic_accuracy", "scale_bench", "bench bench_parts", "bench_metrics", "bench_palpation",
      "bench_plots", "bench_report", "bench_step_cost"}},
    {"evaluation/microbench", {"build_bench", "step_bench"}},
    {"apps/voxelastic",
     {"usage", "commands", "cmd_bench", "cmd_convert", "cmd_palpate_map", "cmd_phantom", "cmd_plot", "cmd_simulate",
      "cmd_verify", "main"}},
    {"apps/probe",
     {"joystick_script", "force_guard", "real_time_meter", "thread_share", "sim_exchange", "rate_thread", "soak", "display",
      "sdl_input", "force_output", "stick_control",
      "probe_view probe_view_impl probe_view_actors probe_view_hud probe_view_levels", "probe_scene", "app_options",
      "app_shared", "device_loop", "gui_loop", "physics_loop", "probe_app", "main"}},
};
// clang-format on

bool is_source(const fs::path& p) {
  const auto ext = p.extension();
  return ext == ".h" || ext == ".hpp" || ext == ".cpp" || ext == ".cc" || ext == ".in" || ext == ".inl";
}

/// The room of a file: its name up to the first dot (`version.h.in` -> "version").
std::string stem_of(const fs::path& file) {
  const std::string name = file.filename().string();
  return name.substr(0, name.find('.'));
}

/// Checks the files directly in `dir` (a folder named like the first part of its includes,
/// "sim" for "sim/state.h") against its rooms `order`, the lowest first. Appends to `up` every
/// include of a room listed after the including file's room, and to `unplaced` every file whose
/// room is not listed (and every include of an unlisted header). Returns the files read.
int check_room_order(const fs::path& dir, const std::vector<std::string>& order, std::vector<std::string>& up,
                     std::vector<std::string>& unplaced) {
  std::map<std::string, std::size_t> level;
  for (std::size_t i = 0; i < order.size(); ++i) {
    std::istringstream stems(order[i]);
    for (std::string stem; stems >> stem;) level[stem] = i;
  }
  const std::string folder = dir.filename().string();
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (!entry.is_regular_file() || !is_source(entry.path())) continue;
    ++files;
    const auto own = level.find(stem_of(entry.path()));
    if (own == level.end()) {
      unplaced.push_back(entry.path().string());
      continue;
    }
    for (const auto& [line, header] : includes_of(entry.path())) {
      // "sim/state.h" in sim/, or a bare "probe_scene.h" beside the file (the apps)
      const bool beside = first_folder(header).empty() && fs::exists(dir / header);
      if (first_folder(header) != folder && !beside) continue;
      const auto target = level.find(stem_of(fs::path(header)));
      const std::string where = entry.path().string() + ":" + std::to_string(line) + ": " + header;
      if (target == level.end())
        unplaced.push_back(where);
      else if (target->second > own->second)
        up.push_back(where + " (room '" + order[target->second] + "' is above '" + order[own->second] + "')");
    }
  }
  return files;
}

}  // namespace

TEST(Layering, IncludesInsideAFolderLookDown) {
  int files = 0;
  for (const auto& [folder, order] : kRoomOrder) {
    const fs::path dir = fs::path(VX_SOURCE_DIR) / folder;
    ASSERT_TRUE(fs::is_directory(dir)) << folder << " is in kRoomOrder but is no folder";
    std::vector<std::string> up, unplaced;
    files += check_room_order(dir, order, up, unplaced);
    for (const auto& u : up) ADD_FAILURE() << "include back up inside " << folder << ": " << u;
    for (const auto& u : unplaced)
      ADD_FAILURE() << "not in the declared rooms of " << folder << " (give it its place in kRoomOrder, "
                    << "tests/core/layering_test.cpp, above every room it includes): " << u;
  }
  EXPECT_GE(files, 150);
}

TEST(Layering, EveryFolderDeclaresItsRooms) {
  // a folder with sources but no declared order would escape the check above
  for (const char* layer : {"src", "pipeline", "evaluation", "apps"})
    for (const auto& entry : fs::directory_iterator(fs::path(VX_SOURCE_DIR) / layer)) {
      if (!entry.is_directory()) continue;
      bool sources = false;
      for (const auto& f : fs::directory_iterator(entry.path())) sources = sources || is_source(f.path());
      const std::string folder = std::string(layer) + "/" + entry.path().filename().string();
      if (!sources) continue;
      EXPECT_TRUE(kRoomOrder.count(folder)) << folder << " has no declared room order (kRoomOrder)";
    }
}

TEST(Layering, RoomCheckerCatchesAnArrowBackUp) {
  // a fixture folder "sim": low.h includes high.h, a room declared above it; a stray header has no room
  const fs::path dir = fs::temp_directory_path() /
                       ("vx_rooms_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed())) / "sim";
  fs::create_directories(dir);
  auto write = [&](const char* name, const char* text) { std::ofstream(dir / name) << text; };
  write("low.h", "#pragma once\n#include <vector>\n#include \"model/model.h\"\n#include \"sim/high.h\"\n");
  write("low.cpp", "#include \"sim/low.h\"\n");
  write("high.h", "#pragma once\n#include \"sim/low.h\"\n#include \"sim/twin.h\"\n");
  write("high.cpp", "#include \"sim/high.h\"\n#include \"sim/low.h\"\n");
  write("twin.h", "#pragma once\n#include \"sim/high.h\"\n");
  write("stray.h", "#pragma once\n#include \"sim/low.h\"\n");
  write("notes.txt", "#include \"sim/high.h\"\n");  // not a source file: not read
  std::vector<std::string> up, unplaced;
  EXPECT_EQ(check_room_order(dir, {"low", "high twin"}, up, unplaced), 6);
  ASSERT_EQ(up.size(), 1u);
  EXPECT_NE(up[0].find("low.h:4: sim/high.h"), std::string::npos) << up[0];
  ASSERT_EQ(unplaced.size(), 1u);
  EXPECT_NE(unplaced[0].find("stray.h"), std::string::npos) << unplaced[0];
  // an app's bare include of a header beside it counts too
  write("bare.h", "#pragma once\n#include \"high.h\"\n#include <vector>\n");
  up.clear();
  unplaced.clear();
  check_room_order(dir, {"bare", "low", "high twin"}, up, unplaced);
  ASSERT_EQ(up.size(), 2u);  // low.h -> sim/high.h, bare.h -> high.h
  EXPECT_NE(up[0].find("high.h"), std::string::npos) << up[0];
  fs::remove(dir / "bare.h");
  // the same files with the arrow turned the right way: high below low is wrong twice
  up.clear();
  unplaced.clear();
  check_room_order(dir, {"high twin", "low"}, up, unplaced);
  EXPECT_EQ(up.size(), 2u);  // high.h and high.cpp include low.h
  // one room for all three: no arrow runs up
  up.clear();
  unplaced.clear();
  check_room_order(dir, {"low high twin", "stray"}, up, unplaced);
  EXPECT_TRUE(up.empty());
  EXPECT_TRUE(unplaced.empty());
  fs::remove_all(dir.parent_path());
}

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
