// The builder is linear in the number of voxels: time per voxel stays flat from 32^3 to 256^3.
#include <benchmark/benchmark.h>

#include <cmath>

#include "model/gradational_builder.h"
#include "model/voxel_shapes.h"

namespace {

/// A ball `diameter` voxels across with a 2-voxel air margin.
vx::VoxelGrid sphere_grid(int diameter) { return vx::ball_grid(diameter + 4, 0.5 * diameter - 0.5); }

void BM_Build(benchmark::State& state, vx::Layout layout) {
  const vx::VoxelGrid grid = sphere_grid(int(state.range(0)));
  vx::BuildSettings settings;
  settings.layout = layout;
  std::int64_t entries = 0, elements = 0;
  for (auto _ : state) {
    const vx::Model m = vx::build_model(grid, settings);
    entries = m.num_vertex_entries();
    elements = m.num_elements();
    benchmark::DoNotOptimize(entries);
  }
  const double voxels = double(grid.geometry().voxel_count());
  state.counters["grid_voxels"] = voxels;
  state.counters["elements"] = double(elements);
  state.counters["vertex_entries"] = double(entries);
  state.counters["voxels_per_s"] = benchmark::Counter(voxels, benchmark::Counter::kIsIterationInvariantRate);
}

}  // namespace

BENCHMARK_CAPTURE(BM_Build, gradational, vx::Layout::gradational)
    ->RangeMultiplier(2)->Range(32, 256)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Build, voxel, vx::Layout::voxel)
    ->RangeMultiplier(2)->Range(32, 128)->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();
