#pragma once
/// @file parallel.h
/// The one parallel loop of the core (OpenMP), in the style of b2ParallelFor: a range is cut
/// into chunks of `grain` items whose boundaries do not depend on the thread count, so a
/// caller that writes per-item results, or per-chunk partial sums reduced in chunk order,
/// gets bit-identical results for 1 and N threads.

#include <omp.h>

#include <algorithm>
#include <cstdint>

namespace vx {

/// Threads a parallel region uses when asked for `requested` (0 = OpenMP's default, i.e.
/// OMP_NUM_THREADS or the number of cores).
[[nodiscard]] inline int resolve_threads(int requested) {
  return requested > 0 ? requested : std::max(1, omp_get_max_threads());
}

/// Ends the calling thread's OpenMP workers (they are started again by its next parallel
/// region). Call it on a thread that is done with parallel work while another thread goes on
/// with its own: GNU OpenMP counts the idle workers of every thread's team, and once they
/// outnumber the cores, every team's waits stop spinning and sleep at once (1,000 spins, not
/// 300,000), so each of the busy team's forks and barriers waits for a wake-up
/// (docs/probe.md, "The app against simulate"). Returns false when the runtime refused
/// (inside a parallel region, or a runtime without OpenMP 5's pause).
inline bool release_openmp_workers() { return omp_pause_resource_all(omp_pause_soft) == 0; }

/// For a thread that from now on leaves the parallel work to another (a display beside the
/// physics): its idle workers go (release_openmp_workers) and its later parallel regions run on
/// it alone, so it never forms a team again (its own OpenMP setting, omp_set_num_threads(1);
/// parallel_for with 0 threads and Eigen follow it; the other threads keep theirs). Returns
/// release_openmp_workers()'s answer.
inline bool leave_parallel_work_to_others() {
  omp_set_num_threads(1);
  return release_openmp_workers();
}

/// The calling thread's OpenMP setting (omp_set_num_threads) at another count for a scope, then
/// back as it was: the loops asked for 0 threads (OpenMP's default) and Eigen follow it.
class ScopedThreads {
 public:
  ScopedThreads() = default;
  ScopedThreads(const ScopedThreads&) = delete;
  ScopedThreads& operator=(const ScopedThreads&) = delete;
  ~ScopedThreads() {
    if (before_ > 0) omp_set_num_threads(before_);
  }
  /// From now to the end of the scope: `threads` (> 0; else nothing changes).
  void set(int threads) {
    if (threads <= 0) return;
    if (before_ == 0) before_ = omp_get_max_threads();
    omp_set_num_threads(threads);
  }

 private:
  int before_{0};  ///< the setting to restore (0: not changed)
};

/// Number of chunks parallel_for cuts [0, n) into.
[[nodiscard]] inline std::int64_t chunk_count(std::int64_t n, std::int64_t grain) {
  grain = std::max<std::int64_t>(1, grain);
  return n <= 0 ? 0 : (n + grain - 1) / grain;
}

/// Calls fn(chunk, begin, end) for the chunks [chunk*grain, min(n, (chunk+1)*grain)) of
/// [0, n), in parallel over `threads` threads (0 = default), chunks handed out dynamically
/// (balances uneven chunks and cores shared with other work). It forks at most one thread per
/// full chunk: a range of less than two full chunks runs on the calling thread, in chunk order
/// (the same chunks, so the same bits). A small model's loops (an explicit step of 1,138 nodes:
/// one full node chunk and 114 nodes) then never wait at a barrier for a worker that a busy
/// machine has not scheduled (it read 381 steps/s on two threads beside a test suite, where real
/// time needs about 5,500: docs/probe.md, "Sharing the cores with the display"). fn must not
/// throw and must not write what another chunk writes.
template <class Fn>
void parallel_for_chunks(std::int64_t n, std::int64_t grain, int threads, Fn&& fn) {
  grain = std::max<std::int64_t>(1, grain);
  const std::int64_t chunks = chunk_count(n, grain);
  if (chunks == 0) return;
  const int t = int(std::min<std::int64_t>(resolve_threads(threads), std::max<std::int64_t>(1, n / grain)));
  if (t <= 1) {
    for (std::int64_t c = 0; c < chunks; ++c) fn(c, c * grain, std::min(n, (c + 1) * grain));
    return;
  }
#pragma omp parallel for num_threads(t) schedule(dynamic, 1)
  for (std::int64_t c = 0; c < chunks; ++c) fn(c, c * grain, std::min(n, (c + 1) * grain));
}

/// Calls fn(begin, end) over chunks of [0, n); see parallel_for_chunks.
template <class Fn>
void parallel_for(std::int64_t n, std::int64_t grain, int threads, Fn&& fn) {
  parallel_for_chunks(n, grain, threads, [&](std::int64_t, std::int64_t b, std::int64_t e) { fn(b, e); });
}

}  // namespace vx
