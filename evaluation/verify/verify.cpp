// voxelastic verify: the runner (worker threads, shards), the reports (JSON, Markdown), merging
// partial reports and the staged output folder. The cases themselves are in verify_cases.cpp.
#include "verify/verify.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <thread>

#include "base/error.h"
#include "util/atomic_file.h"

namespace vx {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

bool rule_passes(CheckRule rule, double value, double expected, double tolerance) {
  if (!std::isfinite(value) || !std::isfinite(expected) || !std::isfinite(tolerance) || tolerance < 0) return false;
  switch (rule) {
    case CheckRule::within: return std::abs(value - expected) <= tolerance;
    case CheckRule::at_most: return value <= expected + tolerance;
    case CheckRule::at_least: return value >= expected - tolerance;
  }
  return false;
}

const char* rule_symbol(CheckRule rule) {
  switch (rule) {
    case CheckRule::within: return "";
    case CheckRule::at_most: return "<=";
    case CheckRule::at_least: return ">=";
  }
  return "";
}

json number(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

/// One plot at a time (plot_png serialises its drawing too): the plots folder is made once.
std::mutex& plot_mutex() {
  static std::mutex m;
  return m;
}

std::string fmt_num(double v) {
  if (!std::isfinite(v)) return "n/a";
  if (v == 0) return "0";
  if (v == std::round(v) && std::abs(v) < 1e12) return fmt::format("{:.0f}", v);  // counts in full
  return fmt::format("{:.4g}", v);
}

/// Markdown table cell: no pipes or line breaks.
std::string cell(std::string s) {
  for (char& c : s)
    if (c == '|' || c == '\n') c = c == '|' ? '/' : ' ';
  return s;
}

std::string expectation(const VerifyCheck& c) {
  switch (c.rule) {
    case CheckRule::within:
      return c.tolerance == 0 ? fmt::format("{} exactly", fmt_num(c.expected))
                              : fmt::format("{} ± {}", fmt_num(c.expected), fmt_num(c.tolerance));
    case CheckRule::at_most: return fmt::format("≤ {}", fmt_num(c.expected + c.tolerance));
    case CheckRule::at_least: return fmt::format("≥ {}", fmt_num(c.expected - c.tolerance));
  }
  return "";
}

// JSON reading with messages that name the file and the entry
const json& need(const json& o, const char* key, const std::string& where) {
  if (!o.is_object() || !o.contains(key)) throw Error(fmt::format("{}: missing \"{}\"", where, key));
  return o.at(key);
}
std::string need_string(const json& o, const char* key, const std::string& where) {
  const json& v = need(o, key, where);
  if (!v.is_string()) throw Error(fmt::format("{}: \"{}\" must be a string", where, key));
  return v.get<std::string>();
}
double need_number(const json& o, const char* key, const std::string& where) {
  const json& v = need(o, key, where);
  if (v.is_null()) return std::nan("");
  if (!v.is_number()) throw Error(fmt::format("{}: \"{}\" must be a number or null", where, key));
  return v.get<double>();
}
std::string opt_string(const json& o, const char* key, const std::string& where) {
  return o.contains(key) ? need_string(o, key, where) : std::string();
}

}  // namespace

VerifyCheck make_check(std::string name, double value, double expected, double tolerance, std::string unit,
                       CheckRule rule, std::string note) {
  VerifyCheck c;
  c.name = std::move(name);
  c.value = value;
  c.expected = expected;
  c.tolerance = tolerance;
  c.unit = std::move(unit);
  c.rule = rule;
  c.note = std::move(note);
  c.passed = rule_passes(rule, value, expected, tolerance);
  return c;
}

// --- context ------------------------------------------------------------------------------------

VerifyContext::VerifyContext(std::string case_name, fs::path report_dir, bool full_suite)
    : case_name_(std::move(case_name)), report_dir_(std::move(report_dir)), full_(full_suite) {}

bool VerifyContext::check(const std::string& what, double value, double expected, double tolerance,
                          const std::string& unit, const std::string& note, CheckRule rule) {
  VerifyCheck c = make_check(case_name_ + "." + what, value, expected, tolerance, unit, rule, note);
  c.case_name = case_name_;
  checks_.push_back(std::move(c));
  return checks_.back().passed;
}

void VerifyContext::plot(const std::string& what, const std::string& caption, const std::vector<PlotPanel>& panels) {
  const std::string file = "plots/" + case_name_ + "-" + what + ".png";
  try {
    std::lock_guard<std::mutex> lock(plot_mutex());
    fs::create_directories(report_dir_ / "plots");
    // plain words in the pictures: names like symplectic_euler get spaces
    std::vector<PlotPanel> shown = panels;
    const auto plain = [](std::string& s) { std::replace(s.begin(), s.end(), '_', ' '); };
    for (PlotPanel& p : shown) {
      plain(p.title), plain(p.xlabel), plain(p.ylabel);
      for (PlotSeries& s : p.series) plain(s.title);
    }
    plot_png(shown, report_dir_ / file);
    plots_.push_back({file, caption});
  } catch (const std::exception& e) {
    log_.push_back(fmt::format("plot {} not drawn: {}", file, e.what()));
  }
}

// --- suites and shards ---------------------------------------------------------------------------

std::vector<std::string> verify_suite_names() { return {"quick", "full"}; }

std::vector<const VerifyCase*> verify_suite(const std::string& suite) {
  if (suite != "quick" && suite != "full")
    throw Error(fmt::format("unknown suite '{}': use quick (a few minutes, the CI suite) or full (every case)", suite));
  std::vector<const VerifyCase*> out;
  for (const VerifyCase& c : verify_cases())
    if (suite == "full" || c.quick) out.push_back(&c);
  return out;
}

const VerifyCase* find_verify_case(const std::string& name) {
  for (const VerifyCase& c : verify_cases())
    if (c.name == name) return &c;
  return nullptr;
}

std::string Shard::str() const { return fmt::format("{}/{}", index, count); }

Shard parse_shard(const std::string& text) {
  const auto slash = text.find('/');
  const auto parse_int = [&](const std::string& s, const char* what) {
    if (s.empty() || s.size() > 6 || !std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; }))
      throw Error(fmt::format("--shard '{}': {} must be a whole number (the form is I/N, e.g. 0/4)", text, what));
    return std::stoi(s);
  };
  if (slash == std::string::npos)
    throw Error(fmt::format("--shard '{}': the form is I/N (shard I of N, 0 <= I < N), e.g. 0/4", text));
  Shard s;
  s.index = parse_int(text.substr(0, slash), "I");
  s.count = parse_int(text.substr(slash + 1), "N");
  if (s.count < 1 || s.count > 10000)
    throw Error(fmt::format("--shard '{}': N must be between 1 and 10000", text));
  if (s.index >= s.count)
    throw Error(fmt::format("--shard '{}': I must be below N (shards are numbered 0 to {})", text, s.count - 1));
  return s;
}

// --- reports -----------------------------------------------------------------------------------

std::vector<const VerifyCheck*> VerifyReport::checks() const {
  std::vector<const VerifyCheck*> out;
  for (const auto& c : cases)
    for (const auto& k : c.checks) out.push_back(&k);
  return out;
}

std::vector<const VerifyCheck*> VerifyReport::failures() const {
  std::vector<const VerifyCheck*> out;
  for (const VerifyCheck* c : checks())
    if (!c->passed) out.push_back(c);
  return out;
}

// --- running -----------------------------------------------------------------------------------

VerifyReport run_verify(const VerifyRunOptions& options, const fs::path& report_dir) {
  if (options.jobs < 1) throw Error(fmt::format("--jobs {}: must be at least 1", options.jobs));
  const std::vector<const VerifyCase*> suite = verify_suite(options.suite);
  for (const std::string& name : options.only) {
    const auto it = std::find_if(suite.begin(), suite.end(), [&](const VerifyCase* c) { return c->name == name; });
    if (it == suite.end()) {
      std::string names;
      for (const VerifyCase* c : suite) names += (names.empty() ? "" : ", ") + c->name;
      throw Error(fmt::format("case '{}' is not in the {} suite (its cases: {})", name, options.suite, names));
    }
  }
  std::vector<const VerifyCase*> todo;
  for (std::size_t i = 0; i < suite.size(); ++i) {
    if (!options.shard.contains(int(i))) continue;
    if (!options.only.empty() && std::find(options.only.begin(), options.only.end(), suite[i]->name) == options.only.end())
      continue;
    todo.push_back(suite[i]);
  }
  if (todo.empty())
    throw Error(fmt::format("shard {} of the {} suite holds no case ({} cases: use N <= {})", options.shard.str(),
                            options.suite, suite.size(), suite.size()));

  VerifyReport report;
  report.suite = options.suite;
  report.shard = options.shard.whole() && options.only.empty() ? "" : options.shard.str();
  report.cases.resize(todo.size());
  std::atomic<std::size_t> next{0};
  std::atomic<int> done{0};
  std::mutex progress_mutex;
  const bool full = options.suite == "full";
  const auto worker = [&] {
    for (std::size_t i = next++; i < todo.size(); i = next++) {
      const VerifyCase& c = *todo[i];
      VerifyCaseResult& r = report.cases[i];
      r.name = c.name;
      VerifyContext ctx(c.name, report_dir, full);
      const auto t0 = std::chrono::steady_clock::now();
      try {
        c.run(ctx);
      } catch (const std::exception& e) {
        r.error = e.what();
      }
      r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      r.checks = ctx.checks();
      r.plots = ctx.plots();
      r.lines = ctx.lines();
      if (!r.error.empty() || r.checks.empty()) {
        VerifyCheck k = make_check(c.name + ".completed", 0.0, 1.0, 0.0, "",
                                   CheckRule::within,
                                   r.error.empty() ? "the case recorded no check" : "the case stopped: " + r.error);
        k.case_name = c.name;
        r.checks.push_back(std::move(k));
      }
      const auto failed = std::count_if(r.checks.begin(), r.checks.end(), [](const VerifyCheck& k) { return !k.passed; });
      if (options.progress) {
        std::lock_guard<std::mutex> lock(progress_mutex);
        const int k = ++done;
        options.progress(fmt::format("[{}/{}] {}: {} ({} checks{}), {:.1f} s", k, todo.size(), c.name,
                                     failed ? "FAILED" : "passed", r.checks.size(),
                                     failed ? fmt::format(", {} failed", failed) : std::string(), r.seconds));
      }
    }
  };
  const int jobs = std::min<int>(options.jobs, int(todo.size()));
  std::vector<std::thread> threads;
  for (int j = 1; j < jobs; ++j) threads.emplace_back(worker);
  worker();
  for (auto& t : threads) t.join();
  return report;
}

// --- JSON --------------------------------------------------------------------------------------

json report_json(const VerifyReport& report) {
  json checks = json::array();
  for (const VerifyCheck* c : report.checks()) {
    json k = {{"name", c->name},         {"passed", c->passed}, {"value", number(c->value)},
              {"expected", number(c->expected)}, {"tolerance", number(c->tolerance)}, {"unit", c->unit}};
    if (!c->case_name.empty()) k["case"] = c->case_name;
    if (!c->note.empty()) k["note"] = c->note;
    if (c->rule != CheckRule::within) k["comparison"] = rule_symbol(c->rule);
    checks.push_back(std::move(k));
  }
  return {{"suite", report.suite}, {"checks", std::move(checks)}};
}

json cases_json(const VerifyReport& report) {
  json cases = json::array();
  for (const VerifyCaseResult& c : report.cases) {
    json plots = json::array();
    for (const VerifyPlot& p : c.plots) plots.push_back({{"file", p.file}, {"caption", p.caption}});
    cases.push_back({{"name", c.name},
                     {"seconds", number(c.seconds)},
                     {"error", c.error},
                     {"plots", std::move(plots)},
                     {"lines", c.lines}});
  }
  return {{"suite", report.suite}, {"shard", report.shard}, {"cases", std::move(cases)}};
}

VerifyReport parse_report(const json& rj, const json& cj, const std::string& where) {
  VerifyReport r;
  const std::string wr = where + "/report.json", wc = where + "/cases.json";
  r.suite = need_string(rj, "suite", wr);
  if (need_string(cj, "suite", wc) != r.suite)
    throw Error(fmt::format("{}: suite '{}' differs from report.json's '{}'", wc, need_string(cj, "suite", wc), r.suite));
  r.shard = opt_string(cj, "shard", wc);
  const json& cases = need(cj, "cases", wc);
  if (!cases.is_array()) throw Error(wc + ": \"cases\" must be an array");
  std::map<std::string, std::size_t> index;
  for (std::size_t i = 0; i < cases.size(); ++i) {
    const std::string w = fmt::format("{} cases[{}]", wc, i);
    VerifyCaseResult c;
    c.name = need_string(cases[i], "name", w);
    c.seconds = need_number(cases[i], "seconds", w);
    c.error = opt_string(cases[i], "error", w);
    if (cases[i].contains("plots")) {
      if (!cases[i]["plots"].is_array()) throw Error(w + ": \"plots\" must be an array");
      for (const json& p : cases[i]["plots"]) c.plots.push_back({need_string(p, "file", w), opt_string(p, "caption", w)});
    }
    if (cases[i].contains("lines")) {
      if (!cases[i]["lines"].is_array()) throw Error(w + ": \"lines\" must be an array");
      for (const json& l : cases[i]["lines"]) {
        if (!l.is_string()) throw Error(w + ": \"lines\" must hold strings");
        c.lines.push_back(l.get<std::string>());
      }
    }
    if (!index.emplace(c.name, r.cases.size()).second) throw Error(fmt::format("{}: case '{}' listed twice", wc, c.name));
    r.cases.push_back(std::move(c));
  }
  const json& checks = need(rj, "checks", wr);
  if (!checks.is_array()) throw Error(wr + ": \"checks\" must be an array");
  for (std::size_t i = 0; i < checks.size(); ++i) {
    const std::string w = fmt::format("{} checks[{}]", wr, i);
    const json& k = checks[i];
    VerifyCheck c;
    c.name = need_string(k, "name", w);
    const json& passed = need(k, "passed", w);
    if (!passed.is_boolean()) throw Error(w + ": \"passed\" must be true or false");
    c.passed = passed.get<bool>();
    c.value = need_number(k, "value", w);
    c.expected = need_number(k, "expected", w);
    c.tolerance = need_number(k, "tolerance", w);
    c.unit = need_string(k, "unit", w);
    c.case_name = need_string(k, "case", w);
    c.note = opt_string(k, "note", w);
    const std::string cmp = opt_string(k, "comparison", w);
    if (cmp == "<=") c.rule = CheckRule::at_most;
    else if (cmp == ">=") c.rule = CheckRule::at_least;
    else if (!cmp.empty()) throw Error(fmt::format("{}: \"comparison\" must be \"<=\" or \">=\" (got '{}')", w, cmp));
    const auto it = index.find(c.case_name);
    if (it == index.end())
      throw Error(fmt::format("{}: check '{}' belongs to case '{}', which cases.json does not list", w, c.name, c.case_name));
    r.cases[it->second].checks.push_back(std::move(c));
  }
  return r;
}

// --- Markdown ----------------------------------------------------------------------------------

std::string report_markdown(const VerifyReport& report) {
  std::ostringstream md;
  const auto all = report.checks();
  const auto failed = report.failures();
  md << "# voxelastic verification report: `" << report.suite << "` suite";
  if (!report.shard.empty()) md << " (partial: shard " << report.shard << ")";
  md << "\n\n";
  if (failed.empty())
    md << "**PASSED**: all " << all.size() << " checks of " << report.cases.size() << " cases passed.\n\n";
  else {
    md << "**FAILED**: " << failed.size() << " of " << all.size() << " checks failed:\n\n";
    for (const VerifyCheck* c : failed)
      md << "- `" << c->name << "`: " << fmt_num(c->value) << " " << c->unit << ", expected " << expectation(*c) << " "
         << c->unit << (c->note.empty() ? "" : " (" + c->note + ")") << "\n";
    md << "\n";
  }
  md << "## How to read this report\n\n"
        "Each case below builds a small synthetic object (a block, a bar, a phantom shape) whose right answer is "
        "known from theory: the volume of a sphere, the modulus behind a stress-strain curve, Hertz's contact law, "
        "beam theory, the frequency of a bar. The program measures the same quantity on the elastic model and "
        "compares. A check **passes** when the measured *value* lies within the *tolerance* of the *expected* value "
        "(`± t`), or on the right side of a bound (`≤`, `≥`). Tolerances are set from the physics and the "
        "discretisation (how many elements resolve the effect), never from today's numbers; each case explains its "
        "own. Units: mm, s, N, kPa; ratios have no unit. The `gradational` layout is the paper's model (small "
        "elements at the surface, large inside), `uniform` puts every element at the smallest size, and `voxel` is "
        "one 8-vertex element per voxel, the reference. The machine-readable version is `report.json`; "
        "`docs/verify.md` describes every case.\n\n";
  md << "| case | what | checks | failed | time |\n|---|---|---|---|---|\n";
  for (const VerifyCaseResult& c : report.cases) {
    const VerifyCase* def = find_verify_case(c.name);
    const auto nf = std::count_if(c.checks.begin(), c.checks.end(), [](const VerifyCheck& k) { return !k.passed; });
    md << "| [" << c.name << "](#" << c.name << ") | " << cell(def ? def->title : "") << " | " << c.checks.size()
       << " | " << (nf ? fmt::format("**{}**", nf) : "0") << " | "
       << (c.seconds >= 0 ? fmt::format("{:.1f} s", c.seconds) : "") << " |\n";
  }
  md << "\n";
  for (const VerifyCaseResult& c : report.cases) {
    const VerifyCase* def = find_verify_case(c.name);
    md << "<a id=\"" << c.name << "\"></a>\n## " << c.name << (def ? ": " + def->title : "") << "\n\n";
    if (def && !def->about.empty()) md << def->about << "\n\n";
    if (!c.error.empty()) md << "**The case stopped with an error:** " << c.error << "\n\n";
    md << "| check | result | value | expected | unit | note |\n|---|---|---|---|---|---|\n";
    for (const VerifyCheck& k : c.checks) {
      const std::string shortname =
          k.name.rfind(c.name + ".", 0) == 0 ? k.name.substr(c.name.size() + 1) : k.name;
      md << "| `" << shortname << "` | " << (k.passed ? "pass" : "**FAIL**") << " | " << fmt_num(k.value) << " | "
         << expectation(k) << " | " << cell(k.unit) << " | " << cell(k.note) << " |\n";
    }
    md << "\n";
    if (!c.lines.empty()) {
      md << "Figures behind the checks:\n\n";
      for (const std::string& l : c.lines) md << "- " << l << "\n";
      md << "\n";
    }
    for (const VerifyPlot& p : c.plots) md << "![" << p.caption << "](" << p.file << ")\n\n*" << p.caption << "*\n\n";
  }
  return md.str();
}

// --- merging -----------------------------------------------------------------------------------

VerifyReport merge_reports(const std::vector<VerifyReport>& parts, const std::vector<std::string>& labels) {
  if (parts.empty()) throw Error("nothing to merge: give the output folders of the shards");
  const auto label = [&](std::size_t i) { return i < labels.size() ? labels[i] : fmt::format("report {}", i + 1); };
  const std::string suite = parts[0].suite;
  for (std::size_t i = 1; i < parts.size(); ++i)
    if (parts[i].suite != suite)
      throw Error(fmt::format("cannot merge: {} is from the '{}' suite but {} is from the '{}' suite", label(i),
                              parts[i].suite, label(0), suite));
  const std::vector<const VerifyCase*> order = verify_suite(suite);
  std::map<std::string, std::pair<std::size_t, const VerifyCaseResult*>> found;
  for (std::size_t i = 0; i < parts.size(); ++i)
    for (const VerifyCaseResult& c : parts[i].cases) {
      if (std::none_of(order.begin(), order.end(), [&](const VerifyCase* d) { return d->name == c.name; }))
        throw Error(fmt::format("cannot merge: {} holds case '{}', which is not in the {} suite of this voxelastic",
                                label(i), c.name, suite));
      const auto [it, fresh] = found.emplace(c.name, std::make_pair(i, &c));
      if (!fresh)
        throw Error(fmt::format("cannot merge: case '{}' is in both {} and {} (was a shard run twice?)", c.name,
                                label(it->second.first), label(i)));
    }
  std::vector<std::string> missing;
  for (const VerifyCase* d : order)
    if (!found.count(d->name)) missing.push_back(d->name);
  if (!missing.empty()) {
    std::string names;
    for (const auto& n : missing) names += (names.empty() ? "" : ", ") + n;
    throw Error(fmt::format("cannot merge: {} of the {} cases of the {} suite are missing: {} (did a shard fail or is "
                            "one folder missing?)",
                            missing.size(), order.size(), suite, names));
  }
  VerifyReport merged;
  merged.suite = suite;
  for (const VerifyCase* d : order) merged.cases.push_back(*found.at(d->name).second);
  return merged;
}

// --- output folders ----------------------------------------------------------------------------

VerifyStage::VerifyStage(const fs::path& dir) : dir_(dir) {
  std::error_code ec;
  fs::create_directories(dir_, ec);
  if (ec || !fs::is_directory(dir_))
    throw Error(fmt::format("--out '{}': cannot create the folder ({})", dir_.string(), ec ? ec.message() : "not a folder"));
  check_output_path(dir_ / "report.json");
  stage_ = dir_ / fmt::format(".verify-staging-{}", ::getpid());
  fs::remove_all(stage_, ec);
  fs::create_directories(stage_ / "plots", ec);
  if (ec) throw Error(fmt::format("--out '{}': cannot create the staging folder ({})", dir_.string(), ec.message()));
}

VerifyStage::~VerifyStage() {
  std::error_code ec;
  fs::remove_all(stage_, ec);
}

void VerifyStage::publish(const VerifyReport& report) {
  if (published_) throw Error("verify: the report was already published");
  write_text_atomically(stage_ / "cases.json", cases_json(report).dump(2) + "\n");
  write_text_atomically(stage_ / "report.md", report_markdown(report));
  write_text_atomically(stage_ / "report.json", report_json(report).dump(2) + "\n");
  std::error_code ec;
  const auto move = [&](const fs::path& from, const fs::path& to) {
    fs::rename(from, to, ec);
    if (ec) throw Error(fmt::format("cannot move '{}' to '{}': {}", from.string(), to.string(), ec.message()));
  };
  // plots/ is replaced as a whole, so no plot of an earlier run is left behind
  if (fs::exists(dir_ / "plots")) move(dir_ / "plots", stage_ / "plots-old");
  move(stage_ / "plots", dir_ / "plots");
  move(stage_ / "cases.json", dir_ / "cases.json");
  move(stage_ / "report.md", dir_ / "report.md");
  move(stage_ / "report.json", dir_ / "report.json");  // last: its presence means the report is whole
  published_ = true;
}

VerifyReport read_report_dir(const fs::path& dir) {
  const auto read = [&](const char* name) {
    const fs::path p = dir / name;
    std::ifstream in(p);
    if (!in)
      throw Error(fmt::format("'{}' has no {} (is it the --out folder of `voxelastic verify`?)", dir.string(), name));
    try {
      return json::parse(in);
    } catch (const json::exception& e) {
      throw Error(fmt::format("'{}' is not valid JSON: {}", p.string(), e.what()));
    }
  };
  const json report = read("report.json");  // first: its absence is the clearer message
  const json cases = read("cases.json");
  return parse_report(report, cases, dir.string());
}

void copy_report_plots(const std::vector<fs::path>& dirs, const std::vector<VerifyReport>& parts, const fs::path& stage_dir) {
  std::error_code ec;
  fs::create_directories(stage_dir / "plots", ec);
  for (std::size_t i = 0; i < dirs.size() && i < parts.size(); ++i)
    for (const VerifyCaseResult& c : parts[i].cases)
      for (const VerifyPlot& p : c.plots) {
        const fs::path rel(p.file);
        if (rel.is_absolute() || rel.parent_path() != "plots")
          throw Error(fmt::format("'{}': plot '{}' is not under plots/", dirs[i].string(), p.file));
        fs::copy_file(dirs[i] / rel, stage_dir / rel, fs::copy_options::overwrite_existing, ec);
        if (ec)
          throw Error(fmt::format("cannot copy plot '{}' of '{}': {}", p.file, dirs[i].string(), ec.message()));
      }
}

}  // namespace vx
