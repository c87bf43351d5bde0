#include "physics/element_batches.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>

#include "base/error.h"
#include "base/huge_pages.h"
#include "physics/element_law.h"
#include "physics/element_pass.h"
#include "physics/physics_model.h"
#include "physics/rigid_sums.h"
#include "physics/rotation_fit.h"

// The lane vectors below never cross a function boundary (everything is always_inline), so the
// ABI note GCC gives for vector arguments without AVX does not apply.
#pragma GCC diagnostic ignored "-Wpsabi"

namespace vx {

void build_element_batches(const PhysicsModel& p, std::int64_t window, ElementBatches& out, int max_rows) {
  max_rows = std::min(max_rows, kBatchMaxRows);
  const Model& m = *p.model;
  const std::int64_t ne = p.num_elements();
  out = ElementBatches{};
  const auto count = [&](std::int32_t e) {
    return m.element_offsets[std::size_t(e) + 1] - m.element_offsets[std::size_t(e)];
  };
  // each window's batched elements sorted by their count, and the arrays' sizes first: the arrays
  // are then allocated once (grown by push_back they touched twice the memory, and fresh memory
  // is most of the cost of building them: 2.1 s of the folded organ's start-up on a loaded machine)
  std::vector<std::int32_t> sorted;  // the windows' orders, one after the other
  std::vector<std::size_t> window_start;
  sorted.reserve(std::size_t(ne));
  std::size_t batches = 0, rows = 0;
  for (std::int64_t w0 = 0; w0 < ne; w0 += window) {
    window_start.push_back(sorted.size());
    for (std::int64_t e = w0; e < std::min(ne, w0 + window); ++e) {
      if (count(std::int32_t(e)) > max_rows)
        out.unbatched.push_back(std::int32_t(e));
      else
        sorted.push_back(std::int32_t(e));
    }
    const auto first = sorted.begin() + std::ptrdiff_t(window_start.back());
    std::stable_sort(first, sorted.end(), [&](std::int32_t a, std::int32_t b) { return count(a) < count(b); });
    for (std::size_t i = window_start.back(); i < sorted.size(); i += kBatchLanes) {
      ++batches;
      // sorted ascending: a batch's last lane has the most entries
      rows += std::size_t(count(sorted[std::min(sorted.size(), i + kBatchLanes) - 1]));
    }
  }
  window_start.push_back(sorted.size());
  out.batches.reserve(batches);
  out.rows.reserve(rows);
  prefer_huge_pages(out.rows.data(), rows * sizeof(BatchRow));
  if (p.has_bending_modes()) {
    out.mode_rows.reserve(rows);
    prefer_huge_pages(out.mode_rows.data(), rows * sizeof(ModeRow));
  }
  for (std::size_t w = 0; w + 1 < window_start.size(); ++w) {
    out.window_offsets.push_back(std::int32_t(out.batches.size()));
    const std::vector<std::int32_t> order(sorted.begin() + std::ptrdiff_t(window_start[w]),
                                          sorted.begin() + std::ptrdiff_t(window_start[w + 1]));
    for (std::size_t i = 0; i < order.size(); i += kBatchLanes) {
      const int lanes = int(std::min<std::size_t>(kBatchLanes, order.size() - i));
      ElementBatch bt{};
      std::int32_t src[kBatchLanes];  // the element whose data a lane holds (empty lanes: lane 0's)
      for (int l = 0; l < kBatchLanes; ++l) {
        src[l] = order[i + std::size_t(l < lanes ? l : 0)];
        const auto e = std::size_t(src[l]);
        bt.element[l] = l < lanes ? src[l] : -1;
        bt.count[l] = l < lanes ? count(src[l]) : 0;
        bt.rows = std::max(bt.rows, count(src[l]));
        bt.stiffness[l] = p.element_stiffness[e];
        bt.affine_stiffness[l] = p.element_affine_stiffness[e];
        bt.damping[l] = p.element_damping[e];
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) bt.spread[3 * r + c][l] = p.element_spread[e](r, c);
      }
      bt.first_row = std::int32_t(out.rows.size());
      for (int r = 0; r < bt.rows; ++r) {
        BatchRow row{};
        ModeRow mrow{};
        for (int l = 0; l < kBatchLanes; ++l) {
          const std::int32_t b = m.element_offsets[std::size_t(src[l])];
          row.slot[l] = -1;
          row.vertex[l] = m.element_vertices[std::size_t(b)];
          if (r >= count(src[l])) continue;  // padding: zero constants at the lane's first node
          const auto j = std::size_t(b + r);
          for (int d = 0; d < 3; ++d) {
            row.rest_weighted[d][l] = p.entry_rest_weighted(d, std::int64_t(j));
            row.gradient[d][l] = p.entry_gradient(d, std::int64_t(j));
          }
          row.weight[l] = p.entry_weight[j];
          row.vertex[l] = m.element_vertices[j];
          if (l < lanes) row.slot[l] = p.entry_slot[j];
          if (p.has_bending_modes())
            for (int d = 0; d < kBendingModes; ++d) mrow.mode[d][l] = p.entry_modes(d, std::int64_t(j));
        }
        out.rows.push_back(row);
        if (p.has_bending_modes()) out.mode_rows.push_back(mrow);
      }
      out.batches.push_back(bt);
    }
  }
  out.window_offsets.push_back(std::int32_t(out.batches.size()));
}

namespace {

#define VX_INLINE [[gnu::always_inline]] inline

using d4 = double __attribute__((vector_size(32)));

VX_INLINE d4 load(const double* p) {
  d4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

VX_INLINE d4 splat(double x) { return d4{x, x, x, x}; }

/// Component d of the lanes' nodes `vertex`.
VX_INLINE d4 gather(const double* xs, const std::int32_t* vertex, int d) {
  return d4{xs[3 * std::int64_t(vertex[0]) + d], xs[3 * std::int64_t(vertex[1]) + d],
            xs[3 * std::int64_t(vertex[2]) + d], xs[3 * std::int64_t(vertex[3]) + d]};
}

/// A 3 x 3 matrix per lane, row-major.
struct Mat3 {
  d4 m[9];
};

/// The rotation matrix of the unit quaternions (x, y, z, w) (Eigen's Quaternion::toRotationMatrix).
VX_INLINE Mat3 rotation_matrix(d4 qx, d4 qy, d4 qz, d4 qw) {
  const d4 tx = 2.0 * qx, ty = 2.0 * qy, tz = 2.0 * qz;
  const d4 twx = tx * qw, twy = ty * qw, twz = tz * qw;
  const d4 txx = tx * qx, txy = ty * qx, txz = tz * qx;
  const d4 tyy = ty * qy, tyz = tz * qy, tzz = tz * qz;
  return Mat3{{1.0 - (tyy + tzz), txy - twz, txz + twy, txy + twz, 1.0 - (txx + tzz), tyz - twx, txz - twy, tyz + twx,
               1.0 - (txx + tyy)}};
}

/// One evaluation of the rotation fit (fit_rotation, rotation_fit.cpp) at the quaternions q for the
/// normalised matrices an: the rotation r, the trace of P = an r^T, the squared moment
/// imbalance g2, whether the negated Hessian is positive definite, and the Newton step's squared
/// length and the quaternions it leads to (rotate_by: n = normalise(q + (0, theta / 2) q)).
struct FitProbe {
  Mat3 r;
  d4 trace{}, g2{}, step2{}, nx{}, ny{}, nz{}, nw{};
  bool pd[kBatchLanes]{};
};

VX_INLINE FitProbe probe_fit(const Mat3& an, d4 qx, d4 qy, d4 qz, d4 qw) {
  FitProbe o;
  o.r = rotation_matrix(qx, qy, qz, qw);
  const d4* a = an.m;
  const d4* r = o.r.m;
  const d4 p00 = a[0] * r[0] + a[1] * r[1] + a[2] * r[2], p01 = a[0] * r[3] + a[1] * r[4] + a[2] * r[5],
           p02 = a[0] * r[6] + a[1] * r[7] + a[2] * r[8];
  const d4 p10 = a[3] * r[0] + a[4] * r[1] + a[5] * r[2], p11 = a[3] * r[3] + a[4] * r[4] + a[5] * r[5],
           p12 = a[3] * r[6] + a[4] * r[7] + a[5] * r[8];
  const d4 p20 = a[6] * r[0] + a[7] * r[1] + a[8] * r[2], p21 = a[6] * r[3] + a[7] * r[4] + a[8] * r[5],
           p22 = a[6] * r[6] + a[7] * r[7] + a[8] * r[8];
  const d4 tr = p00 + p11 + p22;
  o.trace = tr;
  const d4 gx = p21 - p12, gy = p02 - p20, gz = p10 - p01;
  o.g2 = gx * gx + gy * gy + gz * gz;
  const d4 h00 = tr - p00, h11 = tr - p11, h22 = tr - p22;
  const d4 h01 = -0.5 * (p01 + p10), h02 = -0.5 * (p02 + p20), h12 = -0.5 * (p12 + p21);
  const d4 c00 = h11 * h22 - h12 * h12, c01 = h02 * h12 - h01 * h22, c02 = h01 * h12 - h02 * h11;
  const d4 c11 = h00 * h22 - h02 * h02, c12 = h01 * h02 - h00 * h12, c22 = h00 * h11 - h01 * h01;
  const d4 det = h00 * c00 + h01 * c01 + h02 * c02;
  for (int l = 0; l < kBatchLanes; ++l) o.pd[l] = h00[l] > 1e-6 && c22[l] > 1e-12 && det[l] > 1e-18;
  const d4 idet = 1.0 / det;
  const d4 tx = (c00 * gx + c01 * gy + c02 * gz) * idet, ty = (c01 * gx + c11 * gy + c12 * gz) * idet,
           tz = (c02 * gx + c12 * gy + c22 * gz) * idet;
  o.step2 = tx * tx + ty * ty + tz * tz;
  const d4 hx = 0.5 * tx, hy = 0.5 * ty, hz = 0.5 * tz;
  const d4 nw = -(hx * qx + hy * qy + hz * qz) + qw;
  const d4 nx = qw * hx + (hy * qz - hz * qy) + qx;
  const d4 ny = qw * hy + (hz * qx - hx * qz) + qy;
  const d4 nz = qw * hz + (hx * qy - hy * qx) + qz;
  const d4 nn = nw * nw + nx * nx + ny * ny + nz * nz;
  d4 in{};
  for (int l = 0; l < kBatchLanes; ++l) in[l] = nn[l] > 0.0 ? 1.0 / std::sqrt(nn[l]) : 0.0;
  o.nx = nx * in, o.ny = ny * in, o.nz = nz * in, o.nw = nw * in;
  return o;
}

/// One batch: the packed kernel's arithmetic (elements.cpp) with one element per lane.
template <bool kDamping, bool kModes>
VX_INLINE void batch_forces(const ElementBatch& bt, const BatchRow* rows, const ModeRow* mrows, const double* xs,
                            const double* vs, Eigen::Quaterniond* rot, double* ef, const RotationFitSettings& fit,
                            ElementPassStats& st) {
  const int nr = bt.rows;
  d4 ys[kBatchMaxRows][3];                  // positions relative to each lane's first node
  d4 vel[kDamping ? kBatchMaxRows : 1][3];  // velocities
  const d4 ox = gather(xs, rows[0].vertex, 0), oy = gather(xs, rows[0].vertex, 1), oz = gather(xs, rows[0].vertex, 2);
  // pass 1: weighted centroid and A = sum w y R0^T (sum w R0 = 0)
  CentroidSums<d4> cs;
  d4 a00{}, a01{}, a02{}, a10{}, a11{}, a12{}, a20{}, a21{}, a22{};
  for (int r = 0; r < nr; ++r) {
    const BatchRow& row = rows[r];
    const d4 yx = gather(xs, row.vertex, 0) - ox, yy = gather(xs, row.vertex, 1) - oy,
             yz = gather(xs, row.vertex, 2) - oz;
    ys[r][0] = yx;
    ys[r][1] = yy;
    ys[r][2] = yz;
    const d4 w = load(row.weight);
    const d4 c0 = load(row.rest_weighted[0]), c1 = load(row.rest_weighted[1]), c2 = load(row.rest_weighted[2]);
    cs.add(w, yx, yy, yz);
    a00 += yx * c0;
    a01 += yx * c1;
    a02 += yx * c2;
    a10 += yy * c0;
    a11 += yy * c1;
    a12 += yy * c2;
    a20 += yz * c0;
    a21 += yz * c1;
    a22 += yz * c2;
  }
  // the consistent deformation gradient F = sum y g^T (sum g = 0), and (hourglass element)
  // the bending modes' amplitudes qm = sum y h^T (sum h = 0) in the same loop
  d4 f00{}, f01{}, f02{}, f10{}, f11{}, f12{}, f20{}, f21{}, f22{};
  d4 qm[3][kBendingModes] = {};
  for (int r = 0; r < nr; ++r) {
    const BatchRow& row = rows[r];
    const d4 yx = ys[r][0], yy = ys[r][1], yz = ys[r][2];
    const d4 g0 = load(row.gradient[0]), g1 = load(row.gradient[1]), g2 = load(row.gradient[2]);
    f00 += yx * g0;
    f01 += yx * g1;
    f02 += yx * g2;
    f10 += yy * g0;
    f11 += yy * g1;
    f12 += yy * g2;
    f20 += yz * g0;
    f21 += yz * g1;
    f22 += yz * g2;
    if constexpr (kModes) {
      const ModeRow& mr = mrows[r];
      for (int p = 0; p < kBendingModes; ++p) {
        const d4 h = load(mr.mode[p]);
        qm[0][p] += yx * h;
        qm[1][p] += yy * h;
        qm[2][p] += yz * h;
      }
    }
  }
  // the sums of the rigid velocity fit (damping)
  RigidSums<d4> rs;
  if constexpr (kDamping) {
    for (int r = 0; r < nr; ++r) {
      const BatchRow& row = rows[r];
      const d4 vx = gather(vs, row.vertex, 0), vy = gather(vs, row.vertex, 1), vz = gather(vs, row.vertex, 2);
      vel[r][0] = vx;
      vel[r][1] = vy;
      vel[r][2] = vz;
      rs.add(load(row.weight), ys[r][0], ys[r][1], ys[r][2], vx, vy, vz);
    }
  }
  const d4 inv_w = splat(1.0) / cs.sw;
  const d4 cx = cs.sx * inv_w, cy = cs.sy * inv_w, cz = cs.sz * inv_w;  // relative to the first node
  // NaN/Inf in: that lane writes no force, counted
  const d4 probe = (cx + cy + cz + a00 + a01 + a02 + a10 + a11 + a12 + a20 + a21 + a22 + f00 + f01 + f02 + f10 + f11 +
                    f12 + f20 + f21 + f22) *
                   0.0;
  bool finite[kBatchLanes];
  for (int l = 0; l < kBatchLanes; ++l) {
    finite[l] = probe[l] == 0.0;
    if (bt.count[l] > 0 && !finite[l]) ++st.non_finite;
  }

  // the rotation fit (fit_rotation, rotation_fit.cpp) as far as almost every element goes in a
  // running simulation, in lanes: the warm start passes its first test (it maximises tr(Q^T F):
  // moment balance within the tolerance, negated Hessian positive definite), or one Newton step
  // ends the fit (a step short enough, or one after which the test passes); the other lanes
  // run the scalar fit from the warm start (the same result as the scalar kernels)
  d4 q0x, q0y, q0z, q0w;
  for (int l = 0; l < kBatchLanes; ++l) {
    const Eigen::Quaterniond& q = rot[bt.element[l] >= 0 ? bt.element[l] : bt.element[0]];
    q0x[l] = q.x();
    q0y[l] = q.y();
    q0z[l] = q.z();
    q0w[l] = q.w();
  }
  const d4 s2 =
      f00 * f00 + f01 * f01 + f02 * f02 + f10 * f10 + f11 * f11 + f12 * f12 + f20 * f20 + f21 * f21 + f22 * f22;
  d4 is{};
  for (int l = 0; l < kBatchLanes; ++l) is[l] = s2[l] > 0.0 ? 1.0 / std::sqrt(s2[l]) : 0.0;
  const Mat3 fn{f00 * is, f01 * is, f02 * is, f10 * is, f11 * is, f12 * is, f20 * is, f21 * is, f22 * is};
  const FitProbe t0 = probe_fit(fn, q0x, q0y, q0z, q0w);
  FitProbe t1;
  const double tol2 = fit.tolerance * fit.tolerance;
  const d4 fdet = f00 * (f11 * f22 - f12 * f21) - f01 * (f10 * f22 - f12 * f20) + f02 * (f10 * f21 - f11 * f20);
  enum class Fit : unsigned char { warm, stepped, scalar };
  Fit how[kBatchLanes] = {Fit::warm, Fit::warm, Fit::warm, Fit::warm};
  bool probe_again = false;
  for (int l = 0; l < kBatchLanes; ++l) {
    if (bt.count[l] == 0 || !finite[l]) continue;
    if (fdet[l] <= 0.0) ++st.inverted;
    if (s2[l] < 1e-300) continue;  // collapsed to a point: keeps the warm start
    how[l] = Fit::scalar;
    if (fit.max_iterations < 1 || !t0.pd[l]) continue;
    if (t0.g2[l] <= tol2) {
      how[l] = Fit::warm;
    } else if (t0.step2[l] <= 1.0 && (t0.step2[l] <= fit.tolerance || fit.max_iterations > 1)) {
      // (a step over one radian is shortened by the scalar fit: left to it)
      // a step this short leaves an error of order its square: done; a longer one is decided
      // after probing the stepped rotation (whose matrix both need)
      how[l] = Fit::stepped;
      probe_again = true;
    }
  }
  if (probe_again) t1 = probe_fit(fn, t0.nx, t0.ny, t0.nz, t0.nw);
  Eigen::Matrix3d fitted[kBatchLanes];
  for (int l = 0; l < kBatchLanes; ++l) {
    if (how[l] == Fit::stepped && t0.step2[l] > fit.tolerance &&
        !(t1.trace[l] >= t0.trace[l] - 1e-13 && t1.pd[l] && t1.g2[l] <= tol2))
      how[l] = Fit::scalar;  // the step did not end the fit
    if (how[l] == Fit::stepped) {
      rot[bt.element[l]] = Eigen::Quaterniond(t0.nw[l], t0.nx[l], t0.ny[l], t0.nz[l]);
      ++st.rotation_iterations;
    } else if (how[l] == Fit::scalar) {
      Eigen::Matrix3d fl;
      fl << f00[l], f01[l], f02[l], f10[l], f11[l], f12[l], f20[l], f21[l], f22[l];
      bool conv = true;
      st.rotation_iterations += fit_rotation(fl, rot[bt.element[l]], fit, &conv, &fitted[l]);
      st.unconverged += conv ? 0 : 1;
    }
  }
  // the rotation of each lane
  Mat3 q = t0.r;
  for (int l = 0; l < kBatchLanes; ++l)
    for (int i = 0; i < 9; ++i) {
      if (how[l] == Fit::stepped) q.m[i][l] = t1.r.m[i][l];
      if (how[l] == Fit::scalar) q.m[i][l] = fitted[l](i / 3, i % 3);
    }
  // the element's law on the lanes (element_law.h, the scalar kernels' arithmetic: the same bits
  // lane by lane): G = 2 mu V (Q - F) + k (A - F C0), M = k F, and the rigid velocity about the
  // centroid (damping)
  law::ElementForce<d4> force;
  {
    const d4 f[9] = {f00, f01, f02, f10, f11, f12, f20, f21, f22};
    const d4 a[9] = {a00, a01, a02, a10, a11, a12, a20, a21, a22};
    d4 c0[9];
    for (int i = 0; i < 9; ++i) c0[i] = load(bt.spread[i]);
    law::element_stress(a, f, q.m, c0, load(bt.stiffness), load(bt.affine_stiffness), force);
  }
  if constexpr (kDamping) {
    force.damping = load(bt.damping);
    law::rigid_velocity(rs, cs.sw, inv_w, cx, cy, cz, force);
  }
  // pass 2: each entry's force (element_law.h, entry_force: f = M R0' - w k (x - c) + G g
  // [+ modes] [+ c w (v_c + omega x r - v)]), written once
  for (int r = 0; r < nr; ++r) {
    const BatchRow& row = rows[r];
    const d4 rr[3] = {ys[r][0] - cx, ys[r][1] - cy, ys[r][2] - cz};
    const d4 rw[3] = {load(row.rest_weighted[0]), load(row.rest_weighted[1]), load(row.rest_weighted[2])};
    const d4 g[3] = {load(row.gradient[0]), load(row.gradient[1]), load(row.gradient[2])};
    d4 fm[3] = {};
    if constexpr (kModes) {
      const ModeRow& mr = mrows[r];
      for (int p = 0; p < kBendingModes; ++p) {
        const d4 h = load(mr.mode[p]);
        fm[0] += qm[0][p] * h;
        fm[1] += qm[1][p] * h;
        fm[2] += qm[2][p] * h;
      }
    }
    d4 o[3];
    law::entry_force<kModes, kDamping>(force, rw, g, load(row.weight), rr, fm, vel[kDamping ? r : 0], o);
    const d4 o0 = o[0], o1 = o[1], o2 = o[2];
    for (int l = 0; l < kBatchLanes; ++l) {
      if (r >= bt.count[l]) continue;
      double* out = ef + 3 * std::int64_t(row.slot[l]);
      out[0] = finite[l] ? o0[l] : 0.0;
      out[1] = finite[l] ? o1[l] : 0.0;
      out[2] = finite[l] ? o2[l] : 0.0;
    }
  }
}

/// Prefetch distance of the rows, in batches (about 30 kB ahead). Prefetching the gathered
/// nodes and force slots as well was slower (measured: those lines are mostly cached already).
constexpr int kPrefetchRows = 8;

template <bool kDamping, bool kModes>
VX_INLINE void batch_range(const PhysicsModel& phys, const double* xs, const double* vs, Eigen::Quaterniond* rot,
                           double* ef, std::int64_t b0, std::int64_t b1, const RotationFitSettings& fit,
                           ElementPassStats& st) {
  const ElementBatch* batches = phys.element_batches.batches.data();
  const BatchRow* rows = phys.element_batches.rows.data();
  const ModeRow* mrows = phys.element_batches.mode_rows.data();
  for (std::int64_t b = b0; b < b1; ++b) {
    if (b + kPrefetchRows < b1) {  // the rows of a batch further ahead (a stream the hardware
                                   // prefetcher follows too late between the gathers)
      const ElementBatch& far = batches[b + kPrefetchRows];
      const char* p0 = reinterpret_cast<const char*>(rows + far.first_row);
      const char* p1 = reinterpret_cast<const char*>(rows + far.first_row + far.rows);
      for (; p0 < p1; p0 += 64) __builtin_prefetch(p0, 0);
      if constexpr (kModes) {
        const char* m0 = reinterpret_cast<const char*>(mrows + far.first_row);
        const char* m1 = reinterpret_cast<const char*>(mrows + far.first_row + far.rows);
        for (; m0 < m1; m0 += 64) __builtin_prefetch(m0, 0);
      }
    }
    if (b + kPrefetchRows + 1 < b1) {
      // the whole record of the batch whose rows the next iteration prefetches: its first_row and
      // rows, read then, are in the last of its 7 lines, and a demand miss there stalled the loop
      // whenever the hardware prefetchers left that line out, which changed with the code around
      // it (the AVX2 copy lost 5 to 8 % at 128^3 to it after issue 26's change; docs/bench.md)
      const char* next = reinterpret_cast<const char*>(&batches[b + kPrefetchRows + 1]);
      for (std::size_t i = 0; i < sizeof(ElementBatch); i += 64) __builtin_prefetch(next + i, 0);
    }
    batch_forces<kDamping, kModes>(batches[b], rows + batches[b].first_row,
                                   kModes ? mrows + batches[b].first_row : nullptr, xs, vs, rot, ef, fit, st);
  }
}

}  // namespace

// one copy of the kernel per instruction set (the same source; the compiler vectorises the
// lane arithmetic for each)
#define VX_BATCH_RANGE(name, attributes)                                                                           \
  attributes void name(const PhysicsModel& phys, const double* xs, const double* vs, Eigen::Quaterniond* rot,      \
                       double* ef, std::int64_t b0, std::int64_t b1, const RotationFitSettings& fit, bool damping, \
                       ElementPassStats& st) {                                                                     \
    const bool modes = !phys.element_batches.mode_rows.empty();                                                    \
    if (damping && modes)                                                                                          \
      batch_range<true, true>(phys, xs, vs, rot, ef, b0, b1, fit, st);                                             \
    else if (damping)                                                                                              \
      batch_range<true, false>(phys, xs, vs, rot, ef, b0, b1, fit, st);                                            \
    else if (modes)                                                                                                \
      batch_range<false, true>(phys, xs, vs, rot, ef, b0, b1, fit, st);                                            \
    else                                                                                                           \
      batch_range<false, false>(phys, xs, vs, rot, ef, b0, b1, fit, st);                                           \
  }

namespace {
#if defined(__x86_64__) && defined(__GNUC__)
VX_BATCH_RANGE(range_avx512, __attribute__((target("arch=x86-64-v4"))))
VX_BATCH_RANGE(range_avx2, __attribute__((target("arch=x86-64-v3"))))
#endif
VX_BATCH_RANGE(range_generic, )
}  // namespace

void element_batches_range(const PhysicsModel& phys, const double* xs, const double* vs, Eigen::Quaterniond* rot,
                           double* ef, std::int64_t b0, std::int64_t b1, const RotationFitSettings& fit, bool damping,
                           ElementPassStats& st, SimdLevel level) {
  if (level == SimdLevel::automatic || !simd_supported(level)) level = best_simd_level();
  switch (level) {
#if defined(__x86_64__) && defined(__GNUC__)
    case SimdLevel::avx512: return range_avx512(phys, xs, vs, rot, ef, b0, b1, fit, damping, st);
    case SimdLevel::avx2: return range_avx2(phys, xs, vs, rot, ef, b0, b1, fit, damping, st);
#endif
    default: return range_generic(phys, xs, vs, rot, ef, b0, b1, fit, damping, st);
  }
}

}  // namespace vx
