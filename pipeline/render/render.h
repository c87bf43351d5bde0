#pragma once
/// @file render.h
/// Pictures of the model for people: an off-screen VTK render written as PNG.
/// VTK 9.1 on Debian has only X11 rendering: without DISPLAY these functions throw
/// vx::Error saying to run under xvfb-run (never crash).

#include <filesystem>
#include <string>

#include "model/model.h"

namespace vx {

/// What to draw.
struct RenderSettings {
  int width{1200};
  int height{900};
  bool cutaway{true};        ///< remove the octant facing the camera to show the inner levels
  std::string title;         ///< text drawn at the top; empty = none
};

/// True when an X display is available for rendering.
[[nodiscard]] bool display_available();

/// Renders the model's elements coloured by level (with a legend) to a PNG, atomically.
void render_model_png(const Model& model, const std::filesystem::path& png, const RenderSettings& settings = {});

}  // namespace vx
