#pragma once
/// @file simd.h
/// Which instruction set the vector kernels run: the widest this CPU has, or the one the
/// environment variable VOXELASTIC_SIMD names (the same bits on machines with different vector
/// units).

namespace vx {

/// The instruction sets the vector kernels are compiled for (one copy of the same source each):
/// the batched element pass (physics/element_batches.h) and the factor's gathered sweeps
/// (sim/sparse_factor.h).
enum class SimdLevel {
  automatic,  ///< the widest this CPU runs (best_simd_level)
  generic,    ///< baseline x86-64 (SSE2: two lanes per instruction) or any other CPU
  avx2,       ///< x86-64-v3: AVX2 and FMA (four lanes, fused multiply-adds)
  avx512,     ///< x86-64-v4: AVX-512 (eight lanes, 32 vector registers; the element pass uses four)
};
/// True when this CPU runs `level` (automatic and generic: always).
[[nodiscard]] bool simd_supported(SimdLevel level);
/// The level `automatic` stands for (decided once): the widest this CPU runs, or the one the
/// environment variable VOXELASTIC_SIMD names (auto, generic, avx2, avx512), e.g. to get the
/// same bits on machines with different vector units; generic there also means the packed
/// kernel (elements.h). Throws vx::Error for a value that is not a level or that this CPU cannot run.
[[nodiscard]] SimdLevel best_simd_level();
/// "auto", "generic", "avx2" or "avx512".
[[nodiscard]] const char* to_string(SimdLevel level);

}  // namespace vx
