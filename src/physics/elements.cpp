#include "physics/elements.h"

#include <Eigen/LU>
#include <cmath>

#include "base/parallel.h"
#include "physics/element_batches.h"
#include "physics/element_law.h"
#include "physics/rigid_sums.h"

namespace vx {

namespace {

/// The per-element 3 x 3 work of the scalar kernels: the warm-started rotation fit of F (q),
/// the volume term's closest matrix T to F with det T = 1 (t; docs/model.md section 5,
/// "Locking"), and the matrices of the force (element_law.h, element_stress: G and M; G with
/// the volume term's k_v (T - F)).
template <bool kVolume>
struct ElementMatrices {
  Eigen::Matrix3d q, t;
  double wv{0};
  law::ElementForce<double> force;

  ElementMatrices(const PhysicsModel& phys, std::int64_t e, const Eigen::Matrix3d& a, const Eigen::Matrix3d& fg,
                  Eigen::Quaterniond& rot, const RotationFitSettings& fit, ElementPassStats& st) {
    bool conv = true;
    st.rotation_iterations += fit_element_rotation(phys, fg, rot, fit, &conv, &q);
    st.unconverged += conv ? 0 : 1;
    if (element_determinant(phys, fg) <= 0.0) ++st.inverted;
    const Eigen::Matrix3d& c0 = phys.element_spread[std::size_t(e)];
    double ar[9], fr[9], qr[9], cr[9];  // row-major
    for (int i = 0; i < 9; ++i) {
      ar[i] = a(i / 3, i % 3);
      fr[i] = fg(i / 3, i % 3);
      qr[i] = q(i / 3, i % 3);
      cr[i] = c0(i / 3, i % 3);
    }
    law::element_stress(ar, fr, qr, cr, phys.element_stiffness[std::size_t(e)],
                        phys.element_affine_stiffness[std::size_t(e)], force);
    if constexpr (kVolume) {
      wv = phys.element_volume_stiffness[std::size_t(e)];
      Eigen::Quaterniond qv = rot;
      t = element_closest_with_determinant(phys, fg, 1.0, qv, fit);
      for (int i = 0; i < 9; ++i) force.g[i] += wv * (t(i / 3, i % 3) - fg(i / 3, i % 3));
    }
  }
};

/// The bending modes' amplitudes qm = sum_i y_i h_i^T (3 x kBendingModes) of one element's
/// entries [b, b + n) (y: positions relative to x0; sum h = 0), and their force sum_p qm_p h_pi.
inline Eigen::Matrix<double, 3, kBendingModes> mode_amplitudes(const PhysicsModel& phys, const double* xs,
                                                               const std::int32_t* vert, int b, int n,
                                                               const Eigen::Vector3d& x0) {
  Eigen::Matrix<double, 3, kBendingModes> qm = Eigen::Matrix<double, 3, kBendingModes>::Zero();
  for (int j = b; j < b + n; ++j)
    qm.noalias() +=
        (Eigen::Map<const Eigen::Vector3d>(xs + 3 * std::int64_t(vert[j])) - x0) * phys.entry_modes.col(j).transpose();
  return qm;
}

/// The volume points' forces of element e (docs/model.md section 5, "Volume points"), added to
/// its entries' slots of `ef`: f_j += (sum_s G_s) g_j + sum_s G_s delta_sj with
/// G_s = k_s (T_s - F_s). Returns their energy sum_s k_s/2 |F_s - T_s|^2.
double add_volume_point_forces(const PhysicsModel& phys, const double* xs, std::int64_t e, const Eigen::Matrix3d& fg,
                               const Eigen::Quaterniond& q, const RotationFitSettings& fit, double* ef) {
  const Model& m = *phys.model;
  const std::int32_t* slot = phys.entry_slot.data();
  Eigen::Matrix3d gsum = Eigen::Matrix3d::Zero();
  double en = 0;
  for_each_volume_point(phys, xs, int(e), fg, q, fit, [&](int s, const Eigen::Matrix3d& fs, const Eigen::Matrix3d& ts) {
    const double ks = phys.volume_point_stiffness[std::size_t(s)];
    const Eigen::Matrix3d gs = ks * (ts - fs);
    gsum += gs;
    en += 0.5 * ks * (fs - ts).squaredNorm();
    for (int t = phys.volume_point_term_offsets[std::size_t(s)]; t < phys.volume_point_term_offsets[std::size_t(s) + 1];
         ++t)
      Eigen::Map<Eigen::Vector3d>(ef + 3 * std::int64_t(slot[phys.volume_term_entry[std::size_t(t)]])) +=
          gs * phys.volume_term_delta.col(t);
  });
  for (int j = m.element_offsets[std::size_t(e)]; j < m.element_offsets[std::size_t(e) + 1]; ++j)
    Eigen::Map<Eigen::Vector3d>(ef + 3 * std::int64_t(slot[j])) += gsum * phys.entry_gradient.col(j);
  return en;
}

/// The reference element kernel for elements [e0, e1) (ElementKernel::reference): writes 3
/// doubles per vertex entry. Vertex i has weight w_i and weighted rest offset R0'_i = w_i R0_i
/// (material.h). Each loop over the vertices keeps at most ~16 values live, so that baseline
/// x86-64 (16 SSE registers) does not spill: elastic and damping parts run as separate loops,
/// each gathering the positions again and reading the per-entry constants from separate arrays.
/// The element's law (G, M, the rigid velocity) is element_law.h's, as in the other kernels;
/// the per-entry terms are written out here loop by loop (entry_force sums them in one).
template <bool kDamping, bool kEnergy, bool kVolume, bool kModes>
void element_range_reference(const PhysicsModel& phys, const double* xs, const double* vs, Eigen::Quaterniond* rot,
                             double* ef, double* energy_out, std::int64_t e0, std::int64_t e1,
                             const RotationFitSettings& fit, ElementPassStats& st) {
  const Model& m = *phys.model;
  const std::int32_t* off = m.element_offsets.data();
  const std::int32_t* vert = m.element_vertices.data();
  const double* r0s = phys.entry_rest_weighted.data();
  const double* gs = phys.entry_gradient.data();
  const double* wts = phys.entry_weight.data();
  const std::int32_t* slot = phys.entry_slot.data();
  for (std::int64_t e = e0; e < e1; ++e) {
    const int b = off[e], n = off[e + 1] - b;
    // positions relative to the first vertex (keeps sums free of the absolute offset)
    const double* x0 = xs + 3 * std::int64_t(vert[b]);
    const double ox = x0[0], oy = x0[1], oz = x0[2];
    // pass 1a: weighted centroid and A = sum w y R0^T (sum w R0 = 0: no centring needed)
    CentroidSums<double> cs;
    double a00 = 0, a01 = 0, a02 = 0, a10 = 0, a11 = 0, a12 = 0, a20 = 0, a21 = 0, a22 = 0;
    for (int j = b; j < b + n; ++j) {
      const double* xp = xs + 3 * std::int64_t(vert[j]);
      const double* r0 = r0s + 3 * std::int64_t(j);
      const double w = wts[j];
      const double yx = xp[0] - ox, yy = xp[1] - oy, yz = xp[2] - oz;
      cs.add(w, yx, yy, yz);
      a00 += yx * r0[0];
      a01 += yx * r0[1];
      a02 += yx * r0[2];
      a10 += yy * r0[0];
      a11 += yy * r0[1];
      a12 += yy * r0[2];
      a20 += yz * r0[0];
      a21 += yz * r0[1];
      a22 += yz * r0[2];
    }
    // pass 1b: the consistent deformation gradient F = sum y g^T (sum g = 0: no centring)
    double f00 = 0, f01 = 0, f02 = 0, f10 = 0, f11 = 0, f12 = 0, f20 = 0, f21 = 0, f22 = 0;
    for (int j = b; j < b + n; ++j) {
      const double* xp = xs + 3 * std::int64_t(vert[j]);
      const double* g = gs + 3 * std::int64_t(j);
      const double yx = xp[0] - ox, yy = xp[1] - oy, yz = xp[2] - oz;
      f00 += yx * g[0];
      f01 += yx * g[1];
      f02 += yx * g[2];
      f10 += yy * g[0];
      f11 += yy * g[1];
      f12 += yy * g[2];
      f20 += yz * g[0];
      f21 += yz * g[1];
      f22 += yz * g[2];
    }
    const double inv_w = 1.0 / cs.sw;
    const Eigen::Vector3d c(cs.sx * inv_w, cs.sy * inv_w, cs.sz * inv_w);  // relative to x0
    Eigen::Matrix3d a, fg;
    a << a00, a01, a02, a10, a11, a12, a20, a21, a22;
    fg << f00, f01, f02, f10, f11, f12, f20, f21, f22;
    if (!a.allFinite() || !fg.allFinite() || !c.allFinite()) {  // NaN/Inf in: no force out, counted
      ++st.non_finite;
      for (int j = b; j < b + n; ++j) ef[3 * slot[j]] = ef[3 * slot[j] + 1] = ef[3 * slot[j] + 2] = 0.0;
      if constexpr (kEnergy) energy_out[e] = 0.0;
      continue;
    }
    ElementMatrices<kVolume> em(phys, e, a, fg, rot[e], fit, st);
    const Eigen::Matrix3d &q = em.q, &t = em.t;
    const double k = em.force.k, wv = em.wv;
    const double* mq = em.force.m;
    const double* gm = em.force.g;
    // pass 2: elastic force f = M R0' - w k (x - c)   (M = k F, R0' = w R0)
    {
      const double m00 = mq[0], m01 = mq[1], m02 = mq[2], m10 = mq[3], m11 = mq[4], m12 = mq[5], m20 = mq[6],
                   m21 = mq[7], m22 = mq[8];
      const double cx = ox + c.x(), cy = oy + c.y(), cz = oz + c.z();
      for (int j = b; j < b + n; ++j) {
        const double* xp = xs + 3 * std::int64_t(vert[j]);
        const double* r0 = r0s + 3 * std::int64_t(j);
        const double kw = k * wts[j];
        double* out = ef + 3 * std::int64_t(slot[j]);
        out[0] = m00 * r0[0] + m01 * r0[1] + m02 * r0[2] - kw * (xp[0] - cx);
        out[1] = m10 * r0[0] + m11 * r0[1] + m12 * r0[2] - kw * (xp[1] - cy);
        out[2] = m20 * r0[0] + m21 * r0[1] + m22 * r0[2] - kw * (xp[2] - cz);
      }
    }
    // pass 2c: the bending modes' relief, f += sum_p qm_p h_p
    Eigen::Matrix<double, 3, kBendingModes> qm;
    if constexpr (kModes) {
      qm = mode_amplitudes(phys, xs, vert, b, n, Eigen::Vector3d(ox, oy, oz));
      for (int j = b; j < b + n; ++j) {
        double* out = ef + 3 * std::int64_t(slot[j]);
        Eigen::Map<Eigen::Vector3d>(out) += qm * phys.entry_modes.col(j);
      }
    }
    // pass 2b: f += G g
    {
      const double g00 = gm[0], g01 = gm[1], g02 = gm[2], g10 = gm[3], g11 = gm[4], g12 = gm[5], g20 = gm[6],
                   g21 = gm[7], g22 = gm[8];
      for (int j = b; j < b + n; ++j) {
        const double* g = gs + 3 * std::int64_t(j);
        double* out = ef + 3 * std::int64_t(slot[j]);
        out[0] += g00 * g[0] + g01 * g[1] + g02 * g[2];
        out[1] += g10 * g[0] + g11 * g[1] + g12 * g[2];
        out[2] += g20 * g[0] + g21 * g[1] + g22 * g[2];
      }
    }
    double point_energy = 0;
    if constexpr (kVolume)
      if (phys.has_volume_points()) point_energy = add_volume_point_forces(phys, xs, e, fg, rot[e], fit, ef);
    if constexpr (kDamping) {
      // pass 3: the weighted rigid velocity fit: v_c, angular momentum and inertia about c
      RigidSums<double> rs;
      for (int j = b; j < b + n; ++j) {
        const double* xp = xs + 3 * std::int64_t(vert[j]);
        const double* vp = vs + 3 * std::int64_t(vert[j]);
        rs.add(wts[j], xp[0] - ox, xp[1] - oy, xp[2] - oz, vp[0], vp[1], vp[2]);
      }
      const double cd = phys.element_damping[std::size_t(e)];
      law::rigid_velocity(rs, cs.sw, inv_w, c.x(), c.y(), c.z(), em.force);
      // pass 4: f += c w (v_c + omega x r - v)
      const double wx = em.force.omega[0], wy = em.force.omega[1], wz = em.force.omega[2];
      const double cx = ox + c.x(), cy = oy + c.y(), cz = oz + c.z();
      const double ux = em.force.vc[0], uy = em.force.vc[1], uz = em.force.vc[2];
      for (int j = b; j < b + n; ++j) {
        const double* xp = xs + 3 * std::int64_t(vert[j]);
        const double* vp = vs + 3 * std::int64_t(vert[j]);
        const double cw = cd * wts[j];
        const double rx = xp[0] - cx, ry = xp[1] - cy, rz = xp[2] - cz;
        double* out = ef + 3 * std::int64_t(slot[j]);
        out[0] += cw * (ux + wy * rz - wz * ry - vp[0]);
        out[1] += cw * (uy + wz * rx - wx * rz - vp[1]);
        out[2] += cw * (uz + wx * ry - wy * rx - vp[2]);
      }
    }
    if constexpr (kEnergy) {
      double en = 0.5 * phys.element_affine_stiffness[std::size_t(e)] * (fg - q).squaredNorm();
      const Eigen::Vector3d ca = Eigen::Vector3d(ox, oy, oz) + c;
      for (int j = b; j < b + n; ++j) {
        const Eigen::Vector3d r = Eigen::Map<const Eigen::Vector3d>(xs + 3 * std::int64_t(vert[j])) - ca;
        const Eigen::Vector3d rr = phys.entry_rest.col(j);
        en += 0.5 * k * wts[j] * (fg * rr - r).squaredNorm();
      }
      if constexpr (kVolume) en += 0.5 * wv * (fg - t).squaredNorm() + point_energy;
      if constexpr (kModes) en -= 0.5 * qm.squaredNorm();
      energy_out[e] = en;
      st.elastic_energy += en;
    }
  }
}

/// Prefetch distances of the packed kernel, in elements: the packed records of element
/// e + kPrefetchRecords, then (from those records, cached by then) the force slots and
/// positions of element e + kPrefetchAhead.
constexpr int kPrefetchRecords = 4;
constexpr int kPrefetchAhead = 1;
/// A row of [A, F] (and of the packed record's first 6 doubles: w R0, g).
using Row6 = Eigen::Array<double, 6, 1>;

/// The element kernel over the packed per-entry records (ElementKernel::packed): the same
/// arithmetic as element_range_reference, in the same order for every value (the same bits
/// where the compiler contracts no multiply-adds), but streaming one array of 64-byte records,
/// with A and F in one loop (as packets) and each entry's force written once (elastic, gradient
/// and damping parts summed in registers). Measured (bench/step_bench.cpp, element_pass, one
/// thread): 0.66-0.71x the reference's time on the 128^3 and 256^3 spheres, where the reference
/// waits on memory (the scattered writes into the node-major force buffer, the five streams of
/// constants); 0.92-0.96x on 32^3 and 64^3, where both are bound by arithmetic. The software
/// prefetches ahead of the current element: about 15 % on 256^3, within the noise below.
template <bool kDamping, bool kEnergy, bool kVolume, bool kModes>
void element_range_packed(const PhysicsModel& phys, const double* xs, const double* vs, Eigen::Quaterniond* rot,
                          double* ef, double* energy_out, std::int64_t e0, std::int64_t e1,
                          const RotationFitSettings& fit, ElementPassStats& st) {
  const Model& m = *phys.model;
  const std::int32_t* off = m.element_offsets.data();
  const PackedEntry* pk = phys.entry_packed.data();
  for (std::int64_t e = e0; e < e1; ++e) {
    const int b = off[e], n = off[e + 1] - b;
    const PackedEntry* pe = pk + b;
    if (e + kPrefetchRecords < e1) {
      const char* p0 = reinterpret_cast<const char*>(pk + off[e + kPrefetchRecords]);
      const char* p1 = reinterpret_cast<const char*>(pk + off[e + kPrefetchRecords + 1]);
      for (; p0 < p1; p0 += sizeof(PackedEntry)) __builtin_prefetch(p0, 0);
    }
    if (e + kPrefetchAhead < e1) {
      for (int j = off[e + kPrefetchAhead], je = off[e + kPrefetchAhead + 1]; j < je; ++j) {
        __builtin_prefetch(ef + 3 * std::int64_t(pk[j].slot), 1);
        __builtin_prefetch(xs + 3 * std::int64_t(pk[j].vertex), 0);
        if constexpr (kDamping) __builtin_prefetch(vs + 3 * std::int64_t(pk[j].vertex), 0);
      }
    }
    // positions relative to the first vertex (keeps sums free of the absolute offset)
    const double* x0 = xs + 3 * std::int64_t(pe[0].vertex);
    const double ox = x0[0], oy = x0[1], oz = x0[2];
    // pass 1: weighted centroid, A = sum w y R0^T (sum w R0 = 0) and F = sum y g^T (sum g = 0)
    // as the rows of y [w R0^T, g^T] (packets of the record's first 6 doubles)
    CentroidSums<double> cs;
    Row6 ax = Row6::Zero(), ay = Row6::Zero(), az = Row6::Zero();  // rows of [A, F]
    for (int j = 0; j < n; ++j) {
      const PackedEntry& en = pe[j];
      const double* xp = xs + 3 * std::int64_t(en.vertex);
      const Eigen::Map<const Row6, Eigen::Aligned16> cst(en.rest_weighted);
      const double w = en.weight;
      const double yx = xp[0] - ox, yy = xp[1] - oy, yz = xp[2] - oz;
      cs.add(w, yx, yy, yz);
      ax += yx * cst;
      ay += yy * cst;
      az += yz * cst;
    }
    // pass 1b (damping): the sums of the rigid velocity fit; a loop of its own (the gather hits
    // L1 now) because in pass 1 its 12 more sums spill, measured no faster
    RigidSums<double> rs;
    if constexpr (kDamping) {
      for (int j = 0; j < n; ++j) {
        const double* xp = xs + 3 * std::int64_t(pe[j].vertex);
        const double* vp = vs + 3 * std::int64_t(pe[j].vertex);
        rs.add(pe[j].weight, xp[0] - ox, xp[1] - oy, xp[2] - oz, vp[0], vp[1], vp[2]);
      }
    }
    const double inv_w = 1.0 / cs.sw;
    const Eigen::Vector3d c(cs.sx * inv_w, cs.sy * inv_w, cs.sz * inv_w);  // relative to x0
    Eigen::Matrix3d a, fg;
    a << ax(0), ax(1), ax(2), ay(0), ay(1), ay(2), az(0), az(1), az(2);
    fg << ax(3), ax(4), ax(5), ay(3), ay(4), ay(5), az(3), az(4), az(5);
    if (!a.allFinite() || !fg.allFinite() || !c.allFinite()) {  // NaN/Inf in: no force out, counted
      ++st.non_finite;
      for (int j = 0; j < n; ++j) {
        double* out = ef + 3 * std::int64_t(pe[j].slot);
        out[0] = out[1] = out[2] = 0.0;
      }
      if constexpr (kEnergy) energy_out[e] = 0.0;
      continue;
    }
    ElementMatrices<kVolume> em(phys, e, a, fg, rot[e], fit, st);
    const Eigen::Matrix3d &q = em.q, &t = em.t;
    const double k = em.force.k, wv = em.wv;
    // the bending modes' amplitudes (a loop of its own: a separate stream of constants)
    Eigen::Matrix<double, 3, kBendingModes> qm;
    if constexpr (kModes) qm = mode_amplitudes(phys, xs, m.element_vertices.data(), b, n, Eigen::Vector3d(ox, oy, oz));
    // the rigid velocity fit about the centroid (damping)
    if constexpr (kDamping) {
      em.force.damping = phys.element_damping[std::size_t(e)];
      law::rigid_velocity(rs, cs.sw, inv_w, c.x(), c.y(), c.z(), em.force);
    }
    // pass 2: each entry's force (element_law.h, entry_force: f = M R0' - w k (x - c) + G g
    // [+ modes] [+ c w (v_c + omega x r - v)]), written once
    {
      const double cx = ox + c.x(), cy = oy + c.y(), cz = oz + c.z();
      for (int j = 0; j < n; ++j) {
        const PackedEntry& en = pe[j];
        const double* xp = xs + 3 * std::int64_t(en.vertex);
        const double r[3] = {xp[0] - cx, xp[1] - cy, xp[2] - cz};
        double fm[3] = {0.0, 0.0, 0.0}, v[3] = {0.0, 0.0, 0.0}, o[3];
        if constexpr (kModes) Eigen::Vector3d::Map(fm) = qm * phys.entry_modes.col(b + j);
        if constexpr (kDamping) {
          const double* vp = vs + 3 * std::int64_t(en.vertex);
          v[0] = vp[0], v[1] = vp[1], v[2] = vp[2];
        }
        law::entry_force<kModes, kDamping>(em.force, en.rest_weighted, en.gradient, en.weight, r, fm, v, o);
        double* out = ef + 3 * std::int64_t(en.slot);
        out[0] = o[0];
        out[1] = o[1];
        out[2] = o[2];
      }
    }
    double point_energy = 0;
    if constexpr (kVolume)
      if (phys.has_volume_points()) point_energy = add_volume_point_forces(phys, xs, e, fg, rot[e], fit, ef);
    if constexpr (kEnergy) {
      double en = 0.5 * phys.element_affine_stiffness[std::size_t(e)] * (fg - q).squaredNorm();
      const Eigen::Vector3d ca = Eigen::Vector3d(ox, oy, oz) + c;
      for (int j = 0; j < n; ++j) {
        const Eigen::Vector3d r = Eigen::Map<const Eigen::Vector3d>(xs + 3 * std::int64_t(pe[j].vertex)) - ca;
        const Eigen::Vector3d rr = phys.entry_rest.col(b + j);
        en += 0.5 * k * pe[j].weight * (fg * rr - r).squaredNorm();
      }
      if constexpr (kVolume) en += 0.5 * wv * (fg - t).squaredNorm() + point_energy;
      if constexpr (kModes) en -= 0.5 * qm.squaredNorm();
      energy_out[e] = en;
      st.elastic_energy += en;
    }
  }
}

using RangeFn = void (*)(const PhysicsModel&, const double*, const double*, Eigen::Quaterniond*, double*, double*,
                         std::int64_t, std::int64_t, const RotationFitSettings&, ElementPassStats&);

template <template <bool, bool, bool, bool> class Kernel, bool kModes>
RangeFn pick_range(bool damping, bool energy, bool volume) {
  const int key = (damping ? 1 : 0) | (energy ? 2 : 0) | (volume ? 4 : 0);
  switch (key) {
    case 0: return Kernel<false, false, false, kModes>::run;
    case 1: return Kernel<true, false, false, kModes>::run;
    case 2: return Kernel<false, true, false, kModes>::run;
    case 3: return Kernel<true, true, false, kModes>::run;
    case 4: return Kernel<false, false, true, kModes>::run;
    case 5: return Kernel<true, false, true, kModes>::run;
    case 6: return Kernel<false, true, true, kModes>::run;
    default: return Kernel<true, true, true, kModes>::run;
  }
}

template <template <bool, bool, bool, bool> class Kernel>
RangeFn pick_range(bool damping, bool energy, bool volume, bool modes) {
  return modes ? pick_range<Kernel, true>(damping, energy, volume) : pick_range<Kernel, false>(damping, energy, volume);
}

template <bool kDamping, bool kEnergy, bool kVolume, bool kModes>
struct ReferenceKernel {
  static constexpr RangeFn run = &element_range_reference<kDamping, kEnergy, kVolume, kModes>;
};
template <bool kDamping, bool kEnergy, bool kVolume, bool kModes>
struct PackedKernel {
  static constexpr RangeFn run = &element_range_packed<kDamping, kEnergy, kVolume, kModes>;
};

}  // namespace

ElementPassStats compute_element_forces(const PhysicsModel& phys, const Eigen::Matrix3Xd& positions,
                                        const Eigen::Matrix3Xd* velocities, std::vector<Eigen::Quaterniond>& rotations,
                                        Eigen::Matrix3Xd& entry_forces, std::vector<double>* element_energy,
                                        const ElementPassOptions& options, int threads, ElementPassScratch& scratch) {
  const std::int64_t ne = phys.num_elements();
  const bool damping = options.damping && velocities != nullptr;
  const bool energy = options.energy && element_energy != nullptr;
  // sizes are set up once; these are no-ops in a running simulation
  if (entry_forces.cols() != phys.num_vertex_entries()) entry_forces.resize(3, phys.num_vertex_entries());
  if (energy && std::int64_t(element_energy->size()) != ne) element_energy->resize(std::size_t(ne));
  const std::int64_t chunks = chunk_count(ne, kElementGrain);
  if (std::int64_t(scratch.chunks.size()) != element_pass_slots(ne))
    scratch.chunks.resize(std::size_t(element_pass_slots(ne)));
  // the packed kernels need the packed entries (always there in a model from make_physics_model)
  const bool packed =
      options.kernel != ElementKernel::reference && std::int64_t(phys.entry_packed.size()) == phys.num_vertex_entries();
  const ElementBatches& eb = phys.element_batches;
  const bool modes = phys.has_bending_modes();
  // automatic on a CPU without AVX2: the packed kernel (the batched one on two-lane SSE2 is
  // slower once the model leaves the cache: element_pass benchmark, batched_generic)
  const bool vector_unit = options.simd != SimdLevel::automatic || best_simd_level() != SimdLevel::generic;
  // (a 2D model runs the packed kernel: its rotation fit is the closed form of the plane)
  const bool batched = packed && options.kernel == ElementKernel::batched && vector_unit && !energy &&
                       !phys.has_volume_term() && !phys.is_2d() && std::int64_t(eb.window_offsets.size()) == chunks + 1;
  const RangeFn fn = packed ? pick_range<PackedKernel>(damping, energy, phys.has_volume_term(), modes)
                            : pick_range<ReferenceKernel>(damping, energy, phys.has_volume_term(), modes);
  const double* xs = positions.data();
  const double* vs = damping ? velocities->data() : nullptr;
  Eigen::Quaterniond* rot = rotations.data();
  double* ef = entry_forces.data();
  double* en = energy ? element_energy->data() : nullptr;
  // chunk c is the element window [c kElementGrain, (c+1) kElementGrain) for every kernel
  parallel_for_chunks(ne, kElementGrain, threads, [&](std::int64_t chunk, std::int64_t b, std::int64_t e) {
    ElementPassStats st;
    if (batched)
      element_batches_range(phys, xs, vs, rot, ef, eb.window_offsets[std::size_t(chunk)],
                            eb.window_offsets[std::size_t(chunk) + 1], options.rotation, damping, st, options.simd);
    else
      fn(phys, xs, vs, rot, ef, en, b, e, options.rotation, st);
    scratch.chunks[std::size_t(chunk)] = st;
  });
  ElementPassStats& rest = scratch.chunks.back();
  rest = ElementPassStats{};
  if (batched)
    for (const std::int32_t e : eb.unbatched) fn(phys, xs, vs, rot, ef, en, e, e + 1, options.rotation, rest);
  // reduce in chunk order: the same sums for any thread count
  ElementPassStats total;
  for (const auto& s : scratch.chunks) total.add(s);
  return total;
}

void gather_node_forces(const PhysicsModel& phys, const Eigen::Matrix3Xd& entry_forces, Eigen::Matrix3Xd& node_forces,
                        int threads) {
  if (node_forces.cols() != phys.num_nodes()) node_forces.resize(3, phys.num_nodes());
  parallel_for(phys.num_nodes(), kNodeGrain, threads, [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t i = b; i < e; ++i) node_forces.col(i) = gather_node_force(phys, entry_forces, int(i));
  });
}

void element_elastic_matrix(const PhysicsModel& phys, int e, Eigen::MatrixXd& k, bool relieved, bool volume) {
  const Model& m = *phys.model;
  const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
  const auto g = phys.entry_gradient.middleCols(b, n);
  const auto r0 = phys.entry_rest.middleCols(b, n);
  const Eigen::Map<const Eigen::VectorXd> w(phys.entry_weight.data() + b, n);
  Eigen::MatrixXd p = -r0.transpose() * g;  // P_lj = delta_lj - w_j / W - R0_l . g_j
  p.rowwise() -= w.transpose() / w.sum();
  p.diagonal().array() += 1.0;
  const double kv = volume && phys.has_volume_term() ? phys.element_volume_stiffness[std::size_t(e)] : 0.0;
  k.noalias() = (phys.element_affine_stiffness[std::size_t(e)] + kv) * (g.transpose() * g);
  k.noalias() += phys.element_stiffness[std::size_t(e)] * (p.transpose() * w.asDiagonal() * p);
  if (relieved && phys.has_bending_modes()) {
    const auto h = phys.entry_modes.middleCols(b, n);
    k.noalias() -= h.transpose() * h;
  }
  if (volume && phys.has_volume_points()) {  // k_s (g + delta_s)(g + delta_s)^T per volume point
    Eigen::Matrix3Xd gs(3, n);
    for (int s = phys.volume_point_offsets[std::size_t(e)]; s < phys.volume_point_offsets[std::size_t(e) + 1]; ++s) {
      gs = g;
      for (int t = phys.volume_point_term_offsets[std::size_t(s)];
           t < phys.volume_point_term_offsets[std::size_t(s) + 1]; ++t)
        gs.col(phys.volume_term_entry[std::size_t(t)] - b) += phys.volume_term_delta.col(t);
      k.noalias() += phys.volume_point_stiffness[std::size_t(s)] * (gs.transpose() * gs);
    }
  }
}

double element_energy(const PhysicsModel& phys, int e, const Eigen::Matrix3Xd& x, Eigen::Quaterniond& q,
                      const RotationFitSettings& settings) {
  const Model& m = *phys.model;
  const int b = m.element_offsets[e], n = m.element_offsets[e + 1] - b;
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double sw = 0;
  for (int j = b; j < b + n; ++j) {
    c += phys.entry_weight[j] * x.col(m.element_vertices[j]);
    sw += phys.entry_weight[j];
  }
  c /= sw;
  Eigen::Matrix3d fg = Eigen::Matrix3d::Zero();
  for (int j = b; j < b + n; ++j) {
    fg += (x.col(m.element_vertices[j]) - c) * phys.entry_gradient.col(j).transpose();
  }
  Eigen::Matrix3d rq;
  fit_element_rotation(phys, fg, q, settings, nullptr, &rq);
  double en = 0.5 * phys.element_affine_stiffness[e] * (fg - rq).squaredNorm();
  for (int j = b; j < b + n; ++j)
    en += 0.5 * phys.element_stiffness[e] * phys.entry_weight[j] *
          (fg * phys.entry_rest.col(j) - (x.col(m.element_vertices[j]) - c)).squaredNorm();
  if (phys.has_bending_modes()) {
    Eigen::Matrix<double, 3, kBendingModes> qm = Eigen::Matrix<double, 3, kBendingModes>::Zero();
    for (int j = b; j < b + n; ++j) qm += (x.col(m.element_vertices[j]) - c) * phys.entry_modes.col(j).transpose();
    en -= 0.5 * qm.squaredNorm();
  }
  if (phys.has_volume_term()) {
    Eigen::Quaterniond qv = q;
    const Eigen::Matrix3d t = element_closest_with_determinant(phys, fg, 1.0, qv, settings);
    en += 0.5 * phys.element_volume_stiffness[e] * (fg - t).squaredNorm();
    if (phys.has_volume_points())
      for_each_volume_point(phys, x.data(), e, fg, q, settings,
                            [&](int s, const Eigen::Matrix3d& fs, const Eigen::Matrix3d& ts) {
                              en += 0.5 * phys.volume_point_stiffness[std::size_t(s)] * (fs - ts).squaredNorm();
                            });
  }
  return en;
}

}  // namespace vx
