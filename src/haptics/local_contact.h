#pragma once
/// @file local_contact.h
/// The tool force at the haptic rate from a local contact model (docs/model.md section 9;
/// Duriez et al. 2006, SOFA's LCPForceFeedback; Courtecuisse et al. 2015).
///
/// The physics updates at 30-1000 Hz; a haptic device wants a force every millisecond that
/// follows the tool. So at the end of every physics update the simulation publishes, per tool,
/// a linearisation of its contact (LocalContactModel): the nodes touching the tool or near it,
/// their normals n_i, the contact forces lambda0_i at the anchor, their gaps, and the contact
/// compliance
///     W_ij = n_i . C_ij n_j   (mm/N),
/// C the compliance of the tissue between nodes i and j (the implicit integrator's factor:
/// C_ij = (A^-1)_ij I, as SOFA does; else the same matrix on a patch of elements around the
/// contact, local_compliance.h). For a tool displaced by d from the anchor position, the gaps are
///     g(lambda) = u - N^T d + W lambda,     u = g0 - W lambda0,
/// and the contact forces solve the small linear complementarity problem
///     lambda >= 0,  g >= 0,  lambda . g = 0,
/// exactly (an active set on a dense Cholesky factor; a few to a few hundred nodes, no
/// allocation at the device rate). The force of the tissue on the tool is -N lambda. At d = 0 the
/// solution is lambda0: the force equals the anchor force. With a flat tool the force field is
/// the gradient of a concave value function (the LCP is a convex QP with a fixed W), so it is
/// conservative: the local model stores and returns energy, it never makes any. A curved tool
/// (sphere, capsule, cylinder) turns the contact normals as it moves: the free gaps use the exact
/// distance of each node's anchor position from the moved tool, and the force the normals there,
///     g_i = u_i + phi_i(x0 + d) - phi_i(x0),   F = -sum_i lambda_i (n_i + m_i(x0 + d) - m_i(x0)),
/// (m_i(x): the tool's outward normal closest to the node's anchor position with the tool at x)
/// which adds the first-order change of the normals (the tool's geometric stiffness, F d / R
/// sideways) to the linearisation; W keeps the anchor's normals (the error is second order).
/// The turn fades out for a node deeper than a quarter of the tool's radius (none at half of
/// it): far from the anchor the tool's centre or axis can pass a node, whose normal then flips.
///
/// LocalForceRenderer turns it into the force for the hand:
/// - a virtual coupling, a spring k_c between the device and the tool (proxy): its compliance
///   1/k_c joins the contact compliance (W' = W + N^T N / k_c), so the same LCP gives the proxy
///   position q = x_d - N lambda / k_c and the force the spring passes on, and the stiffness the
///   hand can feel is at most k_c;
/// - damping from the device rate T: F_damp = -beta T K v_d with K the stiffness of the current
///   active set (zero in free space). beta = 1/2 exactly cancels the energy a zero-order hold
///   adds to a spring of stiffness K for smooth motion (K T/2 per unit of v^2, Colgate and
///   Schenkel 1997); beta = 1 dissipates as much again;
/// - k_c from Colgate's condition b > K T/2 + |B| for a device of physical damping b:
///   k_c = b / ((1/2 + beta) T), so that k_c T/2 + beta k_c T = b;
/// - re-anchoring without a jump: when a new model arrives, the difference between the force
///   being rendered and the new model's force at the same device position is kept as an offset
///   that fades linearly to zero over the blend time;
/// - an energy guard (a passivity observer and controller, Hannaford and Ryu 2002): the energy
///   the hand has put in, E = -sum_k F_k . (x_{k+1} - x_k), is known after every tick; when the
///   force of the next tick would give back more than E/n along the device's current velocity v,
///   its component along v is cut to what that allows (F . v T' = E/n, T' = 1.2 T for a margin;
///   n = 10 ms / T): as E runs out the force along the motion fades by 1/n per tick instead of
///   dropping in one tick (measured on the organ: a 38 % of peak drop in 3 ticks with n = 1),
///   and a correction is released by 1/n per tick. The
///   coupling and damping cover the hold's energy (Colgate); the guard covers what they do not:
///   the model changing under a moving hand (a new anchor, the latency of a slow physics).
///
/// Units: mm, s, N; compliance mm/N, stiffness N/mm, damping N s/mm, energy N mm (mJ).

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "sim/probe.h"

namespace vx {

/// Where a local model's compliance came from.
enum class ComplianceSource : std::uint8_t {
  none,        ///< no contact candidates (the model holds no node)
  integrator,  ///< the implicit integrator's factor: (M/dt^2 + K + C/dt)^-1, exact for its step
  patch,       ///< that matrix at the model's horizon on a patch of elements around the contact
};
[[nodiscard]] const char* to_string(ComplianceSource s);

/// The contact of one tool, linearised at the end of a physics update (its "anchor").
struct LocalContactModel {
  bool valid{false};                                        ///< false: no physics update yet (no force)
  std::int64_t update{0};                                   ///< physics updates published so far (1 for the first)
  std::int64_t step{0};                                     ///< the physics step of the anchor
  double time_s{0.0};                                       ///< simulated time of the anchor, s
  Eigen::Vector3d anchor_mm{Eigen::Vector3d::Zero()};       ///< tool position the anchor force belongs to
  Eigen::Vector3d anchor_force_n{Eigen::Vector3d::Zero()};  ///< force of the tissue on the tool there, N
  ProbeGeometry tool;                                       ///< the tool's shape (its normals turn as it moves)
  ComplianceSource source{ComplianceSource::none};
  // the candidates: nodes in contact at the anchor, then nodes within the margin
  std::vector<std::int32_t> node;  ///< node ids
  Eigen::Matrix3Xd point_mm;       ///< 3 x m: node positions at the anchor
  Eigen::Matrix3Xd normal;         ///< 3 x m: the tool's outward unit normal at each node
  Eigen::VectorXd force_n;         ///< m: lambda0, the contact force along the normal, N (>= 0)
  Eigen::VectorXd gap_mm;          ///< m: g0, the gap along the normal, mm (0 where lambda0 > 0)
  Eigen::MatrixXd compliance;      ///< m x m: W, symmetric positive definite, mm/N

  [[nodiscard]] int size() const { return int(node.size()); }
  /// Sizes every array for m candidates (keeps capacity: no allocation when m does not grow).
  void resize(int m);
  /// Empty when the arrays agree and the values are sane (finite, lambda0 >= 0, gaps >= 0,
  /// W symmetric with a positive diagonal), else what is wrong.
  [[nodiscard]] std::string validate() const;
};

/// Solves the local contact problem for a tool position (device thread). Allocation-free after
/// construction for models of up to kMaxNodes candidates (larger ones are refused by set()).
class LocalContactSolver {
 public:
  static constexpr int kMaxNodes = 256;  ///< candidates a model may hold
  static constexpr int kMaxRounds = 64;  ///< active-set rounds per solve

  LocalContactSolver();

  /// Takes a model (copies what the solve needs) with the coupling compliance `coupling_mm_n`
  /// (1/k_c; 0: none, the tool is where the device is). Returns false (and holds no contact)
  /// for an invalid model or one with more than kMaxNodes candidates.
  bool set(const LocalContactModel& model, double coupling_mm_n);
  /// Forgets the model (no contact, zero force).
  void clear();

  /// The solution for device position `device_mm`.
  struct Result {
    Eigen::Vector3d force_n{Eigen::Vector3d::Zero()};         ///< force of the tissue on the tool (= on the hand), N
    Eigen::Vector3d proxy_mm{Eigen::Vector3d::Zero()};        ///< where the tool is (device + coupling stretch)
    Eigen::Matrix3d stiffness_n_mm{Eigen::Matrix3d::Zero()};  ///< -d force / d device (symmetric psd), N/mm
    int active{0};                                            ///< nodes in contact
    int rounds{0};                                            ///< active-set rounds taken
    bool converged{true};
  };
  /// Solves the LCP at `device_mm`, warm-started from the last active set.
  const Result& solve(const Eigen::Vector3d& device_mm);

  [[nodiscard]] const Result& result() const { return result_; }
  [[nodiscard]] bool has_model() const { return m_ > 0 || valid_; }
  [[nodiscard]] int size() const { return m_; }
  [[nodiscard]] const Eigen::Vector3d& anchor_mm() const { return anchor_; }
  /// Multipliers of the last solve (m values), N.
  [[nodiscard]] const double* multipliers() const { return lambda_.data(); }

 private:
  bool factor_working_set();
  void solve_working_set(const double* rhs, double* x) const;

  bool valid_{false};
  int m_{0};
  double coupling_{0.0};
  Eigen::Vector3d anchor_{Eigen::Vector3d::Zero()};
  ProbeGeometry tool_;
  bool curved_{false};           ///< the tool's normals turn as it moves
  Eigen::Matrix3Xd point_;       ///< 3 x cap: node positions at the anchor
  Eigen::VectorXd phi0_;         ///< cap: their signed distance from the tool at the anchor
  Eigen::Matrix3Xd turn0_;       ///< 3 x cap: the tool's normal there (the normals turn from it)
  Eigen::Matrix3Xd normal_now_;  ///< 3 x cap: the normals at the current tool position
  Eigen::Matrix3Xd normal_;      ///< 3 x cap
  Eigen::VectorXd free_gap_;     ///< cap: u = g0 - W lambda0
  Eigen::MatrixXd w_;            ///< cap x cap: W + coupling N^T N
  Eigen::VectorXd lambda_;       ///< cap
  Eigen::VectorXd gap_;          ///< cap: b at the current device position
  std::vector<std::uint8_t> in_set_;
  std::vector<int> set_;                        ///< the working set (sorted)
  std::vector<int> factored_set_;               ///< the set the factor is of
  Eigen::MatrixXd chol_;                        ///< cap x cap: lower Cholesky factor of W'_SS
  Eigen::VectorXd rhs_, sol_;                   ///< cap
  Eigen::Matrix<double, Eigen::Dynamic, 3> y_;  ///< cap x 3: L^-1 N_S^T (stiffness)
  Result result_;
};

/// The virtual coupling and damping of the device (LocalForceRenderer).
struct HapticCouplingSettings {
  double device_rate_hz{1000.0};  ///< the device thread's rate, 1/T
  /// b: the physical damping of the device the coupling is sized for, N s/mm (1.5 N s/m: a
  /// modest desktop device; a joystick's friction is larger).
  double device_damping_n_s_mm{1.5e-3};
  /// beta: virtual damping beta T K (1/2 cancels the hold's energy; below it the force is active)
  double damping_margin{1.0};
  double coupling_stiffness_n_mm{0.0};  ///< k_c; <= 0: from Colgate's condition, b / ((1/2 + beta) T)
  double blend_s{0.0};                  ///< re-anchoring fade; <= 0: one physics period (one tick to 50 ms)
  bool energy_guard{true};              ///< the passivity observer and controller

  [[nodiscard]] std::string validate() const;
  [[nodiscard]] double period_s() const { return 1.0 / device_rate_hz; }
  /// k_c, N/mm.
  [[nodiscard]] double stiffness_n_mm() const;
};

/// The force for the hand at every device tick, from the latest local contact model
/// (one per tool, device thread). Allocation-free after init().
class LocalForceRenderer {
 public:
  void init(const HapticCouplingSettings& settings);
  /// No model, no offset, no velocity history.
  void reset();

  /// A new model (from the physics) at device time `now_s`: the force the hand feels does not
  /// jump; the difference fades out over the blend time. `physics_period_s` (the measured time
  /// between updates, 0 if unknown) sets the automatic blend time.
  void update_model(const LocalContactModel& model, double now_s, double physics_period_s = 0.0);

  /// One device tick at device position `device_mm` and time `now_s`.
  struct Output {
    Eigen::Vector3d force_n{Eigen::Vector3d::Zero()};    ///< to the hand (spring + damping + fading offset), N
    Eigen::Vector3d contact_n{Eigen::Vector3d::Zero()};  ///< the local model's force at the proxy, N
    Eigen::Vector3d damping_n{Eigen::Vector3d::Zero()};  ///< the damping part, N
    Eigen::Vector3d offset_n{Eigen::Vector3d::Zero()};   ///< the fading re-anchoring offset, N
    Eigen::Vector3d guard_n{Eigen::Vector3d::Zero()};    ///< the energy guard's correction, N
    double energy_mj{0.0};                               ///< energy the hand has put in so far, N mm
    Eigen::Vector3d proxy_mm{Eigen::Vector3d::Zero()};   ///< the tool (proxy) position, mm
    Eigen::Matrix3d stiffness_n_mm{Eigen::Matrix3d::Zero()};
    int contacts{0};
    bool converged{true};
  };
  const Output& tick(const Eigen::Vector3d& device_mm, double now_s);

  [[nodiscard]] const Output& output() const { return out_; }
  [[nodiscard]] const HapticCouplingSettings& settings() const { return settings_; }
  [[nodiscard]] double coupling_stiffness_n_mm() const { return k_c_; }
  [[nodiscard]] double blend_s() const { return blend_; }
  [[nodiscard]] std::int64_t models() const { return models_; }
  /// Ticks the energy guard changed the force, and the energy it withheld (N mm).
  [[nodiscard]] std::int64_t guard_ticks() const { return guard_ticks_; }
  [[nodiscard]] double guard_energy_mj() const { return guard_energy_; }
  [[nodiscard]] const LocalContactSolver& solver() const { return solver_; }

 private:
  HapticCouplingSettings settings_;
  double k_c_{1.0};
  double blend_{0.02};
  LocalContactSolver solver_;
  bool has_last_{false};
  Eigen::Vector3d last_device_{Eigen::Vector3d::Zero()};
  double last_time_{0.0};
  Eigen::Vector3d offset0_{Eigen::Vector3d::Zero()};  ///< offset at the re-anchoring instant
  double offset_start_{0.0};
  std::int64_t models_{0};
  double energy_{0.0};                                 ///< the hand's net work on the device so far, N mm
  Eigen::Vector3d velocity_{Eigen::Vector3d::Zero()};  ///< the device's, over the last tick
  std::int64_t guard_ticks_{0};
  double guard_energy_{0.0};
  Eigen::Vector3d guard_last_{Eigen::Vector3d::Zero()};  ///< the last tick's correction (released gradually)
  /// The guard's taper: the force gives at most 1/n of the energy left per tick, n = this / T.
  static constexpr double kGuardTaper_s = 0.01;
  Output out_;
};

}  // namespace vx
