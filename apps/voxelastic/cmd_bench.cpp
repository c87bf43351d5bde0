// voxelastic bench [--quick] [--out DIR] [--threads N]: the cost of one step against model size
// (step.csv, step.png) and run time against error on a palpation scene (bench.csv, bench.json,
// bench.md and plots), with the configuration that is best for real time. See docs/bench.md.
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "base/error.h"
#include "bench/bench.h"
#include "bench/haptic_accuracy.h"
#include "bench/scale_bench.h"
#include "commands.h"
#include "render/plot.h"
#include "util/atomic_file.h"
#include "util/log.h"

namespace vx::cli {
namespace {
namespace fs = std::filesystem;

struct BenchOptions {
  bool quick{false};
  std::string out{"out/bench"};
  int threads{1};
  std::vector<int> sizes, step_sizes;
  int reference_size{0};
  double max_run_s{0.0};
  double duration_s{0.0};
  bool skip_step{false}, skip_palpation{false};
  std::string element, reference_element;
  std::string haptic;  ///< a palpation scene: run the haptic accuracy only
  bool quiet{false};
  bool scale{false};
  bool threads_given{false};
  std::vector<std::string> scale_models, scale_configs, scale_lattice_origins;
  double scale_max_wall_s{0.0}, scale_reference_max_wall_s{0.0};
  std::string scale_reference{"symplectic"};
  double poisson{0.0};
};

/// `--haptic SCENE`: the local contact model's force at 1 kHz against the full-rate physics
/// (bench/haptic_accuracy.h; docs/probe.md, "Force shaping").
void run_haptic_command(const BenchOptions& o) {
  const fs::path dir(o.out);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    throw Error(fmt::format("--out '{}': cannot create the folder ({})", o.out, ec ? ec.message() : "not a folder"));
  check_output_path(dir / "haptic_accuracy.md");
  HapticAccuracySettings set;
  set.scene = o.haptic;
  if (!o.quiet) set.log = [](const std::string& line) { fmt::print(stderr, "{}\n", line); };
  const HapticAccuracyResult res = run_haptic_accuracy(set);
  const std::string table = haptic_accuracy_table(res);
  write_text_atomically(dir / "haptic_accuracy.md", table);
  plot_haptic_accuracy(res, dir / "haptic_accuracy.png");
  fmt::print("{}\nhaptic accuracy took {:.0f} s; wrote haptic_accuracy.md, haptic_accuracy.png to {}\n", table,
             res.wall_s, dir.string());
}

/// `bench --scale`: the real-time factor of each configuration on models of growing size
/// (evaluation/bench/scale_bench.h).
void run_scale_command(const BenchOptions& o) {
  ScaleBenchSettings set = ScaleBenchSettings::standard();
  if (!o.scale_models.empty()) {
    std::vector<ScaleModelSpec> keep;
    for (const auto& name : o.scale_models) {
      // "MODEL at S mm": MODEL's shape on a grid of S mm voxels (the physics on fewer nodes),
      // judged against MODEL's reference on MODEL's path; MODEL must be listed before it
      const std::size_t at = name.rfind(" at ");
      double spacing = 0;
      char unit[3] = {0, 0, 0}, tail = 0;
      if (at != std::string::npos && std::sscanf(name.c_str() + at, " at %lf %2s%c", &spacing, unit, &tail) == 2 &&
          std::string(unit) == "mm") {
        const std::string base = name.substr(0, at);
        const auto it = std::find_if(keep.begin(), keep.end(), [&](const ScaleModelSpec& m) { return m.name == base; });
        if (it == keep.end())
          throw Error(
              fmt::format("--scale-models: '{}' is judged against '{}': list '{}' before it", name, base, base));
        if (!(spacing >= 0.25 && spacing <= 8.0))
          throw Error(fmt::format("--scale-models: '{}': the voxel size must be 0.25 to 8 mm", name));
        ScaleModelSpec v = *it;
        v.name = name;
        v.size = std::max(16, int(std::lround(it->size * it->spacing_mm / spacing)));
        v.spacing_mm = spacing;
        v.judged_against = base;
        keep.push_back(v);
        continue;
      }
      bool found = false;
      for (const auto& m : set.models)
        if (m.name == name || m.name == "sphere " + name) keep.push_back(m), found = true;
      // "organ N": the organ phantom at N voxels across (214: the suite's), held as the suite holds it
      int size = 0;
      char rest = 0;
      if (!found && std::sscanf(name.c_str(), "organ %d%c", &size, &rest) == 1 && size >= 16 && size <= 512) {
        keep.push_back({name, "organ", size});
        found = true;
      }
      if (!found)
        throw Error(fmt::format(
            "--scale-models: unknown model '{}' (32, 64, 128, 256, organ, \"organ N\" (N voxels "
            "across, 16 to 512), \"folded (stem)\", \"folded (lower third)\"; \"MODEL at S mm\" after MODEL: "
            "its shape on S mm voxels, judged against MODEL's reference)",
            name));
    }
    set.models = keep;
  }
  if (!o.scale_lattice_origins.empty()) {  // each model at each origin, side by side
    std::vector<ScaleModelSpec> both;
    for (const auto& m : set.models)
      for (const auto& origin : o.scale_lattice_origins) {
        ScaleModelSpec v = m;
        v.lattice_origin = origin;
        if (origin == "crop") v.name += " (crop origin)";
        both.push_back(v);
      }
    set.models = both;
  }
  set.element = o.element;
  set.poisson_ratio = o.poisson;
  if (o.scale_max_wall_s > 0) set.max_wall_s = o.scale_max_wall_s;
  if (o.scale_reference_max_wall_s > 0) set.reference_max_wall_s = o.scale_reference_max_wall_s;
  if (o.scale_reference == "implicit") set.use_implicit_reference();
  if (!o.scale_configs.empty()) {
    std::vector<ScaleConfig> keep, all = set.configs;
    for (const ScaleConfig& c : ScaleBenchSettings::diagnostic_configs()) all.push_back(c);
    for (const auto& c : all)
      for (const auto& want : o.scale_configs)
        if (c.name.find(want) != std::string::npos) {
          keep.push_back(c);
          break;
        }
    if (keep.empty()) throw Error("--scale-configs: no configuration matches");
    set.configs = keep;
  }
  if (o.threads_given) set.threads = {o.threads};
  const fs::path dir(o.out);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    throw Error(fmt::format("--out '{}': cannot create the folder ({})", o.out, ec ? ec.message() : "not a folder"));
  check_output_path(dir / "scale.csv");
  set.curves_dir = dir / "curves";
  if (!o.quiet) set.log = [](const std::string& line) { fmt::print(stderr, "{}\n", line); };
  const ScaleBenchResult res = run_scale_bench(set);
  const std::vector<std::string> written = write_scale_report(res, dir);
  fmt::print("{}", format_scale_table(res));
  fmt::print("bench --scale took {:.0f} s; wrote {} to {}\n", res.total_s, fmt::join(written, ", "), dir.string());
}

void run_bench_command(const BenchOptions& o) {
  if (o.scale) return run_scale_command(o);
  BenchSettings set = o.quick ? BenchSettings::quick_settings() : BenchSettings{};
  set.threads = o.threads;
  if (!o.sizes.empty()) set.sizes = o.sizes;
  if (!o.step_sizes.empty()) set.step_sizes = o.step_sizes;
  if (o.reference_size > 0) set.reference_size = o.reference_size;
  if (o.max_run_s > 0) set.max_run_s = o.max_run_s;
  if (o.duration_s > 0) {
    set.scene.duration_s = o.duration_s;
    set.scene.press_s = 0.5 * o.duration_s;
  }
  if (!o.element.empty()) set.scene.element = element_kind_from_string(o.element);
  if (!o.reference_element.empty()) set.reference_element = element_kind_from_string(o.reference_element);
  set.run_step = !o.skip_step;
  set.run_palpation = !o.skip_palpation;
  set.validate();

  // the outputs first: a mistake there should not cost a whole bench
  const fs::path dir(o.out);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    throw Error(fmt::format("--out '{}': cannot create the folder ({})", o.out, ec ? ec.message() : "not a folder"));
  check_output_path(dir / "bench.json");

  if (o.quiet) log::set_level(std::max(log::level(), log::Level::warn));
  if (!o.quiet) {
    set.log = [](const std::string& line) { fmt::print(stderr, "{}\n", line); };
    fmt::print(stderr,
               "voxelastic bench{}: {} physics thread(s); step sizes {}; palpation sizes {}, reference n = {}\n",
               set.quick ? " --quick" : "", set.threads,
               set.run_step ? fmt::format("{}", fmt::join(set.step_sizes, ", ")) : "-",
               set.run_palpation ? fmt::format("{}", fmt::join(set.sizes, ", ")) : "-", set.reference_size);
  }
  const BenchResult res = run_bench(set);
  const std::vector<std::string> written = write_bench_report(res, dir);

  if (set.run_step) {
    for (Layout r : {Layout::gradational, Layout::uniform, Layout::voxel}) {
      std::vector<StepBenchmarkRow> rows;
      for (const auto& row : res.step_rows)
        if (row.layout == r) rows.push_back(row);
      fmt::print("One step on sphere phantoms, {} models ({} thread(s)):\n{}", to_string(r), set.threads,
                 format_step_benchmark(rows));
    }
    fmt::print(
        "Explicit step time against n, log-log slope: gradational {:.2f}, uniform {:.2f}, voxel-level {:.2f} "
        "(paper: ~2 against ~3)\n",
        res.step_slope_gradational, res.step_slope_uniform, res.step_slope_voxel);
  }
  if (set.run_palpation) {
    int unstable = 0, skipped = 0;
    for (const auto& r : res.rows) {
      unstable += r.status == BenchStatus::unstable;
      skipped += r.status == BenchStatus::skipped;
    }
    fmt::print(
        "Palpation: {} runs ({} unstable, {} skipped), reference voxel-level n = {}: peak force {:.4g} N; Pareto "
        "front of {} runs\n",
        res.rows.size(), unstable, skipped, res.reference.size, res.reference.peak_force_n, res.pareto.size());
    fmt::print("{}\n", best_statement(res));
  }
  for (const auto& n : res.notes) fmt::print("note: {}\n", n);
  fmt::print("bench took {:.0f} s; wrote {} to {}\n", res.total_s, fmt::join(written, ", "), dir.string());
}

}  // namespace

void add_bench_command(CLI::App& app) {
  auto opts = std::make_shared<BenchOptions>();
  CLI::App* sub = app.add_subcommand(
      "bench",
      "Benchmarks (docs/bench.md): the cost of one step on sphere phantoms of growing size for each resolution and "
      "integrator (DIR/step.csv, step.png), and run time against error on a palpation scene (DIR/bench.csv, "
      "bench.json, "
      "bench.md, bench_error.png, bench_cost.png, bench_curves.png) with the best configuration for real time.");
  sub->add_flag("--quick", opts->quick, "the small suite (about 2 minutes on 2 cores; the full one 13 to 17)");
  sub->add_option("-o,--out", opts->out, "output folder (created if missing)")->capture_default_str();
  sub->add_option("--threads", opts->threads, "physics threads (>= 1)")
      ->capture_default_str()
      ->check(CLI::Range(1, 1024))
      ->each([opts](const std::string&) { opts->threads_given = true; });
  sub->add_option("--sizes", opts->sizes, "palpation grid sizes n, voxels across the block, even (e.g. 16,24,32)")
      ->delimiter(',')
      ->check(CLI::Range(8, 256));
  sub->add_option("--step-sizes", opts->step_sizes, "sphere sizes of the step benchmark (e.g. 32,64,128,256)")
      ->delimiter(',')
      ->check(CLI::Range(8, 512));
  sub->add_option("--reference-size", opts->reference_size, "size n of the voxel-level reference (even)")
      ->check(CLI::Range(8, 256));
  sub->add_option("--max-run-s", opts->max_run_s, "skip palpation runs predicted to take longer than this (s)")
      ->check(CLI::PositiveNumber);
  sub->add_option("--duration", opts->duration_s, "simulated time of the palpation scene, s (press half, lift half)")
      ->check(CLI::Range(0.02, 10.0));
  sub->add_option("--element", opts->element,
                  "the element of every model: hourglass (default) or paper (the paper's element, for comparison)")
      ->check(CLI::IsMember({"hourglass", "paper"}));
  sub->add_option("--reference-element", opts->reference_element,
                  "the element of part B's reference (default: that of --element)")
      ->check(CLI::IsMember({"hourglass", "paper"}));
  sub->add_flag("--skip-step", opts->skip_step, "skip the step benchmark (part A)");
  sub->add_flag("--skip-palpation", opts->skip_palpation, "skip run time against error (part B)");
  sub->add_option("--haptic", opts->haptic,
                  "only the haptic accuracy on this palpation scene (e.g. samples/scenes/palpation-lesion.json): the "
                  "local contact model's force at 1 kHz with the physics at 1000, 200, 60 and 30 Hz against the "
                  "full-rate physics (DIR/haptic_accuracy.md, haptic_accuracy.png)")
      ->check(CLI::ExistingFile);
  sub->add_flag(
      "--scale", opts->scale,
      "instead: the real-time factor and force error of each configuration on sphere phantoms 32 to 256 and the "
      "organ and folded phantoms, 1 and 2 threads (DIR/scale.csv, scale.md, scale.png; docs/bench.md)");
  sub->add_option("--poisson", opts->poisson,
                  "--scale: the material's Poisson ratio (default 0, the paper's model; docs/bench.md)")
      ->check(CLI::Range(0.0, 0.499));
  sub->add_option("--scale-models", opts->scale_models,
                  "with --scale: the models (32, 64, 128, 256, organ, \"organ N\", \"folded (stem)\", \"folded (lower "
                  "third)\"; \"MODEL at S mm\" after MODEL: MODEL's shape on S mm voxels, judged against MODEL's "
                  "reference on its path; default: all)")
      ->delimiter(',');
  sub->add_option("--scale-max-wall-s", opts->scale_max_wall_s,
                  "with --scale: time a run over at most this much wall time (the reference runs to the end)")
      ->check(CLI::PositiveNumber);
  sub->add_option("--scale-configs", opts->scale_configs,
                  "with --scale: only the configurations whose name contains one of these (e.g. reference,implicit)")
      ->delimiter(',');
  sub->add_option("--scale-lattice-origins", opts->scale_lattice_origins,
                  "with --scale: run each model with these lattice origins, side by side (best: the fewest vertex "
                  "entries, the default; crop: the crop's 1-voxel margin; e.g. best,crop)")
      ->delimiter(',')
      ->check(CLI::IsMember({"best", "crop"}));
  sub->add_option("--scale-reference", opts->scale_reference,
                  "with --scale: the reference: symplectic (Euler at its stable step, default) or implicit (3 ms steps "
                  "iterated to 1e-5 N: minutes where the symplectic one takes an hour)")
      ->check(CLI::IsMember({"symplectic", "implicit"}));
  sub->add_option("--scale-reference-max-wall-s", opts->scale_reference_max_wall_s,
                  "with --scale: the reference's wall-time budget (default 1800 s; shorter: no error column)")
      ->check(CLI::PositiveNumber);
  sub->callback([opts] {
    opts->quiet = quiet();  // -q: no progress on stderr
    opts->haptic.empty() ? run_bench_command(*opts) : run_haptic_command(*opts);
  });
}

}  // namespace vx::cli
