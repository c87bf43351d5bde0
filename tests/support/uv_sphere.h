#pragma once
/// @file uv_sphere.h
/// A latitude-longitude (UV) sphere for tests: two poles (vertex 0 at +z, vertex 1 at -z), then
/// rings 1..rings-1 of `segments` vertices each, triangles wound the same way round every
/// band. `radius_mm(polar, azimuth)` (radians) sets the distance from `center_mm` of each
/// vertex, so a bumpy ("folded") ball is the same mesh with another radius function.

#include <Eigen/Core>
#include <cmath>
#include <numbers>
#include <vector>

namespace vx::testing {

template <class RadiusFn>
void uv_sphere(int rings, int segments, const Eigen::Vector3d& center_mm, RadiusFn radius_mm,
               Eigen::Matrix3Xd& vertices, Eigen::Matrix3Xi& triangles) {
  constexpr double pi = std::numbers::pi;
  vertices.resize(3, 2 + Eigen::Index(rings - 1) * segments);
  vertices.col(0) = center_mm + Eigen::Vector3d(0, 0, radius_mm(0.0, 0.0));
  vertices.col(1) = center_mm - Eigen::Vector3d(0, 0, radius_mm(pi, 0.0));
  const auto id = [&](int r, int s) { return 2 + (r - 1) * segments + (s % segments); };
  for (int r = 1; r < rings; ++r)
    for (int s = 0; s < segments; ++s) {
      const double th = pi * r / rings, ph = 2 * pi * s / segments;
      vertices.col(id(r, s)) = center_mm + radius_mm(th, ph) * Eigen::Vector3d(std::sin(th) * std::cos(ph),
                                                                              std::sin(th) * std::sin(ph), std::cos(th));
    }
  std::vector<Eigen::Vector3i> t;
  for (int s = 0; s < segments; ++s) {
    t.emplace_back(0, id(1, s), id(1, s + 1));
    t.emplace_back(1, id(rings - 1, s + 1), id(rings - 1, s));
    for (int r = 1; r + 1 < rings; ++r) {
      t.emplace_back(id(r, s), id(r + 1, s), id(r + 1, s + 1));
      t.emplace_back(id(r, s), id(r + 1, s + 1), id(r, s + 1));
    }
  }
  triangles.resize(3, Eigen::Index(t.size()));
  for (std::size_t i = 0; i < t.size(); ++i) triangles.col(Eigen::Index(i)) = t[i];
}

}  // namespace vx::testing
