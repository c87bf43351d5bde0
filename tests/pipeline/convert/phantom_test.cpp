// Phantoms: voxel counts against analytic volumes, exact signed distances, areas, noise and
// the validation of settings.
#include "convert/phantom.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <set>
#include <string>

#include "base/error.h"

using vx::make_phantom;
using vx::PhantomSettings;
using vx::PhantomShape;
using vx::Volume;
using vx::lesion_settings_error;
using vx::phantom_shape;

namespace {

constexpr double kPi = std::numbers::pi;

PhantomSettings settings(const std::string& name, int size, double spacing = 1.0) {
  PhantomSettings s;
  s.name = name;
  s.size = size;
  s.spacing_mm = spacing;
  return s;
}

std::int64_t count_hu(const Volume& v, float hu) {
  std::int64_t n = 0;
  for (float x : v.hu) n += x == hu;
  return n;
}

TEST(Phantom, NamesAreTheDocumentedOnes) {
  EXPECT_EQ(vx::phantom_names(), (std::vector<std::string>{"sphere", "cube", "ellipsoid", "cylinder", "torus",
                                                          "block", "block-lesion", "organ", "folded", "disk",
                                                          "rectangle", "disk-lesion"}));
}

// The voxel count (centres inside) approximates the analytic volume. Flat faces lie on voxel
// faces, so the cube and block are exact; curved shapes are within 3% at 32^3 (the torus,
// whose tube is only 3.8 voxels thick there, within 4%: it is +3.07%) and 1% at 64^3
// (lattice-point counting error falls like the inverse of the size).
TEST(Phantom, TissueVoxelsMatchAnalyticVolume) {
  for (const auto& name : vx::phantom_names())
    for (int size : {32, 64})
      for (double spacing : {1.0, 0.6}) {
        SCOPED_TRACE(name + " size " + std::to_string(size) + " spacing " + std::to_string(spacing));
        PhantomShape shape;
        const Volume v = make_phantom(settings(name, size, spacing), &shape);
        const std::int64_t tissue = v.geometry.voxel_count() - count_hu(v, -1000.0f);
        EXPECT_EQ(tissue, shape.tissue_voxels);
        // the count equals the number of voxel centres with a negative signed distance
        std::int64_t by_distance = 0;
        for (int k = 0; k < v.geometry.dims.z(); ++k)  // one slice for disk, rectangle, disk-lesion
          for (int j = 0; j < size; ++j)
            for (int i = 0; i < size; ++i)
              by_distance += shape.signed_distance_mm(v.geometry.index_to_lps(Eigen::Vector3d(i, j, k))) < 0;
        EXPECT_EQ(by_distance, tissue);
        if (!shape.has_closed_form()) {  // folded: no analytic volume (FoldedPhantom below)
          EXPECT_THROW((void)shape.volume_mm3(), vx::Error);
          EXPECT_THROW((void)shape.area_mm2(), vx::Error);
          continue;
        }
        const double expected = shape.volume_mm3() / std::pow(spacing, 3);
        const double rel = std::abs(double(tissue) - expected) / expected;
        const bool flat = name == "cube" || name == "block" || name == "block-lesion" || name == "rectangle";
        const double tolerance = flat ? 1e-12 : size == 64 ? 0.01 : name == "torus" ? 0.04 : 0.03;
        EXPECT_LT(rel, tolerance) << tissue << " voxels vs " << expected;
      }
}

TEST(Phantom, CentredWithAirMargin) {
  for (const auto& name : vx::phantom_names())
    for (int size : {8, 9, 16, 25, 33, 64}) {
      SCOPED_TRACE(name + " size " + std::to_string(size));
      PhantomShape shape;
      const Volume v = make_phantom(settings(name, size, 0.8), &shape);
      // geometry: centre of the grid at LPS 0, identity direction, spacing as asked
      const int nz = v.geometry.dims.z();  // 1 for the one-slice phantoms
      EXPECT_EQ(nz, shape.is_2d() ? 1 : size);
      const Eigen::Vector3d centre =
          v.geometry.index_to_lps(Eigen::Vector3d(0.5 * (size - 1), 0.5 * (size - 1), 0.5 * (nz - 1)));
      EXPECT_LT(centre.norm(), 1e-12);
      EXPECT_EQ(v.geometry.direction, Eigen::Matrix3d::Identity());
      EXPECT_EQ(v.geometry.spacing_mm, Eigen::Vector3d::Constant(0.8));
      // at least 2 voxels of air on every side
      int lo = size, hi = -1;
      for (int k = 0; k < nz; ++k)
        for (int j = 0; j < size; ++j)
          for (int i = 0; i < size; ++i)
            if (v.at(i, j, k) != -1000.0f) {
              lo = std::min({lo, i, j, nz == 1 ? size : k});
              hi = std::max({hi, i, j, nz == 1 ? -1 : k});
            }
      EXPECT_GE(lo, 2);
      EXPECT_LE(hi, size - 3);
      // symmetric about the centre (except the lesion, which is off-centre on purpose, and the
      // folded phantom, whose stem is at the bottom and whose sulci differ left and right)
      if (name != "block-lesion" && name != "disk-lesion" && name != "folded") {
        for (int k = 0; k < nz; ++k)
          for (int j = 0; j < size; ++j)
            for (int i = 0; i < size; ++i)
              ASSERT_EQ(v.at(i, j, k), v.at(size - 1 - i, size - 1 - j, nz - 1 - k));
      }
    }
}

TEST(Phantom, ProportionsAt64) {
  PhantomShape s;
  (void)make_phantom(settings("sphere", 64), &s);
  EXPECT_DOUBLE_EQ(s.half_extent_mm.x(), 0.4 * 64);
  (void)make_phantom(settings("ellipsoid", 64, 0.5), &s);
  EXPECT_LT((s.half_extent_mm - Eigen::Vector3d(0.42, 0.30, 0.22) * 32).norm(), 1e-12);
  (void)make_phantom(settings("cube", 64), &s);
  EXPECT_DOUBLE_EQ(s.half_extent_mm.x(), 22.0);  // 0.35 * 64 = 22.4, down to a voxel face
  (void)make_phantom(settings("block", 64), &s);
  EXPECT_EQ(s.half_extent_mm, Eigen::Vector3d(25, 19, 12));  // 0.4, 0.3, 0.2 of 64, down to voxel faces
  (void)make_phantom(settings("torus", 64), &s);
  EXPECT_DOUBLE_EQ(s.major_radius_mm, 0.28 * 64);
  EXPECT_DOUBLE_EQ(s.minor_radius_mm, 0.12 * 64);
  (void)make_phantom(settings("cylinder", 64), &s);
  EXPECT_DOUBLE_EQ(s.minor_radius_mm, 0.3 * 64);
  EXPECT_DOUBLE_EQ(s.half_length_mm, 25.0);
}

TEST(Phantom, BlockLesion) {
  PhantomSettings st = settings("block-lesion", 64);
  st.lesion_hu = 120;
  PhantomShape s;
  const Volume v = make_phantom(st, &s);
  // centred at 60% of the block's height, off the axis, radius near 15% of the grid
  EXPECT_NEAR(s.lesion_center_mm.z(), -12.0 + 0.6 * 24.0, 1e-12);
  EXPECT_GT(s.lesion_center_mm.x(), 0.0);
  EXPECT_GT(s.lesion_radius_mm, 0.12 * 64);
  EXPECT_LE(s.lesion_radius_mm, 0.15 * 64);
  // lesion voxels: the analytic ball within 3%, and all wrapped in tissue
  const std::int64_t lesion = count_hu(v, 120.0f);
  EXPECT_EQ(lesion, s.lesion_voxels);
  const double ball = 4.0 / 3.0 * kPi * std::pow(s.lesion_radius_mm, 3);
  EXPECT_NEAR(double(lesion), ball, 0.03 * ball);
  for (int k = 1; k < 63; ++k)
    for (int j = 1; j < 63; ++j)
      for (int i = 1; i < 63; ++i)
        if (v.at(i, j, k) == 120.0f) {
          for (const auto& d : {Eigen::Vector3i(1, 0, 0), Eigen::Vector3i(0, 1, 0), Eigen::Vector3i(0, 0, 1)}) {
            ASSERT_NE(v.at(i + d.x(), j + d.y(), k + d.z()), -1000.0f);
            ASSERT_NE(v.at(i - d.x(), j - d.y(), k - d.z()), -1000.0f);
          }
        }
  // tissue + lesion = the block, exactly
  EXPECT_EQ(count_hu(v, 40.0f) + lesion, std::int64_t(s.volume_mm3()));
}

TEST(Phantom, LesionPlacedAndSizedByTheCaller) {
  // block-lesion 48: the block is 38 x 28 x 18 mm (half 19, 14, 9); a 3 mm lesion at (-6, 4, 3)
  PhantomSettings st = settings("block-lesion", 48);
  st.lesion_center_mm = Eigen::Vector3d(-6.0, 4.0, 3.0);
  st.lesion_radius_mm = 3.0;
  PhantomShape s;
  const Volume v = make_phantom(st, &s);
  EXPECT_EQ(s.half_extent_mm, Eigen::Vector3d(19.0, 14.0, 9.0));
  EXPECT_EQ(s.lesion_center_mm, Eigen::Vector3d(-6.0, 4.0, 3.0));
  EXPECT_EQ(s.lesion_radius_mm, 3.0);
  // the voxel centres within 3 mm of (-6, 4, 3): counted by brute force over the grid
  std::int64_t expected = 0;
  for (int k = 0; k < 48; ++k)
    for (int j = 0; j < 48; ++j)
      for (int i = 0; i < 48; ++i) {
        const Eigen::Vector3d p = v.geometry.index_to_lps(Eigen::Vector3d(i, j, k));
        const bool in = (p - Eigen::Vector3d(-6.0, 4.0, 3.0)).squaredNorm() < 9.0;
        expected += in;
        ASSERT_EQ(v.at(i, j, k) == 120.0f, in) << i << " " << j << " " << k;
      }
  EXPECT_EQ(s.lesion_voxels, expected);
  // a 3 mm ball on a lattice of half-integer voxel centres around an integer point: 136 voxels
  // against 113 mm^3 (coarse: 3 voxels of radius)
  EXPECT_EQ(expected, 136);
  // only the radius: the default centre keeps its place
  PhantomSettings r = settings("block-lesion", 48);
  const PhantomShape d = phantom_shape(r);
  r.lesion_radius_mm = 2.0;
  EXPECT_EQ(phantom_shape(r).lesion_center_mm, d.lesion_center_mm);
  EXPECT_EQ(phantom_shape(r).lesion_radius_mm, 2.0);
  // disk-lesion: a centre in the plane
  PhantomSettings disk = settings("disk-lesion", 48);
  disk.lesion_center_mm = Eigen::Vector3d(-5.0, -5.0, 0.0);
  disk.lesion_radius_mm = 4.0;
  EXPECT_EQ(phantom_shape(disk).lesion_center_mm, Eigen::Vector3d(-5.0, -5.0, 0.0));
  EXPECT_EQ(lesion_settings_error(disk), "");
}

TEST(Phantom, LesionOutsideTheBlockIsRefused) {
  PhantomSettings st = settings("block-lesion", 48);  // half extents 19, 14, 9 mm
  st.lesion_radius_mm = 3.0;
  st.lesion_center_mm = Eigen::Vector3d(0.0, 0.0, 6.0);  // touches the top exactly: allowed
  EXPECT_EQ(lesion_settings_error(st), "");
  st.lesion_center_mm = Eigen::Vector3d(0.0, 0.0, 6.5);  // 0.5 mm out through the top
  EXPECT_NE(lesion_settings_error(st).find("does not fit inside the block"), std::string::npos)
      << lesion_settings_error(st);
  EXPECT_THROW((void)make_phantom(st), vx::Error);
  st.lesion_center_mm = Eigen::Vector3d(-17.0, 0.0, 0.0);  // through the x_min face
  EXPECT_NE(lesion_settings_error(st), "");
  st.lesion_center_mm = Eigen::Vector3d(0.0, 12.0, 0.0);  // through y_max
  EXPECT_NE(lesion_settings_error(st), "");
  st.lesion_center_mm.reset();
  st.lesion_radius_mm = 12.0;  // the default centre with a radius taller than the block
  EXPECT_NE(lesion_settings_error(st), "");
  st.lesion_radius_mm = -1.0;
  EXPECT_NE(lesion_settings_error(st).find("positive"), std::string::npos);
  st.lesion_radius_mm = 2.0;
  st.lesion_center_mm = Eigen::Vector3d(0.0, std::nan(""), 0.0);
  EXPECT_NE(lesion_settings_error(st).find("finite"), std::string::npos);
  // only the lesion phantoms have one
  PhantomSettings block = settings("block", 48);
  block.lesion_radius_mm = 2.0;
  EXPECT_NE(lesion_settings_error(block).find("has no lesion"), std::string::npos);
  EXPECT_THROW((void)phantom_shape(block), vx::Error);
  // disk-lesion: in the plane, inside the disk
  PhantomSettings disk = settings("disk-lesion", 48);
  const double radius = phantom_shape(disk).half_extent_mm.x();
  disk.lesion_radius_mm = 2.0;
  disk.lesion_center_mm = Eigen::Vector3d(0.0, 0.0, 1.0);
  EXPECT_NE(lesion_settings_error(disk).find("z must be 0"), std::string::npos);
  disk.lesion_center_mm = Eigen::Vector3d(radius - 1.0, 0.0, 0.0);
  EXPECT_NE(lesion_settings_error(disk).find("does not fit inside the disk"), std::string::npos);
}

// ---------------------------------------------------------------------------------------
// signed distances

PhantomShape shape_of(const std::string& name) {
  PhantomShape s;
  (void)make_phantom(settings(name, 64), &s);
  return s;
}

TEST(PhantomShape, SignedDistanceAtKnownPoints) {
  const PhantomShape sphere = shape_of("sphere");  // R = 25.6
  EXPECT_NEAR(sphere.signed_distance_mm({0, 0, 0}), -25.6, 1e-12);
  EXPECT_NEAR(sphere.signed_distance_mm({0, 28.6, 0}), 3.0, 1e-12);
  EXPECT_NEAR(sphere.signed_distance_mm({3, 4, 0}), 5.0 - 25.6, 1e-12);

  const PhantomShape block = shape_of("block");  // half sizes 25, 19, 12
  EXPECT_NEAR(block.signed_distance_mm({0, 0, 0}), -12.0, 1e-12);
  EXPECT_NEAR(block.signed_distance_mm({28, 23, 0}), 5.0, 1e-12);   // beyond an edge: (3, 4)
  EXPECT_NEAR(block.signed_distance_mm({-26, -21, 14}), 3.0, 1e-12);  // beyond a corner: (1, 2, 2)
  EXPECT_NEAR(block.signed_distance_mm({24, 0, 0}), -1.0, 1e-12);
  EXPECT_FALSE(block.inside({25.5, 0, 0}));

  const PhantomShape cyl = shape_of("cylinder");  // r = 19.2, half length 25
  EXPECT_NEAR(cyl.signed_distance_mm({0, 0, 0}), -19.2, 1e-12);
  EXPECT_NEAR(cyl.signed_distance_mm({0, 0, 27}), 2.0, 1e-12);        // above the cap
  EXPECT_NEAR(cyl.signed_distance_mm({22.2, 0, 29}), 5.0, 1e-12);     // beyond the rim: (3, 4)
  EXPECT_NEAR(cyl.signed_distance_mm({0, 18.2, 24.5}), -0.5, 1e-12);  // nearer the cap than the side

  const PhantomShape torus = shape_of("torus");  // R = 17.92, r = 7.68
  EXPECT_NEAR(torus.signed_distance_mm({17.92, 0, 0}), -7.68, 1e-12);
  EXPECT_NEAR(torus.signed_distance_mm({0, 0, 0}), 17.92 - 7.68, 1e-12);  // the hole
  EXPECT_NEAR(torus.signed_distance_mm({0, -17.92, 9.68}), 2.0, 1e-12);
  EXPECT_NEAR(torus.signed_distance_mm({27.6, 0, 0}), 27.6 - 17.92 - 7.68, 1e-12);

  const PhantomShape ell = shape_of("ellipsoid");  // 26.88, 19.2, 14.08
  EXPECT_NEAR(ell.signed_distance_mm({0, 0, 0}), -14.08, 1e-9);  // the nearest point is on the short axis
  EXPECT_NEAR(ell.signed_distance_mm({28.88, 0, 0}), 2.0, 1e-9);
  EXPECT_NEAR(ell.signed_distance_mm({0, -20.2, 0}), 1.0, 1e-9);
  EXPECT_NEAR(ell.signed_distance_mm({0, 0, 15.08}), 1.0, 1e-9);
  EXPECT_NEAR(ell.signed_distance_mm({0, 0, 13.08}), -1.0, 1e-9);
  // a point of the surface
  const Eigen::Vector3d on(26.88 * std::sin(0.7) * std::cos(1.1), 19.2 * std::sin(0.7) * std::sin(1.1),
                           14.08 * std::cos(0.7));
  EXPECT_NEAR(ell.signed_distance_mm(on), 0.0, 1e-9);
}

TEST(PhantomShape, EllipsoidDistanceAgreesWithDenseSurfaceSampling) {
  const PhantomShape ell = shape_of("ellipsoid");
  const Eigen::Vector3d e = ell.half_extent_mm;
  // the surface at 1000 x 2000 parameter points (at most ~0.04 mm apart)
  std::vector<Eigen::Vector3d> surface;
  for (int a = 0; a <= 1000; ++a)
    for (int b = 0; b < 2000; ++b) {
      const double th = kPi * a / 1000.0, ph = 2.0 * kPi * b / 2000.0;
      surface.emplace_back(e.x() * std::sin(th) * std::cos(ph), e.y() * std::sin(th) * std::sin(ph),
                           e.z() * std::cos(th));
    }
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-35.0, 35.0);
  for (int t = 0; t < 25; ++t) {
    Eigen::Vector3d p(u(rng), u(rng), u(rng));
    if (t < 3) p[t] = 0.0;  // points on the symmetry planes, the hard case inside
    if (t == 3) p = Eigen::Vector3d(5.0, 2.0, 0.0);
    double best = 1e300;
    for (const auto& q : surface) best = std::min(best, (q - p).squaredNorm());
    best = std::sqrt(best);
    const double d = ell.signed_distance_mm(p);
    // sampling can only overestimate the distance, by at most half the sample spacing
    EXPECT_GE(best, std::abs(d) - 1e-9) << p.transpose();
    EXPECT_LT(best - std::abs(d), 0.03) << p.transpose();
    EXPECT_EQ(d < 0, p.cwiseQuotient(e).squaredNorm() < 1.0);
  }
}

TEST(PhantomShape, DistanceGradientHasUnitLength) {
  // an exact signed distance has |grad| = 1 away from the medial axis
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-30.0, 30.0);
  for (const auto& name : vx::phantom_names()) {
    const PhantomShape s = shape_of(name);
    if (!s.has_closed_form()) continue;  // folded: an approximate distance (FoldedPhantom below)
    int checked = 0;
    for (int t = 0; t < 40; ++t) {
      const Eigen::Vector3d p(u(rng), u(rng), u(rng));
      const double step = 1e-5;
      Eigen::Vector3d g;
      for (int a = 0; a < 3; ++a) {
        Eigen::Vector3d dp = Eigen::Vector3d::Zero();
        dp[a] = step;
        g[a] = (s.signed_distance_mm(p + dp) - s.signed_distance_mm(p - dp)) / (2 * step);
      }
      // skip points within 0.01 mm of a crease of the distance field (medial axis, box edges)
      bool smooth = true;
      for (int a = 0; a < 3 && smooth; ++a) {
        Eigen::Vector3d dp = Eigen::Vector3d::Zero();
        dp[a] = 0.01;
        const double second = s.signed_distance_mm(p + dp) - 2 * s.signed_distance_mm(p) + s.signed_distance_mm(p - dp);
        smooth = std::abs(second) < 1e-3;
      }
      if (!smooth) continue;
      ++checked;
      EXPECT_NEAR(g.norm(), 1.0, 1e-5) << name << " at " << p.transpose();
    }
    EXPECT_GT(checked, 15) << name;
  }
}

TEST(PhantomShape, VolumesAndAreas) {
  PhantomShape s = shape_of("sphere");
  EXPECT_NEAR(s.volume_mm3(), 4.0 / 3.0 * kPi * std::pow(25.6, 3), 1e-9);
  EXPECT_NEAR(s.area_mm2(), 4.0 * kPi * 25.6 * 25.6, 1e-9);
  s = shape_of("cube");
  EXPECT_NEAR(s.volume_mm3(), 44.0 * 44 * 44, 1e-9);
  EXPECT_NEAR(s.area_mm2(), 6.0 * 44 * 44, 1e-9);
  s = shape_of("block");
  EXPECT_NEAR(s.volume_mm3(), 50.0 * 38 * 24, 1e-9);
  EXPECT_NEAR(s.area_mm2(), 2.0 * (50.0 * 38 + 38.0 * 24 + 24.0 * 50), 1e-9);
  s = shape_of("cylinder");
  EXPECT_NEAR(s.volume_mm3(), kPi * 19.2 * 19.2 * 50, 1e-9);
  EXPECT_NEAR(s.area_mm2(), 2 * kPi * 19.2 * 50 + 2 * kPi * 19.2 * 19.2, 1e-9);
  s = shape_of("torus");
  EXPECT_NEAR(s.volume_mm3(), 2 * kPi * kPi * 17.92 * 7.68 * 7.68, 1e-9);
  EXPECT_NEAR(s.area_mm2(), 4 * kPi * kPi * 17.92 * 7.68, 1e-9);

  // ellipsoid area: the closed form against a numerical surface integral (midpoint rule
  // over the parameters, |r_theta x r_phi|), and against Knud Thomsen's 1%-approximation
  s = shape_of("ellipsoid");
  const Eigen::Vector3d e = s.half_extent_mm;
  EXPECT_NEAR(s.volume_mm3(), 4.0 / 3.0 * kPi * e.prod(), 1e-9);
  const int nt = 2000, np = 4000;
  double area = 0;
  for (int a = 0; a < nt; ++a)
    for (int b = 0; b < np; ++b) {
      const double th = kPi * (a + 0.5) / nt, ph = 2 * kPi * (b + 0.5) / np;
      const Eigen::Vector3d rt(e.x() * std::cos(th) * std::cos(ph), e.y() * std::cos(th) * std::sin(ph),
                               -e.z() * std::sin(th));
      const Eigen::Vector3d rp(-e.x() * std::sin(th) * std::sin(ph), e.y() * std::sin(th) * std::cos(ph), 0.0);
      area += rt.cross(rp).norm();
    }
  area *= (kPi / nt) * (2 * kPi / np);
  EXPECT_NEAR(s.area_mm2(), area, 1e-6 * area);
  const double p = 1.6075;
  const double thomsen = 4 * kPi *
                         std::pow((std::pow(e.x() * e.y(), p) + std::pow(e.y() * e.z(), p) + std::pow(e.z() * e.x(), p)) / 3,
                                  1 / p);
  EXPECT_NEAR(s.area_mm2(), thomsen, 0.0111 * thomsen);
  // degenerate ellipsoids: a sphere, and prolate / oblate spheroids (closed forms)
  s.half_extent_mm = Eigen::Vector3d(5, 5, 5);
  EXPECT_NEAR(s.area_mm2(), 4 * kPi * 25, 1e-9);
  const double a = 3, c = 5;  // prolate: semi-axes a, a, c > a
  const double ecc = std::sqrt(1 - a * a / (c * c));
  s.half_extent_mm = Eigen::Vector3d(a, a, c);
  EXPECT_NEAR(s.area_mm2(), 2 * kPi * a * a * (1 + c / (a * ecc) * std::asin(ecc)), 1e-9);
  s.half_extent_mm = Eigen::Vector3d(c, c, a);  // oblate: semi-axes c, c, a < c
  const double eo = std::sqrt(1 - a * a / (c * c));
  EXPECT_NEAR(s.area_mm2(), 2 * kPi * c * c * (1 + (1 - eo * eo) / eo * std::atanh(eo)), 1e-9);
}

// ---------------------------------------------------------------------------------------

TEST(Phantom, NoiseIsSeededGaussianWholeHu) {
  PhantomSettings st = settings("cube", 32);
  const Volume clean = make_phantom(st);
  st.noise_hu = 25.0;
  st.seed = 42;
  const Volume a = make_phantom(st);
  const Volume b = make_phantom(st);
  EXPECT_EQ(a.hu, b.hu);  // same seed, same volume
  st.seed = 43;
  EXPECT_NE(make_phantom(st).hu, a.hu);
  double sum = 0, sum2 = 0;
  for (std::size_t i = 0; i < a.hu.size(); ++i) {
    EXPECT_EQ(a.hu[i], std::nearbyint(a.hu[i]));
    const double d = a.hu[i] - clean.hu[i];
    sum += d;
    sum2 += d * d;
  }
  const double n = double(a.hu.size());
  const double mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
  // 32768 samples: the mean is within 4 standard errors (0.55 HU); rounding adds 1/12 HU^2
  EXPECT_NEAR(mean, 0.0, 0.6);
  EXPECT_NEAR(sd, std::sqrt(25.0 * 25.0 + 1.0 / 12.0), 0.03 * 25.0);
}

void expect_error(const PhantomSettings& s, const std::vector<std::string>& needles) {
  try {
    (void)make_phantom(s);
    ADD_FAILURE() << "no vx::Error for " << s.name << " size " << s.size;
  } catch (const vx::Error& e) {
    for (const auto& n : needles) EXPECT_NE(std::string(e.what()).find(n), std::string::npos) << e.what();
  }
}

TEST(Phantom, BadSettingsAreRefused) {
  expect_error(settings("pyramid", 32), {"pyramid", "sphere", "torus", "block-lesion"});
  expect_error(settings("sphere", 3), {"3", "4 to 1024"});
  expect_error(settings("sphere", 1025), {"1025", "4 to 1024"});
  expect_error(settings("sphere", 32, 0.0), {"spacing"});
  expect_error(settings("sphere", 32, -1.0), {"spacing"});
  expect_error(settings("sphere", 32, std::nan("")), {"spacing"});
  expect_error(settings("sphere", 32, std::numeric_limits<double>::infinity()), {"spacing"});
  PhantomSettings s = settings("sphere", 32);
  s.noise_hu = -1;
  expect_error(s, {"noise"});
  // the smallest sizes still give a shape or a clear error; from 8 on every shape has voxels
  int refused = 0;
  for (const auto& name : vx::phantom_names())
    for (int size : {4, 5, 6, 7, 8}) {
      try {
        PhantomShape shape;
        (void)make_phantom(settings(name, size), &shape);
        EXPECT_GT(shape.tissue_voxels, 0) << name;
      } catch (const vx::Error& e) {
        ++refused;
        EXPECT_LT(size, 8) << name;
        EXPECT_NE(std::string(e.what()).find("too small"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("8 or more"), std::string::npos) << e.what();
      }
    }
  EXPECT_EQ(refused, 6);  // ellipsoid, torus and organ at 4 and 6
}

}  // namespace

// ---------------------------------------------------------------------------------------
// the folded (brain-like) phantom at its default size, 214 voxels of 1 mm

namespace {

class FoldedPhantom : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    shape_ = new PhantomShape;
    volume_ = new Volume(make_phantom(settings("folded", 214), shape_));
  }
  static void TearDownTestSuite() {
    delete volume_;
    delete shape_;
  }
  static bool tissue(int i, int j, int k) { return volume_->at(i, j, k) != -1000.0f; }
  /// The voxel whose centre is nearest to p (LPS mm); the grid has 1 mm voxels.
  static Eigen::Vector3i voxel_of(const Eigen::Vector3d& p) {
    const Eigen::Vector3d ijk = p - volume_->geometry.origin_mm;
    return Eigen::Vector3i(int(std::lround(ijk.x())), int(std::lround(ijk.y())), int(std::lround(ijk.z())));
  }
  static bool tissue_at(const Eigen::Vector3d& p) {
    const Eigen::Vector3i v = voxel_of(p);
    return tissue(v.x(), v.y(), v.z());
  }
  static PhantomShape* shape_;
  static Volume* volume_;
};
PhantomShape* FoldedPhantom::shape_ = nullptr;
Volume* FoldedPhantom::volume_ = nullptr;

constexpr int kN = 214;

/// Voxel faces between tissue and air (the staircase surface's area, mm^2 at 1 mm).
std::int64_t boundary_faces(const Volume& v) {
  const Eigen::Vector3i d = v.geometry.dims;
  std::int64_t faces = 0;
  for (int k = 1; k + 1 < d.z(); ++k)
    for (int j = 1; j + 1 < d.y(); ++j)
      for (int i = 1; i + 1 < d.x(); ++i) {
        if (v.at(i, j, k) == -1000.0f) continue;
        faces += (v.at(i + 1, j, k) == -1000.0f) + (v.at(i - 1, j, k) == -1000.0f) + (v.at(i, j + 1, k) == -1000.0f) +
                 (v.at(i, j - 1, k) == -1000.0f) + (v.at(i, j, k + 1) == -1000.0f) + (v.at(i, j, k - 1) == -1000.0f);
      }
  return faces;
}

TEST_F(FoldedPhantom, OneBrainSizedPieceOnAStem) {
  const PhantomShape& s = *shape_;
  // one 6-connected piece
  std::vector<char> seen(volume_->hu.size(), 0);
  std::int64_t first = -1;
  for (std::size_t x = 0; x < volume_->hu.size() && first < 0; ++x)
    if (volume_->hu[x] != -1000.0f) first = std::int64_t(x);
  ASSERT_GE(first, 0);
  std::vector<std::int64_t> stack{first};
  seen[std::size_t(first)] = 1;
  std::int64_t reached = 0;
  const std::int64_t steps[6] = {1, -1, kN, -kN, std::int64_t(kN) * kN, -std::int64_t(kN) * kN};
  while (!stack.empty()) {
    const std::int64_t x = stack.back();
    stack.pop_back();
    ++reached;
    for (std::int64_t st : steps) {
      const std::size_t y = std::size_t(x + st);  // the air margin keeps every neighbour inside the grid
      if (volume_->hu[y] != -1000.0f && !seen[y]) {
        seen[y] = 1;
        stack.push_back(std::int64_t(y));
      }
    }
  }
  EXPECT_EQ(reached, s.tissue_voxels);
  // 140 x 180 x 150 mm overall (voxel centres span one voxel less than the shape)
  Eigen::Vector3i lo(kN, kN, kN), hi(-1, -1, -1);
  for (int k = 0; k < kN; ++k)
    for (int j = 0; j < kN; ++j)
      for (int i = 0; i < kN; ++i)
        if (tissue(i, j, k)) {
          lo = lo.cwiseMin(Eigen::Vector3i(i, j, k));
          hi = hi.cwiseMax(Eigen::Vector3i(i, j, k));
        }
  const Eigen::Vector3i extent = hi - lo + Eigen::Vector3i::Ones();
  EXPECT_NEAR(extent.x(), 140, 2);
  EXPECT_NEAR(extent.y(), 180, 2);
  EXPECT_NEAR(extent.z(), 150, 2);
  // the stem: 15 to 25 mm across, its bottom face the lowest tissue, standing out below the
  // body: every slice below the body is a disc of its radius about its axis
  EXPECT_GE(2 * s.stem_radius_mm, 15.0);
  EXPECT_LE(2 * s.stem_radius_mm, 25.0);
  EXPECT_NEAR(volume_->geometry.index_to_lps(lo.cast<double>()).z(), s.stem_center_mm.z(), 1.0);
  const double body_bottom = s.center_mm.z() - s.half_extent_mm.z();
  EXPECT_LT(s.stem_center_mm.z(), body_bottom - 10.0);
  int slices = 0;
  for (int k = lo.z(); volume_->geometry.index_to_lps(Eigen::Vector3d(0, 0, k)).z() < body_bottom - 1.0; ++k) {
    std::int64_t count = 0;
    for (int j = 0; j < kN; ++j)
      for (int i = 0; i < kN; ++i)
        if (tissue(i, j, k)) {
          ++count;
          const Eigen::Vector3d p = volume_->geometry.index_to_lps(Eigen::Vector3d(i, j, k));
          EXPECT_LE(std::hypot(p.x() - s.stem_center_mm.x(), p.y() - s.stem_center_mm.y()), s.stem_radius_mm);
        }
    const double disc = kPi * s.stem_radius_mm * s.stem_radius_mm;
    EXPECT_NEAR(double(count), disc, 0.06 * disc) << "slice " << k;
    ++slices;
  }
  std::printf("folded 214: %lld voxels in one piece; extent %d x %d x %d; %d stem slices below the body\n",
              (long long)reached, extent.x(), extent.y(), extent.z(), slices);
  EXPECT_GE(slices, 12);
}

TEST_F(FoldedPhantom, FissureSeparatesTheHemispheresAboveItsFloor) {
  const PhantomShape& s = *shape_;
  EXPECT_GE(2 * s.fissure_half_width_mm, 3.0);  // wider than two voxels
  std::int64_t above = 0, below = 0, left = 0, right = 0;
  for (int k = 0; k < kN; ++k)
    for (int j = 0; j < kN; ++j)
      for (int i = 0; i < kN; ++i) {
        if (!tissue(i, j, k)) continue;
        const Eigen::Vector3d p = volume_->geometry.index_to_lps(Eigen::Vector3d(i, j, k));
        const bool strip = std::abs(p.x()) < s.fissure_half_width_mm;  // the mid-sagittal strip
        if (p.z() > s.fissure_bottom_z_mm) {
          above += strip;
          (p.x() < 0 ? left : right) += !strip;
        } else {
          below += strip;
        }
      }
  std::printf("folded 214: mid-sagittal strip %lld voxels above the fissure's floor, %lld below; hemispheres %lld / "
              "%lld\n",
              (long long)above, (long long)below, (long long)left, (long long)right);
  EXPECT_EQ(above, 0);
  // joined below: the strip holds tissue from the stem up to the fissure's floor
  EXPECT_GT(below, 4000);
  // two hemispheres of about equal size above the floor (their sulci differ)
  EXPECT_GT(left, 400000);
  EXPECT_NEAR(double(left) / double(right), 1.0, 0.05);
  // the floor lies between 40% and 60% of the way up (a corpus callosum's height)
  const double bottom = s.stem_center_mm.z(), top = s.center_mm.z() + s.half_extent_mm.z();
  EXPECT_GT((s.fissure_bottom_z_mm - bottom) / (top - bottom), 0.4);
  EXPECT_LT((s.fissure_bottom_z_mm - bottom) / (top - bottom), 0.6);
}

TEST_F(FoldedPhantom, FoldsAreSulci5To15MmDeep) {
  const PhantomShape& s = *shape_;
  const Eigen::Vector3d& a = s.half_extent_mm;
  // arcs over the top of a hemisphere (the plane x = 35 mm, above the fissure's floor) at a
  // given depth below the ellipsoid (along its short axis): count the air gaps (sulci) crossed
  const auto sulci_crossed = [&](double depth_mm, double x) {
    const double r = 1.0 - depth_mm / a.minCoeff();
    const double yz = std::sqrt(r * r - (x / a.x()) * (x / a.x()));
    int gaps = 0;
    bool in_air = false;
    for (int t = 0; t <= 4000; ++t) {
      const double th = kPi * t / 4000.0;
      const Eigen::Vector3d p(x, -a.y() * yz * std::cos(th), s.center_mm.z() + a.z() * yz * std::sin(th));
      if (p.z() < s.fissure_bottom_z_mm) continue;
      const bool air = !tissue_at(p);
      gaps += air && !in_air;
      in_air = air;
    }
    return gaps;
  };
  for (double x : {-35.0, 35.0}) {
    SCOPED_TRACE(x);
    std::printf("folded 214: sulci crossed over the top at x = %g mm: %d at 2 mm deep, %d at 5 mm, %d at 15 mm\n", x,
                sulci_crossed(2.0, x), sulci_crossed(5.0, x), sulci_crossed(15.0, x));
    EXPECT_GE(sulci_crossed(2.0, x), 8);   // many sulci just under the crowns of the gyri
    EXPECT_GE(sulci_crossed(5.0, x), 6);   // at least 5 mm deep
    EXPECT_EQ(sulci_crossed(15.0, x), 0);  // none 15 mm deep
  }
  // folding: the surface is more than twice the smooth organ's of the same size
  PhantomShape organ;
  const Volume o = make_phantom(settings("organ", kN), &organ);
  const double ratio = double(boundary_faces(*volume_)) / double(boundary_faces(o));
  std::printf("folded 214: %lld boundary voxel faces, %.2f x the organ's; %lld tissue voxels, %.3f of the ellipsoid\n",
              (long long)boundary_faces(*volume_), ratio, (long long)s.tissue_voxels,
              double(s.tissue_voxels) / (4.0 / 3.0 * kPi * a.prod()));
  EXPECT_GT(ratio, 2.0);
  EXPECT_LT(ratio, 4.0);
  // the cortex keeps most of the volume: 75-90% of the enclosing ellipsoid's
  const double ellipsoid = 4.0 / 3.0 * kPi * a.prod();
  EXPECT_GT(double(s.tissue_voxels), 0.75 * ellipsoid);
  EXPECT_LT(double(s.tissue_voxels), 0.90 * ellipsoid);
}

// The approximate signed distance: its sign is the voxels' (TissueVoxelsMatchAnalyticVolume),
// it is 1-Lipschitz, and so |d| is at most the true distance: no voxel centre of the other side
// lies within |d| of a point.
TEST_F(FoldedPhantom, SignedDistanceNeverOverstatesTheDistance) {
  const PhantomShape& s = *shape_;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> ux(-75, 75), uy(-95, 95), uz(-80, 80);
  int near = 0, inside = 0, deep = 0;
  double largest_gradient = 0;
  for (int t = 0; t < 3000; ++t) {
    const Eigen::Vector3d p(ux(rng), uy(rng), uz(rng));
    const double d = s.signed_distance_mm(p);
    // every point within 4 mm of the surface, and 150 from 4 to 16 mm (under the sulci's floors)
    if (std::abs(d) > 16.0 || (std::abs(d) > 4.0 && deep++ >= 150)) continue;
    near += std::abs(d) <= 4.0;
    inside += d < 0;
    Eigen::Vector3d g;
    for (int a = 0; a < 3; ++a) {
      Eigen::Vector3d dp = Eigen::Vector3d::Zero();
      dp[a] = 1e-4;
      g[a] = (s.signed_distance_mm(p + dp) - s.signed_distance_mm(p - dp)) / 2e-4;
    }
    largest_gradient = std::max(largest_gradient, g.norm());
    const Eigen::Vector3i c = voxel_of(p);
    const int reach = int(std::ceil(std::abs(d))) + 1;
    for (int k = c.z() - reach; k <= c.z() + reach; ++k)
      for (int j = c.y() - reach; j <= c.y() + reach; ++j)
        for (int i = c.x() - reach; i <= c.x() + reach; ++i) {
          const Eigen::Vector3d q = volume_->geometry.index_to_lps(Eigen::Vector3d(i, j, k));
          if ((q - p).norm() < std::abs(d)) {
            ASSERT_EQ(tissue(i, j, k), d < 0) << p.transpose() << " d " << d;
          }
        }
  }
  std::printf("folded 214: %d points within 4 mm of the surface, %d from 4 to 16 mm (%d inside), largest gradient "
              "%.6f\n",
              near, std::min(deep, 150), inside, largest_gradient);
  EXPECT_GE(deep, 150);
  EXPECT_GT(near, 500);
  EXPECT_GT(inside, 150);
  EXPECT_LT(largest_gradient, 1.0 + 1e-6);
  EXPECT_GT(largest_gradient, 0.99);
}

TEST(Phantom, FoldedIsDeterministicAndScalesWithTheGrid) {
  PhantomShape a, b;
  EXPECT_EQ(make_phantom(settings("folded", 64), &a).hu, make_phantom(settings("folded", 64), &b).hu);
  PhantomShape half;
  (void)make_phantom(settings("folded", 107, 2.0), &half);  // the same 214 mm edge
  PhantomShape full;
  (void)make_phantom(settings("folded", 214, 1.0), &full);
  EXPECT_LT((half.half_extent_mm - full.half_extent_mm).norm(), 1e-9);
  EXPECT_DOUBLE_EQ(half.stem_radius_mm, full.stem_radius_mm);
  EXPECT_LT((full.half_extent_mm - Eigen::Vector3d(70, 90, 68)).norm(), 1e-9);
  EXPECT_DOUBLE_EQ(full.fold_depth_mm, 10.0);
  EXPECT_DOUBLE_EQ(a.fold_depth_mm, 10.0 * 64 / 214);
}

}  // namespace
