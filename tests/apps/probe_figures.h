#pragma once
// The figures `voxelastic-probe` prints in its last lines and status lines, read back by the app's
// tests (probe_app_test.cpp, probe_display_test.cpp).

#include <regex>
#include <sstream>
#include <string>
#include <vector>

namespace vx::testing {

struct Figures {
  double startup_s{-1}, sim_s{-1}, wall_s{-1}, factor{-1}, steps_per_s{-1}, dt_ms{-1};
  double load_s{-1}, total_startup_s{-1};  // loading the scene; the whole start-up (load + open to the first step)
  long steps{-1};
  std::vector<double> status_factors;  // "(0.09x real time, last 1 s)" of each status line
  std::vector<std::string> status_lines;
};

inline Figures read_figures(const std::string& out) {
  Figures f;
  std::smatch m;
  const std::regex last(
      R"(start-up ([0-9.]+) s \(loading the scene ([0-9.]+) s, then open to the first physics step ([0-9.]+) s\); )"
      R"(after it ([0-9.]+) s simulated in ([0-9.]+) s wall )"
      R"(\(([0-9.]+)x real time[^)]*\); physics ([0-9]+) steps \(([0-9.]+) steps/s after the start-up, )"
      R"(dt ([0-9.e-]+) ms\))");
  if (std::regex_search(out, m, last)) {
    f.total_startup_s = std::stod(m[1]), f.load_s = std::stod(m[2]), f.startup_s = std::stod(m[3]);
    f.sim_s = std::stod(m[4]), f.wall_s = std::stod(m[5]), f.factor = std::stod(m[6]);
    f.steps = std::stol(m[7]), f.steps_per_s = std::stod(m[8]), f.dt_ms = std::stod(m[9]);
  }
  std::stringstream ss(out);
  for (std::string line; std::getline(ss, line);) {
    if (line.rfind("t = ", 0) != 0) continue;
    f.status_lines.push_back(line);
    if (std::regex_search(line, m, std::regex(R"(\(([0-9.]+)x real time, last 1 s\))")))
      f.status_factors.push_back(std::stod(m[1]));
  }
  return f;
}

}  // namespace vx::testing
