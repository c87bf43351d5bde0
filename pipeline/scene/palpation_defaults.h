#pragma once
/// @file palpation_defaults.h
/// The probe app's defaults for an object without a scene of its own (a volume or a model), as
/// data: default_palpation_scene() returns a Scene whose `palpation` defaults prepare_scene
/// places once the object is built (place_palpation_defaults): the nodes of the tissue's lower
/// part held (lower_part_nodes), walls around it with a table under it, one capsule tool just
/// above tissue near the top centre (default_tool_start), the fast configuration
/// (fast_configuration.h) and a device with the paper's shaping. A scene file and these defaults
/// are built by the same prepare_scene (scene.h).
///
/// Units: mm, kPa; directions in LPS.

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "scene/scene.h"

namespace vx {

/// A scene of `object` (a volume or a model file) made of `material` with the palpation
/// `defaults`. Throws vx::Error for an invalid material.
[[nodiscard]] Scene default_palpation_scene(const SceneObject& object, const Material& material,
                                            const PalpationDefaults& defaults = {});

/// Where the default tool starts (default_tool_start).
struct ToolStart {
  Eigen::Vector3d start_mm{0, 0, 0};    ///< the tool's reference point (its tip sphere's centre)
  Eigen::Vector3d surface_mm{0, 0, 0};  ///< the tissue's top on the tool's axis below it
  double tissue_below_mm{0.0};          ///< tissue under surface_mm along -up, mm (>= the press depth when found)
  bool found{false};                    ///< false: no column holds the press depth (start above the centre)
};

/// The start of a tool of radius `radius_mm` pressed straight down (against `up`): above the
/// highest top of tissue near the top centre (within a lateral radius of the tissue box's
/// centre, widened until one qualifies) whose column holds tissue at least `press_depth_mm`
/// deep, and whose neighbours within the tool's radius (else half of it) hold tissue from within
/// half the press depth of it down to the press depth: a fissure or a hole at the centre is
/// passed over, and the tool does not sit on its edge. Tissue thinner than the press depth
/// everywhere: the thickest column near the centre. The start is `clearance_mm` plus the radius
/// above the highest tissue within the tool's radius.
/// `grid` is the voxel grid of `model` (grid_from_model).
[[nodiscard]] ToolStart default_tool_start(const Model& model, const VoxelGrid& grid, const Eigen::Vector3d& up,
                                           double radius_mm, double press_depth_mm, double clearance_mm);

/// Nodes whose height along `up` lies in the lowest `fraction` of the model's height (the
/// default support).
[[nodiscard]] std::vector<int> lower_part_nodes(const Model& model, const Eigen::Vector3d& up, double fraction);

/// prepare_scene's stage for a scene with palpation defaults, once `out` holds the built model
/// and its physics: up (in the slice plane of a 2D model), the fixed nodes, walls, the tool, the
/// fast configuration's integrator (threads: `options.threads_override`, else 1) and device,
/// and a log line saying what was chosen. Returns a flag per node (1: fixed).
std::vector<std::uint8_t> place_palpation_defaults(const PalpationDefaults& defaults,
                                                   const PrepareSceneOptions& options, PreparedScene& out);

}  // namespace vx
