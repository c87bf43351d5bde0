// Synthetic CT-like phantoms with analytic shapes: the ground truth for tests and demos.

#include "convert/phantom.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <random>

#include "base/error.h"
#include "util/text.h"

namespace vx {
namespace {

constexpr double kPi = std::numbers::pi;

const std::vector<std::string>& names() {
  static const std::vector<std::string> n = {"sphere", "cube",  "ellipsoid",    "cylinder", "torus",
                                             "block",  "block-lesion", "organ", "folded", "disk",
                                             "rectangle", "disk-lesion"};
  return n;
}

/// Signed distance to an axis-aligned box of half sizes b centred at 0 (exact).
double box_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& b) {
  const Eigen::Vector3d q = p.cwiseAbs() - b;
  return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
}

// ---- distance from a point to an ellipse / ellipsoid (Eberly's robust bisection) ----------
// The closest point x to y (first quadrant/octant, semi-axes e0 >= e1 [>= e2]) satisfies
// x_i = e_i^2 y_i / (e_i^2 + t); t is the root of a monotone function, found by bisection
// in a bracket that needs no derivative, so the answer is exact to rounding.

/// Root s of (r0 z0/(s+r0))^2 + (z1/(s+1))^2 - 1 (2D).
double root_2d(double r0, double z0, double z1, double g) {
  const double n0 = r0 * z0;
  double s0 = z1 - 1.0;
  double s1 = g < 0 ? 0.0 : std::hypot(n0, z1) - 1.0;
  double s = 0.0;
  for (int i = 0; i < 2000; ++i) {
    s = 0.5 * (s0 + s1);
    if (s == s0 || s == s1) break;
    const double a = n0 / (s + r0), b = z1 / (s + 1.0);
    const double gs = a * a + b * b - 1.0;
    if (gs > 0) s0 = s;
    else if (gs < 0) s1 = s;
    else break;
  }
  return s;
}

/// Root s of sum_i (r_i z_i/(s+r_i))^2 - 1 with r2 = 1 (3D).
double root_3d(double r0, double r1, double z0, double z1, double z2, double g) {
  const double n0 = r0 * z0, n1 = r1 * z1;
  double s0 = z2 - 1.0;
  double s1 = g < 0 ? 0.0 : std::sqrt(n0 * n0 + n1 * n1 + z2 * z2) - 1.0;
  double s = 0.0;
  for (int i = 0; i < 2000; ++i) {
    s = 0.5 * (s0 + s1);
    if (s == s0 || s == s1) break;
    const double a = n0 / (s + r0), b = n1 / (s + r1), c = z2 / (s + 1.0);
    const double gs = a * a + b * b + c * c - 1.0;
    if (gs > 0) s0 = s;
    else if (gs < 0) s1 = s;
    else break;
  }
  return s;
}

/// Unsigned distance from (y0, y1) >= 0 to the ellipse with semi-axes e0 >= e1 > 0.
double ellipse_distance(double e0, double e1, double y0, double y1) {
  if (y1 > 0) {
    if (y0 > 0) {
      const double z0 = y0 / e0, z1 = y1 / e1, g = z0 * z0 + z1 * z1 - 1.0;
      if (g == 0) return 0.0;
      const double r0 = (e0 / e1) * (e0 / e1);
      const double s = root_2d(r0, z0, z1, g);
      const double x0 = r0 * y0 / (s + r0), x1 = y1 / (s + 1.0);
      return std::hypot(x0 - y0, x1 - y1);
    }
    return std::abs(y1 - e1);
  }
  const double numer0 = e0 * y0, denom0 = e0 * e0 - e1 * e1;
  if (numer0 < denom0) {
    const double xde0 = numer0 / denom0;
    const double x0 = e0 * xde0, x1 = e1 * std::sqrt(std::max(0.0, 1.0 - xde0 * xde0));
    return std::hypot(x0 - y0, x1);
  }
  return std::abs(y0 - e0);
}

/// Unsigned distance from y >= 0 to the ellipsoid with semi-axes e0 >= e1 >= e2 > 0.
double ellipsoid_distance(double e0, double e1, double e2, double y0, double y1, double y2) {
  if (y2 > 0) {
    if (y1 > 0) {
      if (y0 > 0) {
        const double z0 = y0 / e0, z1 = y1 / e1, z2 = y2 / e2;
        const double g = z0 * z0 + z1 * z1 + z2 * z2 - 1.0;
        if (g == 0) return 0.0;
        const double r0 = (e0 / e2) * (e0 / e2), r1 = (e1 / e2) * (e1 / e2);
        const double s = root_3d(r0, r1, z0, z1, z2, g);
        const double x0 = r0 * y0 / (s + r0), x1 = r1 * y1 / (s + r1), x2 = y2 / (s + 1.0);
        return std::sqrt((x0 - y0) * (x0 - y0) + (x1 - y1) * (x1 - y1) + (x2 - y2) * (x2 - y2));
      }
      return ellipse_distance(e1, e2, y1, y2);  // in the plane x = 0
    }
    if (y0 > 0) return ellipse_distance(e0, e2, y0, y2);  // in the plane y = 0
    return std::abs(y2 - e2);
  }
  // y2 = 0: the closest point may leave the plane z = 0 (inside, near the centre)
  const double denom0 = e0 * e0 - e2 * e2, denom1 = e1 * e1 - e2 * e2;
  const double numer0 = e0 * y0, numer1 = e1 * y1;
  if (numer0 < denom0 && numer1 < denom1) {
    const double xde0 = numer0 / denom0, xde1 = numer1 / denom1;
    const double discr = 1.0 - xde0 * xde0 - xde1 * xde1;
    if (discr > 0) {
      const double x0 = e0 * xde0, x1 = e1 * xde1, x2 = e2 * std::sqrt(discr);
      return std::sqrt((x0 - y0) * (x0 - y0) + (x1 - y1) * (x1 - y1) + x2 * x2);
    }
  }
  return ellipse_distance(e0, e1, y0, y1);  // in the plane z = 0
}

/// Surface area of an ellipsoid (Legendre's formula with incomplete elliptic integrals).
double ellipsoid_area(Eigen::Vector3d e) {
  std::sort(e.data(), e.data() + 3, std::greater<>());
  const double a = e[0], b = e[1], c = e[2];
  if (a - c <= 1e-12 * a) return 4.0 * kPi * a * a;
  const double phi = std::acos(c / a);
  const double k = std::sqrt(std::clamp(a * a * (b * b - c * c) / (b * b * (a * a - c * c)), 0.0, 1.0));
  const double s = std::sin(phi), co = std::cos(phi);
  return 2.0 * kPi * c * c + 2.0 * kPi * a * b / s * (std::ellint_2(k, phi) * s * s + std::ellint_1(k, phi) * co * co);
}

/// Largest half size <= `half_mm` whose faces lie on voxel faces of an n-voxel axis centred
/// at 0 (for even n the faces are at whole voxels from the centre, for odd n at halves).
double snap_inward(double half_mm, int n, double h) {
  const double off = (n % 2) ? 0.5 : 0.0;
  double k = std::floor(half_mm / h - off + 1e-9);
  k = std::max(k, off > 0 ? 0.0 : 1.0);
  return (k + off) * h;
}


// ---- the folded (brain-like) shape ------------------------------------------------------
// Every piece below is a 1-Lipschitz function that is zero on its surface, negative inside;
// max (intersection), min (union) and negation keep that, so the combination is one too.

/// Bound on the gradient of the gyroid's sheet function along the ellipsoid: sqrt(3), the
/// gyroid's largest gradient (on its sheet it lies between sqrt(2) and sqrt(3)), times 1.1 for
/// the oblique push along a ray onto an ellipsoid whose axes differ by up to 1.33.
constexpr double kFoldGradient = 1.7320508075688772 * 1.1;

/// The gyroid, sin x cos y + sin y cos z + sin z cos x: its zero set is a connected,
/// maze-like sheet (the sulci where it crosses the cortex).
double gyroid(const Eigen::Vector3d& u) {
  return std::sin(u.x()) * std::cos(u.y()) + std::sin(u.y()) * std::cos(u.z()) + std::sin(u.z()) * std::cos(u.x());
}

/// The folded shape's function (phantom.h): negative inside, zero on the surface.
double folded_distance(const PhantomShape& s, const Eigen::Vector3d& p_mm) {
  const Eigen::Vector3d p = p_mm - s.center_mm;
  const Eigen::Vector3d& a = s.half_extent_mm;
  const double a_min = a.minCoeff();
  // the body: an ellipsoid's distance bound a_min (|p/a| - 1), gradient a_min/a_max..1
  const double r = p.cwiseQuotient(a).norm();
  const double body = a_min * (r - 1.0);
  // sulci: a slab of half width fold_half_width_mm about the gyroid's sheet, traced on the
  // ellipsoid (the point pushed along its ray from the centre onto the surface, so the sulcal
  // walls run straight in and no gyrus hangs over another), fold_depth_mm deep. Evaluated
  // everywhere: deep inside, the nearest surface may be a sulcus's floor
  const double omega = 2.0 * kPi / s.fold_period_mm;
  const Eigen::Vector3d q = p / std::max(r, 1e-9);
  const double wall = std::abs(gyroid(omega * q)) * r / (omega * kFoldGradient) - s.fold_half_width_mm;
  // no sulcus within fold_depth_mm / 2 of the fissure's wall: an unfolded medial rim holds
  // every gyrus next to the fissure to the body (sulci crossing it cut off slivers)
  const double rim = s.fissure_half_width_mm + 0.5 * s.fold_depth_mm - std::abs(p.x());
  const double sulcus = std::max({wall, -body - s.fold_depth_mm, rim});
  const double folded = std::max(body, -sulcus);
  // the longitudinal fissure: a slab |x| < fissure half width above fissure_bottom_z_mm
  const double fissure = std::max(std::abs(p_mm.x() - s.center_mm.x()) - s.fissure_half_width_mm,
                                  s.fissure_bottom_z_mm - p_mm.z());
  const double hemispheres = std::max(folded, -fissure);
  // the stem: a vertical cylinder from stem_center_mm (its bottom face) up into the body
  const Eigen::Vector3d d = p_mm - s.stem_center_mm;
  const double stem = std::max(std::hypot(d.x(), d.y()) - s.stem_radius_mm, std::max(-d.z(), d.z() - s.stem_length_mm));
  return std::min(hemispheres, stem);
}

}  // namespace

std::vector<std::string> phantom_names() { return names(); }

double PhantomShape::signed_distance_mm(const Eigen::Vector3d& p_mm) const {
  // one-slice (2D) shapes: the distance in the slice plane (z = 0)
  if (name == "disk" || name == "disk-lesion")
    return std::hypot(p_mm.x() - center_mm.x(), p_mm.y() - center_mm.y()) - half_extent_mm.x();
  if (name == "rectangle") {
    const Eigen::Vector2d q = (p_mm - center_mm).head<2>().cwiseAbs() - half_extent_mm.head<2>();
    return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
  }
  if (name == "folded") return folded_distance(*this, p_mm);
  const Eigen::Vector3d p = p_mm - center_mm;
  if (name == "sphere") return p.norm() - half_extent_mm.x();
  if (name == "cube" || name == "block" || name == "block-lesion") return box_distance(p, half_extent_mm);
  if (name == "cylinder") {
    const double dr = std::hypot(p.x(), p.y()) - minor_radius_mm;
    const double dz = std::abs(p.z()) - half_length_mm;
    return std::hypot(std::max(dr, 0.0), std::max(dz, 0.0)) + std::min(std::max(dr, dz), 0.0);
  }
  if (name == "torus") {
    const double q = std::hypot(p.x(), p.y()) - major_radius_mm;
    return std::hypot(q, p.z()) - minor_radius_mm;
  }
  if (name == "ellipsoid" || name == "organ") {
    // sort the axes by length, descending, and fold the point into the first octant
    std::array<int, 3> order{0, 1, 2};
    std::sort(order.begin(), order.end(), [&](int a, int b) { return half_extent_mm[a] > half_extent_mm[b]; });
    const Eigen::Vector3d& e = half_extent_mm;
    const double d = ellipsoid_distance(e[order[0]], e[order[1]], e[order[2]], std::abs(p[order[0]]),
                                        std::abs(p[order[1]]), std::abs(p[order[2]]));
    const double f = p.cwiseQuotient(e).squaredNorm();
    return f < 1.0 ? -d : d;
  }
  throw Error("PhantomShape: unknown shape '" + name + "'");
}

double PhantomShape::volume_mm3() const {
  if (!has_closed_form())
    throw Error("PhantomShape: the " + name + " phantom has no closed-form volume; count its voxels");
  const Eigen::Vector3d& e = half_extent_mm;
  if (is_2d()) return area_mm2() * 2.0 * e.z();  // the slab: the shape's area times the slice thickness
  if (name == "sphere" || name == "ellipsoid" || name == "organ") return 4.0 / 3.0 * kPi * e.prod();
  if (name == "cube" || name == "block" || name == "block-lesion") return 8.0 * e.prod();
  if (name == "cylinder") return kPi * minor_radius_mm * minor_radius_mm * 2.0 * half_length_mm;
  if (name == "torus") return 2.0 * kPi * kPi * major_radius_mm * minor_radius_mm * minor_radius_mm;
  throw Error("PhantomShape: unknown shape '" + name + "'");
}

double PhantomShape::area_mm2() const {
  if (!has_closed_form()) throw Error("PhantomShape: the " + name + " phantom has no closed-form area");
  const Eigen::Vector3d& e = half_extent_mm;
  if (name == "disk" || name == "disk-lesion") return kPi * e.x() * e.x();
  if (name == "rectangle") return 4.0 * e.x() * e.y();
  if (name == "sphere") return 4.0 * kPi * e.x() * e.x();
  if (name == "ellipsoid" || name == "organ") return ellipsoid_area(e);
  if (name == "cube" || name == "block" || name == "block-lesion")
    return 8.0 * (e.x() * e.y() + e.y() * e.z() + e.z() * e.x());
  if (name == "cylinder")
    return 2.0 * kPi * minor_radius_mm * 2.0 * half_length_mm + 2.0 * kPi * minor_radius_mm * minor_radius_mm;
  if (name == "torus") return 4.0 * kPi * kPi * major_radius_mm * minor_radius_mm;
  throw Error("PhantomShape: unknown shape '" + name + "'");
}

PhantomShape phantom_shape(const PhantomSettings& s) {
  // validate
  const auto& known = names();
  if (std::find(known.begin(), known.end(), s.name) == known.end()) {
    std::string list;
    for (const auto& n : known) list += (list.empty() ? "" : ", ") + n;
    const std::string near = nearest_word(s.name, known);
    throw Error(fmt::format("unknown phantom '{}'{} (choose one of: {})", s.name,
                            near.empty() ? std::string() : "; did you mean '" + near + "'?", list));
  }
  if (!(s.thickness_mm >= 0) || !std::isfinite(s.thickness_mm))
    throw Error(fmt::format("phantom slice thickness {} mm must be a positive number (0: the pixel spacing)",
                            s.thickness_mm));
  if (s.size < 4 || s.size > 1024)
    throw Error(fmt::format("phantom size {} voxels is out of range: use 4 to 1024 voxels per axis", s.size));
  if (!std::isfinite(s.spacing_mm) || s.spacing_mm <= 0)
    throw Error(fmt::format("phantom spacing {} mm must be a positive number (e.g. 1.0)", s.spacing_mm));
  if (!std::isfinite(s.noise_hu) || s.noise_hu < 0)
    throw Error(fmt::format("phantom noise {} HU must be zero or positive", s.noise_hu));
  if (!std::isfinite(s.tissue_hu) || !std::isfinite(s.air_hu) || !std::isfinite(s.lesion_hu))
    throw Error("phantom HU values (tissue, air, lesion) must be finite numbers");

  const int n = s.size;
  const double h = s.spacing_mm;
  // the length the proportions refer to: the grid's edge, shrunk for small grids so the widest
  // shape (ellipsoid, 0.42 half-axis) keeps `margin` voxels of air on each side
  const int margin = std::min(2, (n - 2) / 2);
  const double scale = std::min(n * h, (n - 2 * margin) * h / 0.84);

  PhantomShape shape;
  shape.name = s.name;
  shape.center_mm = Eigen::Vector3d::Zero();
  // one-slice (2D) phantoms: an n x n x 1 grid, the slice `thickness` deep
  const bool flat = shape.is_2d();
  const double thickness = flat ? (s.thickness_mm > 0 ? s.thickness_mm : h) : h;
  if (flat) {
    if (s.name == "rectangle") {
      shape.half_extent_mm =
          Eigen::Vector3d(snap_inward(0.4 * scale, n, h), snap_inward(0.25 * scale, n, h), 0.5 * thickness);
    } else {
      shape.half_extent_mm = Eigen::Vector3d(0.4 * scale, 0.4 * scale, 0.5 * thickness);
      if (s.name == "disk-lesion") {
        // the stiffer inclusion: radius a quarter of the disk's, centred halfway up (+y)
        shape.lesion_center_mm = Eigen::Vector3d(0.0, 0.5 * shape.half_extent_mm.x(), 0.0);
        shape.lesion_radius_mm = 0.25 * shape.half_extent_mm.x();
      }
    }
  } else if (s.name == "sphere") {
    shape.half_extent_mm = Eigen::Vector3d::Constant(0.4 * scale);
  } else if (s.name == "cube") {
    shape.half_extent_mm = Eigen::Vector3d::Constant(snap_inward(0.35 * scale, n, h));
  } else if (s.name == "ellipsoid") {
    shape.half_extent_mm = Eigen::Vector3d(0.42, 0.30, 0.22) * scale;
  } else if (s.name == "organ") {
    // an organ-sized stand-in: 140 x 180 x 150 mm at size 214 and 1 mm voxels
    shape.half_extent_mm = Eigen::Vector3d(0.42 * 140.0 / 180.0, 0.42, 0.42 * 150.0 / 180.0) * scale;
  } else if (s.name == "folded") {
    // a brain-like stand-in, every length a fraction of the grid's edge (mm at size 214, 1 mm)
    const double k = scale / 214.0;
    shape.center_mm = Eigen::Vector3d(0.0, 0.0, 7.0 * k);
    shape.half_extent_mm = Eigen::Vector3d(70.0, 90.0, 68.0) * k;
    shape.fold_period_mm = 30.0 * k;
    shape.fold_half_width_mm = 1.5 * k;
    shape.fold_depth_mm = 10.0 * k;
    shape.fissure_half_width_mm = 2.0 * k;
    shape.fissure_bottom_z_mm = -5.0 * k;
    shape.stem_center_mm = Eigen::Vector3d(0.0, 0.0, -75.0 * k);
    shape.stem_radius_mm = 10.0 * k;
    shape.stem_length_mm = 45.0 * k;
  } else if (s.name == "cylinder") {
    shape.minor_radius_mm = 0.3 * scale;
    shape.half_length_mm = snap_inward(0.4 * scale, n, h);
    shape.half_extent_mm = Eigen::Vector3d(shape.minor_radius_mm, shape.minor_radius_mm, shape.half_length_mm);
  } else if (s.name == "torus") {
    shape.major_radius_mm = 0.28 * scale;
    shape.minor_radius_mm = 0.12 * scale;
    const double outer = shape.major_radius_mm + shape.minor_radius_mm;
    shape.half_extent_mm = Eigen::Vector3d(outer, outer, shape.minor_radius_mm);
  } else {  // block, block-lesion
    shape.half_extent_mm = Eigen::Vector3d(snap_inward(0.4 * scale, n, h), snap_inward(0.3 * scale, n, h),
                                           snap_inward(0.2 * scale, n, h));
    if (s.name == "block-lesion") {
      // off-axis, at 60% of the block's height; radius ~0.15, kept inside the block
      const Eigen::Vector3d& b = shape.half_extent_mm;
      shape.lesion_center_mm = Eigen::Vector3d(0.3 * b.x(), 0.0, -b.z() + 0.6 * 2.0 * b.z());
      shape.lesion_radius_mm = std::min(0.15 * scale, 0.9 * (b.z() - shape.lesion_center_mm.z()));
    }
  }
  // a lesion placed and sized by the caller replaces the default one, inside the shape
  if (s.lesion_center_mm || s.lesion_radius_mm != 0.0) {
    if (const std::string e = lesion_settings_error(s); !e.empty()) throw Error(e);
    if (s.lesion_center_mm) shape.lesion_center_mm = *s.lesion_center_mm;
    if (s.lesion_radius_mm != 0.0) shape.lesion_radius_mm = s.lesion_radius_mm;
  }
  return shape;
}

std::string lesion_settings_error(const PhantomSettings& s) {
  if (!s.lesion_center_mm && s.lesion_radius_mm == 0.0) return {};
  if (s.name != "block-lesion" && s.name != "disk-lesion")
    return fmt::format("phantom '{}' has no lesion: the lesion centre and radius apply to block-lesion and disk-lesion",
                       s.name);
  if (!std::isfinite(s.lesion_radius_mm) || s.lesion_radius_mm < 0.0)
    return fmt::format("lesion radius {} mm must be a positive number", s.lesion_radius_mm);
  if (s.lesion_center_mm && !s.lesion_center_mm->allFinite()) return "lesion centre must be three finite numbers (mm)";
  // the default shape: its block (disk), and the default lesion for what was not given
  PhantomSettings base = s;
  base.lesion_center_mm.reset();
  base.lesion_radius_mm = 0.0;
  PhantomShape shape;
  try {
    shape = phantom_shape(base);
  } catch (const Error&) {
    return {};  // the other settings are wrong: phantom_shape says what
  }
  const Eigen::Vector3d c = s.lesion_center_mm ? *s.lesion_center_mm : shape.lesion_center_mm;
  const double r = s.lesion_radius_mm != 0.0 ? s.lesion_radius_mm : shape.lesion_radius_mm;
  const Eigen::Vector3d& e = shape.half_extent_mm;
  const std::string where = fmt::format("a lesion of radius {:g} mm centred at ({:g}, {:g}, {:g}) mm", r, c.x(), c.y(), c.z());
  if (s.name == "disk-lesion") {
    if (c.z() != 0.0)
      return fmt::format("{}: disk-lesion is one slice in the plane z = 0, so the lesion centre's z must be 0", where);
    if (c.head<2>().norm() + r > e.x())
      return fmt::format("{} does not fit inside the disk of radius {:g} mm centred at the origin: keep "
                         "sqrt(x^2 + y^2) + radius <= {:g} mm",
                         where, e.x(), e.x());
    return {};
  }
  if (((c.cwiseAbs().array() + r) > e.array()).any())
    return fmt::format("{} does not fit inside the block, {:g} x {:g} x {:g} mm centred at the origin (x, y, z): keep "
                       "|x| + radius <= {:g}, |y| + radius <= {:g} and |z| + radius <= {:g} mm",
                       where, 2 * e.x(), 2 * e.y(), 2 * e.z(), e.x(), e.y(), e.z());
  return {};
}

Volume make_phantom(const PhantomSettings& s, PhantomShape* shape_out) {
  PhantomShape shape = phantom_shape(s);  // validates the settings
  const int n = s.size;
  const double h = s.spacing_mm;
  const bool flat = shape.is_2d();
  const int nz = flat ? 1 : n;
  const double thickness = flat ? (s.thickness_mm > 0 ? s.thickness_mm : h) : h;

  Volume v;
  GridGeometry& g = v.geometry;
  g.dims = Eigen::Vector3i(n, n, nz);
  g.spacing_mm = Eigen::Vector3d(h, h, thickness);
  const double corner = -0.5 * (n - 1) * h;  // grid centre at (0,0,0)
  g.origin_mm = Eigen::Vector3d(corner, corner, flat ? 0.0 : corner);
  g.direction = Eigen::Matrix3d::Identity();
  v.hu.assign(std::size_t(g.voxel_count()), float(s.air_hu));

  // voxel centres inside get tissue: the same tests as the signed distance's sign, without
  // its cost (and the ellipsoid by its implicit equation)
  enum class Kind { sphere, box, cylinder, torus, ellipsoid, disk, rectangle, folded };
  const Kind kind = (s.name == "disk" || s.name == "disk-lesion") ? Kind::disk
                    : s.name == "rectangle"  ? Kind::rectangle
                    : s.name == "sphere"     ? Kind::sphere
                    : s.name == "cylinder" ? Kind::cylinder
                    : s.name == "torus"    ? Kind::torus
                    : s.name == "folded"   ? Kind::folded
                    : (s.name == "ellipsoid" || s.name == "organ") ? Kind::ellipsoid
                                            : Kind::box;
  const auto inside = [&](const Eigen::Vector3d& p) {
    switch (kind) {
      case Kind::sphere: return p.squaredNorm() < shape.half_extent_mm.x() * shape.half_extent_mm.x();
      case Kind::box: return (p.cwiseAbs().array() < shape.half_extent_mm.array()).all();
      case Kind::cylinder:
        return std::abs(p.z()) < shape.half_length_mm &&
               p.x() * p.x() + p.y() * p.y() < shape.minor_radius_mm * shape.minor_radius_mm;
      case Kind::torus: {
        const double q = std::hypot(p.x(), p.y()) - shape.major_radius_mm;
        return q * q + p.z() * p.z() < shape.minor_radius_mm * shape.minor_radius_mm;
      }
      case Kind::folded: return folded_distance(shape, p) < 0;  // the signed distance's own sign
      case Kind::ellipsoid: return p.cwiseQuotient(shape.half_extent_mm).squaredNorm() < 1.0;
      case Kind::disk: return p.head<2>().squaredNorm() < shape.half_extent_mm.x() * shape.half_extent_mm.x();
      case Kind::rectangle: return (p.head<2>().cwiseAbs().array() < shape.half_extent_mm.head<2>().array()).all();
    }
    return false;
  };
  const bool has_lesion = s.name == "block-lesion" || s.name == "disk-lesion";
  const double lesion_r2 = shape.lesion_radius_mm * shape.lesion_radius_mm;
  std::int64_t tissue = 0, lesion = 0;
#pragma omp parallel for schedule(static) reduction(+ : tissue, lesion)
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < n; ++j) {
      float* row = v.hu.data() + std::size_t(n) * (std::size_t(j) + std::size_t(n) * std::size_t(k));
      for (int i = 0; i < n; ++i) {
        // (2i - (n-1)) h/2: exact mirror images, so the phantom is symmetric to the last bit
        const Eigen::Vector3d p = Eigen::Vector3d(2 * i - (n - 1), 2 * j - (n - 1), 2 * k - (nz - 1)) * (0.5 * h);
        if (!inside(p)) continue;
        ++tissue;
        if (has_lesion && (p - shape.lesion_center_mm).squaredNorm() < lesion_r2) {
          row[i] = float(s.lesion_hu);
          ++lesion;
        } else {
          row[i] = float(s.tissue_hu);
        }
      }
    }
  }
  if (tissue == 0)
    throw Error(fmt::format("phantom '{}' is too small for a {}^3 grid: no voxel lies inside it; use a size "
                            "of 8 or more (every phantom has voxels from 8 on)",
                            s.name, n));
  shape.tissue_voxels = tissue;
  shape.lesion_voxels = lesion;

  // noise, one draw per voxel in storage order (deterministic for a seed), rounded to whole HU
  if (s.noise_hu > 0) {
    std::mt19937 rng(s.seed);
    std::normal_distribution<double> noise(0.0, s.noise_hu);
    for (float& x : v.hu) x = float(std::nearbyint(double(x) + noise(rng)));
  }
  if (shape_out) *shape_out = shape;
  return v;
}

}  // namespace vx
