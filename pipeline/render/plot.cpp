#include "render/plot.h"

#include <fmt/format.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <random>
#include <sstream>

#include "base/error.h"
#include "util/atomic_file.h"

namespace vx {
namespace fs = std::filesystem;

namespace {

/// A gnuplot single-quoted string ('' escapes a quote).
std::string gp_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("''") : std::string(1, c);
  return out + "'";
}

/// A shell single-quoted word.
std::string sh_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

std::string read_all(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

/// A unique temporary path.
fs::path temp_path(const std::string& stem, const std::string& ext) {
  std::random_device rd;
  return fs::temp_directory_path() / fmt::format("{}-{}-{:x}{}", stem, ::getpid(), rd(), ext);
}

}  // namespace

std::string find_gnuplot() {
  const char* path = std::getenv("PATH");
  std::string dirs = path ? path : "/usr/bin:/bin";
  std::stringstream ss(dirs);
  std::string dir;
  while (std::getline(ss, dir, ':')) {
    if (dir.empty()) continue;
    const fs::path exe = fs::path(dir) / "gnuplot";
    if (::access(exe.c_str(), X_OK) == 0) return exe.string();
  }
  return "";
}

void check_gnuplot() {
  const std::string exe = find_gnuplot();
  if (exe.empty())
    throw Error("plot: gnuplot was not found on PATH; install it (Debian: apt-get install gnuplot-nox) or set "
                "\"outputs\": {\"plot\": false} in the scene");
  const fs::path err = temp_path("vx-gnuplot-check", ".txt");
  const std::string cmd = fmt::format("{} -e {} > /dev/null 2> {}", sh_quote(exe),
                                      sh_quote("set terminal pngcairo; set output '/dev/null'; plot 1"),
                                      sh_quote(err.string()));
  const int rc = std::system(cmd.c_str());
  const std::string msg = read_all(err);
  std::error_code ec;
  fs::remove(err, ec);
  if (rc != 0)
    throw Error(fmt::format("plot: {} cannot draw PNGs (pngcairo terminal): {}; install gnuplot-nox or set \"outputs\": "
                            "{{\"plot\": false}} in the scene",
                            exe, msg.empty() ? "exit code " + std::to_string(rc) : msg));
}

void plot_png(const std::vector<PlotPanel>& panels, const fs::path& png, int width, int panel_height) {
  if (panels.empty()) throw Error("plot: nothing to draw");
  // the script, with the data inline as datablocks
  std::ostringstream gp;
  gp.precision(10);
  int block = 0;
  for (const auto& panel : panels)
    for (const auto& s : panel.series) {
      gp << "$D" << block++ << " << EOD\n";
      for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i)
        if (std::isfinite(s.x[i]) && std::isfinite(s.y[i]) && !(panel.log_x && s.x[i] <= 0) &&
            !(panel.log_y && s.y[i] <= 0))
          gp << s.x[i] << " " << s.y[i] << "\n";
      gp << "EOD\n";
    }
  gp << "set multiplot layout " << panels.size() << ",1\n";
  gp << "set grid\nset key top left\n";
  block = 0;
  for (const auto& panel : panels) {
    gp << "set title " << gp_quote(panel.title) << "\n";
    gp << "set xlabel " << gp_quote(panel.xlabel) << "\n";
    gp << "set ylabel " << gp_quote(panel.ylabel) << "\n";
    gp << (panel.log_x ? "set logscale x\n" : "unset logscale x\n");
    gp << (panel.log_y ? "set logscale y\n" : "unset logscale y\n");
    gp << "set key " << panel.key << "\n";
    gp << "set xrange " << (panel.xrange.empty() ? "[*:*]" : panel.xrange) << "\n";
    gp << "set yrange " << (panel.yrange.empty() ? "[*:*]" : panel.yrange) << "\n";
    if (panel.series.empty()) {
      gp << "set label 1 'no data' at graph 0.5, 0.5 center\nplot [0:1] [0:1] NaN notitle\nunset label 1\n";
      continue;
    }
    gp << "plot ";
    for (std::size_t k = 0; k < panel.series.size(); ++k) {
      const auto& s = panel.series[k];
      gp << (k ? ", " : "") << "$D" << block++ << " using 1:2 with "
         << (s.points ? "points" : s.with_points ? "linespoints" : "lines") << " lw " << s.line_width;
      if (s.points) gp << " pt " << s.point_type << " ps " << (s.point_type == 7 ? 0.4 : 0.9);
      if (s.with_points) gp << " pt " << s.point_type << " ps 0.8";
      if (s.dash_type > 0) gp << " dt " << s.dash_type;
      if (!s.color.empty()) gp << " lc rgb " << gp_quote(s.color);
      gp << " title " << gp_quote(s.title);
    }
    gp << "\n";
  }
  gp << "unset multiplot\n";

  gnuplot_png(gp.str(), png, width, panel_height * int(panels.size()));
}

std::string gnuplot_quote(const std::string& s) { return gp_quote(s); }

void gnuplot_png(const std::string& commands, const fs::path& png, int width, int height) {
  const std::string exe = find_gnuplot();
  if (exe.empty()) check_gnuplot();  // throws with the install hint
  write_atomically(png, [&](const fs::path& tmp) {
    std::ostringstream gp;
    gp << "set terminal pngcairo size " << width << "," << height << " enhanced font 'DejaVu Sans,10'\n";
    gp << "set output " << gp_quote(tmp.string()) << "\n";
    gp << commands;
    const fs::path script = temp_path("vx-plot", ".gp");
    const fs::path err = temp_path("vx-plot", ".txt");
    {
      std::ofstream out(script);
      out << gp.str();
      if (!out) throw Error("plot: cannot write the temporary script " + script.string());
    }
    const std::string cmd = fmt::format("{} {} > /dev/null 2> {}", sh_quote(exe), sh_quote(script.string()),
                                        sh_quote(err.string()));
    const int rc = std::system(cmd.c_str());
    const std::string msg = read_all(err);
    std::error_code ec;
    fs::remove(script, ec);
    fs::remove(err, ec);
    if (rc != 0 || !fs::exists(tmp) || fs::file_size(tmp) == 0)
      throw Error(fmt::format("plot: gnuplot failed drawing {}: {}", png.string(),
                              msg.empty() ? "exit code " + std::to_string(rc) : msg));
  });
}

}  // namespace vx
