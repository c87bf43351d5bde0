// voxelastic: CT volumes to gradational-resolution elastic models, simulation, verification.
#include <fmt/core.h>

#include <cstdio>
#include <exception>
#include <string>
#include <vector>

#include "base/error.h"
#include "base/version.h"
#include "commands.h"
#include "physics/element_batches.h"
#include "usage.h"
#include "util/exit_codes.h"
#include "util/log.h"

int main(int argc, char** argv) {
  // stdout a line at a time: its notes and results come between the progress and warnings on
  // stderr; block-buffered into a pipe or a log, they all came after them, at the exit
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  CLI::App app{"voxelastic: CT volumes to gradational-resolution elastic models (units: mm, s, N, kPa, HU)"};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("voxelastic ") + vx::kVersion);
  // -q / -v anywhere on the line (subcommands inherit fallthrough): notes and progress at
  // info, hidden by -q; warnings and errors always on stderr; details at debug, shown by -v
  bool quiet = false, verbose = false;
  app.add_flag("-q,--quiet", quiet, "print only warnings and errors (on stderr) besides the results");
  app.add_flag("-v,--verbose", verbose, "also print details (debug level)");
  app.fallthrough();
  app.parse_complete_callback([&] {
    vx::log::set_level(verbose ? vx::log::Level::debug : quiet ? vx::log::Level::warn : vx::log::Level::info);
  });
  vx::cli::add_phantom_command(app);
  vx::cli::add_convert_command(app);
  vx::cli::add_simulate_command(app);
  vx::cli::add_verify_command(app);
  vx::cli::add_bench_command(app);
  vx::cli::add_palpate_map_command(app);
  vx::cli::add_plot_command(app);
  // long options with '_' for '-' too, as 3D Slicer writes them (convert --xml)
  const std::vector<std::string> args = vx::cli::hyphenated_long_options(argc, argv);
  std::vector<const char*> arg_ptrs;
  for (const std::string& a : args) arg_ptrs.push_back(a.c_str());
  const char* const* av = arg_ptrs.data();
  // a mistyped command is told as one, with the nearest command (CLI11 would say "A subcommand
  // is required")
  if (const std::string unknown = vx::cli::unknown_subcommand_message(app, argc, av); !unknown.empty()) {
    fmt::print(stderr, "voxelastic: {}\n", unknown);
    return vx::exit_code::usage;
  }
  try {
    (void)vx::best_simd_level();  // a bad VOXELASTIC_SIMD is an error here, not inside a worker
    app.parse(argc, av);
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; every usage mistake exits 2 (the convention of Unix tools),
    // with the nearest option for a typo
    if (app.exit(e) == 0) return vx::exit_code::ok;
    if (const std::string hint = vx::cli::option_suggestion(app, argc, av); !hint.empty())
      fmt::print(stderr, "voxelastic: {}\n", hint);
    return vx::exit_code::usage;
  } catch (const vx::NoDisplay& e) {
    fmt::print(stderr, "voxelastic: error: {}\n", e.what());
    return vx::exit_code::no_display;
  } catch (const vx::Interrupted& e) {
    fmt::print(stderr, "voxelastic: {}\n", e.what());
    return vx::exit_code::interrupted;
  } catch (const vx::Error& e) {
    fmt::print(stderr, "voxelastic: error: {}\n", e.what());
    return vx::exit_code::error;
  } catch (const std::exception& e) {
    fmt::print(stderr, "voxelastic: internal error: {} (please report this)\n", e.what());
    return vx::exit_code::internal;
  }
  return vx::exit_code::ok;
}
