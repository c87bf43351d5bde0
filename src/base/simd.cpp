#include "base/simd.h"

#include <cstdlib>
#include <string>

#include "base/error.h"

namespace vx {

bool simd_supported(SimdLevel level) {
  switch (level) {
    case SimdLevel::automatic:
    case SimdLevel::generic: return true;
#if defined(__x86_64__) && defined(__clang__)
    // clang 14 (the fuzz and sanitizer builds) knows no x86-64-vN levels here: their key features
    case SimdLevel::avx2:
      return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") && __builtin_cpu_supports("bmi2");
    case SimdLevel::avx512:
      return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
             __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl");
#elif defined(__x86_64__) && defined(__GNUC__)
    case SimdLevel::avx2: return __builtin_cpu_supports("x86-64-v3");
    case SimdLevel::avx512: return __builtin_cpu_supports("x86-64-v4");
#else
    default: return false;
#endif
  }
  return false;
}

namespace {

SimdLevel pick_simd_level() {
  const SimdLevel widest = simd_supported(SimdLevel::avx512) ? SimdLevel::avx512
                           : simd_supported(SimdLevel::avx2) ? SimdLevel::avx2
                                                             : SimdLevel::generic;
  const char* env = std::getenv("VOXELASTIC_SIMD");
  if (env == nullptr || *env == '\0') return widest;
  const std::string want = env;
  for (const SimdLevel level : {SimdLevel::automatic, SimdLevel::generic, SimdLevel::avx2, SimdLevel::avx512}) {
    if (want != to_string(level)) continue;
    if (level == SimdLevel::automatic) return widest;
    if (!simd_supported(level))
      throw Error("VOXELASTIC_SIMD=" + want + ": this CPU cannot run " + want + " (the widest it runs is " +
                  to_string(widest) + "); unset it or choose auto, generic, avx2 or avx512");
    return level;
  }
  throw Error("VOXELASTIC_SIMD=" + want +
              " is not an instruction set; unset it or choose auto, generic, avx2 or avx512");
}

}  // namespace

SimdLevel best_simd_level() {
  static const SimdLevel best = pick_simd_level();
  return best;
}

const char* to_string(SimdLevel level) {
  switch (level) {
    case SimdLevel::automatic: return "auto";
    case SimdLevel::generic: return "generic";
    case SimdLevel::avx2: return "avx2";
    case SimdLevel::avx512: return "avx512";
  }
  return "?";
}

}  // namespace vx
