// The CI soak's organ (tests/apps/probe_soak_slow_test.cpp: the folded phantom at 4.3 mm voxels,
// the probe app's palpation defaults, the fast configuration) outside the app, to measure what
// the soak judges at Poisson 0.45 (issue 27): how fast the tissue comes back to rest after a
// press, and the local contact model's patch compliance's memory as the tool moves.
// Measurements (--gtest_also_run_disabled_tests): DISABLED_Measure with VX_RELEASE_NU,
// VX_RELEASE_ITERATIONS, VX_RELEASE_TOL_MM, VX_RELEASE_RES_N, VX_RELEASE_FREE_ITERATIONS,
// VX_RELEASE_FREE_TOL_MM (the implicit integrator's settings); DISABLED_PatchMemory with
// VX_RELEASE_MOVES, VX_RELEASE_TRIM (malloc_trim after each), VX_RELEASE_MMAP_THRESHOLD (mallopt),
// VX_RELEASE_MODEL (another organ: a .vtu or a volume), VX_RELEASE_RADIUS (the patch radius, mm).
#include <gtest/gtest.h>
#include <malloc.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "convert/phantom.h"
#include "haptics/local_compliance.h"
#include "io/volume_io.h"
#include "probe_scene.h"
#include "sim/simulation.h"

using namespace vx;
using namespace vx::probe;

namespace {

double env(const char* name, double fallback) {
  const char* v = std::getenv(name);
  return v ? std::atof(v) : fallback;
}

/// The soak's organ as the probe app loads it (headless) at Poisson `nu`.
ProbeScene soak_organ(double nu) {
  DefaultSceneOptions o;
  o.poisson_ratio = nu;
  o.display = false;
  // another organ (a .vtu or a volume)
  if (const char* model = std::getenv("VX_RELEASE_MODEL")) return load_probe_scene(model, o);
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("vx_probe_release_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  PhantomSettings ph;
  ph.name = "folded";
  ph.size = 50;
  ph.spacing_mm = 4.3;
  write_volume(make_phantom(ph), dir / "folded.nrrd");
  ProbeScene scene = load_probe_scene(dir / "folded.nrrd", o);
  std::filesystem::remove_all(dir);
  return scene;
}

/// A contact of `m` free surface nodes: the nearest to surface node `c` (rest positions).
std::vector<std::int32_t> contact_around(const Simulation& sim, std::int32_t c, int m) {
  const Eigen::Matrix3Xd& rest = sim.physics().model->rest_positions;
  std::vector<std::pair<double, std::int32_t>> near;
  for (const std::int32_t n : sim.contact_solver().nodes())
    if (!sim.state().node_fixed[std::size_t(n)]) near.push_back({(rest.col(n) - rest.col(c)).norm(), n});
  std::partial_sort(near.begin(), near.begin() + m, near.end());
  std::vector<std::int32_t> nodes;
  for (int i = 0; i < m; ++i) nodes.push_back(near[std::size_t(i)].second);
  return nodes;
}

double largest_distance_mm(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  return (a - b).colwise().norm().maxCoeff();
}

struct Release {
  double press_mm{0};            ///< the largest node displacement during the press
  std::vector<double> share;     ///< the largest node distance from rest / press_mm at kTimes
  double press_step_ms{0};       ///< mean wall time of a step in contact
  double release_step_ms{0};     ///< mean wall time of a step after the release
  double press_iterations{0};    ///< mean local/global iterations per step in contact
  double release_iterations{0};  ///< the same after the release
};

constexpr double kTimes[] = {0.5, 1, 2, 4, 6, 8, 10.5};

/// The tool pressed down 3 mm past first contact at 4 mm/s, held 1 s, lifted at 5 mm/s; the
/// largest node distance from the rest shape after the lift starts.
Release press_and_release(const ProbeScene& scene, const IntegratorSettings& integrator) {
  SimulationSettings s = scene.simulation;
  s.integrator = integrator;
  Simulation sim(scene.physics, s);
  const Eigen::Matrix3Xd rest = sim.state().positions;
  const Eigen::Vector3d down(0, 1, 0);  // the palpation defaults' up is anterior (-y)
  Eigen::Vector3d target = sim.probe(0).pose.position_mm;
  const double dt = sim.dt_s();
  Release r;
  using clock = std::chrono::steady_clock;
  int press_steps = 0, release_steps = 0;
  auto step = [&](bool release) {
    sim.set_live(0, {LiveCommand::Kind::position, target});
    const auto t0 = clock::now();
    const std::int64_t before = sim.counters().iterations;
    sim.step();
    const double ms = std::chrono::duration<double, std::milli>(clock::now() - t0).count();
    const double its = double(sim.counters().iterations - before);
    if (release) {
      r.release_step_ms += ms;
      r.release_iterations += its;
      ++release_steps;
    } else if (!sim.step_contacts().empty()) {
      r.press_step_ms += ms;
      r.press_iterations += its;
      ++press_steps;
    }
    r.press_mm = std::max(r.press_mm, largest_distance_mm(sim.state().positions, rest));
  };
  // down to first contact, then 3 mm more
  for (int k = 0; k < 4000 && sim.step_contacts().empty(); ++k) {
    target += 4.0 * dt * down;
    step(false);
  }
  for (double d = 0; d < 3.0; d += 4.0 * dt) {
    target += 4.0 * dt * down;
    step(false);
  }
  for (double t = 0; t < 1.0; t += dt) step(false);
  const double release_s = sim.time_s();
  std::size_t next = 0;
  while (next < std::size(kTimes)) {
    if (sim.time_s() - release_s < 2.0) target -= 5.0 * dt * down;
    step(true);
    if (sim.time_s() - release_s >= kTimes[next] - 0.5 * dt) {
      r.share.push_back(largest_distance_mm(sim.state().positions, rest) / r.press_mm);
      ++next;
    }
  }
  r.press_step_ms /= std::max(1, press_steps);
  r.press_iterations /= std::max(1, press_steps);
  r.release_step_ms /= std::max(1, release_steps);
  r.release_iterations /= std::max(1, release_steps);
  return r;
}

long resident_kb() {
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  long pages = 0, resident = 0;
  if (f && std::fscanf(f, "%ld %ld", &pages, &resident) != 2) resident = 0;
  if (f) std::fclose(f);
  return resident * (sysconf(_SC_PAGESIZE) / 1024);
}

}  // namespace

// Issue 27: at Poisson 0.45 the fast configuration's one local/global iteration per step let the
// organ come back to rest slowly (the projective matrix holds the volume term on every gradient
// component); with its iterations while no tool touches (IntegratorSettings::free_iterations) it
// is back within 1 % of the press 4 s after the release, and the steps in contact still take one
// iteration. Measured (docs/model.md section 5, "The return to rest"): 3.43 % at 4 s with one
// iteration, 0.14 % with the free iterations (0.14 % at Poisson 0 with one).
TEST(ProbeRelease, ThePressedOrganComesBackToRestAtPoisson045) {
  const ProbeScene scene = soak_organ(0.45);
  ASSERT_EQ(scene.simulation.integrator.max_iterations, 1);
  ASSERT_GT(scene.simulation.integrator.free_iterations, 1);
  const Release now = press_and_release(scene, scene.simulation.integrator);
  IntegratorSettings one = scene.simulation.integrator;
  one.free_iterations = 0;
  const Release before = press_and_release(scene, one);
  for (const Release* r : {&before, &now}) {
    std::printf("%s: press %.3f mm; from rest at", r == &now ? "free iterations" : "one iteration", r->press_mm);
    for (std::size_t k = 0; k < r->share.size(); ++k) std::printf(" %.1f s %.3f %%,", kTimes[k], 100 * r->share[k]);
    std::printf(" iterations per step in contact %.2f, after the release %.2f\n", r->press_iterations,
                r->release_iterations);
  }
  ASSERT_EQ(now.share.size(), std::size(kTimes));
  EXPECT_GT(now.press_mm, 0.5);
  EXPECT_LT(now.share[3], 0.01) << "4 s after the release";
  EXPECT_LT(now.share[4], 0.005) << "6 s after the release";
  EXPECT_GT(before.share[3], 0.01) << "with one iteration (the cause)";
  EXPECT_EQ(now.press_iterations, 1.0) << "the steps in contact cost what they cost";
  EXPECT_GT(now.release_iterations, 2.0);
}

TEST(ProbeRelease, DISABLED_Measure) {
  const double nu = env("VX_RELEASE_NU", 0.45);
  const ProbeScene scene = soak_organ(nu);
  IntegratorSettings in = scene.simulation.integrator;
  in.max_iterations = int(env("VX_RELEASE_ITERATIONS", in.max_iterations));
  in.tolerance_mm = env("VX_RELEASE_TOL_MM", in.tolerance_mm);
  in.residual_tolerance_n = env("VX_RELEASE_RES_N", in.residual_tolerance_n);
  in.free_iterations = int(env("VX_RELEASE_FREE_ITERATIONS", in.free_iterations));
  in.free_tolerance_mm = env("VX_RELEASE_FREE_TOL_MM", in.free_tolerance_mm);
  const Release r = press_and_release(scene, in);
  std::printf(
      "nu %.2f, iterations %d, tolerance %g mm, residual %g N, free iterations %d, free tolerance %g mm: "
      "press %.3f mm; from rest at",
      nu, in.max_iterations, in.tolerance_mm, in.residual_tolerance_n, in.free_iterations, in.free_tolerance_mm,
      r.press_mm);
  for (std::size_t k = 0; k < r.share.size(); ++k) std::printf(" %.1f s %.3f %%,", kTimes[k], 100 * r.share[k]);
  std::printf("\n  step in contact %.1f ms (%.2f iterations), after the release %.1f ms (%.2f iterations)\n",
              r.press_step_ms, r.press_iterations, r.release_step_ms, r.release_iterations);
}

// The patch compliance's memory as the contact moves over the organ (the soak's tool radius 4 mm:
// the automatic patch radius max(6 x 4, 12 x the surface node spacing)).
TEST(ProbeRelease, DISABLED_PatchMemory) {
  if (const double t = env("VX_RELEASE_MMAP_THRESHOLD", 0); t > 0) mallopt(M_MMAP_THRESHOLD, int(t));
  const ProbeScene scene = soak_organ(0.45);
  const PhysicsModel& p = *scene.physics;
  Simulation sim(scene.physics, scene.simulation);
  PatchCompliance pc;
  pc.init(scene.physics, sim.state().node_fixed, 0.1);
  const double radius = env("VX_RELEASE_RADIUS", std::max(24.0, 12.0 * surface_node_spacing_mm(*p.model)));
  const std::vector<std::int32_t>& surface = sim.contact_solver().nodes();
  std::mt19937 rng(1);
  Eigen::MatrixXd g;
  const int moves = int(env("VX_RELEASE_MOVES", 200));
  const long start_kb = resident_kb();
  double worst_ms = 0, total_ms = 0;
  for (int k = 0; k <= moves; ++k) {
    // a contact of up to 40 surface nodes around a random one
    const int c = surface[std::uniform_int_distribution<std::size_t>(0, surface.size() - 1)(rng)];
    const int m = std::uniform_int_distribution<int>(4, 40)(rng);
    const std::vector<std::int32_t> nodes = contact_around(sim, c, m);
    const auto t0 = std::chrono::steady_clock::now();
    ASSERT_TRUE(pc.compute(nodes, radius, g));
    const double ms = 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    worst_ms = std::max(worst_ms, ms);
    total_ms += ms;
    if (env("VX_RELEASE_TRIM", 0) > 0) malloc_trim(0);
    if (k % 20 == 0) {
      std::printf("move %d: %d contact nodes, %.1f ms (worst so far %.1f ms, mean %.1f ms)\n", k, m, ms, worst_ms,
                  total_ms / (k + 1));
      const struct mallinfo2 mi = mallinfo2();
      std::printf(
          "move %d: patch %d nodes, refactors %lld, columns %lld (cached %d, restarts %lld), cache %.2f MB, "
          "factor %.2f MB; resident %+ld kB, heap in use %.1f MB, arena %.1f MB, mmapped %.1f MB\n",
          k, pc.patch_nodes(), (long long)pc.refactors(), (long long)pc.columns_solved(), pc.cached_columns(),
          (long long)pc.cache_restarts(), 1e-6 * double(pc.cache_bytes()), 1e-6 * double(pc.factor().stored_bytes()),
          resident_kb() - start_kb, 1e-6 * double(mi.uordblks + mi.hblkhd), 1e-6 * double(mi.arena),
          1e-6 * double(mi.hblkhd));
    }
  }
}

// How much holding the patch's border stiffens the local contact model, on an organ
// (VX_RELEASE_MODEL) at Poisson 0.45: contacts of 40 surface nodes around random surface nodes,
// the stiffness of pressing them all 1 mm (1^T G^-1 1, N/mm) with patches of radius 12 to 48 mm,
// against the largest, and the time each patch took.
TEST(ProbeRelease, DISABLED_PatchRadius) {
  const ProbeScene scene = soak_organ(0.45);
  Simulation sim(scene.physics, scene.simulation);
  PatchCompliance pc;  // one per organ: each patch assembles its own block
  pc.init(scene.physics, sim.state().node_fixed, 0.1);
  const std::vector<std::int32_t>& surface = sim.contact_solver().nodes();
  std::mt19937 rng(3);
  const std::vector<double> radii{12, 16, 24, 36, 48};
  for (int k = 0; k < int(env("VX_RELEASE_MOVES", 5)); ++k) {
    const int c = surface[std::uniform_int_distribution<std::size_t>(0, surface.size() - 1)(rng)];
    const std::vector<std::int32_t> nodes = contact_around(sim, c, 40);
    std::vector<double> k_n_mm;
    std::string line;
    for (const double r : radii) {  // each radius a new patch of the one PatchCompliance
      Eigen::MatrixXd g;
      const auto t0 = std::chrono::steady_clock::now();
      ASSERT_TRUE(pc.compute(nodes, r, g));
      const double ms = 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      const Eigen::VectorXd ones = Eigen::VectorXd::Ones(g.rows());
      k_n_mm.push_back(ones.dot(g.ldlt().solve(ones)));
      line += " | " + std::to_string(int(r)) + " mm: " + std::to_string(pc.patch_nodes()) + " nodes, " +
              std::to_string(ms) + " ms, k " + std::to_string(k_n_mm.back());
    }
    std::printf("contact %d%s | stiffness over the 48 mm patch's:", k, line.c_str());
    for (const double kk : k_n_mm) std::printf(" %.3f", kk / k_n_mm.back());
    std::printf("\n");
  }
}
