// Phantoms: voxel counts against analytic volumes, exact signed distances, areas, noise and
// the validation of settings.
#include "convert/phantom.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <numbers>
#include <random>
#include <set>
#include <string>

#include "base/error.h"

using vx::make_phantom;
using vx::PhantomSettings;
using vx::PhantomShape;
using vx::Volume;

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
                                                          "block", "block-lesion", "organ", "disk", "rectangle",
                                                          "disk-lesion"}));
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
        const double expected = shape.volume_mm3() / std::pow(spacing, 3);
        const double rel = std::abs(double(tissue) - expected) / expected;
        const bool flat = name == "cube" || name == "block" || name == "block-lesion" || name == "rectangle";
        const double tolerance = flat ? 1e-12 : size == 64 ? 0.01 : name == "torus" ? 0.04 : 0.03;
        EXPECT_LT(rel, tolerance) << tissue << " voxels vs " << expected;
        // the count also equals the number of voxel centres with a negative signed distance
        std::int64_t by_distance = 0;
        for (int k = 0; k < v.geometry.dims.z(); ++k)  // one slice for disk, rectangle, disk-lesion
          for (int j = 0; j < size; ++j)
            for (int i = 0; i < size; ++i)
              by_distance += shape.signed_distance_mm(v.geometry.index_to_lps(Eigen::Vector3d(i, j, k))) < 0;
        EXPECT_EQ(by_distance, tissue);
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
      // symmetric about the centre (except the lesion, which is off-centre on purpose)
      if (name != "block-lesion" && name != "disk-lesion") {
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
