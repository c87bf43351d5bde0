// The plot spec of `voxelastic plot` (render/plot.h, parse_plot_spec): JSON read strictly,
// every unknown key and wrong type refused with where it stands; the drawing is plot.cpp's.
#include <fmt/format.h>

#include <algorithm>
#include <initializer_list>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "base/error.h"
#include "render/plot.h"

namespace vx {

namespace {

using json = nlohmann::json;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Calls `f(key, value)` for each key of object `j` at `where`, refusing keys not in `known`.
template <class F>
void each_key(const json& j, const std::string& where, std::initializer_list<const char*> known, F f) {
  if (!j.is_object()) throw Error("plot spec: " + where + " is not an object");
  for (auto it = j.begin(); it != j.end(); ++it) {
    if (std::none_of(known.begin(), known.end(), [&](const char* k) { return it.key() == k; })) {
      std::string list;
      for (const char* k : known) list += (list.empty() ? "" : ", ") + std::string(k);
      throw Error("plot spec: " + where + "." + it.key() + ": unknown key (known: " + list + ")");
    }
    try {
      f(it.key(), it.value());
    } catch (const json::exception& e) {
      throw Error("plot spec: " + where + "." + it.key() + ": " + e.what());
    }
  }
}

std::vector<double> numbers(const json& j, const std::string& where) {
  if (!j.is_array()) throw Error("plot spec: " + where + " is not an array of numbers");
  std::vector<double> out;
  for (const json& v : j) {
    if (v.is_null())
      out.push_back(kNaN);
    else if (v.is_number())
      out.push_back(v.get<double>());
    else
      throw Error("plot spec: " + where + " holds " + std::string(v.type_name()) + ", not a number or null");
  }
  return out;
}

}  // namespace

PlotSpec parse_plot_spec(const std::string& text) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    throw Error(std::string("plot spec: not valid JSON: ") + e.what());
  }
  PlotSpec spec;
  each_key(j, "$", {"width", "panel_height", "panels"}, [&](const std::string& k, const json& v) {
    if (k == "width") spec.width = v.get<int>();
    if (k == "panel_height") spec.panel_height = v.get<int>();
    if (k == "panels") {
      if (!v.is_array() || v.empty()) throw Error("plot spec: $.panels must be a non-empty array");
      for (std::size_t i = 0; i < v.size(); ++i) {
        const std::string wp = fmt::format("$.panels[{}]", i);
        PlotPanel p;
        each_key(
            v[i], wp, {"title", "subtitle", "xlabel", "ylabel", "log_x", "log_y", "key", "xrange", "yrange", "series"},
            [&](const std::string& pk, const json& pv) {
              if (pk == "title") p.title = pv.get<std::string>();
              if (pk == "subtitle") p.subtitle = pv.get<std::string>();
              if (pk == "xlabel") p.xlabel = pv.get<std::string>();
              if (pk == "ylabel") p.ylabel = pv.get<std::string>();
              if (pk == "log_x") p.log_x = pv.get<bool>();
              if (pk == "log_y") p.log_y = pv.get<bool>();
              if (pk == "key") p.key = pv.get<std::string>();
              if (pk == "xrange") p.xrange = pv.get<std::string>();
              if (pk == "yrange") p.yrange = pv.get<std::string>();
              if (pk == "series") {
                if (!pv.is_array()) throw Error("plot spec: " + wp + ".series is not an array");
                for (std::size_t k = 0; k < pv.size(); ++k) {
                  const std::string ws = fmt::format("{}.series[{}]", wp, k);
                  PlotSeries s;
                  each_key(
                      pv[k], ws,
                      {"title", "x", "y", "points", "with_points", "line_width", "dash_type", "point_type", "color"},
                      [&](const std::string& sk, const json& sv) {
                        if (sk == "title") s.title = sv.get<std::string>();
                        if (sk == "x") s.x = numbers(sv, ws + ".x");
                        if (sk == "y") s.y = numbers(sv, ws + ".y");
                        if (sk == "points") s.points = sv.get<bool>();
                        if (sk == "with_points") s.with_points = sv.get<bool>();
                        if (sk == "line_width") s.line_width = sv.get<double>();
                        if (sk == "dash_type") s.dash_type = sv.get<int>();
                        if (sk == "point_type") s.point_type = sv.get<int>();
                        if (sk == "color") s.color = sv.get<std::string>();
                      });
                  if (s.x.size() != s.y.size())
                    throw Error(fmt::format("plot spec: {}: x has {} values, y {}", ws, s.x.size(), s.y.size()));
                  if (!s.color.empty()) check_plot_color(s.color);  // a bad colour is told before drawing
                  p.series.push_back(std::move(s));
                }
              }
            });
        spec.panels.push_back(std::move(p));
      }
    }
  });
  if (spec.panels.empty()) throw Error("plot spec: $.panels is missing: nothing to draw");
  return spec;
}

}  // namespace vx
