#pragma once
/// @file region_stiffening.h
/// How much the regional solves of the implicit integrator (ProjectiveSolver::set_region,
/// integrators.h region_radius_mm) over-stiffen a tool's press on a given support, estimated
/// before the run (docs/model.md section 7, "Regional solves on a weak support").
///
/// Why a regional solve stiffens: the global solve is exact on the region, but the nodes
/// outside it keep their positions (they sleep), so their velocity is zero and the next step's
/// inertial term M/dt^2 (x - y) pulls them back to where they were. Over many steps the far field
/// is held by springs of stiffness m_i/dt^2 per node. For a press that deforms the tissue near
/// the tool this changes nothing (the elastic stiffness there dominates m/dt^2 by orders of
/// magnitude at 30 ms). For an organ held at a small patch (a stem) the press also tilts the
/// whole organ about its support; that soft mode's stiffness is below the far field's total
/// m/dt^2, so the held far field takes the load a whole organ would give to: the press is too hard.
///
/// The estimate (linear, quasi-static): with K the static projective matrix (free nodes, no mass
/// term) and f a unit load spread over the nodes under the tool,
///   c_full   = f^T K^-1 f                 (the whole model gives),
///   c_region = f^T (K + D_far)^-1 f,      D_far = m_i / dt^2 on the free nodes farther than the
///                                         region radius from the tool,
/// and a press to a given depth costs force_ratio = c_full / c_region times the force it should.
/// Both solves are conjugate gradients preconditioned by an incomplete Cholesky factor of K
/// (Eigen); K is scalar (the same for x, y and z), so the press direction does not enter
/// (RegionStiffeningSettings::rotation_curvature: the tangent, which couples them).
/// Units: mm, N, s.

#include <Eigen/Core>
#include <atomic>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "physics/physics_model.h"

namespace vx {

class RegionStiffeningCache;

struct RegionStiffeningSettings {
  Eigen::Vector3d tool_mm{0, 0, 0};  ///< the tool's centre where it starts (the region's centre)
  double tool_radius_mm{4.0};        ///< the load spreads over the free nodes within this of the node nearest the tool
  double region_radius_mm{30.0};     ///< the regional solves' radius (integrators.h)
  double time_step_s{0.03};          ///< the implicit step
  double tolerance{1e-3};    ///< conjugate gradients: relative residual (the compliance converges as its square)
  int max_iterations{2000};  ///< conjugate gradients, per solve
  /// true: the tangent at rest (three coordinates, less each element's rotation curvature): the
  /// whole model's compliance as the converged static press gives it (tested), about 4x the
  /// cost; false: the projective matrix alone (one coordinate): stiffer near the tool, but the
  /// ratio it gives agreed within 1 % on the tested column
  bool rotation_curvature{false};
  /// When set and true, the estimate stops at its next conjugate-gradient iteration and returns
  /// no estimate (reason "cancelled"): a run that ends before a background estimate does not wait
  /// for it (prepare_scene's RegionCheck::background).
  const std::atomic<bool>* cancel{nullptr};
  /// Estimates kept by their content (below); null: none.
  RegionStiffeningCache* cache{nullptr};
};

struct RegionStiffeningEstimate {
  bool valid{false};  ///< false: no estimate (reason says why)
  std::string reason;
  int load_nodes{0};                   ///< free nodes under the tool
  int region_nodes{0};                 ///< free nodes within the region radius (awake)
  int far_nodes{0};                    ///< free nodes outside it (held by m/dt^2)
  double compliance_full_mm_n{0.0};    ///< f^T K^-1 f for a unit total load, mm/N
  double compliance_region_mm_n{0.0};  ///< f^T (K + D_far)^-1 f, mm/N
  double force_ratio{1.0};             ///< c_full / c_region: the regional press's force over the whole model's
  int iterations_full{0}, iterations_region{0};  ///< conjugate-gradient iterations
  double seconds{0.0};                           ///< wall time of the estimate (when loaded: of the load)
  bool loaded{false};                            ///< true: read from RegionStiffeningSettings::cache, not solved
  /// The estimated relative force error, force_ratio - 1.
  [[nodiscard]] double error_rel() const { return force_ratio - 1.0; }
};

/// The estimate for `physics` held at `node_fixed` (1: fixed; a part of the model that no fixed
/// node holds makes K singular: then no estimate). Allocates; about 1 s of one core on 57,000 nodes.
[[nodiscard]] RegionStiffeningEstimate estimate_region_stiffening(const PhysicsModel& physics,
                                                                  const std::vector<std::uint8_t>& node_fixed,
                                                                  const RegionStiffeningSettings& settings);

/// A store of estimates by the content of what they are estimated from (pipeline/io/
/// region_check_cache.h keeps one in the factor cache's folder): the estimate is the same every
/// time an organ starts on the same support with the same tool, and on the folded organ it takes
/// 10 s of one core beside the run's first seconds. estimate_region_stiffening asks it once K is
/// assembled (its key: a 64-bit content hash of K, the load, the held far field, the node
/// numbering, the solves' settings and, with rotation_curvature, the arrays the tangent reads)
/// and offers it every valid estimate it solves.
class RegionStiffeningCache {
 public:
  virtual ~RegionStiffeningCache() = default;
  /// The stored estimate of `key` (`free_nodes`: of the model, for the file's name), or nothing.
  virtual std::optional<RegionStiffeningEstimate> load(std::uint64_t key, int free_nodes) = 0;
  /// Offers the estimate of `key`, just solved.
  virtual void store(std::uint64_t key, int free_nodes, const RegionStiffeningEstimate& estimate) = 0;
};

}  // namespace vx
