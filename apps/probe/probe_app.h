#pragma once
/// @file probe_app.h
/// The palpation app's run (its options: app_options.h). Three rates, never waiting on each other, each a
/// class and file of its own:
/// - physics_loop.h (fixed tick, default 1 kHz): the simulation to the wall clock, in slow motion
///   when it cannot keep up; local shaping: one update per tick and a local contact model;
/// - device_loop.h (fixed tick, default 1 kHz): the sticks (or the script), the device force
///   (paper: half sines; local: the local contact model at every tick, the tool in wall time),
///   the force outputs;
/// - gui_loop.h (display rate): window events, the deformed surface, HUD, plot, screenshots, and
///   the figures it reports (real_time_meter.h).
/// What they hand each other is written down in app_shared.h; probe_app.cpp opens everything,
/// starts the threads and reports at the end.

#include "app_options.h"

namespace vx::probe {

/// Runs the app; returns the exit code. Throws vx::Error for bad input found before the run.
/// A session that quits while its solver is still being factored in the background (METIS or the
/// numeric factorisation, which cannot be cut short) does not wait for it: once every output is
/// written and the factor cache closed, the process ends here with the exit code (std::_Exit).
[[nodiscard]] int run_probe_app(const AppOptions& options);

}  // namespace vx::probe
