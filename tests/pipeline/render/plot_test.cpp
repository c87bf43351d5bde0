#include "render/plot.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <filesystem>

#include "base/error.h"
#include "support/png_stats.h"

using namespace vx;
namespace fs = std::filesystem;
using vx::testing::png_dark_pixels;
using vx::testing::png_stats;

namespace {

class Plot : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("vx_plot_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    // VX_KEEP_PNG=folder keeps the pictures for a look
    if (const char* keep = std::getenv("VX_KEEP_PNG"))
      for (const auto& f : fs::directory_iterator(dir_))
        fs::copy_file(f.path(), fs::path(keep) / f.path().filename(), fs::copy_options::overwrite_existing);
    fs::remove_all(dir_);
  }
  fs::path dir_;
};

/// Two curves; without `labels` the title and axis labels are blanks (the same layout, no ink).
PlotPanel two_curves(bool labels) {
  PlotPanel p;
  p.title = labels ? "A sine and a cosine" : " ";
  p.xlabel = labels ? "time (s)" : " ";
  p.ylabel = labels ? "force (N)" : " ";
  PlotSeries a, b;
  a.title = "sine";
  b.title = "cosine";
  b.dash_type = 2;
  for (int i = 0; i <= 200; ++i) {
    const double t = i * 0.05;
    a.x.push_back(t), a.y.push_back(std::sin(t));
    b.x.push_back(t), b.y.push_back(std::cos(t));
  }
  p.series = {a, b};
  return p;
}

/// Pixels within 40 of colour (r, g, b) in every channel.
long long pixels_near(const fs::path& png, int r, int g, int b) {
  vtkNew<vtkPNGReader> rd;
  rd->SetFileName(png.string().c_str());
  rd->Update();
  int dims[3];
  rd->GetOutput()->GetDimensions(dims);
  long long n = 0;
  for (int y = 0; y < dims[1]; ++y)
    for (int x = 0; x < dims[0]; ++x) {
      const auto c = vx::testing::png_pixel(rd->GetOutput(), x, y);
      n += std::abs(c[0] - r) < 40 && std::abs(c[1] - g) < 40 && std::abs(c[2] - b) < 40;
    }
  return n;
}

}  // namespace

TEST(PlotTicks, RoundStepsAndDecades) {
  EXPECT_EQ(plot_ticks(0, 10, false, 5), (std::vector<double>{0, 2, 4, 6, 8, 10}));
  EXPECT_EQ(plot_ticks(0, 1, false, 5), (std::vector<double>{0, 0.2, 0.4, 0.6000000000000001, 0.8, 1}));
  const auto t = plot_ticks(-0.3, 0.35, false, 6);  // step 0.1, inside the range
  ASSERT_EQ(t.size(), 7u);
  EXPECT_NEAR(t.front(), -0.3, 1e-12);
  EXPECT_NEAR(t.back(), 0.3, 1e-12);
  const auto d = plot_ticks(1, 1000, true);
  ASSERT_EQ(d.size(), 4u);
  for (std::size_t i = 0; i < d.size(); ++i) EXPECT_NEAR(d[i], std::pow(10.0, double(i)), 1e-9);
  // a narrow log range: 1, 2 and 5 labelled
  const auto n = plot_ticks(1, 30, true);
  EXPECT_EQ(n, (std::vector<double>{1, 2, 5, 10, 20}));
}

TEST_F(Plot, DrawsLinesInTheirColoursAndTheText) {
  const fs::path with = dir_ / "with_text.png", without = dir_ / "without_text.png";
  plot_png({two_curves(true)}, with, 800, 400);
  plot_png({two_curves(false)}, without, 800, 400);
  const auto s = png_stats(with);
  EXPECT_EQ(s.width, 800);
  EXPECT_EQ(s.height, 400);
  EXPECT_GT(s.drawn, 8000);    // frame, grid, two curves, text
  EXPECT_GT(s.colours, 50);    // anti-aliased edges
  EXPECT_LT(s.drawn, 400000);  // not a filled box
  // the two series in the first two colours of the cycle (#1f77b4, #d62728)
  EXPECT_GT(pixels_near(with, 0x1f, 0x77, 0xb4), 600);
  EXPECT_GT(pixels_near(with, 0xd6, 0x27, 0x28), 300);
  // the axis labels: ink under the x tick labels and left of the y tick labels only with text
  EXPECT_GT(png_dark_pixels(with, 200, 365, 600, 400), 40);  // "time (s)"
  EXPECT_EQ(png_dark_pixels(without, 200, 365, 600, 400), 0);
  EXPECT_GT(png_dark_pixels(with, 0, 100, 30, 350), 40);  // "force (N)", turned
  EXPECT_EQ(png_dark_pixels(without, 0, 100, 30, 350), 0);
  EXPECT_GT(png_dark_pixels(with, 200, 0, 600, 30), 60);  // the title
  // tick labels are there in both
  EXPECT_GT(png_dark_pixels(without, 0, 30, 60, 360), 40);
  for (const auto& f : fs::directory_iterator(dir_))  // no temporary files left
    EXPECT_EQ(f.path().filename().string().find(".tmp"), std::string::npos) << f.path();
}

namespace {

/// The box of the pixels darker than 128 in [x0, x1) x [y0, y1): {left, top, right, bottom},
/// inclusive ({x1, y1, x0 - 1, y0 - 1} when there are none).
std::array<int, 4> ink_box(const fs::path& png, int x0, int y0, int x1, int y1) {
  vtkNew<vtkPNGReader> rd;
  rd->SetFileName(png.string().c_str());
  rd->Update();
  std::array<int, 4> b{x1, y1, x0 - 1, y0 - 1};
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      const auto c = vx::testing::png_pixel(rd->GetOutput(), x, y);
      if (c[0] < 128 && c[1] < 128 && c[2] < 128)
        b = {std::min(b[0], x), std::min(b[1], y), std::max(b[2], x), std::max(b[3], y)};
    }
  return b;
}

}  // namespace

TEST_F(Plot, CaretsAreSuperscriptsAsInGnuplot) {
  // "n^{22}" against "n22": the 22 raised above the n and smaller (a narrower label), the caret
  // and braces not drawn; the same turned on the y axis, and a one-character "n^2"
  const auto draw = [&](const std::string& x_text, const std::string& y_text, const char* name) {
    PlotPanel p = two_curves(false);
    p.xlabel = x_text;
    p.ylabel = y_text;
    plot_png({p}, dir_ / name, 800, 400);
    return dir_ / name;
  };
  const fs::path plain = draw("n22", "n22", "plain.png"), raised = draw("n^{22}", "n^{22}", "raised.png"),
                 one = draw("n^2", "n^2", "one.png"), digit = draw("n2", "n2", "digit.png");
  // along the x label: smaller digits, no caret or braces
  const auto w = [](const std::array<int, 4>& b) { return b[2] - b[0] + 1; };
  const auto h = [](const std::array<int, 4>& b) { return b[3] - b[1] + 1; };
  const auto px = ink_box(plain, 200, 360, 600, 400), rx = ink_box(raised, 200, 360, 600, 400);
  ASSERT_GT(w(px), 0);
  ASSERT_GT(w(rx), 0);
  EXPECT_LT(w(rx), w(px) - 3);
  EXPECT_GT(w(rx), w(px) / 2);
  // across it: the last digit's lowest ink (its baseline) above the n's, for the raised ones only
  const auto raised_by = [&](const fs::path& png, const std::array<int, 4>& b) {
    const auto first = ink_box(png, b[0], b[1], b[0] + 3, b[3] + 1),
               last = ink_box(png, b[2] - 2, b[1], b[2] + 1, b[3] + 1);
    return first[3] - last[3];
  };
  EXPECT_LE(std::abs(raised_by(plain, px)), 1);
  EXPECT_GE(raised_by(raised, rx), 4);
  const auto ox = ink_box(one, 200, 360, 600, 400), dx = ink_box(digit, 200, 360, 600, 400);
  EXPECT_LT(w(ox), w(dx));
  EXPECT_LE(std::abs(raised_by(digit, dx)), 1);
  EXPECT_GE(raised_by(one, ox), 4);
  // turned: the label reads upwards, the n at its bottom, the digits raised to the left
  const auto py = ink_box(plain, 0, 100, 30, 350), ry = ink_box(raised, 0, 100, 30, 350);
  ASSERT_GT(h(py), 0);
  ASSERT_GT(h(ry), 0);
  EXPECT_LT(h(ry), h(py) - 3);
  const auto turned_raised_by = [&](const fs::path& png, const std::array<int, 4>& b) {
    const auto first = ink_box(png, b[0], b[3] - 2, b[2] + 1, b[3] + 1),
               last = ink_box(png, b[0], b[1], b[2] + 1, b[1] + 3);
    return first[2] - last[2];
  };
  EXPECT_LE(std::abs(turned_raised_by(plain, py)), 1);
  EXPECT_GE(turned_raised_by(raised, ry), 4);
  // a '^' with nothing after it, or an unclosed group, is drawn as written
  const fs::path caret = draw("n^", " ", "caret.png"), bare = draw("n", " ", "bare.png");
  EXPECT_GT(png_dark_pixels(caret, 200, 365, 600, 400), png_dark_pixels(bare, 200, 365, 600, 400));
  EXPECT_NO_THROW(draw("n^{22", " ", "open.png"));
}

TEST_F(Plot, LogAxesBoxesColourBarAndStackedPanels) {
  PlotPanel log;
  log.title = "error against run time";
  log.xlabel = "run time (s)";
  log.ylabel = "error";
  log.log_x = log.log_y = true;
  log.key = "outside right top";
  PlotSeries s;
  s.title = "points";
  s.points = true;
  s.point_type = 13;
  s.x = {0.01, 0.1, 1, 10, -1};  // -1 dropped on a log axis
  s.y = {1, 0.3, 0.1, 0.01, 5};
  log.series = {s};
  PlotPanel map;
  map.title = "a map";
  map.equal_aspect = true;
  map.color_bar = {"stiffness, N/mm", 0.0, 1.0};
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 5; ++j) map.rects.push_back({double(i), double(j), i + 1.0, j + 1.0, "", (i + j) / 14.0});
  map.labels.push_back({"estimate", 5, 2.5, "red", true});
  map.key = "below";
  const fs::path png = dir_ / "two.png";
  plot_png({log, map}, png, 900, 380);
  const auto st = png_stats(png);
  EXPECT_EQ(st.width, 900);
  EXPECT_EQ(st.height, 760);
  // the viridis ends (#440154 and #fde725) in the map and its bar
  EXPECT_GT(pixels_near(png, 0x44, 0x01, 0x54), 200);
  EXPECT_GT(pixels_near(png, 0xfd, 0xe7, 0x25), 200);
  // the diamonds in the cycle's first colour, in the upper panel only
  EXPECT_GT(pixels_near(png, 0x1f, 0x77, 0xb4), 60);
}

TEST_F(Plot, EmptyPanelsSayNoDataAndBadInputIsAnError) {
  PlotPanel empty;
  empty.title = "nothing";
  plot_png({empty}, dir_ / "empty.png", 400, 300);
  EXPECT_GT(png_stats(dir_ / "empty.png").drawn, 500);
  PlotPanel bad = two_curves(true);
  bad.series[0].color = "chartreuse-ish";
  EXPECT_THROW(plot_png({bad}, dir_ / "bad.png", 400, 300), Error);
  bad = two_curves(true);
  bad.xrange = "[0:";
  EXPECT_THROW(plot_png({bad}, dir_ / "bad.png", 400, 300), Error);
  bad.xrange = "[0:x]";
  EXPECT_THROW(plot_png({bad}, dir_ / "bad.png", 400, 300), Error);
  EXPECT_THROW(plot_png({}, dir_ / "bad.png"), Error);
  EXPECT_THROW(plot_png({two_curves(true)}, dir_ / "missing" / "bad.png"), Error);
  EXPECT_FALSE(fs::exists(dir_ / "bad.png"));
  // a fixed range holds: a curve outside it is clipped, not drawn over the margins
  PlotPanel clip = two_curves(false);
  clip.yrange = "[-0.2:0.2]";
  clip.series.resize(1);
  plot_png({clip}, dir_ / "clip.png", 600, 300);
  EXPECT_GT(png_stats(dir_ / "clip.png").drawn, 2000);
}

TEST_F(Plot, SpecFromJsonForScripts) {
  const PlotSpec spec = parse_plot_spec(R"js({"width": 700, "panel_height": 300, "panels": [{
      "title": "contrast against depth", "xlabel": "depth (mm)", "ylabel": "contrast", "key": "outside right top",
      "yrange": "[0.9:*]", "series": [{"title": "r 3 mm", "x": [1, 2, 3], "y": [2.5, null, 1.2], "line_width": 2,
      "dash_type": 2, "color": "#1b9e77"}, {"x": [1, 3], "y": [2.5, 1.2], "points": true, "point_type": 6}]}]})js");
  EXPECT_EQ(spec.width, 700);
  EXPECT_EQ(spec.panel_height, 300);
  ASSERT_EQ(spec.panels.size(), 1u);
  const PlotPanel& p = spec.panels[0];
  EXPECT_EQ(p.key, "outside right top");
  ASSERT_EQ(p.series.size(), 2u);
  EXPECT_TRUE(std::isnan(p.series[0].y[1]));  // null: a gap
  EXPECT_EQ(p.series[0].dash_type, 2);
  EXPECT_TRUE(p.series[1].points);
  EXPECT_EQ(p.series[1].point_type, 6);
  plot_png(spec.panels, dir_ / "spec.png", spec.width, spec.panel_height);
  EXPECT_EQ(png_stats(dir_ / "spec.png").width, 700);
  // mistakes name the key
  auto error_of = [](const std::string& text) {
    try {
      (void)parse_plot_spec(text);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(error_of(R"({"panels": [{"series": [{"x": [1], "y": [1], "colour": "red"}]}]})")
                .find("$.panels[0].series[0].colour: unknown key"),
            std::string::npos);
  EXPECT_NE(error_of(R"({"panels": [{"series": [{"x": [1, 2], "y": [1]}]}]})").find("x has 2 values, y 1"),
            std::string::npos);
  EXPECT_NE(error_of(R"({"panels": [{"title": 3}]})").find("$.panels[0].title"), std::string::npos);
  EXPECT_NE(error_of(R"({"panels": [{"series": [{"x": ["a"], "y": [1]}]}]})").find("not a number"), std::string::npos);
  EXPECT_NE(error_of(R"({"panels": [{"series": [{"x": [1], "y": [1], "color": "mauve"}]}]})").find("unknown colour"),
            std::string::npos);
  EXPECT_NE(error_of("{").find("not valid JSON"), std::string::npos);
  EXPECT_NE(error_of("{}").find("nothing to draw"), std::string::npos);
}
