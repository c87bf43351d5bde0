#pragma once
/// @file scene_helpers.h
/// Test helpers for scene files (tests/pipeline/scene/scene_test.cpp, prepare_scene_test.cpp):
/// a small valid scene (a box indented by a ball), the message a scene's parse throws, and a
/// fresh temporary folder.
#include <unistd.h>

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "base/error.h"
#include "scene/scene.h"

#define EXPECT_CONTAINS(haystack, needle) \
  EXPECT_NE(std::string(haystack).find(needle), std::string::npos) << "message: " << (haystack)

namespace vx::testing {

/// A small valid scene: a box indented by a ball.
inline nlohmann::json base_scene() {
  return nlohmann::json::parse(R"({
    "object": {"box_mm": {"min": [0, 0, 0], "max": [12, 12, 6]}, "voxel_mm": 1.0},
    "material": {"youngs_modulus_kpa": 10, "poisson_ratio": 0, "density_kg_m3": 1000, "damping": 0.1},
    "fixed": ["z_min"],
    "integrator": {"type": "symplectic_euler", "dt_s": "auto"},
    "probes": [{"name": "ball", "shape": "sphere", "radius_mm": 3,
                "path": [{"t_s": 0, "position_mm": [6, 6, 9.2]}, {"t_s": 0.05, "position_mm": [6, 6, 8.2]}]}],
    "duration_s": 0.05
  })");
}

/// The message of the vx::Error that parsing `j` throws ("" when it does not throw).
inline std::string error_of(const nlohmann::json& j) {
  try {
    (void)parse_scene(j, std::filesystem::path(VX_SAMPLES_DIR) / "scenes", "test.json");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

inline std::string error_of_text(const std::string& text) {
  try {
    (void)parse_scene(text, ".", "test.json");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

inline std::filesystem::path temp_dir(const std::string& name) {
  const std::filesystem::path d =
      std::filesystem::temp_directory_path() / ("vx_scene_test_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

}  // namespace vx::testing
