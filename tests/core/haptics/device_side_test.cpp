// The device side of a simulation (haptics/device_side.h): the device force inside a run (zero
// at every device update, its mean follows the raw mean), skipping changes no device force, the
// reset and the detaching, and the local contact models handed across threads.
#include "haptics/device_side.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <optional>
#include <thread>
#include <vector>

#include "base/error.h"
#include "base/parallel.h"
#include "support/sim_helpers.h"

using namespace vx;
using namespace vx::testing;

// The device force inside a run: zero at every device update, its mean follows the raw mean.
TEST(DeviceSide, DeviceForceZeroAtUpdatesMeanFollowsRaw) {
  auto phys = physics_of(block_model(20, 20, 10), 10.0);
  SimulationSettings s;
  s.integrator = symplectic(*phys);
  s.fixed_nodes = nodes_on_face(*phys->model, BoxFace::z_min);
  s.probes = {path_probe("ball", ProbeShape::sphere, 5.0,
                         {{0.0, {10, 10, 15.2}}, {0.2, {10, 10, 13.5}}, {0.5, {10, 10, 13.5}}})};
  DeviceForceSettings dev;
  dev.update_interval_s = 0.01;
  Simulation sim(phys, s);
  const DeviceSide device(sim, {dev, std::nullopt});
  double raw = 0, shaped = 0;
  int updates = 0, samples = 0;
  while (sim.time_s() < 0.5 - 0.5 * sim.dt_s()) {
    ASSERT_EQ(sim.step(), StepStatus::ok);
    const ProbeOutput& o = sim.probe(0);
    const DeviceOutput& d = device.output(0);
    if (d.pulse.start_s == o.time_s && sim.time_s() > 0) {
      EXPECT_EQ(d.shaped_force_n, Eigen::Vector3d::Zero()) << "at t = " << o.time_s;
      ++updates;
    }
    if (sim.time_s() > 0.3) {  // held: compare means
      raw += o.raw_force_n.z();
      shaped += d.shaped_force_n.z();
      ++samples;
    }
  }
  EXPECT_GE(updates, 48);
  EXPECT_GT(raw / samples, 0.01);
  EXPECT_NEAR(shaped / raw, 1.0, 0.02);
  EXPECT_EQ(device.counters().device_shaping_steps, sim.counters().steps);
  // the device thread's copy is the last step's
  EXPECT_EQ(device.output_snapshot(0).shaped_force_n, device.output(0).shaped_force_n);
}

namespace {

/// Probes near and far, walls, friction and a device: every optional piece of work.
SimulationSettings busy_scene(const PhysicsModel& phys, bool skip) {
  SimulationSettings s;
  s.integrator = symplectic(phys);
  s.integrator.threads = 1;
  s.gravity_mm_s2 = {0, 0, -kStandardGravityMmS2};
  s.workspace.enabled = true;
  s.workspace.min_mm = {-5, -5, 0};
  s.workspace.max_mm = {17, 17, 30};
  s.contact.friction = 0.3;
  ProbeSettings cap = path_probe("rod", ProbeShape::capsule, 2.0, {{0.0, {6, 6, 14}}, {0.05, {6, 6, 10.5}}});
  cap.geometry.length_mm = 20;
  s.probes = {cap, path_probe("far", ProbeShape::sphere, 2.0, {{0.0, {40, 40, 40}}})};
  s.skip_unneeded = skip;
  return s;
}

DeviceSideSettings device_every(double interval_s) {
  DeviceSideSettings d;
  d.device = DeviceForceSettings{};
  d.device->update_interval_s = interval_s;
  return d;
}

}  // namespace

TEST(DeviceSide, SkippingChangesNoDeviceForce) {
  auto phys = physics_of(block_model(12, 12, 12), 10.0);
  Simulation lean(phys, busy_scene(*phys, true)), full(phys, busy_scene(*phys, false));
  const DeviceSide lean_device(lean, device_every(0.005)), full_device(full, device_every(0.005));
  // without a device the lean run shapes nothing, the full one every probe every step
  Simulation bare(phys, busy_scene(*phys, true)), bare_full(phys, busy_scene(*phys, false));
  const DeviceSide none(bare, {}), none_full(bare_full, {});
  double max_shaped = 0;
  for (int k = 0; k < 300; ++k) {
    for (Simulation* s : {&lean, &full, &bare, &bare_full}) ASSERT_EQ(s->step(), StepStatus::ok);
    max_shaped = std::max(max_shaped, lean_device.output(0).shaped_force_n.norm());
    for (int p = 0; p < 2; ++p) {
      ASSERT_EQ(lean.probe(p).raw_force_n, full.probe(p).raw_force_n) << "step " << k;
      ASSERT_EQ(lean_device.output(p).shaped_force_n, full_device.output(p).shaped_force_n) << "step " << k;
      ASSERT_EQ(none.output(p).shaped_force_n, Eigen::Vector3d::Zero());
      ASSERT_EQ(none_full.output(p).shaped_force_n, Eigen::Vector3d::Zero());  // shaped, not played
    }
  }
  EXPECT_GT(max_shaped, 0.0);
  EXPECT_EQ(lean_device.counters().device_shaping_steps, 600);
  EXPECT_EQ(none.counters().device_shaping_steps, 0);
  EXPECT_EQ(none.counters().device_shaping_skipped, 600);
  EXPECT_EQ(none_full.counters().device_shaping_steps, 600);
  EXPECT_TRUE(lean_device.has_device());
  EXPECT_FALSE(none.has_device());
}

TEST(DeviceSide, ResetClearsTheDeviceForceAndDetachingLeavesThePhysics) {
  auto phys = physics_of(block_model(12, 12, 12), 10.0);
  Simulation a(phys, busy_scene(*phys, true)), b(phys, busy_scene(*phys, true));
  {
    const DeviceSide device(a, device_every(0.005));
    double max_shaped = 0;
    for (int k = 0; k < 200; ++k) {
      ASSERT_EQ(a.step(), StepStatus::ok);
      ASSERT_EQ(b.step(), StepStatus::ok);
      max_shaped = std::max(max_shaped, device.output(0).shaped_force_n.norm());
    }
    ASSERT_GT(max_shaped, 0.0);
    EXPECT_EQ(a.state().positions, b.state().positions);  // the device side changes no physics
    a.reset();
    b.reset();
    EXPECT_EQ(device.output(0).shaped_force_n, Eigen::Vector3d::Zero());
    EXPECT_EQ(device.output_snapshot(0).pulse.duration_s, 0.0);
  }
  // the device side gone, the simulation steps on as one that never had one
  for (int k = 0; k < 200; ++k) {
    ASSERT_EQ(a.step(), StepStatus::ok);
    ASSERT_EQ(b.step(), StepStatus::ok);
  }
  EXPECT_EQ(a.state().positions, b.state().positions);
  EXPECT_EQ(a.probe(0).raw_force_n, b.probe(0).raw_force_n);
}

TEST(DeviceSide, BadSettingsAreRefused) {
  auto phys = physics_of(block_model(6, 6, 6), 10.0);
  Simulation sim(phys, busy_scene(*phys, true));
  DeviceSideSettings bad = device_every(-1.0);
  EXPECT_THROW(DeviceSide(sim, bad), Error);
  DeviceSideSettings lc;
  lc.local_contact = LocalContactSettings{};
  lc.local_contact->horizon_s = 0.0;
  EXPECT_THROW(DeviceSide(sim, lc), Error);
  DeviceSide none(sim, {});
  LocalContactModel m;
  EXPECT_THROW(none.build_local_contact(0, m), Error);  // no local contact settings
  EXPECT_EQ(none.take_local_contact(0), nullptr);
}

// The probe app's hand-over: a physics thread steps and publishes a model per update while a
// device thread takes them (haptics/device_side.h, "any thread"). Every model the device sees is
// whole (valid, one update's anchor force exactly, the newest: updates only go up) and the last
// one published reaches it. scripts/tsan.sh runs this under ThreadSanitizer.
TEST(DeviceSide, LocalContactModelsAcrossThreads) {
  auto phys = physics_of(block_model(16, 16, 8), 5.0);
  const double tp = 1.0 / 60.0;
  SimulationSettings s;
  s.integrator.kind = IntegratorKind::implicit;
  s.integrator.time_step_s = tp;
  s.integrator.threads = 1;
  s.fixed_nodes = nodes_on_face(*phys->model, BoxFace::z_min);
  ProbeSettings probe;
  probe.name = "tool";
  probe.geometry.radius_mm = 4;
  probe.drive = ProbeDrive::live;
  probe.start_mm = {8, 8, 12.3};
  probe.max_speed_mm_s = 500;
  s.probes = {probe};
  DeviceSideSettings ds;
  ds.local_contact = LocalContactSettings{};
  ds.local_contact->update_period_s = tp;
  Simulation sim(phys, s);
  DeviceSide side(sim, ds);
  constexpr int kUpdates = 40;
  // physics thread: press 2 mm over the updates; what each update published, by update number
  std::vector<Eigen::Vector3d> published(kUpdates + 1, Eigen::Vector3d::Zero());
  std::vector<int> published_size(kUpdates + 1, 0);
  std::atomic<bool> done{false};
  std::thread physics([&] {
    const Eigen::Vector3d from = sim.probe(0).pose.position_mm, to(8, 8, 10.0);
    for (int k = 1; k <= kUpdates; ++k) {
      sim.set_live(0, {LiveCommand::Kind::position, from + (to - from) * (double(k) / kUpdates)});
      if (sim.step() != StepStatus::ok) break;
      side.publish_local_contact();
      LocalContactModel check;
      side.build_local_contact(0, check);
      published[std::size_t(k)] = check.anchor_force_n;
      published_size[std::size_t(k)] = check.size();
      std::this_thread::sleep_for(std::chrono::microseconds(200));  // let the device thread interleave
    }
    done.store(true, std::memory_order_release);
  });
  // device thread (this one): take what is new, solve at the anchor
  struct Seen {
    std::int64_t update;
    bool valid;
    Eigen::Vector3d anchor_force_n, solved_n;
    int size;
  };
  std::vector<Seen> seen;
  seen.reserve(kUpdates + 1);
  LocalContactSolver solver;
  const auto take = [&] {
    const LocalContactModel* m = side.take_local_contact(0);
    if (!m) return;
    EXPECT_EQ(m->validate(), "") << "update " << m->update;
    Eigen::Vector3d solved = Eigen::Vector3d::Zero();
    if (m->valid && solver.set(*m, 0.0)) solved = solver.solve(m->anchor_mm).force_n;
    seen.push_back({m->update, m->valid, m->anchor_force_n, solved, m->size()});
  };
  while (!done.load(std::memory_order_acquire)) {
    take();
    std::this_thread::yield();
  }
  physics.join();
  take();
  ASSERT_EQ(side.local_contact_updates(), kUpdates);
  ASSERT_FALSE(seen.empty());
  EXPECT_EQ(seen.back().update, kUpdates);  // the newest reached the device
  std::int64_t last = -1;
  int in_contact = 0;
  for (const Seen& x : seen) {
    ASSERT_GT(x.update, last);  // never an older model after a newer one
    // the construction's "no model yet" (DeviceSide::after_reset), when taken before update 1
    if (x.update == 0) {
      EXPECT_FALSE(x.valid);
      EXPECT_EQ(x.size, 0);
      last = 0;
      continue;
    }
    EXPECT_TRUE(x.valid) << "update " << x.update;
    ASSERT_LE(x.update, kUpdates);
    last = x.update;
    EXPECT_EQ(x.anchor_force_n, published[std::size_t(x.update)]) << "update " << x.update;
    EXPECT_EQ(x.size, published_size[std::size_t(x.update)]) << "update " << x.update;
    if (x.anchor_force_n.norm() > 0) {
      ++in_contact;
      EXPECT_LT((x.solved_n - x.anchor_force_n).norm(), 1e-9 * x.anchor_force_n.norm() + 1e-12)
          << "update " << x.update;
    }
  }
  EXPECT_GT(published[kUpdates].z(), 0.0);  // the tool pressed (force on the tool upwards)
  EXPECT_GT(in_contact, 0);
  std::printf("%zu of %d updates taken by the device thread, %d in contact; last force %.4f N\n", seen.size(), kUpdates,
              in_contact, published[kUpdates].z());
}

// The local model's scan of the surface for candidates runs in chunks on the physics' threads:
// a tool that touches nodes of several chunks gets the same model, node for node and bit for bit,
// on one thread and on two (the chunks' finds appended in chunk order).
TEST(DeviceSide, TheLocalModelIsTheSameOnOneThreadAndOnTwo) {
  auto phys = physics_of(block_model(48, 48, 16), 5.0);
  SimulationSettings s;
  s.integrator.kind = IntegratorKind::implicit;
  s.integrator.time_step_s = 0.01;
  s.integrator.threads = 1;
  s.fixed_nodes = nodes_on_face(*phys->model, BoxFace::z_min);
  ProbeSettings probe;
  probe.name = "tool";
  probe.geometry.radius_mm = 12;
  probe.drive = ProbeDrive::live;
  probe.start_mm = {24, 24, 28.5};  // over the top face's centre, 0.5 mm above it
  s.probes = {probe};
  DeviceSideSettings ds;
  ds.local_contact = LocalContactSettings{};
  ds.local_contact->margin_mm = 2.0;
  Simulation sim(phys, s);
  DeviceSide side(sim, ds);
  const std::vector<std::int32_t>& surface = sim.contact_solver().nodes();
  ASSERT_GE(std::int64_t(surface.size()), 2 * DeviceSide::kLocalScanGrain);  // a scan that forks
  LocalContactModel one, two;
  {
    ScopedThreads scope;
    scope.set(1);
    side.build_local_contact(0, one);
  }
  {
    ScopedThreads scope;
    scope.set(2);
    side.build_local_contact(0, two);
  }
  ASSERT_GT(one.size(), 20);
  // the candidates come from more than one chunk of the scan
  std::vector<std::int64_t> chunk_of(std::size_t(phys->num_nodes()), -1);
  for (std::size_t k = 0; k < surface.size(); ++k)
    chunk_of[std::size_t(surface[k])] = std::int64_t(k) / DeviceSide::kLocalScanGrain;
  std::int64_t lo = 1 << 30, hi = -1;
  for (const std::int32_t n : one.node) {
    ASSERT_GE(chunk_of[std::size_t(n)], 0) << "node " << n << " is not a surface node";
    lo = std::min(lo, chunk_of[std::size_t(n)]);
    hi = std::max(hi, chunk_of[std::size_t(n)]);
  }
  EXPECT_LT(lo, hi);
  // fewer candidates than the model holds, so none was dropped: they come in the scan's order
  ASSERT_LT(one.size(), ds.local_contact->max_nodes);
  std::vector<std::int64_t> at(std::size_t(phys->num_nodes()), -1);
  for (std::size_t k = 0; k < surface.size(); ++k) at[std::size_t(surface[k])] = std::int64_t(k);
  for (int k = 1; k < one.size(); ++k)
    EXPECT_LT(at[std::size_t(one.node[std::size_t(k - 1)])], at[std::size_t(one.node[std::size_t(k)])]) << k;
  // every candidate is within the margin of the tool (a ball 0.5 mm above the face: its nodes at
  // a gap of 0.5 to 2 mm)
  for (int k = 0; k < one.size(); ++k) {
    EXPECT_GE(one.gap_mm[k], 0.5 - 1e-9);
    EXPECT_LT(one.gap_mm[k], 2.0);
  }
  EXPECT_EQ(one.node, two.node);
  EXPECT_EQ(one.point_mm, two.point_mm);
  EXPECT_EQ(one.normal, two.normal);
  EXPECT_EQ(one.gap_mm, two.gap_mm);
  EXPECT_EQ(one.compliance, two.compliance);
}
