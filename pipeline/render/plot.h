#pragma once
/// @file plot.h
/// PNG plots without a display: line and point plots, filled boxes coloured by value (the
/// palpation map) and text, rasterised on the CPU into a VTK image (anti-aliased lines and
/// markers; text by VTK's FreeType tools, no OpenGL) and written by vtkPNGWriter. No shell, no
/// external program: works headless (CI, a server). Pixel sizes; data in the caller's units.
/// In every text (titles, axis labels, legends), `^c` and `^{...}` are superscripts, as in
/// gnuplot's enhanced text: "8 n^3", "depth^{1.5}, mm^{1.5}".

#include <filesystem>
#include <limits>
#include <string>
#include <vector>

namespace vx {

/// One curve.
struct PlotSeries {
  std::string title;         ///< the legend's text ("": not in the legend)
  std::vector<double> x, y;  ///< same length; non-finite samples break the line
  bool points{false};        ///< draw points instead of lines
  double line_width{1.5};    ///< pixels
  bool with_points{false};   ///< lines with a point at every sample
  int dash_type{0};          ///< 0 or 1 solid, 2 dashed, 3 dotted, 4 dash-dot
  int point_type{7};         ///< 7 disc, 6 open circle, 5 square, 9 triangle, 13 diamond, 1 plus, 2 cross
  std::string color{};       ///< "#rrggbb" or a name (black, red, orange, gray40, ...); "": the next of the cycle
};

/// A filled rectangle in data coordinates: a fixed colour, or a value coloured by the panel's
/// colour bar (when `color` is "").
struct PlotRect {
  double x0{0}, y0{0}, x1{0}, y1{0};
  std::string color{};
  double value{std::numeric_limits<double>::quiet_NaN()};
};

/// Text at a point in data coordinates (centred above it), with a cross marking the point when `marker`.
struct PlotLabel {
  std::string text;
  double x{0}, y{0};
  std::string color{"black"};
  bool marker{false};
};

/// The colour scale of value-coloured rectangles, drawn right of the plot (viridis).
struct PlotColorBar {
  std::string label;  ///< "" = no colour bar
  double lo{0}, hi{1};
};

/// One panel (plots are stacked vertically).
struct PlotPanel {
  std::string title, xlabel, ylabel;
  std::vector<PlotSeries> series;
  bool log_x{false}, log_y{false};  ///< logarithmic axes (samples <= 0 on them are dropped)
  std::string key{"best"};          ///< legend: "best" (the inside corner over the fewest samples), "top left",
                                    ///< "top right", "bottom left", "bottom right", "below", "outside right top"
  std::string xrange{}, yrange{};   ///< "[lo:hi]", either side "*" (automatic); "": automatic
  std::string subtitle{};           ///< a second, smaller title line
  std::vector<PlotRect> rects{};    ///< drawn under the series
  std::vector<PlotLabel> labels{};  ///< drawn over the series
  PlotColorBar color_bar{};
  bool equal_aspect{false};  ///< one unit on x as long as one on y (a map)
};

/// Draws the panels into one PNG (width x height pixels per panel), atomically.
/// Throws vx::Error on bad input (an unknown colour, a malformed range) or a failed write.
void plot_png(const std::vector<PlotPanel>& panels, const std::filesystem::path& png, int width = 900,
              int panel_height = 420);

/// Panels and picture size read from JSON (what `voxelastic plot` draws for scripts):
/// {"width": 900, "panel_height": 420, "panels": [{"title", "subtitle", "xlabel", "ylabel",
/// "log_x", "log_y", "key", "xrange", "yrange", "series": [{"title", "x": [...], "y": [...]
/// (null: a gap), "points", "with_points", "line_width", "dash_type", "point_type", "color"}]}]},
/// every key but "panels" optional, the meanings as in PlotPanel and PlotSeries.
struct PlotSpec {
  std::vector<PlotPanel> panels;
  int width{900}, panel_height{420};
};
/// Throws vx::Error naming the key ("panels[0].series[2].x: ...") for invalid JSON, an unknown
/// key or a value of the wrong type.
[[nodiscard]] PlotSpec parse_plot_spec(const std::string& json_text);
/// Throws vx::Error unless `color` is one plot_png draws: "#rrggbb", or black, white, red, blue,
/// green, orange, purple, brown, gray (grey), grayNN (NN percent of white).
void check_plot_color(const std::string& color);

/// Tick positions for an axis over [lo, hi]: round steps (1, 2 or 5 times a power of ten) about
/// `target` apart, or decades on a log axis. Exposed for tests.
[[nodiscard]] std::vector<double> plot_ticks(double lo, double hi, bool log, int target = 6);

}  // namespace vx
