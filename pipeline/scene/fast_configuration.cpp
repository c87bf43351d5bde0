#include "scene/fast_configuration.h"

#include "sim/time_step.h"

namespace vx {

FastConfiguration default_fast_configuration() {
  return {.kind = IntegratorKind::implicit,
          .time_step_s = kImplicitAutomaticTimeStepS,
          .iterations = 1,
          .free_iterations = 8,
          .free_tolerance_mm = 1e-6,
          .large_model_nodes = 20000,
          .large_model_time_step_s = 0.03,
          .large_model_region_radius_mm = 60.0,
          .device_update_steps = 2.0};
}

IntegratorSettings FastConfiguration::integrator_for(int nodes) const {
  IntegratorSettings s;
  s.kind = kind;
  s.time_step_s = time_step_for(nodes);
  s.region_radius_mm = region_radius_for(nodes);
  s.max_iterations = iterations;
  s.free_iterations = free_iterations_for(nodes);
  s.free_tolerance_mm = free_tolerance_mm;
  s.threads = 1;
  return s;
}

DeviceForceSettings FastConfiguration::device_for(int nodes) const {
  DeviceForceSettings d;
  d.update_interval_s = device_update_interval_for(nodes);
  return d;
}

}  // namespace vx
