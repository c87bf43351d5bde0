// From a volume in HU to a binary voxel grid.

#include "convert/threshold.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <optional>
#include <string>
#include <vector>

#include "base/error.h"
#include "util/text.h"

namespace vx {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

struct Preset {
  const char* name;
  HuRange range;
  const char* what;
};

constexpr Preset kPresets[] = {
    {"soft-tissue", {-100.0, 300.0}, "muscle, organs"},
    {"bone", {300.0, 3000.0}, "cortical and trabecular bone"},
    {"fat", {-150.0, -30.0}, "adipose tissue"},
    {"lung", {-950.0, -400.0}, "aerated lung"},
    {"tissue", {-200.0, kInf}, "everything that is not air"},
};

/// A whole-string number; "inf", "+inf", "-inf" allowed; empty for anything else.
std::optional<double> parse_hu(const std::string& text) {
  const std::string s = lower(trim(text));
  if (s == "inf" || s == "+inf") return kInf;
  if (s == "-inf") return -kInf;
  if (s.empty()) return std::nullopt;
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size() || std::isnan(v) || std::isinf(v)) return std::nullopt;
  return v;
}

std::string fmt_hu(double v) {
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  return fmt::format("{}", v);
}

std::string presets_help() {
  std::string s;
  for (const auto& p : kPresets)
    s += fmt::format("{}{} ({}:{} HU, {})", s.empty() ? "" : ", ", p.name, fmt_hu(p.range.lo), fmt_hu(p.range.hi),
                     p.what);
  return s;
}

}  // namespace

HuRange parse_threshold(const std::string& text_in) {
  const std::string text = trim(text_in);
  const std::string key = lower(text);
  for (const auto& p : kPresets)
    if (key == p.name) return p.range;
  auto fail = [&](const std::string& why) -> Error {
    return Error(fmt::format("bad threshold '{}': {}. Give LO (tissue is LO HU and above), LO:HI (inclusive, either "
                             "may be inf/-inf), or a preset: {}",
                             text_in, why, presets_help()));
  };
  if (text.empty()) throw fail("it is empty");
  // the separator is the first ':' (numbers have none)
  const auto colon = text.find(':');
  HuRange r;
  if (colon == std::string::npos) {
    const auto lo = parse_hu(text);
    if (!lo) {
      std::vector<std::string> names;
      for (const auto& p : kPresets) names.emplace_back(p.name);
      const std::string near = nearest_word(text, names);
      throw fail(near.empty() ? std::string("not a number or preset name")
                              : fmt::format("not a number or preset name (did you mean '{}'?)", near));
    }
    r.lo = *lo;
    r.hi = kInf;
  } else {
    const auto lo = parse_hu(text.substr(0, colon));
    const auto hi = parse_hu(text.substr(colon + 1));
    if (!lo) throw fail(fmt::format("the lower bound '{}' is not a number", trim(text.substr(0, colon))));
    if (!hi) throw fail(fmt::format("the upper bound '{}' is not a number", trim(text.substr(colon + 1))));
    r.lo = *lo;
    r.hi = *hi;
  }
  if (r.lo == kInf) throw fail("the lower bound cannot be +inf");
  if (r.lo > r.hi) throw fail(fmt::format("the lower bound {} is above the upper bound {}", fmt_hu(r.lo), fmt_hu(r.hi)));
  return r;
}

VoxelGrid threshold(const Volume& volume, const HuRange& range) {
  const GridGeometry& g = volume.geometry;
  if ((g.dims.array() <= 0).any())
    throw Error(fmt::format("cannot threshold an empty volume ({}x{}x{} voxels)", g.dims.x(), g.dims.y(), g.dims.z()));
  if (std::int64_t(volume.hu.size()) != g.voxel_count())
    throw Error(fmt::format("cannot threshold: the volume holds {} values for {}x{}x{} voxels", volume.hu.size(),
                            g.dims.x(), g.dims.y(), g.dims.z()));
  if (std::isnan(range.lo) || std::isnan(range.hi) || range.lo > range.hi)
    throw Error(fmt::format("cannot threshold with the HU range {}:{} (need lo <= hi)", fmt_hu(range.lo),
                            fmt_hu(range.hi)));
  VoxelGrid grid(g);
  std::vector<std::uint8_t>& out = grid.data();
  const std::int64_t n = std::int64_t(volume.hu.size());
  const float* in = volume.hu.data();
  const double lo = range.lo, hi = range.hi;
  // NaN compares false: never tissue
#pragma omp parallel for schedule(static)
  for (std::int64_t i = 0; i < n; ++i) {
    const double v = in[i];
    out[std::size_t(i)] = (v >= lo && v <= hi) ? 1 : 0;
  }
  return grid;
}

}  // namespace vx
