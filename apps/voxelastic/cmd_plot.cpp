// voxelastic plot SPEC.json -o OUT.png: a line or point plot from a JSON description, drawn as
// voxelastic draws its own (render/plot.h: no display, no other program); for scripts such as
// the palpation sweep's gather (workflow/scripts/detectability.py).
#include <fmt/format.h>

#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <memory>
#include <sstream>
#include <string>

#include "base/error.h"
#include "commands.h"
#include "render/plot.h"
#include "util/atomic_file.h"

namespace vx::cli {
namespace {
namespace fs = std::filesystem;

struct PlotOptions {
  std::string spec;    ///< a JSON file, or "-" for standard input
  std::string output;  ///< the PNG
};

void run_plot(const PlotOptions& o) {
  if (fs::path(o.output).extension() != ".png")
    throw CLI::ValidationError("-o", fmt::format("'{}': give a .png path", o.output));
  std::string text;
  if (o.spec == "-") {
    text.assign(std::istreambuf_iterator<char>(std::cin), std::istreambuf_iterator<char>());
  } else {
    std::ifstream in(o.spec);
    if (!in) throw Error(fmt::format("'{}': cannot read the plot description", o.spec));
    std::ostringstream s;
    s << in.rdbuf();
    text = s.str();
  }
  check_output_path(o.output);
  const PlotSpec spec = parse_plot_spec(text);
  plot_png(spec.panels, o.output, spec.width, spec.panel_height);
  if (!quiet()) fmt::print("wrote {} ({} x {} pixels)\n", o.output, spec.width, spec.panel_height * spec.panels.size());
}

}  // namespace

void add_plot_command(CLI::App& app) {
  auto opts = std::make_shared<PlotOptions>();
  auto* sub = app.add_subcommand(
      "plot",
      "Draw a line or point plot described in JSON into a PNG, without a display (for scripts; the keys are "
      "listed in pipeline/render/plot.h: panels with title, xlabel, ylabel, log_x, log_y, key, xrange, yrange "
      "and series with title, x, y, points, with_points, line_width, dash_type, point_type, color).");
  sub->add_option("SPEC", opts->spec, "the plot as JSON, or - for standard input")->required()->type_name("SPEC.json");
  sub->add_option("-o,--output", opts->output, "the PNG to write")->required()->type_name("OUT.png");
  sub->callback([opts] { run_plot(*opts); });
}

}  // namespace vx::cli
