// The machinery of `voxelastic verify` (evaluation/verify/verify.h): checks and their rules, suites and
// shards, report.json round trips, merging partial reports, report.md, the staged output folder,
// and one real case run end to end.
#include "verify/verify.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>

#include "base/error.h"
#include "support/png_stats.h"

namespace fs = std::filesystem;
using json = nlohmann::json;
using namespace vx;

namespace {

/// A report of `names` (cases of the quick suite), one passing check each, and one failing check
/// for the case named `failing`.
VerifyReport fake_report(const std::vector<std::string>& names, const std::string& failing = "") {
  VerifyReport r;
  r.suite = "quick";
  for (const std::string& n : names) {
    VerifyCaseResult c;
    c.name = n;
    c.seconds = 1.5;
    VerifyCheck k = make_check(n + ".ratio", 1.01, 1.0, 0.05, "", CheckRule::within, "a ratio");
    k.case_name = n;
    c.checks.push_back(k);
    if (n == failing) {
      VerifyCheck f = make_check(n + ".bound", 2.0, 1.0, 0.5, "mm", CheckRule::at_most, "a bound");
      f.case_name = n;
      c.checks.push_back(f);
    }
    c.plots.push_back({"plots/" + n + "-x.png", "a plot of " + n});
    c.lines.push_back("figures of " + n);
    r.cases.push_back(std::move(c));
  }
  return r;
}

std::vector<std::string> quick_names() {
  std::vector<std::string> out;
  for (const VerifyCase* c : verify_suite("quick")) out.push_back(c->name);
  return out;
}

class VerifyDir : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_verify_test_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

}  // namespace

TEST(Verify, CheckRules) {
  EXPECT_TRUE(make_check("a", 1.04, 1.0, 0.05, "").passed);
  EXPECT_TRUE(make_check("a", 0.951, 1.0, 0.05, "").passed);
  EXPECT_FALSE(make_check("a", 1.06, 1.0, 0.05, "").passed);
  EXPECT_FALSE(make_check("a", 0.94, 1.0, 0.05, "").passed);
  EXPECT_TRUE(make_check("a", 0.0, 1.0, 0.0, "", CheckRule::at_most).passed);
  EXPECT_TRUE(make_check("a", 1.1, 1.0, 0.1, "", CheckRule::at_most).passed);
  EXPECT_FALSE(make_check("a", 1.2, 1.0, 0.1, "", CheckRule::at_most).passed);
  EXPECT_TRUE(make_check("a", 5.0, 1.3, 0.0, "", CheckRule::at_least).passed);
  EXPECT_FALSE(make_check("a", 1.29, 1.3, 0.0, "", CheckRule::at_least).passed);
  // exact checks (counts) and unmeasurable values
  EXPECT_TRUE(make_check("a", 23816, 23816, 0.0, "elements").passed);
  EXPECT_FALSE(make_check("a", 23815, 23816, 0.0, "elements").passed);
  EXPECT_FALSE(make_check("a", std::nan(""), 1.0, 1e9, "").passed);
  EXPECT_FALSE(make_check("a", std::nan(""), 1.0, 0.0, "", CheckRule::at_most).passed);
  EXPECT_FALSE(make_check("a", 1.0, 1.0, -1.0, "").passed);
}

TEST(Verify, SuitesAreStableAndQuickIsInFull) {
  const auto quick = verify_suite("quick"), full = verify_suite("full");
  ASSERT_EQ(full.size(), verify_cases().size());
  EXPECT_GE(quick.size(), 10u);
  EXPECT_LT(quick.size(), full.size());
  std::set<std::string> names;
  for (std::size_t i = 0; i < full.size(); ++i) {
    EXPECT_EQ(full[i], &verify_cases()[i]) << "full keeps the table's order";
    EXPECT_TRUE(names.insert(full[i]->name).second) << "duplicate case " << full[i]->name;
    EXPECT_FALSE(full[i]->about.empty()) << full[i]->name << " explains itself";
    EXPECT_EQ(find_verify_case(full[i]->name), full[i]);
  }
  // quick is the quick-marked cases, in the same relative order
  std::size_t j = 0;
  for (const VerifyCase* c : full)
    if (c->quick) {
      ASSERT_EQ(quick.at(j++), c);
    }
  EXPECT_EQ(j, quick.size());
  // the known-failing gradational compression is not in the quick (CI) suite
  EXPECT_EQ(std::count_if(quick.begin(), quick.end(), [](const VerifyCase* c) { return c->name == "compression-gradational"; }), 0);
  EXPECT_THROW((void)verify_suite("medium"), Error);
  EXPECT_EQ(find_verify_case("no-such-case"), nullptr);
}

TEST(Verify, ShardsParseAndPartitionTheSuite) {
  const Shard s = parse_shard("2/5");
  EXPECT_EQ(s.index, 2);
  EXPECT_EQ(s.count, 5);
  EXPECT_EQ(s.str(), "2/5");
  EXPECT_TRUE(parse_shard("0/1").whole());
  for (const char* bad : {"3/2", "2/2", "0/0", "1", "", "/", "a/b", "-1/2", "1/-2", "1/2/3", "0/20000", " 0/2", "1.5/3"})
    EXPECT_THROW((void)parse_shard(bad), Error) << "'" << bad << "'";
  try {
    (void)parse_shard("3/2");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("I must be below N"), std::string::npos) << e.what();
  }
  // every case in exactly one shard, for any N
  const int cases = int(verify_suite("full").size());
  for (int n : {1, 2, 3, 7, 40}) {
    std::vector<int> hits(std::size_t(cases), 0);
    for (int i = 0; i < n; ++i)
      for (int c = 0; c < cases; ++c) hits[std::size_t(c)] += Shard{i, n}.contains(c) ? 1 : 0;
    for (int h : hits) EXPECT_EQ(h, 1) << "N = " << n;
  }
}

TEST(Verify, ReportJsonHasTheDocumentedShapeAndRoundTrips) {
  VerifyReport r = fake_report({"model-counts", "geometry"}, "geometry");
  r.cases[0].checks[0].value = std::nan("");  // an unmeasurable value is written as null
  r.cases[0].checks[0].passed = false;
  const json j = report_json(r);
  ASSERT_EQ(j.size(), 2u);
  EXPECT_EQ(j.at("suite"), "quick");
  ASSERT_EQ(j.at("checks").size(), 3u);
  const json& k0 = j["checks"][0];
  EXPECT_EQ(k0.at("name"), "model-counts.ratio");
  EXPECT_EQ(k0.at("passed"), false);
  EXPECT_TRUE(k0.at("value").is_null());
  EXPECT_EQ(k0.at("expected"), 1.0);
  EXPECT_EQ(k0.at("tolerance"), 0.05);
  EXPECT_EQ(k0.at("unit"), "");
  EXPECT_EQ(k0.at("case"), "model-counts");
  EXPECT_EQ(k0.at("note"), "a ratio");
  EXPECT_FALSE(k0.contains("comparison")) << "two-sided checks carry no comparison";
  const json& k2 = j["checks"][2];
  EXPECT_EQ(k2.at("name"), "geometry.bound");
  EXPECT_EQ(k2.at("comparison"), "<=");
  EXPECT_EQ(k2.at("passed"), false);
  EXPECT_EQ(k2.at("unit"), "mm");
  for (const json& k : j["checks"])
    for (const auto& [key, v] : k.items())
      EXPECT_TRUE(std::set<std::string>({"name", "passed", "value", "expected", "tolerance", "unit", "case", "note",
                                         "comparison"})
                      .count(key))
          << key;

  // round trip through text
  const VerifyReport back = parse_report(json::parse(j.dump()), json::parse(cases_json(r).dump()), "test");
  ASSERT_EQ(back.cases.size(), 2u);
  EXPECT_EQ(back.suite, "quick");
  EXPECT_EQ(back.cases[1].name, "geometry");
  EXPECT_DOUBLE_EQ(back.cases[1].seconds, 1.5);
  ASSERT_EQ(back.cases[1].checks.size(), 2u);
  EXPECT_EQ(back.cases[1].checks[1].rule, CheckRule::at_most);
  EXPECT_DOUBLE_EQ(back.cases[1].checks[1].value, 2.0);
  EXPECT_TRUE(std::isnan(back.cases[0].checks[0].value));
  EXPECT_EQ(back.cases[1].plots.at(0).file, "plots/geometry-x.png");
  EXPECT_EQ(back.cases[1].lines.at(0), "figures of geometry");
  EXPECT_EQ(back.failures().size(), 2u);

  // malformed reports are refused with the file and the entry
  json bad = j;
  bad["checks"][1].erase("passed");
  EXPECT_THROW((void)parse_report(bad, cases_json(r), "x"), Error);
  bad = j;
  bad["checks"][1]["case"] = "elsewhere";
  try {
    (void)parse_report(bad, cases_json(r), "x");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("elsewhere"), std::string::npos) << e.what();
  }
  json other = cases_json(r);
  other["suite"] = "full";
  EXPECT_THROW((void)parse_report(j, other, "x"), Error);
}

TEST(Verify, MergeCombinesShardsInSuiteOrderAndRefusesGapsAndDuplicates) {
  const auto names = quick_names();
  std::vector<std::string> a, b;
  for (std::size_t i = 0; i < names.size(); ++i) (i % 2 ? b : a).push_back(names[i]);
  const VerifyReport ra = fake_report(a), rb = fake_report(b, names[1]);
  const VerifyReport merged = merge_reports({rb, ra}, {"shard1", "shard0"});
  ASSERT_EQ(merged.cases.size(), names.size());
  for (std::size_t i = 0; i < names.size(); ++i) EXPECT_EQ(merged.cases[i].name, names[i]);
  EXPECT_TRUE(merged.shard.empty());
  EXPECT_EQ(merged.checks().size(), names.size() + 1);
  ASSERT_EQ(merged.failures().size(), 1u);
  EXPECT_EQ(merged.failures()[0]->name, names[1] + ".bound");

  const auto message = [](const std::function<void()>& f) {
    try {
      f();
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  // a missing shard: the missing cases are named
  const std::string missing = message([&] { (void)merge_reports({ra}, {"shard0"}); });
  EXPECT_NE(missing.find("missing"), std::string::npos) << missing;
  EXPECT_NE(missing.find(names[1]), std::string::npos) << missing;
  // a shard given twice
  const std::string dup = message([&] { (void)merge_reports({ra, rb, ra}, {"s0", "s1", "s0again"}); });
  EXPECT_NE(dup.find(names[0]), std::string::npos) << dup;
  EXPECT_NE(dup.find("s0again"), std::string::npos) << dup;
  // suites differ
  VerifyReport full = rb;
  full.suite = "full";
  const std::string suites = message([&] { (void)merge_reports({ra, full}, {"s0", "s1"}); });
  EXPECT_NE(suites.find("suite"), std::string::npos) << suites;
  // a case the suite does not have
  const std::string foreign = message([&] { (void)merge_reports({ra, rb, fake_report({"compression-gradational"})}, {}); });
  EXPECT_NE(foreign.find("compression-gradational"), std::string::npos) << foreign;
  EXPECT_THROW((void)merge_reports({}, {}), Error);
}

TEST(Verify, MarkdownExplainsListsAndLinks) {
  const VerifyReport ok = fake_report({"model-counts", "geometry"});
  const std::string md = report_markdown(ok);
  EXPECT_NE(md.find("**PASSED**: all 2 checks of 2 cases"), std::string::npos) << md;
  EXPECT_NE(md.find("How to read this report"), std::string::npos);
  EXPECT_NE(md.find("![a plot of geometry](plots/geometry-x.png)"), std::string::npos);
  EXPECT_NE(md.find("| `ratio` | pass | 1.01 | 1 ± 0.05 |"), std::string::npos) << md;
  EXPECT_NE(md.find(find_verify_case("geometry")->about.substr(0, 40)), std::string::npos) << "the case's explanation";
  const std::string bad = report_markdown(fake_report({"geometry"}, "geometry"));
  EXPECT_NE(bad.find("**FAILED**: 1 of 2 checks failed"), std::string::npos) << bad;
  EXPECT_NE(bad.find("| `bound` | **FAIL** | 2 | ≤ 1.5 | mm |"), std::string::npos) << bad;
}

TEST_F(VerifyDir, StagePublishesWholeReportsAndLeavesNothingOnFailure) {
  const fs::path out = dir_ / "out";
  {
    VerifyStage stage(out);
    ASSERT_TRUE(fs::is_directory(stage.path() / "plots"));
    std::ofstream(stage.path() / "plots" / "geometry-x.png") << "png";
    stage.publish(fake_report({"geometry"}));
  }
  for (const char* f : {"report.json", "report.md", "cases.json", "plots/geometry-x.png"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  const VerifyReport back = read_report_dir(out);
  EXPECT_EQ(back.cases.at(0).name, "geometry");
  // an abandoned run (exception before publish) removes its stage and keeps the old report
  const std::string before = [&] {
    std::ifstream in(out / "report.json");
    return std::string(std::istreambuf_iterator<char>(in), {});
  }();
  try {
    VerifyStage stage(out);
    std::ofstream(stage.path() / "plots" / "half.png") << "half";
    throw Error("a case crashed");
  } catch (const Error&) {
  }
  std::set<std::string> names;
  for (const auto& e : fs::directory_iterator(out)) names.insert(e.path().filename().string());
  EXPECT_EQ(names, (std::set<std::string>{"cases.json", "plots", "report.json", "report.md"}));
  std::ifstream in(out / "report.json");
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), before);
  // a second publish replaces plots/ as a whole
  {
    VerifyStage stage(out);
    std::ofstream(stage.path() / "plots" / "model-counts-x.png") << "png";
    stage.publish(fake_report({"model-counts"}));
  }
  EXPECT_FALSE(fs::exists(out / "plots" / "geometry-x.png"));
  EXPECT_TRUE(fs::exists(out / "plots" / "model-counts-x.png"));
  // merge copies the plots a report refers to
  const fs::path merged = dir_ / "merged";
  {
    VerifyStage stage(merged);
    copy_report_plots({out}, {read_report_dir(out)}, stage.path());
    EXPECT_TRUE(fs::exists(stage.path() / "plots" / "model-counts-x.png"));
  }
  // a folder that cannot be created: a file where a folder should be
  std::ofstream(dir_ / "file") << "x";
  EXPECT_THROW(VerifyStage(dir_ / "file" / "sub"), Error);
  EXPECT_THROW((void)read_report_dir(dir_), Error) << "no report.json";
}

TEST_F(VerifyDir, RunsARealCaseAndRefusesBadRequests) {
  VerifyRunOptions o;
  o.suite = "quick";
  o.jobs = 2;
  o.only = {"model-counts"};
  std::vector<std::string> progress;
  o.progress = [&](const std::string& l) { progress.push_back(l); };
  const VerifyReport r = run_verify(o, dir_);
  ASSERT_EQ(r.cases.size(), 1u);
  EXPECT_EQ(r.shard, "0/1") << "a subset is a partial report";
  const VerifyCaseResult& c = r.cases[0];
  EXPECT_EQ(c.name, "model-counts");
  EXPECT_TRUE(c.error.empty()) << c.error;
  EXPECT_GE(c.seconds, 0.0);
  ASSERT_EQ(progress.size(), 1u);
  EXPECT_NE(progress[0].find("[1/1] model-counts: passed"), std::string::npos) << progress[0];
  // the paper's shells, exactly
  bool found = false;
  for (const VerifyCheck& k : c.checks) {
    EXPECT_TRUE(k.passed) << k.name << ": " << k.value << " vs " << k.expected;
    EXPECT_EQ(k.case_name, "model-counts");
    if (k.name == "model-counts.cube128.level0_elements") {
      found = true;
      EXPECT_EQ(k.value, 23816);
    }
  }
  EXPECT_TRUE(found);
  ASSERT_FALSE(c.plots.empty());
  const auto png = vx::testing::png_stats(dir_ / c.plots[0].file);  // a real picture, not an empty file
  EXPECT_GT(png.width, 400) << c.plots[0].file;
  EXPECT_GT(png.drawn, 5000) << c.plots[0].file;
  EXPECT_GT(png.colours, 20) << c.plots[0].file;

  o.jobs = 0;
  EXPECT_THROW((void)run_verify(o, dir_), Error);
  o.jobs = 1;
  o.only = {"compression-gradational"};  // in full only
  EXPECT_THROW((void)run_verify(o, dir_), Error);
  o.only = {"model-counts"};
  o.shard = {1, 2};  // model-counts is case 0
  EXPECT_THROW((void)run_verify(o, dir_), Error);
  o.suite = "nope";
  EXPECT_THROW((void)run_verify(o, dir_), Error);
}
