#pragma once
/// @file commands.h
/// Each subcommand of the `voxelastic` command line registers itself on the app.
/// A subcommand's callback throws vx::Error for bad input; main() turns it into a message
/// and exit code 1; command-line mistakes (CLI11 parse errors, the checks of usage.h) exit 2.

#include <CLI/CLI.hpp>

#include "util/log.h"

namespace vx::cli {

/// -q, wherever it is on the line: main() sets the log level before any subcommand runs, so
/// a subcommand asks here instead of adding its own -q (which would hide the app's).
[[nodiscard]] inline bool quiet() { return !log::enabled(log::Level::info); }

void add_phantom_command(CLI::App& app);  ///< voxelastic phantom NAME -o OUT
void add_convert_command(CLI::App& app);  ///< voxelastic convert INPUT -o MODEL.vtu
void add_simulate_command(CLI::App& app); ///< voxelastic simulate SCENE.json --out DIR
void add_bench_command(CLI::App& app);    ///< voxelastic bench [--quick] [--out DIR] [--threads N]
void add_verify_command(CLI::App& app);   ///< voxelastic verify [--suite S] --out DIR, voxelastic verify-merge DIR... --out DIR
void add_palpate_map_command(CLI::App& app);  ///< voxelastic palpate-map INPUT --out DIR
void add_plot_command(CLI::App& app);         ///< voxelastic plot SPEC.json -o OUT.png

}  // namespace vx::cli
