// voxelastic verify [--suite quick|full] [--out DIR] [--jobs N] [--shard I/N] [--case NAME]...:
// runs the verification suite (evaluation/verify/verify.h) and writes DIR/report.json, DIR/report.md and
// DIR/plots/. voxelastic verify-merge DIR... --out DIR: combines the reports of the shards.
// Exit 0 when every check passed, 1 when one failed (or on an error), 2 for usage errors.
#include <fmt/core.h>

#include <algorithm>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "base/error.h"
#include "commands.h"
#include "util/log.h"
#include "render/plot.h"
#include "verify/verify.h"

namespace vx::cli {
namespace {
namespace fs = std::filesystem;

struct VerifyOptions {
  std::string suite{"quick"};
  std::string out{"verify-report"};
  int jobs{0};
  std::string shard{"0/1"};
  std::vector<std::string> cases;
  bool quiet{false};
};

struct MergeOptions {
  std::vector<std::string> inputs;
  std::string out;
  bool quiet{false};
};

/// Prints the outcome; throws vx::Error (exit 1) when a check failed.
void finish(const VerifyReport& report, const fs::path& out, bool quiet) {
  const auto all = report.checks();
  const auto failed = report.failures();
  if (!quiet)
    fmt::print("verify: {} suite{}: {} of {} checks passed in {} cases; report: {}\n", report.suite,
               report.shard.empty() ? "" : " (shard " + report.shard + ")", all.size() - failed.size(), all.size(),
               report.cases.size(), (out / "report.md").string());
  if (failed.empty()) return;
  for (const VerifyCheck* c : failed)
    fmt::print(stderr, "verify: FAILED {}: {:.6g} {}, expected {}{}\n", c->name, c->value, c->unit,
               c->rule == CheckRule::at_most    ? fmt::format("<= {:.6g}", c->expected + c->tolerance)
               : c->rule == CheckRule::at_least ? fmt::format(">= {:.6g}", c->expected - c->tolerance)
                                                : fmt::format("{:.6g} +- {:.3g}", c->expected, c->tolerance),
               c->note.empty() ? "" : " (" + c->note + ")");
  throw Error(fmt::format("{} of {} checks failed (listed above; details in {})", failed.size(), all.size(),
                          (out / "report.md").string()));
}

void run_verify_command(const VerifyOptions& o) {
  // usage mistakes first (exit 2): cases outside the suite, a shard that holds nothing
  const std::vector<const VerifyCase*> suite = verify_suite(o.suite);
  const Shard shard = parse_shard(o.shard);
  std::string names;
  for (const VerifyCase* c : suite) names += (names.empty() ? "" : ", ") + c->name;
  int selected = 0;
  for (const std::string& name : o.cases)
    if (std::none_of(suite.begin(), suite.end(), [&](const VerifyCase* c) { return c->name == name; }))
      throw CLI::ValidationError("--case", fmt::format("'{}' is not a case of the {} suite (its cases: {})", name, o.suite, names));
  for (std::size_t i = 0; i < suite.size(); ++i)
    if (shard.contains(int(i)) &&
        (o.cases.empty() || std::find(o.cases.begin(), o.cases.end(), suite[i]->name) != o.cases.end()))
      ++selected;
  if (selected == 0)
    throw CLI::ValidationError("--shard", fmt::format("shard {} holds no case of the {} suite ({} cases{})", o.shard,
                                                      o.suite, suite.size(), o.cases.empty() ? "" : " with --case"));

  VerifyStage stage(o.out);  // creates the folder and checks it is writable before any work
  VerifyRunOptions run;
  run.suite = o.suite;
  run.jobs = o.jobs > 0 ? o.jobs : std::max(1, int(std::thread::hardware_concurrency()));
  run.shard = shard;
  run.only = o.cases;
  if (o.quiet) log::set_level(std::max(log::level(), log::Level::warn));
  if (!o.quiet) {
    run.progress = [](const std::string& line) { fmt::print(stderr, "verify: {}\n", line); };
    fmt::print(stderr, "verify: {} suite{}: {} cases on {} worker thread(s), one physics thread each -> {}\n", o.suite,
               shard.whole() ? "" : " shard " + shard.str(), selected, std::min(run.jobs, selected), o.out);
  }
  const VerifyReport report = run_verify(run, stage.path());
  stage.publish(report);
  finish(report, o.out, o.quiet);
}

void run_merge_command(const MergeOptions& o) {
  std::vector<fs::path> dirs;
  std::vector<VerifyReport> parts;
  for (const std::string& d : o.inputs) {
    dirs.emplace_back(d);
    parts.push_back(read_report_dir(d));
  }
  const VerifyReport merged = merge_reports(parts, o.inputs);
  VerifyStage stage(o.out);
  copy_report_plots(dirs, parts, stage.path());
  stage.publish(merged);
  finish(merged, o.out, o.quiet);
}

}  // namespace

void add_verify_command(CLI::App& app) {
  auto opts = std::make_shared<VerifyOptions>();
  CLI::App* sub = app.add_subcommand(
      "verify",
      "Run the verification suite on synthetic phantoms (geometry, element counts, compression, Hertz, cantilever, "
      "frequency, convergence, stability, lesion) and write DIR/report.json, DIR/report.md and DIR/plots/. Exit 0 "
      "when every check passes, 1 when one fails. See docs/verify.md.");
  sub->add_option("--suite", opts->suite, "quick (a few minutes, the CI suite) or full (every case, under 30 min on 2 cores)")
      ->check(CLI::IsMember({"quick", "full"}))
      ->capture_default_str();
  sub->add_option("-o,--out", opts->out, "output folder (created if missing)")->capture_default_str();
  sub->add_option("-j,--jobs", opts->jobs, "cases run at once (default: one per core)")->check(CLI::Range(1, 256));
  sub->add_option("--shard", opts->shard,
                  "run only the cases whose index % N == I (stable order) for a job array; merge with verify-merge")
      ->check([](const std::string& s) {
        try {
          (void)parse_shard(s);
          return std::string();
        } catch (const Error& e) {
          return std::string(e.what());
        }
      })
      ->capture_default_str();
  sub->add_option("--case", opts->cases, "run only this case (repeatable; names in docs/verify.md)");
  sub->callback([opts] {
    opts->quiet = quiet();  // -q: no progress or summary (failures are still printed)
    run_verify_command(*opts);
  });

  auto mopts = std::make_shared<MergeOptions>();
  CLI::App* merge = app.add_subcommand(
      "verify-merge",
      "Combine the reports of `voxelastic verify --shard I/N` runs (one folder each) into one report; checks that "
      "the suites match and that every case appears exactly once.");
  merge->add_option("DIR", mopts->inputs, "output folders of the shards")->required()->check(CLI::ExistingDirectory);
  merge->add_option("-o,--out", mopts->out, "folder for the merged report (created if missing)")->required();
  merge->callback([mopts] {
    mopts->quiet = quiet();  // -q: no summary (failures are still printed)
    run_merge_command(*mopts);
  });
}

}  // namespace vx::cli
