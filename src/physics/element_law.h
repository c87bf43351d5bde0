#pragma once
/// @file element_law.h
/// The element's law written once (elements.h states it; docs/model.md sections 2 to 5): the
/// arithmetic that turns one element's sums into its forces, as templates on the number type T
/// (double for one element in the scalar kernels, a vector of kBatchLanes doubles, Lanes, one
/// element per lane in the batched kernel), as Box2D v3 keeps the scalar and the wide form of
/// its contact solver in one source. Values in, values out: where the numbers come from
/// (separate arrays, packed records, batch rows) and where the forces go stays in the kernels,
/// and so does the rotation fit (rotation_fit.h). Used by all three kernels: the reference and
/// packed ones (elements.cpp) and the batched one (element_batches.cpp: element_stress,
/// rigid_velocity and entry_force on its lanes, the same bits lane by lane as before).
///
/// Why a first attempt on the lanes cost 10 to 15 % at 128^3 (issue 26): entry_force summed its
/// components in loops over d, and GCC's early scalar replacement, which turns small local
/// arrays into registers, runs before loops are unrolled; so the lane kernel's r, fm and o
/// stayed arrays on the stack, and after unrolling their loads were forwarded but the stores
/// were not removed: 9 dead 32-byte stores per row of the hot loop (objdump, every instruction
/// set), beside its scattered force writes, which is where the 128^3 pass (bound by memory)
/// waits. Written out component by component (below) the row loop has no stack store, as the
/// lane kernel's own copy had none. Measured after (docs/bench.md, "The element pass": 7
/// alternated pairs, one thread, CPU time against the lane copy): AVX-512 0.97 at 128^3, 1.03
/// at 64^3 (noise); AVX2 1.05 at 128^3 and 1.16 at 64^3. That AVX2 cost was not the law's: the
/// generated code of both is the same up to register allocation (element_stress's arrays do not
/// stay on the stack), and the time went to a cache miss on the batch record the loop reads
/// ahead, which the hardware prefetchers covered or not depending on the code around it; the
/// record is now prefetched whole (element_batches.cpp, batch_range), and then the law costs
/// nothing on either instruction set (docs/bench.md).
///
///   G = 2 mu V (Q - F) + k (A - F C0),   M = k F                      element_stress
///   v_c = sum_i w_i v_i / W,   omega = I^{-1} (L - W c x v_c),
///   I = tr(Y) 1 - Y,   Y = sum_i w_i r_i r_i^T                          rigid_velocity
///   f_i = M w_i R0_i - k w_i r_i + G g_i [+ sum_p qm_p h_pi]
///         [+ c w_i (v_c + omega x r_i - v_i)]                           entry_force
///
/// 3 x 3 matrices are row-major arrays of 9. Every function is always inlined. Internal to the
/// core.

#include "physics/element_batch_layout.h"
#include "physics/rigid_sums.h"

// The lane vectors never cross a function boundary (everything here is always inlined), so the
// ABI note GCC gives for vector arguments without AVX does not apply.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wpsabi"

namespace vx::law {

/// kBatchLanes doubles, one element each (a GCC/Clang vector: + - * / act lane by lane).
using Lanes = double __attribute__((vector_size(8 * kBatchLanes)));

/// The matrices and rates of one element's force (or of one per lane).
template <class T>
struct ElementForce {
  T m[9];        ///< M = k F
  T g[9];        ///< G (+ the volume term's k_v (T - F), added by the caller)
  T k{};         ///< k_e, N/mm
  T damping{};   ///< c_e, N*s/mm (0 without damping)
  T vc[3]{};     ///< v_c, the weighted mean velocity, mm/s
  T omega[3]{};  ///< the rigid angular velocity about the centroid, 1/s
};

/// G = kaff (Q - F) + k (A - F C0) and M = k F into `out` (a, f, q, c0: row-major).
template <class T>
[[gnu::always_inline]] inline void element_stress(const T (&a)[9], const T (&f)[9], const T (&q)[9], const T (&c0)[9],
                                                  T k, T kaff, ElementForce<T>& out) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      const T fc = f[3 * i] * c0[j] + f[3 * i + 1] * c0[3 + j] + f[3 * i + 2] * c0[6 + j];
      out.g[3 * i + j] = kaff * (q[3 * i + j] - f[3 * i + j]) + k * (a[3 * i + j] - fc);
    }
  for (int i = 0; i < 9; ++i) out.m[i] = k * f[i];
  out.k = k;
}

/// omega set to zero where the inertia's trace `tr` is not positive (a collapsed element) or
/// omega is not finite (a collinear one).
[[gnu::always_inline]] inline void zero_degenerate_spin(double tr, double (&w)[3]) {
  if (!(tr > 0.0) || (w[0] + w[1] + w[2]) * 0.0 != 0.0) w[0] = w[1] = w[2] = 0.0;
}
[[gnu::always_inline]] inline void zero_degenerate_spin(const Lanes& tr, Lanes (&w)[3]) {
  const Lanes probe = (w[0] + w[1] + w[2]) * 0.0;
  for (int l = 0; l < kBatchLanes; ++l)
    if (!(tr[l] > 0.0) || probe[l] != 0.0) w[0][l] = w[1][l] = w[2][l] = 0.0;
}

/// The element's best rigid velocity (the damping's reference) from the weighted sums `rs` of
/// the offsets y = x - x0 and velocities, their weight `sw` (1 / sw in `inv_w`) and the
/// centroid c (relative to x0): v_c and omega into `out` (omega by the adjugate of the
/// symmetric inertia, with a tiny regularisation for a collinear element).
template <class T>
[[gnu::always_inline]] inline void rigid_velocity(const RigidSums<T>& rs, T sw, T inv_w, T cx, T cy, T cz,
                                                  ElementForce<T>& out) {
  const T ux = rs.svx * inv_w, uy = rs.svy * inv_w, uz = rs.svz * inv_w;
  // angular momentum about the centroid: L - sw c x vc
  const T angx = rs.lx - sw * (cy * uz - cz * uy), angy = rs.ly - sw * (cz * ux - cx * uz),
          angz = rs.lz - sw * (cx * uy - cy * ux);
  // sum w r r^T about the centroid, the inertia tr 1 - that (+ tiny regularisation)
  const T yxx = rs.ixx - sw * cx * cx, yxy = rs.ixy - sw * cx * cy, yxz = rs.ixz - sw * cx * cz;
  const T yyy = rs.iyy - sw * cy * cy, yyz = rs.iyz - sw * cy * cz, yzz = rs.izz - sw * cz * cz;
  const T tr = yxx + yyy + yzz;
  const T reg = tr * (1.0 + 1e-10);
  const T i00 = reg - yxx, i11 = reg - yyy, i22 = reg - yzz, i01 = -yxy, i02 = -yxz, i12 = -yyz;
  // omega = I^{-1} ang by the adjugate of the symmetric I
  const T c00 = i11 * i22 - i12 * i12, c01 = i02 * i12 - i01 * i22, c02 = i01 * i12 - i02 * i11;
  const T c11 = i00 * i22 - i02 * i02, c12 = i01 * i02 - i00 * i12, c22 = i00 * i11 - i01 * i01;
  const T inv_det = 1.0 / (i00 * c00 + i01 * c01 + i02 * c02);
  out.vc[0] = ux, out.vc[1] = uy, out.vc[2] = uz;
  out.omega[0] = (c00 * angx + c01 * angy + c02 * angz) * inv_det;
  out.omega[1] = (c01 * angx + c11 * angy + c12 * angz) * inv_det;
  out.omega[2] = (c02 * angx + c12 * angy + c22 * angz) * inv_det;
  zero_degenerate_spin(tr, out.omega);
}

/// The force of one vertex entry into `o`: its constants w R0 (`rw`), g and w, its offset `r`
/// from the element's centroid, the bending modes' force `fm` (kModes) and its velocity `v`
/// (kDamping). The terms are summed in this order in every kernel.
template <bool kModes, bool kDamping, class T>
[[gnu::always_inline]] inline void entry_force(const ElementForce<T>& el, const T (&rw)[3], const T (&g)[3], T w,
                                               const T (&r)[3], const T (&fm)[3], const T (&v)[3], T (&o)[3]) {
  // written out component by component, not as loops over d: GCC's early scalar replacement
  // (before it unrolls loops) then turns the lane kernel's r, fm and o into registers; with
  // loops they stayed arrays on the stack, 9 dead 32-byte stores per row (issue 26)
  const T kw = el.k * w;
  o[0] = el.m[0] * rw[0] + el.m[1] * rw[1] + el.m[2] * rw[2] - kw * r[0];
  o[1] = el.m[3] * rw[0] + el.m[4] * rw[1] + el.m[5] * rw[2] - kw * r[1];
  o[2] = el.m[6] * rw[0] + el.m[7] * rw[1] + el.m[8] * rw[2] - kw * r[2];
  o[0] += el.g[0] * g[0] + el.g[1] * g[1] + el.g[2] * g[2];
  o[1] += el.g[3] * g[0] + el.g[4] * g[1] + el.g[5] * g[2];
  o[2] += el.g[6] * g[0] + el.g[7] * g[1] + el.g[8] * g[2];
  if constexpr (kModes) {
    o[0] += fm[0];
    o[1] += fm[1];
    o[2] += fm[2];
  }
  if constexpr (kDamping) {
    const T cw = el.damping * w;
    const T(&u)[3] = el.vc;
    const T(&s)[3] = el.omega;
    o[0] += cw * (u[0] + s[1] * r[2] - s[2] * r[1] - v[0]);
    o[1] += cw * (u[1] + s[2] * r[0] - s[0] * r[2] - v[1]);
    o[2] += cw * (u[2] + s[0] * r[1] - s[1] * r[0] - v[2]);
  }
}

}  // namespace vx::law

#pragma GCC diagnostic pop
