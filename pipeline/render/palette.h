#pragma once
/// @file palette.h
/// The colours of element levels, the same in every picture (render.h) and in the probe app's
/// levels view: ColorBrewer Set2 (distinct, colour-blind friendly), level 0 (the fine surface
/// shell) first, repeating after 8 levels.

#include <array>

namespace vx {

/// Level `level` (>= 0) as red, green, blue in [0, 1].
[[nodiscard]] inline std::array<double, 3> level_colour(int level) {
  static constexpr unsigned char set2[8][3] = {{102, 194, 165}, {252, 141, 98}, {141, 160, 203}, {231, 138, 195},
                                               {166, 216, 84},  {255, 217, 47}, {229, 196, 148}, {179, 179, 179}};
  const auto* c = set2[level % 8];
  return {c[0] / 255.0, c[1] / 255.0, c[2] / 255.0};
}

}  // namespace vx
