// voxelastic: CT volumes to gradational-resolution elastic models, simulation, verification.
#include <fmt/core.h>

#include <exception>

#include "base/error.h"
#include "base/version.h"
#include "commands.h"
#include "physics/element_batches.h"

int main(int argc, char** argv) {
  CLI::App app{"voxelastic: CT volumes to gradational-resolution elastic models (units: mm, s, N, kPa, HU)"};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("voxelastic ") + vx::kVersion);
  vx::cli::add_phantom_command(app);
  vx::cli::add_convert_command(app);
  vx::cli::add_simulate_command(app);
  vx::cli::add_verify_command(app);
  vx::cli::add_bench_command(app);
  try {
    (void)vx::best_simd_level();  // a bad VOXELASTIC_SIMD is an error here, not inside a worker
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; every usage mistake exits 2 (the convention of Unix tools)
    return app.exit(e) == 0 ? 0 : 2;
  } catch (const vx::Error& e) {
    fmt::print(stderr, "voxelastic: error: {}\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    fmt::print(stderr, "voxelastic: internal error: {}\n", e.what());
    return 3;
  }
  return 0;
}
