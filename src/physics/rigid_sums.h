#pragma once
/// @file rigid_sums.h
/// The weighted sums of an element's rigid velocity fit (elements.h, damping), shared by the
/// element kernels: T is double for the scalar kernels and a vector of lanes (one element each)
/// for the batched one (element_batches.h). Internal to the core.

namespace vx {

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
    ixx += wx * yx; ixy += wx * yy; ixz += wx * yz;
    iyy += wy * yy; iyz += wy * yz; izz += wz * yz;
  }
};

}  // namespace vx
