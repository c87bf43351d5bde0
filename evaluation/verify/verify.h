#pragma once
/// @file verify.h
/// `voxelastic verify`: a suite of cases on synthetic phantoms, each comparing the model with an
/// analytic expectation (geometry, element counts, mechanics, convergence, stability), and the
/// reports they make: report.json (machine-readable checks), report.md (for people) and PNG plots.
///
/// A case is a named function that records checks (value, expected, tolerance, unit) and plots.
/// Suites: `quick` (the cases marked quick: robust, a few minutes on 2 cores, run in CI) and
/// `full` (every case). Cases keep a stable order, so `--shard I/N` (cases whose index % N == I)
/// splits a suite over the machines of a job array and merge_reports() puts it back together.
///
/// Output folder layout (docs/verify.md):
///   report.json  {"suite": S, "checks": [{"name", "passed", "value", "expected", "tolerance",
///                "unit", "case", "note", "comparison"}...]} ("comparison" only for one-sided
///                checks: "<=" passes when value <= expected + tolerance, ">=" when
///                value >= expected - tolerance; otherwise |value - expected| <= tolerance)
///   report.md    what each check means, a table per case, the plots
///   cases.json   the cases run: name, seconds, error, plots (what a merge needs)
///   plots/       <case>-<what>.png
/// Everything is staged in a hidden folder inside the output folder and moved into place at the
/// end, report.json last: a failed run leaves the previous report untouched.

#include <filesystem>
#include <functional>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "render/plot.h"

namespace vx {

/// How a check compares its value with the expectation.
enum class CheckRule : std::uint8_t {
  within,    ///< |value - expected| <= tolerance
  at_most,   ///< value <= expected + tolerance
  at_least,  ///< value >= expected - tolerance
};

/// One check of a report.
struct VerifyCheck {
  std::string name;        ///< unique in a suite, "<case>.<what>"
  bool passed{false};
  double value{0.0};       ///< measured (NaN when it could not be measured: fails)
  double expected{0.0};    ///< analytic or reference expectation
  double tolerance{0.0};   ///< allowed deviation (see rule), in `unit`
  std::string unit;        ///< "" for ratios and counts
  CheckRule rule{CheckRule::within};
  std::string case_name;   ///< the case that made it
  std::string note;        ///< what was compared, in a sentence
};

/// A check with `passed` set from the rule; a non-finite value, expectation or tolerance fails.
[[nodiscard]] VerifyCheck make_check(std::string name, double value, double expected, double tolerance,
                                     std::string unit, CheckRule rule = CheckRule::within, std::string note = "");

/// A plot a case drew, relative to the report folder.
struct VerifyPlot {
  std::string file;     ///< "plots/<case>-<what>.png"
  std::string caption;
};

/// What a running case records into.
class VerifyContext {
 public:
  /// `report_dir` is the folder the plots go under (its plots/ subfolder, created if missing).
  VerifyContext(std::string case_name, std::filesystem::path report_dir, bool full_suite);

  [[nodiscard]] const std::string& case_name() const { return case_name_; }
  /// True in the full suite (cases may use larger models there).
  [[nodiscard]] bool full() const { return full_; }

  /// Records a check named "<case>.<what>" (see CheckRule); returns whether it passed.
  bool check(const std::string& what, double value, double expected, double tolerance, const std::string& unit,
             const std::string& note, CheckRule rule = CheckRule::within);
  /// Draws panels into plots/<case>-<what>.png. A failed plot is not a failed check: the
  /// report says the plot is missing and why.
  void plot(const std::string& what, const std::string& caption, const std::vector<PlotPanel>& panels);
  /// A line of context for the report (figures behind the checks).
  void log(const std::string& line) { log_.push_back(line); }

  [[nodiscard]] const std::vector<VerifyCheck>& checks() const { return checks_; }
  [[nodiscard]] const std::vector<VerifyPlot>& plots() const { return plots_; }
  [[nodiscard]] const std::vector<std::string>& lines() const { return log_; }

 private:
  std::string case_name_;
  std::filesystem::path report_dir_;
  bool full_;
  std::vector<VerifyCheck> checks_;
  std::vector<VerifyPlot> plots_;
  std::vector<std::string> log_;
};

/// One case of a suite.
struct VerifyCase {
  std::string name;   ///< stable id, e.g. "hertz-voxel"
  std::string title;  ///< one line for the report
  /// Markdown for newcomers: what is simulated, the analytic expectation, and the reason for
  /// each tolerance.
  std::string about;
  bool quick{false};  ///< part of the quick suite (the full suite runs every case)
  std::function<void(VerifyContext&)> run;
};

/// Every case, in the stable order the suites and shards use (verify_cases.cpp).
[[nodiscard]] const std::vector<VerifyCase>& verify_cases();
/// The names of the suites: quick, full.
[[nodiscard]] std::vector<std::string> verify_suite_names();
/// The cases of `suite` in their stable order. Throws vx::Error for an unknown suite.
[[nodiscard]] std::vector<const VerifyCase*> verify_suite(const std::string& suite);
/// The case called `name`, or nullptr.
[[nodiscard]] const VerifyCase* find_verify_case(const std::string& name);

/// A part of a suite: the cases whose index % count == index.
struct Shard {
  int index{0};
  int count{1};
  [[nodiscard]] bool whole() const { return count == 1; }
  [[nodiscard]] bool contains(int case_index) const { return case_index % count == index; }
  [[nodiscard]] std::string str() const;  ///< "I/N"
};
/// Parses "I/N" (0 <= I < N <= 10000). Throws vx::Error saying what is wrong.
[[nodiscard]] Shard parse_shard(const std::string& text);

/// The result of one case.
struct VerifyCaseResult {
  std::string name;
  double seconds{-1.0};             ///< wall time (< 0: unknown)
  std::string error;                ///< the exception that stopped the case ("" when it finished)
  std::vector<VerifyCheck> checks;  ///< a case that threw also gets a failed "<case>.completed" check
  std::vector<VerifyPlot> plots;
  std::vector<std::string> lines;   ///< context lines for report.md
};

/// A report: the suite and the results of its cases (all of them, or one shard's).
struct VerifyReport {
  std::string suite;
  std::string shard;                    ///< "" for a whole suite, "I/N" for a partial report
  std::vector<VerifyCaseResult> cases;  ///< in suite order

  [[nodiscard]] std::vector<const VerifyCheck*> checks() const;
  [[nodiscard]] std::vector<const VerifyCheck*> failures() const;
  [[nodiscard]] bool passed() const { return failures().empty(); }
};

/// How to run a suite.
struct VerifyRunOptions {
  std::string suite{"quick"};
  int jobs{1};                     ///< cases run at once (each with one physics thread)
  Shard shard;
  std::vector<std::string> only;   ///< when not empty: only these cases of the suite (by name)
  /// Progress lines ("[3/14] hertz-voxel: passed, 5 checks, 12.3 s"); may be empty.
  std::function<void(const std::string&)> progress;
};

/// Runs the cases of the suite (and shard) on `jobs` worker threads, plots under `report_dir`.
/// Throws vx::Error for an unknown suite or case name, a case not in the suite, jobs < 1, or a
/// shard that holds no case. A case that throws is reported as failed, the others go on.
[[nodiscard]] VerifyReport run_verify(const VerifyRunOptions& options, const std::filesystem::path& report_dir);

/// report.json of a report (non-finite numbers as null).
[[nodiscard]] nlohmann::json report_json(const VerifyReport& report);
/// cases.json of a report.
[[nodiscard]] nlohmann::json cases_json(const VerifyReport& report);
/// Reads a report back from report.json and cases.json (`where` names them in messages).
/// Throws vx::Error for a malformed report.
[[nodiscard]] VerifyReport parse_report(const nlohmann::json& report, const nlohmann::json& cases,
                                        const std::string& where);
/// report.md: an introduction for newcomers, the summary, then per case what it checks, its
/// table and its plots (relative links).
[[nodiscard]] std::string report_markdown(const VerifyReport& report);

/// Combines partial reports of one suite. Throws vx::Error when the suites differ, a case is
/// missing or appears twice (naming the case and the reports), or a case is not in the suite.
[[nodiscard]] VerifyReport merge_reports(const std::vector<VerifyReport>& parts,
                                         const std::vector<std::string>& labels);

/// An output folder in the making: `dir/.verify-staging-<pid>/` holds plots and reports until
/// publish() moves them into `dir` (report.json last). Destroying an unpublished stage removes it.
class VerifyStage {
 public:
  /// Creates `dir` if needed and the staging folder inside. Throws vx::Error when `dir` cannot
  /// be created or written.
  explicit VerifyStage(const std::filesystem::path& dir);
  ~VerifyStage();
  VerifyStage(const VerifyStage&) = delete;
  VerifyStage& operator=(const VerifyStage&) = delete;

  /// Where plots go while the report is made (its plots/ subfolder).
  [[nodiscard]] const std::filesystem::path& path() const { return stage_; }
  /// Writes report.json, report.md and cases.json into the stage, then moves plots/ and the
  /// three files into the output folder (the previous plots/ is replaced). Throws vx::Error.
  void publish(const VerifyReport& report);

 private:
  std::filesystem::path dir_, stage_;
  bool published_{false};
};

/// Reads report.json and cases.json from a verify output folder. Throws vx::Error.
[[nodiscard]] VerifyReport read_report_dir(const std::filesystem::path& dir);
/// Copies each input folder's plots of its cases into `stage_dir`/plots/. Throws vx::Error.
void copy_report_plots(const std::vector<std::filesystem::path>& dirs, const std::vector<VerifyReport>& parts,
                       const std::filesystem::path& stage_dir);

}  // namespace vx
