#pragma once
/// @file rigid_sums.h
/// The weighted sums an element's pass collects over its vertices, its centroid's and its rigid
/// velocity fit's (elements.h, damping), shared by the element kernels: T is double for the
/// scalar kernels and a vector of lanes (one element each) for the batched one
/// (element_batches.h). Internal to the core.

namespace vx {

/// Over the vertices of an element, with weights w and offsets y = x - x0 from its first vertex:
/// sw = sum w and s = sum w y (the weighted centroid c = s / sw, relative to x0).
template <class T>
struct CentroidSums {
  T sw{}, sx{}, sy{}, sz{};

  /// Adds one vertex (always inlined, as RigidSums::add).
  [[gnu::always_inline]] inline void add(T w, T yx, T yy, T yz) {
    sw += w;
    sx += w * yx;
    sy += w * yy;
    sz += w * yz;
  }
};

/// Over the vertices of an element, with weights w, offsets y = x - x0 from its first vertex and
/// velocities v: sv = sum w v, l = sum w y x v, i = sum w y y^T (upper triangle).
template <class T>
struct RigidSums {
  T svx{}, svy{}, svz{}, lx{}, ly{}, lz{}, ixx{}, ixy{}, ixz{}, iyy{}, iyz{}, izz{};

  /// Adds one vertex (always inlined: the batched kernel's copies are compiled per instruction set).
  [[gnu::always_inline]] inline void add(T w, T yx, T yy, T yz, T vx, T vy, T vz) {
    const T wx = w * yx, wy = w * yy, wz = w * yz;
    svx += w * vx;
    svy += w * vy;
    svz += w * vz;
    lx += wy * vz - wz * vy;
    ly += wz * vx - wx * vz;
    lz += wx * vy - wy * vx;
    ixx += wx * yx;
    ixy += wx * yy;
    ixz += wx * yz;
    iyy += wy * yy;
    iyz += wy * yz;
    izz += wz * yz;
  }
};

}  // namespace vx
