#include "sim/probe.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "base/error.h"

namespace vx {

std::string slice_probe_problem(const ProbeGeometry& g, const Eigen::Vector3d& normal) {
  const double along = std::abs(g.axis.normalized().dot(normal));
  switch (g.shape) {
    case ProbeShape::sphere: return "";
    case ProbeShape::cylinder:
      if (along > 1.0 - 1e-6) return "";
      return "a cylinder meets a slice model only with its axis along the slice normal (a circle in the plane)";
    case ProbeShape::capsule:
    case ProbeShape::plane:
      if (along < 1e-6) return "";
      return std::string("a ") + to_string(g.shape) + " meets a slice model only with its " +
             (g.shape == ProbeShape::plane ? "normal" : "axis") + " in the slice plane (a " +
             (g.shape == ProbeShape::plane ? "straight wall" : "rounded rod") + " in the plane)";
  }
  return "unknown shape";
}

const char* to_string(ProbeShape s) {
  switch (s) {
    case ProbeShape::sphere: return "sphere";
    case ProbeShape::cylinder: return "cylinder";
    case ProbeShape::capsule: return "capsule";
    case ProbeShape::plane: return "plane";
  }
  return "?";
}

ProbeShape parse_probe_shape(const std::string& s) {
  if (s == "sphere") return ProbeShape::sphere;
  if (s == "cylinder") return ProbeShape::cylinder;
  if (s == "capsule") return ProbeShape::capsule;
  if (s == "plane") return ProbeShape::plane;
  throw Error("unknown probe shape \"" + s + "\": use sphere, cylinder, capsule or plane");
}

std::string ProbeGeometry::validate() const {
  std::ostringstream err;
  const bool round = shape != ProbeShape::plane;
  if (round && !(radius_mm > 0 && std::isfinite(radius_mm))) err << "radius " << radius_mm << " mm must be > 0; ";
  if (shape == ProbeShape::cylinder && !(length_mm > 0 && std::isfinite(length_mm)))
    err << "cylinder length " << length_mm << " mm must be > 0; ";
  if (shape == ProbeShape::capsule && !(length_mm >= 0 && std::isfinite(length_mm)))
    err << "capsule length " << length_mm << " mm must be >= 0; ";
  if (!axis.allFinite() || !(std::abs(axis.norm() - 1.0) < 1e-9))
    err << (shape == ProbeShape::plane ? "normal" : "axis") << " must be a unit vector (got norm " << axis.norm()
        << "); ";
  return err.str();
}

namespace {

/// A unit vector perpendicular to unit `a`.
Eigen::Vector3d any_perpendicular(const Eigen::Vector3d& a) {
  const Eigen::Vector3d helper = std::abs(a.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  return a.cross(helper).normalized();
}

/// Signed distance to a ball of radius r at c.
double ball_distance(const Eigen::Vector3d& c, double r, const Eigen::Vector3d& x, const Eigen::Vector3d& fallback,
                     Eigen::Vector3d* point, Eigen::Vector3d* normal) {
  const Eigen::Vector3d d = x - c;
  const double len = d.norm();
  const Eigen::Vector3d n = len > 1e-12 ? Eigen::Vector3d(d / len) : fallback;
  if (point) *point = c + r * n;
  if (normal) *normal = n;
  return len - r;
}

}  // namespace

double probe_signed_distance(const ProbeGeometry& g, const Eigen::Vector3d& c, const Eigen::Vector3d& x,
                             Eigen::Vector3d* point, Eigen::Vector3d* normal) {
  switch (g.shape) {
    case ProbeShape::sphere: return ball_distance(c, g.radius_mm, x, -g.axis, point, normal);
    case ProbeShape::capsule: {
      // closest point of the segment tip -> tip + length * axis
      const double t = std::clamp((x - c).dot(g.axis), 0.0, g.length_mm);
      return ball_distance(c + t * g.axis, g.radius_mm, x, any_perpendicular(g.axis), point, normal);
    }
    case ProbeShape::plane: {
      const double s = (x - c).dot(g.axis);
      if (point) *point = x - s * g.axis;
      if (normal) *normal = g.axis;
      return s;
    }
    case ProbeShape::cylinder: {
      const double h = 0.5 * g.length_mm;
      const Eigen::Vector3d d = x - c;
      const double t = d.dot(g.axis);
      const Eigen::Vector3d rho = d - t * g.axis;
      const double r = rho.norm();
      const Eigen::Vector3d radial = r > 1e-12 ? Eigen::Vector3d(rho / r) : any_perpendicular(g.axis);
      const Eigen::Vector3d cap = t >= 0 ? g.axis : Eigen::Vector3d(-g.axis);
      const double dr = r - g.radius_mm;
      const double dz = std::abs(t) - h;
      if (dr < 0 && dz < 0) {
        // inside: leave through the nearer of the side and the cap
        if (dr > dz) {
          if (point) *point = c + t * g.axis + g.radius_mm * radial;
          if (normal) *normal = radial;
          return dr;
        }
        if (point) *point = x + (-dz) * cap;
        if (normal) *normal = cap;
        return dz;
      }
      // outside: the closest point clamps the radial and axial coordinates
      const Eigen::Vector3d q = c + std::clamp(t, -h, h) * g.axis + std::min(r, g.radius_mm) * radial;
      const Eigen::Vector3d e = x - q;
      const double len = e.norm();
      if (point) *point = q;
      if (normal) *normal = len > 1e-12 ? Eigen::Vector3d(e / len) : (dr >= dz ? radial : cap);
      return len;
    }
  }
  return 0.0;
}

double probe_bounding_ball(const ProbeGeometry& g, const Eigen::Vector3d& position, Eigen::Vector3d& centre) {
  centre = position;
  switch (g.shape) {
    case ProbeShape::sphere: return g.radius_mm;
    case ProbeShape::capsule:
      // the segment's middle; its half length plus the radius reaches both rounded ends
      centre = position + 0.5 * g.length_mm * g.axis;
      return 0.5 * g.length_mm + g.radius_mm;
    case ProbeShape::cylinder: return std::hypot(0.5 * g.length_mm, g.radius_mm);  // a rim's corner
    case ProbeShape::plane: return std::numeric_limits<double>::infinity();
  }
  return std::numeric_limits<double>::infinity();
}

const char* to_string(JoystickMode m) { return m == JoystickMode::rate ? "rate" : "position"; }

JoystickMode parse_joystick_mode(const std::string& s) {
  if (s == "rate") return JoystickMode::rate;
  if (s == "position") return JoystickMode::position;
  throw Error("unknown joystick mode '" + s + "': use rate or position");
}

const char* to_string(ProbeDrive d) {
  switch (d) {
    case ProbeDrive::path: return "path";
    case ProbeDrive::joystick: return "joystick";
    case ProbeDrive::live: return "live";
  }
  return "?";
}

Eigen::Vector3d JoystickMapping::map(const Eigen::Vector3d& axes) const {
  Eigen::Vector3d a;
  for (int j = 0; j < 3; ++j) {
    const double v = std::clamp(axes[j], -1.0, 1.0);
    const double m = std::abs(v);
    a[j] = m <= dead_zone ? 0.0 : std::copysign((m - dead_zone) / (1.0 - dead_zone), v);
  }
  const Eigen::Vector3d dir = directions * a;
  return (mode == JoystickMode::rate ? max_speed_mm_s : range_mm) * dir;
}

std::string JoystickMapping::validate() const {
  std::ostringstream err;
  if (!(dead_zone >= 0 && dead_zone < 1)) err << "dead zone " << dead_zone << " must be in [0, 1); ";
  if (mode == JoystickMode::rate && !(max_speed_mm_s > 0 && std::isfinite(max_speed_mm_s)))
    err << "max speed " << max_speed_mm_s << " mm/s must be > 0; ";
  if (mode == JoystickMode::position && !(range_mm > 0 && std::isfinite(range_mm)))
    err << "range " << range_mm << " mm must be > 0; ";
  for (int j = 0; j < 3; ++j) {
    const double n = directions.col(j).norm();
    if (!directions.col(j).allFinite() || !(n < 1e-12 || std::abs(n - 1.0) < 1e-9))
      err << "direction of axis " << j << " must be a unit vector or zero; ";
  }
  return err.str();
}

namespace {

template <class Key>
std::string check_times(const std::vector<Key>& keys, const char* what) {
  std::ostringstream err;
  if (keys.empty()) err << what << " needs at least one key; ";
  for (std::size_t k = 0; k < keys.size(); ++k) {
    if (!std::isfinite(keys[k].t_s) || keys[k].t_s < 0) err << what << " key " << k << ": time must be >= 0; ";
    if (k > 0 && !(keys[k].t_s > keys[k - 1].t_s))
      err << what << " key " << k << ": times must increase (" << keys[k - 1].t_s << " s then " << keys[k].t_s
          << " s); ";
  }
  return err.str();
}

/// Index of the segment [k, k+1] holding t (keys sorted, at least two, t inside).
template <class Key>
std::size_t segment(const std::vector<Key>& keys, double t) {
  auto it = std::upper_bound(keys.begin(), keys.end(), t, [](double x, const Key& k) { return x < k.t_s; });
  return std::size_t(std::max<std::ptrdiff_t>(1, it - keys.begin()) - 1);
}

template <class Key, class Get>
Eigen::Vector3d interpolate(const std::vector<Key>& keys, double t, Get get) {
  if (keys.empty()) return Eigen::Vector3d::Zero();
  if (keys.size() == 1 || t <= keys.front().t_s) return get(keys.front());
  if (t >= keys.back().t_s) return get(keys.back());
  const std::size_t k = segment(keys, t);
  const double u = (t - keys[k].t_s) / (keys[k + 1].t_s - keys[k].t_s);
  return (1.0 - u) * get(keys[k]) + u * get(keys[k + 1]);
}

}  // namespace

Eigen::Vector3d path_position(const std::vector<PathKey>& path, double t) {
  return interpolate(path, t, [](const PathKey& k) { return k.position_mm; });
}

Eigen::Vector3d joystick_axes(const std::vector<JoystickKey>& keys, double t) {
  return interpolate(keys, t, [](const JoystickKey& k) { return k.axes; });
}

std::string ProbeSettings::validate() const {
  std::ostringstream err;
  err << geometry.validate();
  switch (drive) {
    case ProbeDrive::path:
      err << check_times(path, "path");
      for (std::size_t k = 0; k < path.size(); ++k)
        if (!path[k].position_mm.allFinite()) err << "path key " << k << ": position is not finite; ";
      break;
    case ProbeDrive::joystick:
      err << check_times(joystick, "joystick");
      for (std::size_t k = 0; k < joystick.size(); ++k)
        if (!(joystick[k].axes.allFinite() && joystick[k].axes.cwiseAbs().maxCoeff() <= 1.0))
          err << "joystick key " << k << ": axis values must be in [-1, 1]; ";
      err << mapping.validate();
      break;
    case ProbeDrive::live:
      err << mapping.validate();
      if (!(max_speed_mm_s > 0 && std::isfinite(max_speed_mm_s)))
        err << "max speed " << max_speed_mm_s << " mm/s must be > 0; ";
      break;
  }
  if (drive != ProbeDrive::path && !start_mm.allFinite()) err << "start position is not finite; ";
  return err.str();
}

Eigen::Vector3d ProbeSettings::initial_position() const {
  switch (drive) {
    case ProbeDrive::path: return path_position(path, 0.0);
    case ProbeDrive::joystick:
      return mapping.mode == JoystickMode::position
                 ? Eigen::Vector3d(start_mm + mapping.map(joystick_axes(joystick, 0.0)))
                 : start_mm;
    case ProbeDrive::live: return start_mm;
  }
  return start_mm;
}

double ProbeSettings::max_scripted_speed_mm_s() const {
  double v = 0.0;
  switch (drive) {
    case ProbeDrive::path:
      for (std::size_t k = 1; k < path.size(); ++k)
        v = std::max(v, (path[k].position_mm - path[k - 1].position_mm).norm() / (path[k].t_s - path[k - 1].t_s));
      break;
    case ProbeDrive::joystick:
      if (mapping.mode == JoystickMode::rate) {
        for (const auto& k : joystick) v = std::max(v, mapping.map(k.axes).norm());
      } else {
        for (std::size_t k = 1; k < joystick.size(); ++k)
          v = std::max(v, (mapping.map(joystick[k].axes) - mapping.map(joystick[k - 1].axes)).norm() /
                              (joystick[k].t_s - joystick[k - 1].t_s));
      }
      break;
    case ProbeDrive::live: v = std::max(max_speed_mm_s, mapping.max_speed_mm_s); break;
  }
  return v;
}

ProbeDriver::ProbeDriver(ProbeSettings settings) : settings_(std::move(settings)) { reset(); }

void ProbeDriver::reset() {
  state_.position_mm = settings_.initial_position();
  state_.velocity_mm_s.setZero();
  live_ = {};
}

void ProbeDriver::advance(double t, double dt) {
  const Eigen::Vector3d old = state_.position_mm;
  Eigen::Vector3d next = old;
  switch (settings_.drive) {
    case ProbeDrive::path: next = path_position(settings_.path, t); break;
    case ProbeDrive::joystick:
      if (settings_.mapping.mode == JoystickMode::rate) {
        // velocity proportional to tilt; the trapezoid of the (piecewise-linear) stick signal
        const Eigen::Vector3d v0 = settings_.mapping.map(joystick_axes(settings_.joystick, t - dt));
        const Eigen::Vector3d v1 = settings_.mapping.map(joystick_axes(settings_.joystick, t));
        next = old + 0.5 * dt * (v0 + v1);
      } else {
        next = settings_.start_mm + settings_.mapping.map(joystick_axes(settings_.joystick, t));
      }
      break;
    case ProbeDrive::live:
      switch (live_.kind) {
        case LiveCommand::Kind::hold: break;
        case LiveCommand::Kind::velocity: next = old + dt * live_.value; break;
        case LiveCommand::Kind::axes: {
          const JoystickMapping& m = settings_.mapping;
          if (m.mode == JoystickMode::rate)
            next = old + dt * m.map(live_.value);
          else
            next = settings_.start_mm + m.map(live_.value);
          break;
        }
        case LiveCommand::Kind::position: next = live_.value; break;
      }
      // a live probe never moves faster than its speed limit (no tunnelling through the tissue)
      if (const double step = (next - old).norm(), limit = settings_.max_speed_mm_s * dt; step > limit)
        next = old + (limit / step) * (next - old);
      break;
  }
  state_.position_mm = next;
  state_.velocity_mm_s = (next - old) / dt;
}

}  // namespace vx
