#pragma once
/// @file plot.h
/// PNG line plots without a display, drawn by gnuplot (pngcairo terminal) from a temporary
/// script: the data travel inside the script as datablocks, so nothing else is written.

#include <filesystem>
#include <string>
#include <vector>

namespace vx {

/// One curve.
struct PlotSeries {
  std::string title;
  std::vector<double> x, y;  ///< same length
  bool points{false};        ///< draw points instead of lines
  double line_width{1.5};
  bool with_points{false};   ///< lines with a point at every sample
  int dash_type{0};          ///< gnuplot dash type: 0 solid, 2 dashed, 3 dotted, ...
  int point_type{7};         ///< gnuplot point type (7 disc, 5 square, 9 triangle, 13 diamond, ...)
  std::string color{};       ///< gnuplot colour name or "#rrggbb" ("": the next of gnuplot's cycle)
};

/// One panel (plots are stacked vertically).
struct PlotPanel {
  std::string title, xlabel, ylabel;
  std::vector<PlotSeries> series;
  bool log_x{false}, log_y{false};  ///< logarithmic axes (samples <= 0 on them are dropped)
  std::string key{"top left"};      ///< gnuplot key position, e.g. "top right", "bottom right", "below"
  std::string xrange{}, yrange{};   ///< gnuplot ranges, e.g. "[10:300]" ("": automatic)
};

/// The gnuplot executable found on PATH, or "" when there is none.
[[nodiscard]] std::string find_gnuplot();

/// Throws vx::Error unless gnuplot with the pngcairo terminal is available, saying how to
/// install it (gnuplot-nox) or how to do without (`"plot": false` in the scene's outputs).
void check_gnuplot();

/// Draws the panels into one PNG (width x height pixels per panel), atomically.
/// Throws vx::Error with gnuplot's message on failure.
void plot_png(const std::vector<PlotPanel>& panels, const std::filesystem::path& png, int width = 900,
              int panel_height = 420);

/// Runs a gnuplot script (its commands after the terminal and output, which this sets:
/// pngcairo, width x height pixels) into a PNG, atomically: for pictures that are not line
/// plots (the palpation map). Throws vx::Error with gnuplot's message on failure.
void gnuplot_png(const std::string& commands, const std::filesystem::path& png, int width, int height);

/// `s` as a gnuplot single-quoted string.
[[nodiscard]] std::string gnuplot_quote(const std::string& s);

}  // namespace vx
