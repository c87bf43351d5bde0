#include "scene/fast_configuration.h"

#include <fmt/format.h>

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
  s.single_precision_sweeps = large(nodes) && large_model_single_precision_sweeps;
  s.threads = 1;
  return s;
}

DeviceForceSettings FastConfiguration::device_for(int nodes) const {
  DeviceForceSettings d;
  d.update_interval_s = device_update_interval_for(nodes);
  return d;
}

namespace {

/// Whether incompressible_iterations_warning() applies.
bool few_iterations_on_incompressible(const IntegratorSettings& integrator, double poisson_ratio) {
  return integrator.kind == IntegratorKind::implicit && integrator.residual_tolerance_n <= 0 &&
         integrator.max_iterations <= kSlowVolumeMaxIterations && poisson_ratio >= kSlowVolumePoissonRatio;
}

}  // namespace

std::string incompressible_iterations_status(const IntegratorSettings& integrator, double poisson_ratio) {
  if (!few_iterations_on_incompressible(integrator, poisson_ratio)) return {};
  return fmt::format("Poisson {:g}, {} iteration{} per step: forces {} off a converged run (console)", poisson_ratio,
                     integrator.max_iterations, integrator.max_iterations == 1 ? "" : "s",
                     poisson_ratio >= 0.45 ? "8.5-13 %" : "over 5 %");
}

std::string incompressible_iterations_warning(const IntegratorSettings& integrator, double poisson_ratio) {
  if (!few_iterations_on_incompressible(integrator, poisson_ratio)) return {};
  return fmt::format(
      "Poisson ratio {:g} with {} local/global iteration{} per step: these iterations converge slowly on a nearly "
      "incompressible tissue{}, so the force runs high in a press and falls away early in a slide (the fast "
      "configuration against converged runs of a press and "
      "slide, RMS force error of the peak: at 0.45 8.5 to 13 % on spheres, the organ and the folded organ, at 0.4 "
      "6.6 % and at 0.3 3.9 % on the 128 sphere; docs/bench.md, \"The 5 % table at Poisson 0.45\"); for forces within "
      "5 % use \"integrator\": {} (no region; 2.2 % on the 128 sphere, tens of times slower than real time)",
      poisson_ratio, integrator.max_iterations, integrator.max_iterations == 1 ? "" : "s",
      integrator.region_radius_mm > 0 ? ", and the regional solves hold still the far field it pushes into" : "",
      accurate_integrator_json(poisson_ratio));
}

std::string accurate_integrator_json(double poisson_ratio) {
  if (poisson_ratio >= kSlowVolumePoissonRatio)
    return "{\"type\": \"implicit\", \"dt_s\": 0.01, \"iterations\": 30, \"residual_tolerance_n\": 1e-5}";
  return "{\"type\": \"implicit\", \"dt_s\": 0.01, \"iterations\": 5}";
}

}  // namespace vx
