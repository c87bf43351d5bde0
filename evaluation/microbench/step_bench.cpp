// voxelastic_bench_step: one step of each integrator on sphere phantoms of growing size
// (the gradational model of a ball of radius n/2 - 1 voxels, lowest cap fixed, under gravity).
// Counters: ns per element and per vertex entry, threads, model size, real-time factor.
// element_pass/<kernel>/n: the element pass alone with each kernel, side by side.
// element/<pass or step>/<element>/n: the paper's element against the hourglass one.
// team/<idle_team or released>/n: implicit steps beside another thread's idle OpenMP team, kept
//   and released (base/parallel.h, release_openmp_workers), side by side.
// sweep/<full or regional>/<kernel>/n: the implicit solver's factor solved with the column
//   sweeps against the gathered ones on each instruction set (sim/sparse_factor.h), side by side.
// assembly/<threads>/n: the implicit solver's matrix assembled on one thread and on two.
// unit_columns/<alone or together>/n: 64 unit columns of a simplicial factor (a contact patch's,
//   haptics/local_compliance.cpp) one at a time and kUnitLanes at a time, side by side.
//   voxelastic_bench_step [--benchmark_filter=...]   (OMP_NUM_THREADS sets the threads)
// Targets (issue): explicit step of the 128^3 sphere (~19k elements, ~270k entries) < 1 ms on
// 2 cores; ns/entry flat from 32^3 to 256^3; implicit 128^3 at dt = 1 ms in real time.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "base/error.h"
#include "base/parallel.h"
#include "bench/step_benchmark.h"
#include "model/gradational_builder.h"
#include "physics/calibration.h"
#include "physics/elements.h"
#include "sim/integrators.h"
#include "sim/projective_solver.h"
#include "sim/sparse_factor.h"
#include "sim/state.h"

namespace {

using namespace vx;

/// Calibrated sphere models, built once per size and element.
const std::shared_ptr<const PhysicsModel>& sphere(int n, ElementKind element = CalibrationOptions{}.element) {
  static std::map<std::pair<int, ElementKind>, std::shared_ptr<const PhysicsModel>> cache;
  auto it = cache.find({n, element});
  if (it == cache.end()) {
    const StepBenchmarkSettings defaults;
    auto model = std::make_shared<const Model>(build_model(make_sphere_grid(n)));
    CalibrationOptions opt;
    opt.element = element;
    it = cache.emplace(std::make_pair(n, element), make_physics_model(model, defaults.material, {}, opt)).first;
  }
  return it->second;
}

/// The benchmark scenario's state: the lowest cap of nodes fixed, under gravity.
SimState sphere_state(const std::shared_ptr<const PhysicsModel>& physics) {
  const Model& model = *physics->model;
  SimState s = make_state(physics);
  const double zmin = model.rest_positions.row(2).minCoeff();
  s.fix_nodes(nodes_in_box(model, Eigen::Vector3d::Constant(-1e30), Eigen::Vector3d(1e30, 1e30, zmin + 1.01)));
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  return s;
}

/// Threads, model size and the wall time `ns` (per step or pass) over elements and vertex
/// entries, in ns.
void size_counters(benchmark::State& bs, const Model& model, double ns) {
  bs.counters["threads"] = resolve_threads(0);
  bs.counters["elements"] = model.num_elements();
  bs.counters["entries"] = double(model.num_vertex_entries());
  bs.counters["ns_per_element"] = ns / model.num_elements();
  bs.counters["ns_per_entry"] = ns / double(model.num_vertex_entries());
}

void step(benchmark::State& bs, IntegratorKind kind, int n, ElementKind element = CalibrationOptions{}.element) {
  const auto& physics = sphere(n, element);
  const Model& model = *physics->model;
  SimState s = sphere_state(physics);
  IntegratorSettings is;
  is.kind = kind;
  is.time_step_s = kind == IntegratorKind::implicit ? 1e-3 : 0.5 * stable_time_step(*physics, kind);
  auto integ = make_integrator(is);
  integ->advance(s, 10);  // factorisation (implicit) and warm-up
  StepReport rep;
  std::int64_t fit_iterations = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (auto _ : bs) {
    rep = integ->step(s);
    fit_iterations += s.element_stats.rotation_iterations;
    if (s.failed()) {
      bs.SkipWithError(s.message.c_str());
      break;
    }
  }
  const double steps = double(std::max<benchmark::IterationCount>(1, bs.iterations()));
  const double step_ns =
      std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - t0).count() / steps;
  size_counters(bs, model, step_ns);
  // real-time factor dt / step
  bs.counters["dt_ms"] = is.time_step_s * 1e3;
  bs.counters["realtime_x"] = is.time_step_s * 1e9 / step_ns;
  if (kind == IntegratorKind::implicit) bs.counters["iterations"] = rep.iterations;
  // rotation fit iterations per element and step (explicit: those of the one element pass)
  bs.counters["fit_iterations"] = double(fit_iterations) / steps / model.num_elements();
}

/// Implicit steps with another thread's OpenMP team idle beside them, as the probe app's
/// physics runs beside its main thread, which loaded the scene with OpenMP (base/parallel.h,
/// release_openmp_workers): `idle_team` keeps that team, `released` lets its workers go first.
/// GNU OpenMP counts the idle workers; once they and the steps' own outnumber the cores, the
/// steps' waits stop spinning and each fork and barrier waits for a wake-up.
void beside_another_team(benchmark::State& bs, bool release, int n) {
  std::mutex m;
  std::condition_variable cv;
  bool ready = false, done = false;
  std::thread other([&] {
    std::vector<double> v(4096, 1.0);
    parallel_for(std::int64_t(v.size()), 256, 2, [&](std::int64_t b, std::int64_t e) {
      for (std::int64_t i = b; i < e; ++i) v[std::size_t(i)] *= 2.0;
    });
    if (release) (void)release_openmp_workers();
    {
      std::lock_guard lock(m);
      ready = true;
    }
    cv.notify_all();
    std::unique_lock lock(m);
    cv.wait(lock, [&] { return done; });
  });
  {
    std::unique_lock lock(m);
    cv.wait(lock, [&] { return ready; });
  }
  step(bs, IntegratorKind::implicit, n);
  {
    std::lock_guard lock(m);
    done = true;
  }
  cv.notify_all();
  other.join();
}

/// The element pass alone (elastic and damping forces of every element, as in an explicit
/// step), with the given kernel: the packed kernel against the reference side by side.
void element_pass(benchmark::State& bs, ElementKernel kernel, SimdLevel simd, int n,
                  ElementKind element = CalibrationOptions{}.element) {
  const auto& physics = sphere(n, element);
  const Model& model = *physics->model;
  SimState s = sphere_state(physics);
  IntegratorSettings is;
  is.kind = IntegratorKind::explicit_euler;
  is.time_step_s = 0.5 * stable_time_step(*physics, is.kind);
  // a deformed, moving state; the pass alternates between the positions of two successive
  // steps, so that the warm-started rotation fit does its work as in a running simulation
  auto integ = make_integrator(is);
  integ->advance(s, 9);
  const Eigen::Matrix3Xd previous = s.positions;
  integ->advance(s, 1);
  const Eigen::Matrix3Xd* positions[2] = {&previous, &s.positions};
  ElementPassOptions opt;
  opt.kernel = kernel;
  opt.simd = simd;
  ElementPassStats st;
  std::int64_t passes = 0, fit_iterations = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (auto _ : bs) {
    st = compute_element_forces(*physics, *positions[passes % 2], &s.velocities, s.rotations, s.scratch.entry_forces,
                                nullptr, opt, 0, s.scratch.element_pass);
    fit_iterations += st.rotation_iterations;
    ++passes;
    benchmark::ClobberMemory();
  }
  const double steps = double(std::max<benchmark::IterationCount>(1, bs.iterations()));
  const double pass_ns =
      std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - t0).count() / steps;
  size_counters(bs, model, pass_ns);
  // rotation fit iterations per element and pass (warm-started: about one Newton step)
  bs.counters["fit_iterations"] =
      double(fit_iterations) / double(std::max<std::int64_t>(1, passes)) / model.num_elements();
}

/// The implicit solver's factor of a sphere (30 ms steps, damped, the lowest cap fixed), once per
/// size: the solver's own, or (`as_patch`) factored as the probe app's contact patches are
/// (Eigen's simplicial LDL^T on an AMD ordering, haptics/local_compliance.cpp).
SparseFactor& sphere_factor(int n, bool as_patch = false) {
  static std::map<std::pair<int, bool>, std::unique_ptr<SparseFactor>> cache;
  auto& f = cache[{n, as_patch}];
  if (!f) {
    const auto& physics = sphere(n);
    const SimState s = sphere_state(physics);
    const NodeNumbering numbering = number_nodes(s.node_fixed);
    ProjectiveSetup setup;
    setup.time_step_s = 0.03;
    setup.damping = true;
    Eigen::SparseMatrix<double> a;
    assemble_projective_matrix(*physics, numbering, setup, a, nullptr);
    f = std::make_unique<SparseFactor>();
    if (!(as_patch ? f->compute(a, SparseFactor::Backend::eigen_amd) : f->compute(a)))
      throw Error("step benchmark: the sphere's matrix did not factor");
  }
  return *f;
}

/// One solve with the factor: the whole model (solve3), or a regional one (the free nodes within
/// 30 mm of the sphere's highest node awake; the right-hand side changed on them: the forward half on
/// their ancestors, the backward half on the closure), as the fast configuration's step does.
struct SweepVariant {
  SparseFactor::SweepKernel kernel;
  SimdLevel simd;
  int threads;  ///< the passes' threads (tree-parallel above 1)
};

void sweep(benchmark::State& bs, bool regional, const SweepVariant& v, int n) {
  SparseFactor& f = sphere_factor(n);
  f.set_sweep_kernel(v.kernel, v.simd);
  f.set_threads(v.threads);
  const auto& physics = sphere(n);
  const Model& model = *physics->model;
  const NodeNumbering numbering = number_nodes(sphere_state(physics).node_fixed);
  const int rows = f.size();
  Eigen::MatrixX3d b = Eigen::MatrixX3d::Random(rows, 3), x(rows, 3);
  f.solve3(b, x);
  std::vector<int> awake;
  Eigen::Index highest = 0;
  model.rest_positions.row(2).maxCoeff(&highest);
  const Eigen::Vector3d top = model.rest_positions.col(highest);
  for (int i = 0; i < rows; ++i)
    if ((model.rest_positions.col(numbering.free_nodes[std::size_t(i)]) - top).norm() < 30.0) awake.push_back(i);
  if (regional) f.set_partial_rows(awake);
  std::int64_t k = 0;
  for (auto _ : bs) {
    if (regional) {
      for (const int i : awake) b.row(i) *= 1.0 + 1e-3 * double(++k % 7);
      f.forward3_partial(b);
      f.backward3_partial({}, {}, x);
    } else {
      f.solve3(b, x);
    }
    benchmark::DoNotOptimize(x.data());
  }
  bs.counters["rows"] = rows;
  bs.counters["awake"] = regional ? double(awake.size()) : double(rows);
  bs.counters["closure_columns"] = regional ? double(f.partial_columns()) : double(rows);
  bs.counters["factor_nonzeros"] = double(f.nonzeros());
  bs.counters["widest_supernode"] = f.widest_supernode();
}

/// Unit columns of a sphere's implicit matrix factored as the probe app's contact patches are: the
/// 64 rows nearest the sphere's highest node (a contact's), solved one at a time (solve_unit) or
/// together (solve_units), as a new contact's columns are.
void unit_columns(benchmark::State& bs, bool together, int n) {
  SparseFactor& f = sphere_factor(n, true);
  const auto& physics = sphere(n);
  const Model& model = *physics->model;
  const NodeNumbering numbering = number_nodes(sphere_state(physics).node_fixed);
  const int rows = f.size();
  Eigen::Index highest = 0;
  model.rest_positions.row(2).maxCoeff(&highest);
  const Eigen::Vector3d top = model.rest_positions.col(highest);
  std::vector<std::pair<double, int>> by_distance;
  for (int i = 0; i < rows; ++i)
    by_distance.emplace_back((model.rest_positions.col(numbering.free_nodes[std::size_t(i)]) - top).norm(), i);
  std::sort(by_distance.begin(), by_distance.end());
  std::vector<int> contact;
  for (std::size_t k = 0; k < std::min<std::size_t>(64, by_distance.size()); ++k)
    contact.push_back(by_distance[k].second);
  std::vector<double> out(contact.size() * std::size_t(rows));
  for (auto _ : bs) {
    if (together) {
      f.solve_units(contact.data(), int(contact.size()), out.data(), std::size_t(rows));
    } else {
      for (std::size_t k = 0; k < contact.size(); ++k) f.solve_unit(contact[k], out.data() + k * std::size_t(rows));
    }
    benchmark::DoNotOptimize(out.data());
  }
  bs.counters["rows"] = rows;
  bs.counters["columns"] = double(contact.size());
  bs.counters["factor_nonzeros"] = double(f.nonzeros());
}

/// The implicit solver's matrix assembled (the first start's share before the ordering and the
/// factorisation) on `threads`.
void assembly(benchmark::State& bs, int threads, int n) {
  const auto& physics = sphere(n);
  const NodeNumbering numbering = number_nodes(sphere_state(physics).node_fixed);
  ProjectiveSetup setup;
  setup.time_step_s = 0.03;
  setup.damping = true;
  Eigen::SparseMatrix<double> a, coupling;
  for (auto _ : bs) {
    assemble_projective_matrix(*physics, numbering, setup, a, &coupling, threads);
    benchmark::DoNotOptimize(a.valuePtr());
  }
  bs.counters["threads"] = threads;
  bs.counters["rows"] = double(a.rows());
  bs.counters["nonzeros"] = double(a.nonZeros());
}

}  // namespace

int main(int argc, char** argv) {
  for (IntegratorKind kind :
       {IntegratorKind::explicit_euler, IntegratorKind::symplectic_euler, IntegratorKind::implicit})
    for (int n : {32, 64, 128, 256}) {
      if (kind == IntegratorKind::implicit && n > 128) continue;  // factorisation too large for the bench
      benchmark::RegisterBenchmark((std::string("step/") + to_string(kind) + "/" + std::to_string(n)).c_str(),
                                   [kind, n](benchmark::State& bs) { step(bs, kind, n); })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime()
          ->MinTime(0.5);
    }
  // implicit steps beside another thread's idle OpenMP team, kept and released, interleaved
  for (int n : {32, 64, 128})
    for (const bool release : {false, true})
      benchmark::RegisterBenchmark(
          (std::string("team/") + (release ? "released" : "idle_team") + "/" + std::to_string(n)).c_str(),
          [release, n](benchmark::State& bs) { beside_another_team(bs, release, n); })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime()
          ->MinTime(0.5);
  // the element pass with each kernel (the batched one with each instruction set this CPU
  // runs), interleaved per size so that they run under the same machine load (compare ratios,
  // not absolute times)
  struct Variant {
    ElementKernel kernel;
    SimdLevel simd;
  };
  std::vector<Variant> variants{{ElementKernel::reference, SimdLevel::automatic},
                                {ElementKernel::packed, SimdLevel::automatic}};
  for (SimdLevel simd : {SimdLevel::generic, SimdLevel::avx2, SimdLevel::avx512})
    if (simd_supported(simd)) variants.push_back({ElementKernel::batched, simd});
  for (int n : {32, 64, 128, 256})
    for (const Variant& v : variants) {
      std::string name = std::string("element_pass/") + to_string(v.kernel);
      if (v.kernel == ElementKernel::batched) name += std::string("_") + to_string(v.simd);
      benchmark::RegisterBenchmark((name + "/" + std::to_string(n)).c_str(),
                                   [v, n](benchmark::State& bs) { element_pass(bs, v.kernel, v.simd, n); })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime()
          ->MinTime(0.5);
    }
  // the paper's element against the hourglass one (element_modes.h): the element pass with the
  // packed kernel and the batched one (the widest instruction set), and a symplectic step,
  // interleaved per size
  for (int n : {32, 64, 128, 256})
    for (const ElementKind element : {ElementKind::paper, ElementKind::hourglass}) {
      const std::string tail = std::string("/") + to_string(element) + "/" + std::to_string(n);
      benchmark::RegisterBenchmark(("element/packed" + tail).c_str(),
                                   [element, n](benchmark::State& bs) {
                                     element_pass(bs, ElementKernel::packed, SimdLevel::automatic, n, element);
                                   })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime()
          ->MinTime(0.5);
      benchmark::RegisterBenchmark(("element/batched" + tail).c_str(),
                                   [element, n](benchmark::State& bs) {
                                     element_pass(bs, ElementKernel::batched, SimdLevel::automatic, n, element);
                                   })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime()
          ->MinTime(0.5);
      benchmark::RegisterBenchmark(
          ("element/step_symplectic" + tail).c_str(),
          [element, n](benchmark::State& bs) { step(bs, IntegratorKind::symplectic_euler, n, element); })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime()
          ->MinTime(0.5);
    }
  // the factor's sweeps: the column kernel against the gathered one on each instruction set,
  // interleaved per size and solve
  // and on the widest instruction set tree-parallel on 2 threads
  std::vector<SweepVariant> sweeps{{SparseFactor::SweepKernel::column, SimdLevel::generic, 1}};
  for (SimdLevel simd : {SimdLevel::generic, SimdLevel::avx2, SimdLevel::avx512})
    if (simd_supported(simd)) sweeps.push_back({SparseFactor::SweepKernel::gathered, simd, 1});
  sweeps.push_back({SparseFactor::SweepKernel::gathered, best_simd_level(), 2});
  for (int n : {64, 128})
    for (const bool regional : {false, true})
      for (const SweepVariant& v : sweeps) {
        std::string name =
            std::string("sweep/") + (regional ? "regional/" : "full/") + SparseFactor::to_string(v.kernel);
        if (v.kernel == SparseFactor::SweepKernel::gathered) name += std::string("_") + to_string(v.simd);
        if (v.threads > 1) name += std::string("_") + std::to_string(v.threads) + "threads";
        benchmark::RegisterBenchmark((name + "/" + std::to_string(n)).c_str(),
                                     [regional, v, n](benchmark::State& bs) { sweep(bs, regional, v, n); })
            ->Unit(benchmark::kMillisecond)
            ->UseRealTime()
            ->MinTime(0.5);
      }
  // a contact patch's unit columns one at a time and together, interleaved per size
  for (int n : {32, 64})
    for (const bool together : {false, true})
      benchmark::RegisterBenchmark(
          (std::string("unit_columns/") + (together ? "together" : "alone") + "/" + std::to_string(n)).c_str(),
          [together, n](benchmark::State& bs) { unit_columns(bs, together, n); })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime()
          ->MinTime(0.5);
  // the implicit solver's assembly on one thread and on two, interleaved per size
  for (int n : {64, 128, 256})
    for (const int threads : {1, 2})
      benchmark::RegisterBenchmark(("assembly/" + std::to_string(threads) + "threads/" + std::to_string(n)).c_str(),
                                   [threads, n](benchmark::State& bs) { assembly(bs, threads, n); })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime()
          ->MinTime(0.5);
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
