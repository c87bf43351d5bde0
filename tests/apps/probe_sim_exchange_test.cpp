// The hand-off between the probe app's physics thread and its other loops (sim_exchange.h): a
// physics thread steps while an input thread moves a live probe and a device thread reads the
// force and asks for frames; commands reach the simulation, outputs and frames come back.
#include "sim_exchange.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <thread>

#include "base/error.h"
#include "support/sim_helpers.h"

using namespace vx;
using namespace vx::probe;
using namespace vx::testing;

TEST(SimulationExchange, LiveProbeAcrossThreads) {
  auto phys = physics_of(block_model(12, 12, 6), 10.0);
  Simulation sim(phys, live_press_settings(*phys));
  SimulationExchange exchange(sim);
  EXPECT_THROW(exchange.set_live(3, {}), Error);
  EXPECT_THROW(exchange.set_live(1, {}), Error);                              // driven by its path
  EXPECT_EQ(exchange.probe(0).pose.position_mm, Eigen::Vector3d(6, 6, 9.5));  // published at the start

  std::atomic<bool> done{false}, sent{false};
  std::thread physics([&] {
    // 400 steps, as the physics loop takes them; it starts once the input thread has sent its
    // command (on a loaded machine the steps could otherwise all run before it arrives)
    while (!sent) std::this_thread::yield();
    for (int k = 0; k < 400; ++k) {
      exchange.apply_live(sim);
      sim.step();
      exchange.publish(sim);
    }
    done = true;
  });
  // input thread: press down; the device thread reads forces and asks for frames meanwhile. The
  // first frame is asked for before the physics starts, and the loop reads once more after the
  // physics has ended: on a loaded machine its 400 steps could otherwise all run before this
  // thread's loop reads anything (a flaky run: no frame, no force)
  exchange.set_live(0, {LiveCommand::Kind::position, {6, 6, 7.0}});
  exchange.request_frame();
  sent = true;
  double seen = 0;
  int frames = 0;
  SimulationFrame frame;
  for (bool ended = false; !ended;) {
    ended = done;  // this pass reads what the physics published up to here, its last step too
    seen = std::max(seen, exchange.probe(0).raw_force_n.z());
    exchange.request_frame();
    if (exchange.take_frame(frame)) {
      ++frames;
      EXPECT_EQ(frame.positions.cols(), phys->model->num_nodes());
      EXPECT_EQ(frame.probes.size(), 2u);
    }
    std::this_thread::yield();
  }
  physics.join();
  EXPECT_EQ(sim.steps(), 400);
  const ProbeOutput o = exchange.probe(0);
  EXPECT_GT(o.raw_force_n.z(), 0.0);               // the last step's, still pressing
  EXPECT_NEAR(o.pose.position_mm.z(), 7.0, 1e-9);  // reached the target at <= 50 mm/s
  EXPECT_EQ(o.time_s, sim.time_s());               // the last step's
  EXPECT_GT(seen, 0.0);
  EXPECT_GT(exchange.frames_published(), 0);
  EXPECT_GE(exchange.frames_published(), frames);
}

TEST(SimulationExchange, AFrameOnlyWhenAskedAndTakenOnce) {
  auto phys = physics_of(block_model(6, 6, 4), 10.0);
  Simulation sim(phys, live_press_settings(*phys));
  SimulationExchange exchange(sim);
  SimulationFrame frame;
  sim.step();
  exchange.publish(sim);
  EXPECT_FALSE(exchange.take_frame(frame));  // nobody asked
  EXPECT_EQ(exchange.frames_published(), 0);
  exchange.request_frame();
  sim.step();
  exchange.publish(sim);
  ASSERT_TRUE(exchange.take_frame(frame));
  EXPECT_EQ(frame.step, 2);
  EXPECT_EQ(frame.positions, sim.state().positions);
  EXPECT_FALSE(exchange.take_frame(frame));  // taken
  // without the node positions (a display that draws the surface only): the rest of the frame
  exchange.request_frame(false);
  sim.step();
  exchange.publish(sim);
  ASSERT_TRUE(exchange.take_frame(frame));
  EXPECT_EQ(frame.step, 3);
  EXPECT_EQ(frame.positions.cols(), 0);
  ASSERT_EQ(frame.probes.size(), 2u);
  EXPECT_EQ(frame.probes[0].pose.position_mm, sim.probe(0).pose.position_mm);
  // and with them again, into the buffers the frames went through
  exchange.request_frame(true);
  sim.step();
  exchange.publish(sim);
  ASSERT_TRUE(exchange.take_frame(frame));
  EXPECT_EQ(frame.step, 4);
  EXPECT_EQ(frame.positions, sim.state().positions);
  // a command waits for apply_live: the simulation has not seen it before
  exchange.set_live(0, {LiveCommand::Kind::velocity, {0, 0, -20}});
  sim.step();
  EXPECT_EQ(sim.probe(0).pose.velocity_mm_s.z(), 0.0);
  exchange.apply_live(sim);
  sim.step();
  EXPECT_LT(sim.probe(0).pose.velocity_mm_s.z(), 0.0);
}

// The display surface swapped while the simulation runs (the probe app's preview replaced by the
// decimated surface: SimulationExchange::offer_surface, Simulation::set_surface): the frame of the
// publish after the offer deforms the new surface and carries it (its triangles for the view);
// the ones before carry the old. A surface of another model is refused and the old one kept.
TEST(SimulationExchange, AnOfferedSurfaceIsDeformedFromTheNextPublishOnAndTheFrameCarriesIt) {
  auto phys = physics_of(block_model(6, 6, 4), 10.0);
  const Model& model = *phys->model;
  // the top face as two triangles, then as a fan of four around its centre
  Eigen::Matrix3Xd two(3, 4), four(3, 5);
  two << 0, 6, 6, 0, 0, 0, 6, 6, 4, 4, 4, 4;
  Eigen::Matrix3Xi two_t(3, 2), four_t(3, 4);
  two_t << 0, 0, 1, 2, 2, 3;
  four << 0, 6, 6, 0, 3, 0, 0, 6, 6, 3, 4, 4, 4, 4, 4;
  four_t << 0, 1, 2, 3, 1, 2, 3, 0, 4, 4, 4, 4;
  auto first = std::make_shared<const EmbeddedSurface>(embed_surface(model, two, two_t, SurfaceMethod::iso));
  auto second = std::make_shared<const EmbeddedSurface>(embed_surface(model, four, four_t, SurfaceMethod::iso));
  SimulationSettings settings = live_press_settings(*phys);
  settings.surface = first;
  Simulation sim(phys, settings);
  SimulationExchange exchange(sim);
  SimulationFrame frame;
  // a display's frame: asked for (the surface only), one step, published
  const auto step_and_publish = [&] {
    exchange.request_frame(false);
    sim.step();
    exchange.publish(sim);
  };
  step_and_publish();
  ASSERT_TRUE(exchange.take_frame(frame));
  EXPECT_EQ(frame.surface, first);
  EXPECT_EQ(frame.surface_vertices.cols(), 4);

  exchange.offer_surface(second);
  EXPECT_EQ(exchange.surfaces_taken(), 0);  // not before the physics publishes
  step_and_publish();
  EXPECT_EQ(exchange.surfaces_taken(), 1);
  ASSERT_TRUE(exchange.take_frame(frame));
  EXPECT_EQ(frame.surface, second);
  ASSERT_EQ(frame.surface_vertices.cols(), 5);
  ASSERT_EQ(frame.surface_normals.cols(), 5);
  Eigen::Matrix3Xd expected;
  deform_vertices(*second, sim.state().positions, expected);
  EXPECT_LT((frame.surface_vertices - expected).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_EQ(sim.surface_vertices().cols(), 5);

  // a surface of another model: refused, the simulation keeps its own
  auto other_model = block_model(5, 5, 4);
  auto other = std::make_shared<const EmbeddedSurface>(embed_surface(*other_model, two, two_t, SurfaceMethod::iso));
  EXPECT_THROW(sim.set_surface(other), Error);
  EXPECT_EQ(sim.surface_vertices().cols(), 5);
  // and none: frames without a surface
  sim.set_surface(nullptr);
  step_and_publish();
  ASSERT_TRUE(exchange.take_frame(frame));
  EXPECT_EQ(frame.surface, nullptr);
  EXPECT_EQ(frame.surface_vertices.cols(), 0);
}
