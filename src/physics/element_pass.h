#pragma once
/// @file element_pass.h
/// What an element pass is asked for and what it counts (elements.h runs it): the kernel and
/// instruction set (ElementKernel, SimdLevel), the rotation fit's settings, the counters
/// summed over elements (ElementPassStats), and the chunks of elements it runs in parallel.
/// Below both kernels' rooms: the batched kernel (element_batches.h) fills the same counters.

#include <cstdint>
#include <vector>

#include "base/parallel.h"
#include "physics/element_batch_layout.h"
#include "physics/rotation_fit.h"

namespace vx {

/// Which implementation of the element pass runs; both compute the same forces.
enum class ElementKernel {
  batched,    ///< the fastest: packed's arithmetic on kBatchLanes elements at once (element_batches.h);
              ///< without energy and volume term, and with simd automatic only on a CPU with AVX2
              ///< (else packed runs)
  packed,     ///< packed per-entry constants (PackedEntry), each force written once
  reference,  ///< the plain kernel, one loop per term over separate arrays (for tests and benchmarks)
};

/// "batched", "packed" or "reference".
[[nodiscard]] inline const char* to_string(ElementKernel k) {
  switch (k) {
    case ElementKernel::batched: return "batched";
    case ElementKernel::packed: return "packed";
    case ElementKernel::reference: return "reference";
  }
  return "?";
}

/// What an element pass should compute.
struct ElementPassOptions {
  bool damping{true};  ///< add damping (needs velocities)
  bool energy{false};  ///< write per-element elastic energy
  RotationFitSettings rotation;
  ElementKernel kernel{ElementKernel::batched};
  SimdLevel simd{SimdLevel::automatic};  ///< the batched kernel's instruction set (element_batches.h)
};

/// Counters of one element pass (summed over elements).
struct ElementPassStats {
  std::int64_t inverted{0};             ///< elements with det(A) <= 0 (inverted or flat)
  std::int64_t unconverged{0};          ///< elements whose rotation fit did not reach the tolerance
  std::int64_t rotation_iterations{0};  ///< total fit iterations
  std::int64_t non_finite{0};           ///< elements with a NaN/Inf input or fit
  double elastic_energy{0.0};           ///< N*mm (only with options.energy)
  void add(const ElementPassStats& o) {
    inverted += o.inverted;
    unconverged += o.unconverged;
    rotation_iterations += o.rotation_iterations;
    non_finite += o.non_finite;
    elastic_energy += o.elastic_energy;
  }
};

/// Scratch of an element pass, allocated once (per-chunk partial counters).
struct ElementPassScratch {
  std::vector<ElementPassStats> chunks;  ///< element_pass_slots(elements) of them
};

/// Element grain of the parallel passes (elements per chunk).
inline constexpr std::int64_t kElementGrain = 256;
/// Node grain of the parallel passes (nodes per chunk).
inline constexpr std::int64_t kNodeGrain = 1024;

/// Partial counters of an element pass over `elements`: one per element window (chunk of
/// kElementGrain), and one for the elements the batched kernel leaves to the packed one.
[[nodiscard]] inline std::int64_t element_pass_slots(std::int64_t elements) {
  return chunk_count(elements, kElementGrain) + 1;
}

}  // namespace vx
