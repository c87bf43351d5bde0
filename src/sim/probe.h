#pragma once
/// @file probe.h
/// A rigid probe: its shape and signed distance (the geometry contact.h collides with), and how
/// it moves (docs/model.md section 8): a keyframed path, a scripted joystick (paper 4.2: the tool moves with a
/// velocity proportional to the stick's tilt; or an optional position-control mapping), or live
/// input from outside (the probe app sets a target position or velocity each step).
///
/// Every driver gives the probe position at the end of each step; the probe velocity used by
/// the collision response is the step's displacement over dt, so a probe's motion and the
/// velocity it imparts always agree. Units: mm, s, mm/s.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

namespace vx {

/// The shape of a rigid probe (tool). Probes translate; their axis is fixed in the world.
enum class ProbeShape : std::uint8_t {
  sphere,    ///< ball of `radius_mm` centred at the probe position
  cylinder,  ///< flat-ended cylinder of `radius_mm`, `length_mm`, centred at the position, along `axis`
  capsule,   ///< rod with a rounded tip: segment from the tip-sphere centre (the position) to
             ///< position + length_mm * axis, swept by a ball of `radius_mm` (the surgeon's tool)
  plane,     ///< a plate: the half-space behind the plane through the position with normal `axis`
             ///< (the normal points out of the plate, towards the tissue)
};
[[nodiscard]] const char* to_string(ProbeShape s);
/// Parses "sphere", "cylinder", "capsule" or "plane"; throws vx::Error otherwise.
[[nodiscard]] ProbeShape parse_probe_shape(const std::string& s);

/// The geometry of a probe in the world (LPS mm).
struct ProbeGeometry {
  ProbeShape shape{ProbeShape::sphere};
  double radius_mm{5.0};                ///< sphere, cylinder, capsule
  double length_mm{0.0};                ///< cylinder: full length; capsule: rod length behind the tip centre
  Eigen::Vector3d axis{0.0, 0.0, 1.0};  ///< unit. cylinder: its axis; capsule: tip -> handle; plane: normal

  /// Empty when valid, else what is wrong (sizes > 0, axis not zero).
  [[nodiscard]] std::string validate() const;
};

/// A 2D (slice) model meets a probe in its cut by the slice plane (docs/model.md section 12.2):
/// a sphere is a circle; a cylinder along the slice normal a circle too; a capsule or plane whose
/// axis lies in the slice plane a rounded rod or a straight wall. Empty when `g` has such a cut
/// for a slice of unit normal `normal`, else what is wrong and what to use instead.
[[nodiscard]] std::string slice_probe_problem(const ProbeGeometry& g, const Eigen::Vector3d& normal);

/// Where a probe is this step.
struct ProbeState {
  Eigen::Vector3d position_mm{Eigen::Vector3d::Zero()};
  Eigen::Vector3d velocity_mm_s{Eigen::Vector3d::Zero()};
};

/// Signed distance of point `x` from the surface of the probe at `position` (negative inside),
/// mm, with the closest surface point and the outward unit normal there.
/// The normal is well defined everywhere (a point on the axis of a sphere/capsule/cylinder gets
/// a fixed perpendicular direction).
[[nodiscard]] double probe_signed_distance(const ProbeGeometry& g, const Eigen::Vector3d& position,
                                           const Eigen::Vector3d& x, Eigen::Vector3d* surface_point = nullptr,
                                           Eigen::Vector3d* normal = nullptr);

/// A ball that holds the probe at `position`: its centre in `centre`, its radius returned (mm;
/// infinite for a plane). No point is nearer the probe than it is to the ball:
/// probe_signed_distance(g, position, x) >= |x - centre| - radius for every x, with equality for
/// a sphere. A scan over many nodes rejects the far ones with a squared distance, without the
/// signed distance's square root and normal.
[[nodiscard]] double probe_bounding_ball(const ProbeGeometry& g, const Eigen::Vector3d& position,
                                         Eigen::Vector3d& centre);

/// A keyframe of a path: where the probe is at time t.
struct PathKey {
  double t_s{0.0};
  Eigen::Vector3d position_mm{Eigen::Vector3d::Zero()};  ///< LPS mm
};

/// A sample of a scripted joystick: stick deflections in [-1, 1] at time t (linearly
/// interpolated between samples, held after the last).
struct JoystickKey {
  double t_s{0.0};
  Eigen::Vector3d axes{Eigen::Vector3d::Zero()};  ///< up to three axes; unused ones 0
};

/// How stick deflections become probe motion.
enum class JoystickMode : std::uint8_t {
  rate,      ///< velocity = max_speed * mapped deflection (the paper's rate control)
  position,  ///< position = start + range * mapped deflection (position control)
};
[[nodiscard]] const char* to_string(JoystickMode m);
/// Parses "rate" or "position"; throws vx::Error otherwise.
[[nodiscard]] JoystickMode parse_joystick_mode(const std::string& s);

/// The joystick mapping. The deflection of each axis is first cut by the dead zone and
/// rescaled (|a| <= dead_zone -> 0, |a| = 1 -> 1), then mapped to LPS by `directions`.
/// The one stick mapping: scripted joysticks and live probes of a scene, and the probe app's
/// sticks (apps/probe/stick_control.h, which maps by the view instead of `directions`).
struct JoystickMapping {
  JoystickMode mode{JoystickMode::rate};
  Eigen::Matrix3d directions{Eigen::Matrix3d::Identity()};  ///< column j: LPS direction of axis j (unit or 0)
  double max_speed_mm_s{20.0};                              ///< rate: speed at full deflection, mm/s
  double range_mm{20.0};                                    ///< position: displacement at full deflection, mm
  double dead_zone{0.0};                                    ///< in [0, 1)

  /// The mapped LPS vector of deflections (rate: velocity mm/s; position: offset mm).
  [[nodiscard]] Eigen::Vector3d map(const Eigen::Vector3d& axes) const;
  [[nodiscard]] std::string validate() const;
};

/// What drives a probe.
enum class ProbeDrive : std::uint8_t { path, joystick, live };
[[nodiscard]] const char* to_string(ProbeDrive d);

/// A probe: its shape and how it moves (plain settings; the scene file fills them).
struct ProbeSettings {
  std::string name;  ///< for reports ("probe0", "left", ...)
  ProbeGeometry geometry;
  ProbeDrive drive{ProbeDrive::path};
  std::vector<PathKey> path;                          ///< path: at least one key, times increasing
  std::vector<JoystickKey> joystick;                  ///< joystick: at least one sample, times increasing
  JoystickMapping mapping;                            ///< joystick (and live axes)
  Eigen::Vector3d start_mm{Eigen::Vector3d::Zero()};  ///< joystick and live: position at t = 0
  double max_speed_mm_s{200.0};                       ///< live: a position target is approached at most this fast

  /// Empty when valid, else what is wrong.
  [[nodiscard]] std::string validate() const;
  /// Position at t = 0.
  [[nodiscard]] Eigen::Vector3d initial_position() const;
  /// Largest speed the scripted motion reaches (path segments, joystick rate or position
  /// steps); for live probes max_speed_mm_s. mm/s.
  [[nodiscard]] double max_scripted_speed_mm_s() const;
};

/// Position on a keyframed path at time t (linear between keys, held outside).
[[nodiscard]] Eigen::Vector3d path_position(const std::vector<PathKey>& path, double t_s);
/// Interpolated joystick deflections at time t.
[[nodiscard]] Eigen::Vector3d joystick_axes(const std::vector<JoystickKey>& keys, double t_s);

/// A live command for a probe (from the probe app's input thread, via Simulation).
struct LiveCommand {
  enum class Kind : std::uint8_t { hold, position, velocity, axes } kind{Kind::hold};
  Eigen::Vector3d value{Eigen::Vector3d::Zero()};  ///< position mm / velocity mm/s / stick deflections
};

/// Moves one probe step by step.
class ProbeDriver {
 public:
  explicit ProbeDriver(ProbeSettings settings = {});
  /// Back to t = 0.
  void reset();
  /// Advances to time t_s = t_prev + dt_s; sets position and velocity (displacement / dt).
  void advance(double t_s, double dt_s);
  /// Live input (used by `live` probes only; kept until replaced).
  void set_live(const LiveCommand& command) { live_ = command; }

  [[nodiscard]] const ProbeSettings& settings() const { return settings_; }
  [[nodiscard]] const ProbeState& state() const { return state_; }

 private:
  ProbeSettings settings_;
  ProbeState state_;
  LiveCommand live_;
};

}  // namespace vx
