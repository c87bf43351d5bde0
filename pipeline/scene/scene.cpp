// Scene files: strict JSON reading with JSON paths in every message, and building the scene.
#include "scene/scene.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "base/error.h"
#include "convert/threshold.h"
#include "io/model_io.h"
#include "sim/time_step.h"

namespace vx {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

// ---------------------------------------------------------------------------------------------
// strict reading

/// Unit suffixes of our key names (longest first), for "wrong unit" hints.
const std::vector<std::string>& unit_suffixes() {
  static const std::vector<std::string> s = {"_kg_m3", "_mm_s2", "_mm_s", "_m_s2", "_kpa", "_mm", "_s", "_n"};
  return s;
}

/// A key without its unit suffix ("youngs_modulus_kpa" -> "youngs_modulus").
std::string stem(const std::string& key) {
  for (const auto& u : unit_suffixes())
    if (key.size() > u.size() && key.compare(key.size() - u.size(), u.size(), u) == 0)
      return key.substr(0, key.size() - u.size());
  return key;
}

/// The unit a suffix stands for, for messages.
std::string unit_of(const std::string& key) {
  static const std::vector<std::pair<std::string, std::string>> names = {
      {"_kg_m3", "kg/m^3"}, {"_mm_s2", "mm/s^2"}, {"_mm_s", "mm/s"}, {"_m_s2", "m/s^2"},
      {"_kpa", "kPa"},      {"_mm", "mm"},         {"_s", "s"},       {"_n", "N"}};
  for (const auto& [s, n] : names)
    if (key.size() > s.size() && key.compare(key.size() - s.size(), s.size(), s) == 0) return n;
  if (key == "gravity") return "m/s^2";
  return "";
}

std::size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> prev(b.size() + 1), cur(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) prev[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    cur[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j)
      cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
    std::swap(prev, cur);
  }
  return prev[b.size()];
}

std::string type_name(const json& j) {
  if (j.is_null()) return "null";
  if (j.is_boolean()) return "a boolean";
  if (j.is_number()) return "a number";
  if (j.is_string()) return "the string \"" + j.get<std::string>() + "\"";
  if (j.is_array()) return "an array";
  return "an object";
}

/// Where we are: the file and the JSON path.
struct Where {
  std::string file;
  std::string path;  ///< "$", "$.probes[0]", ...
  [[nodiscard]] Where key(const std::string& k) const { return {file, path + "." + k}; }
  [[nodiscard]] Where index(std::size_t i) const { return {file, path + "[" + std::to_string(i) + "]"}; }
  [[noreturn]] void fail(const std::string& what) const { throw Error(file + ": " + path + ": " + what); }
};

/// A JSON object whose keys are checked against the allowed ones.
class Obj {
 public:
  Obj(const json& j, Where where, std::vector<std::string> allowed)
      : j_(j), where_(std::move(where)), allowed_(std::move(allowed)) {
    if (!j_.is_object()) where_.fail("expected an object { ... }, got " + type_name(j_));
    for (auto it = j_.begin(); it != j_.end(); ++it) check_key(it.key());
  }

  [[nodiscard]] const Where& where() const { return where_; }
  [[nodiscard]] bool has(const std::string& k) const { return j_.contains(k); }
  [[nodiscard]] const json& at(const std::string& k) const { return j_.at(k); }
  [[nodiscard]] Where at_where(const std::string& k) const { return where_.key(k); }
  /// Fails unless exactly one of `keys` is present; returns it.
  [[nodiscard]] std::string one_of(const std::vector<std::string>& keys, const std::string& what) const {
    std::vector<std::string> present;
    for (const auto& k : keys)
      if (has(k)) present.push_back(k);
    if (present.size() != 1)
      where_.fail(fmt::format("{} needs exactly one of {}, found {}", what, fmt::join(quoted(keys), ", "),
                              present.empty() ? std::string("none") : fmt::format("{}", fmt::join(quoted(present), " and "))));
    return present.front();
  }
  void forbid(const std::string& k, const std::string& why) const {
    if (has(k)) where_.key(k).fail(why);
  }

  [[nodiscard]] double number(const std::string& k) const { return as_number(j_.at(k), where_.key(k), unit_of(k)); }
  [[nodiscard]] double number(const std::string& k, double def) const { return has(k) ? number(k) : def; }
  [[nodiscard]] double required_number(const std::string& k, const std::string& hint) const {
    if (!has(k)) where_.fail(fmt::format("missing \"{}\" ({})", k, hint));
    return number(k);
  }
  [[nodiscard]] int integer(const std::string& k, int def) const {
    if (!has(k)) return def;
    const json& v = j_.at(k);
    if (!v.is_number_integer()) where_.key(k).fail("expected a whole number, got " + type_name(v));
    return v.get<int>();
  }
  [[nodiscard]] bool boolean(const std::string& k, bool def) const {
    if (!has(k)) return def;
    const json& v = j_.at(k);
    if (!v.is_boolean()) where_.key(k).fail("expected true or false, got " + type_name(v));
    return v.get<bool>();
  }
  [[nodiscard]] std::string string(const std::string& k, const std::string& def) const {
    if (!has(k)) return def;
    const json& v = j_.at(k);
    if (!v.is_string()) where_.key(k).fail("expected a string, got " + type_name(v));
    return v.get<std::string>();
  }
  [[nodiscard]] Eigen::Vector3d vec3(const std::string& k) const { return as_vec3(j_.at(k), where_.key(k), unit_of(k)); }
  [[nodiscard]] Eigen::Vector3d vec3(const std::string& k, const Eigen::Vector3d& def) const {
    return has(k) ? vec3(k) : def;
  }

  static double as_number(const json& v, const Where& w, const std::string& unit) {
    if (v.is_number() && !v.is_boolean()) {
      const double x = v.get<double>();
      if (!std::isfinite(x)) w.fail("must be a finite number");
      return x;
    }
    if (v.is_string())
      w.fail(fmt::format("expected a number{}, got {}; write the bare number (units are fixed by the key)",
                         unit.empty() ? "" : " in " + unit, type_name(v)));
    w.fail(fmt::format("expected a number{}, got {}", unit.empty() ? "" : " in " + unit, type_name(v)));
  }
  static Eigen::Vector3d as_vec3(const json& v, const Where& w, const std::string& unit) {
    if (!v.is_array() || v.size() != 3)
      w.fail(fmt::format("expected 3 numbers [x, y, z]{}, got {}{}", unit.empty() ? "" : " in " + unit, type_name(v),
                         v.is_array() ? fmt::format(" of {} values", v.size()) : ""));
    Eigen::Vector3d out;
    for (int c = 0; c < 3; ++c) out[c] = as_number(v[std::size_t(c)], w.index(std::size_t(c)), unit);
    return out;
  }

 private:
  static std::vector<std::string> quoted(const std::vector<std::string>& v) {
    std::vector<std::string> q;
    for (const auto& s : v) q.push_back("\"" + s + "\"");
    return q;
  }

  void check_key(const std::string& k) const {
    if (std::find(allowed_.begin(), allowed_.end(), k) != allowed_.end()) return;
    const Where w = where_.key(k);
    // the same quantity in another unit (or without its unit)
    for (const auto& a : allowed_) {
      const std::string s = stem(a);
      const std::string unit = unit_of(a);
      if (unit.empty()) continue;
      if (k == s || (k.size() > s.size() + 1 && k.compare(0, s.size() + 1, s + "_") == 0))
        w.fail(fmt::format("unknown key \"{}\": {} is given in {} as \"{}\"", k, s, unit, a));
    }
    // a typo
    std::string best;
    std::size_t best_d = 3;
    for (const auto& a : allowed_) {
      const std::size_t d = edit_distance(k, a);
      if (d < best_d) best_d = d, best = a;
    }
    if (!best.empty()) w.fail(fmt::format("unknown key \"{}\"; did you mean \"{}\"?", k, best));
    w.fail(fmt::format("unknown key \"{}\"; allowed here: {}", k, fmt::join(quoted(allowed_), ", ")));
  }

  const json& j_;
  Where where_;
  std::vector<std::string> allowed_;
};

/// An array (of at least `min_size` elements).
const json& array_at(const Obj& o, const std::string& k, std::size_t min_size, const std::string& what) {
  const json& v = o.at(k);
  if (!v.is_array()) o.at_where(k).fail("expected an array [ ... ] of " + what + ", got " + type_name(v));
  if (v.size() < min_size)
    o.at_where(k).fail(fmt::format("needs at least {} {} (got {})", min_size, what, v.size()));
  return v;
}

void require(bool ok, const Where& w, const std::string& what) {
  if (!ok) w.fail(what);
}

// ---------------------------------------------------------------------------------------------
// sections

SceneObject read_object(const Obj& o, const fs::path& base) {
  SceneObject obj;
  const std::string src = o.one_of({"phantom", "volume", "model", "box_mm"}, "the object");
  const auto path_of = [&](const std::string& k) {
    const std::string p = o.string(k, "");
    if (p.empty()) o.at_where(k).fail("the path is empty");
    const fs::path full = fs::path(p).is_absolute() ? fs::path(p) : base / p;
    if (!fs::exists(full))
      o.at_where(k).fail(fmt::format("\"{}\" does not exist (looked for {}; relative paths start at the scene's folder)",
                                     p, full.string()));
    return full;
  };

  // how to get tissue voxels from HU (phantom, volume)
  const auto read_threshold = [&](HuRange def) {
    if (!o.has("threshold")) return def;
    const json& t = o.at("threshold");
    const Where w = o.at_where("threshold");
    if (t.is_number()) return HuRange{Obj::as_number(t, w, "HU"), std::numeric_limits<double>::infinity()};
    if (t.is_string()) {
      try {
        return parse_threshold(t.get<std::string>());
      } catch (const Error& e) {
        w.fail(e.what());
      }
    }
    if (t.is_object()) {
      const Obj r(t, w, {"lo", "hi"});
      HuRange h;
      h.lo = r.number("lo", -std::numeric_limits<double>::infinity());
      h.hi = r.number("hi", std::numeric_limits<double>::infinity());
      require(h.lo < h.hi, w, fmt::format("lo {} HU must be below hi {} HU", h.lo, h.hi));
      return h;
    }
    w.fail("expected a number (lowest tissue HU), a string \"LO:HI\" or a preset name, or {\"lo\": .., \"hi\": ..}; got " +
           type_name(t));
  };

  if (src == "phantom") {
    obj.source = ObjectSource::phantom;
    obj.phantom.name = o.string("phantom", "");
    const auto names = phantom_names();
    if (std::find(names.begin(), names.end(), obj.phantom.name) == names.end())
      o.at_where("phantom").fail(fmt::format("unknown phantom \"{}\"; choose one of: {}", obj.phantom.name,
                                             fmt::join(names, ", ")));
    obj.phantom.size = o.integer("size", obj.phantom.size);
    require(obj.phantom.size >= 4 && obj.phantom.size <= 1024, o.at_where("size"), "must be 4 to 1024 voxels per axis");
    obj.phantom.spacing_mm = o.number("spacing_mm", obj.phantom.spacing_mm);
    require(obj.phantom.spacing_mm > 0 && obj.phantom.spacing_mm <= 50, o.at_where("spacing_mm"),
            "voxel size must be > 0 and at most 50 mm");
    obj.phantom.tissue_hu = o.number("tissue_hu", obj.phantom.tissue_hu);
    obj.phantom.air_hu = o.number("air_hu", obj.phantom.air_hu);
    obj.phantom.lesion_hu = o.number("lesion_hu", obj.phantom.lesion_hu);
    obj.phantom.noise_hu = o.number("noise_hu", obj.phantom.noise_hu);
    require(obj.phantom.noise_hu >= 0, o.at_where("noise_hu"), "must be >= 0 HU");
    obj.phantom.seed = unsigned(o.integer("seed", int(obj.phantom.seed)));
    // between air and tissue by default
    obj.prepare.range = read_threshold({0.5 * (obj.phantom.air_hu + obj.phantom.tissue_hu),
                                        std::numeric_limits<double>::infinity()});
    o.forbid("series_uid", "series_uid applies to a DICOM \"volume\" only");
  } else if (src == "volume") {
    obj.source = ObjectSource::volume;
    obj.path = path_of("volume");
    obj.prepare.range = read_threshold(HuRange{});
    obj.read.series_uid = o.string("series_uid", "");
    obj.read.any_modality = o.boolean("any_modality", false);
    for (const char* k : {"size", "spacing_mm", "tissue_hu", "air_hu", "lesion_hu", "noise_hu", "seed"})
      o.forbid(k, std::string(k) + " applies to a \"phantom\" object only");
  } else if (src == "model") {
    obj.source = ObjectSource::model;
    obj.path = path_of("model");
    for (const char* k : {"threshold", "resolution", "max_level", "largest_component", "fill_holes", "voxel_mm", "crop",
                          "size", "spacing_mm", "tissue_hu", "air_hu", "lesion_hu", "noise_hu", "seed", "series_uid"})
      o.forbid(k, std::string(k) + " does not apply to a model file: it was set when the model was converted "
                                   "(voxelastic convert)");
  } else {
    obj.source = ObjectSource::box;
    const Obj b(o.at("box_mm"), o.at_where("box_mm"), {"min", "max"});
    if (!b.has("min") || !b.has("max")) b.where().fail("needs \"min\" and \"max\" corners [x, y, z] in mm");
    obj.box_min_mm = b.vec3("min");
    obj.box_max_mm = b.vec3("max");
    obj.box_voxel_mm = o.number("voxel_mm", 1.0);
    require(obj.box_voxel_mm > 0 && obj.box_voxel_mm <= 50, o.at_where("voxel_mm"), "must be > 0 and at most 50 mm");
    const Eigen::Vector3d size = obj.box_max_mm - obj.box_min_mm;
    for (int c = 0; c < 3; ++c) {
      require(size[c] > 0, b.where(), "min must be below max on every axis");
      const double n = size[c] / obj.box_voxel_mm;
      require(std::abs(n - std::round(n)) < 1e-6 * std::max(1.0, n), b.where(),
              fmt::format("the box is {} mm along axis {}, not a whole number of {} mm voxels; adjust min/max or voxel_mm",
                          size[c], "xyz"[c], obj.box_voxel_mm));
      require(std::round(n) >= 2, b.where(), fmt::format("the box needs at least 2 voxels along {}", "xyz"[c]));
      require(std::round(n) <= 1024, b.where(), fmt::format("the box is more than 1024 voxels along {}", "xyz"[c]));
    }
    for (const char* k : {"threshold", "largest_component", "fill_holes", "crop", "size", "spacing_mm", "tissue_hu",
                          "air_hu", "lesion_hu", "noise_hu", "seed", "series_uid"})
      o.forbid(k, std::string(k) + " does not apply to a box (it is all tissue; its voxel size is voxel_mm)");
  }
  if (src == "phantom" || src == "volume") {
    obj.prepare.largest_component = o.boolean("largest_component", false);
    obj.prepare.fill_holes = o.boolean("fill_holes", false);
    obj.prepare.crop = o.boolean("crop", true);
    obj.prepare.voxel_mm = o.number("voxel_mm", 0.0);
    require(obj.prepare.voxel_mm >= 0 && obj.prepare.voxel_mm <= 50, o.at_where("voxel_mm"),
            "resampling voxel size must be 0 (keep) or up to 50 mm");
  }
  if (src != "model") {
    const std::string r = o.string("resolution", "gradational");
    try {
      obj.build.layout = parse_layout(r);
    } catch (const Error&) {
      o.at_where("resolution").fail("unknown resolution \"" + r + "\"; use gradational, uniform or voxel");
    }
    obj.build.max_level = o.integer("max_level", -1);
    require(obj.build.max_level >= -1, o.at_where("max_level"), "must be -1 (no limit) or a level >= 0");
  }
  return obj;
}

SceneMaterial read_material(const Obj& o, ObjectSource source) {
  SceneMaterial m;
  Material& b = m.base;
  b.youngs_modulus_kpa = o.number("youngs_modulus_kpa", b.youngs_modulus_kpa);
  require(b.youngs_modulus_kpa > 0, o.at_where("youngs_modulus_kpa"),
          fmt::format("must be > 0 kPa (got {}); soft tissue is about 1 to 100 kPa", b.youngs_modulus_kpa));
  require(b.youngs_modulus_kpa <= 1e8, o.at_where("youngs_modulus_kpa"),
          fmt::format("{} kPa is above any tissue (cortical bone ~2e7 kPa); the unit is kPa", b.youngs_modulus_kpa));
  b.poisson_ratio = o.number("poisson_ratio", b.poisson_ratio);
  require(b.poisson_ratio >= 0 && b.poisson_ratio < 0.5, o.at_where("poisson_ratio"),
          fmt::format("must be in [0, 0.5) (got {}); 0 is the paper's model, tissue ~0.45", b.poisson_ratio));
  b.density_kg_m3 = o.number("density_kg_m3", b.density_kg_m3);
  require(b.density_kg_m3 >= 10, o.at_where("density_kg_m3"),
          fmt::format("{} kg/m^3 is too light for tissue; the unit is kg/m^3 (water 1000, not 1.0 g/cm^3)",
                      b.density_kg_m3));
  require(b.density_kg_m3 <= 25000, o.at_where("density_kg_m3"),
          fmt::format("{} kg/m^3 is denser than any material; the unit is kg/m^3", b.density_kg_m3));
  b.damping_ratio = o.number("damping", b.damping_ratio);
  require(b.damping_ratio >= 0 && b.damping_ratio <= 10, o.at_where("damping"),
          fmt::format("must be in [0, 10] (got {}): a ratio of each element's critical damping (e.g. 0.1)",
                      b.damping_ratio));

  if (o.has("hounsfield_table")) {
    const Where w = o.at_where("hounsfield_table");
    if (source == ObjectSource::model || source == ObjectSource::box)
      w.fail("needs the object's HU values: use an object with \"volume\" or \"phantom\" (a model file or a box has none)");
    const json& t = array_at(o, "hounsfield_table", 2, "rows {\"hu\": .., \"youngs_modulus_kpa\": ..}");
    for (std::size_t i = 0; i < t.size(); ++i) {
      const Obj r(t[i], w.index(i), {"hu", "youngs_modulus_kpa"});
      HuModulus row;
      row.hu = r.required_number("hu", "the HU value of this row");
      row.youngs_modulus_kpa = r.required_number("youngs_modulus_kpa", "the modulus at that HU, kPa");
      require(row.youngs_modulus_kpa > 0 && row.youngs_modulus_kpa <= 1e8, r.at_where("youngs_modulus_kpa"),
              "must be > 0 and at most 1e8 kPa");
      if (!m.hounsfield.empty())
        require(row.hu > m.hounsfield.back().hu, r.at_where("hu"),
                fmt::format("rows must be sorted by increasing HU ({} after {})", row.hu, m.hounsfield.back().hu));
      m.hounsfield.push_back(row);
    }
  }
  if (o.has("inclusions")) {
    const Where w = o.at_where("inclusions");
    const json& list = array_at(o, "inclusions", 1, "inclusions");
    for (std::size_t i = 0; i < list.size(); ++i) {
      const Obj r(list[i], w.index(i), {"center_mm", "radius_mm", "youngs_modulus_kpa", "density_kg_m3"});
      Inclusion inc;
      if (!r.has("center_mm")) r.where().fail("missing \"center_mm\" [x, y, z] (LPS mm)");
      inc.center_mm = r.vec3("center_mm");
      inc.radius_mm = r.required_number("radius_mm", "the inclusion's radius, mm");
      require(inc.radius_mm > 0, r.at_where("radius_mm"), "must be > 0 mm");
      inc.youngs_modulus_kpa = r.required_number("youngs_modulus_kpa", "the inclusion's modulus, kPa");
      require(inc.youngs_modulus_kpa > 0 && inc.youngs_modulus_kpa <= 1e8, r.at_where("youngs_modulus_kpa"),
              "must be > 0 and at most 1e8 kPa");
      inc.density_kg_m3 = r.number("density_kg_m3", 0.0);
      if (r.has("density_kg_m3"))
        require(inc.density_kg_m3 >= 10 && inc.density_kg_m3 <= 25000, r.at_where("density_kg_m3"),
                "must be 10 to 25000 kg/m^3");
      m.inclusions.push_back(inc);
    }
  }
  return m;
}

BoxFace parse_face(const std::string& s, const Where& w) {
  static const std::vector<std::pair<std::string, BoxFace>> faces = {
      {"x_min", BoxFace::x_min}, {"x_max", BoxFace::x_max}, {"y_min", BoxFace::y_min},
      {"y_max", BoxFace::y_max}, {"z_min", BoxFace::z_min}, {"z_max", BoxFace::z_max}};
  for (const auto& [n, f] : faces)
    if (n == s) return f;
  w.fail("unknown face \"" + s + "\"; use x_min, x_max, y_min, y_max, z_min or z_max (faces of the object's bounding box, LPS)");
}

std::vector<FixedRegion> read_fixed(const json& j, const Where& w) {
  if (!j.is_array()) w.fail("expected an array such as [\"z_min\"], got " + type_name(j));
  std::vector<FixedRegion> out;
  for (std::size_t i = 0; i < j.size(); ++i) {
    FixedRegion r;
    const Where wi = w.index(i);
    if (j[i].is_string()) {
      r.face = parse_face(j[i].get<std::string>(), wi);
      r.label = j[i].get<std::string>();
    } else if (j[i].is_object()) {
      const Obj o(j[i], wi, {"face", "within_mm", "box_mm"});
      const std::string k = o.one_of({"face", "box_mm"}, "a fixed region");
      if (k == "face") {
        r.label = o.string("face", "");
        r.face = parse_face(r.label, o.at_where("face"));
        r.within_mm = o.number("within_mm", 0.0);
        require(r.within_mm >= 0, o.at_where("within_mm"), "must be >= 0 mm");
      } else {
        o.forbid("within_mm", "within_mm applies to a \"face\"");
        r.is_face = false;
        const Obj b(o.at("box_mm"), o.at_where("box_mm"), {"min", "max"});
        if (!b.has("min") || !b.has("max")) b.where().fail("needs \"min\" and \"max\" corners [x, y, z] in mm");
        r.box_min_mm = b.vec3("min");
        r.box_max_mm = b.vec3("max");
        require((r.box_min_mm.array() <= r.box_max_mm.array()).all(), b.where(), "min must not exceed max");
        r.label = "box";
      }
    } else {
      wi.fail("expected a face name such as \"z_min\" or an object {\"face\": .., \"within_mm\": ..} / {\"box_mm\": ..}; got " +
              type_name(j[i]));
    }
    out.push_back(r);
  }
  return out;
}

std::vector<PathKey> read_path(const json& j, const Where& w) {
  if (!j.is_array() || j.empty())
    w.fail("expected an array of keyframes [{\"t_s\": .., \"position_mm\": [x, y, z]}, ...] (at least one)");
  std::vector<PathKey> keys;
  for (std::size_t i = 0; i < j.size(); ++i) {
    const Obj k(j[i], w.index(i), {"t_s", "position_mm"});
    PathKey key;
    key.t_s = k.required_number("t_s", "the keyframe's time, s");
    require(key.t_s >= 0, k.at_where("t_s"), "must be >= 0 s");
    if (!keys.empty())
      require(key.t_s > keys.back().t_s, k.at_where("t_s"),
              fmt::format("keyframe times must increase ({} s after {} s)", key.t_s, keys.back().t_s));
    if (!k.has("position_mm")) k.where().fail("missing \"position_mm\" [x, y, z] (LPS mm)");
    key.position_mm = k.vec3("position_mm");
    keys.push_back(key);
  }
  return keys;
}

/// Joystick mapping keys shared by `joystick` and `live`.
void read_mapping(const Obj& o, JoystickMapping& m) {
  const std::string mode = o.string("mode", "rate");
  try {
    m.mode = parse_joystick_mode(mode);
  } catch (const Error&) {
    o.at_where("mode").fail("unknown mode \"" + mode + "\"; use \"rate\" (velocity proportional to tilt, the paper) or \"position\"");
  }
  m.max_speed_mm_s = o.number("speed_mm_s", m.max_speed_mm_s);
  require(m.max_speed_mm_s > 0 && m.max_speed_mm_s <= 1e5, o.at_where("speed_mm_s"), "must be > 0 mm/s (speed at full tilt)");
  m.range_mm = o.number("range_mm", m.range_mm);
  require(m.range_mm > 0, o.at_where("range_mm"), "must be > 0 mm (displacement at full tilt)");
  m.dead_zone = o.number("dead_zone", m.dead_zone);
  require(m.dead_zone >= 0 && m.dead_zone < 1, o.at_where("dead_zone"), "must be in [0, 1)");
  if (o.has("directions")) {
    const json& d = o.at("directions");
    const Where w = o.at_where("directions");
    if (!d.is_array() || d.empty() || d.size() > 3)
      w.fail("expected 1 to 3 LPS directions, one per stick axis, e.g. [[1, 0, 0], [0, 0, -1]]");
    m.directions.setZero();
    for (std::size_t a = 0; a < d.size(); ++a) {
      const Eigen::Vector3d v = Obj::as_vec3(d[a], w.index(a), "");
      const double n = v.norm();
      require(n > 0, w.index(a), "a direction must not be zero");
      m.directions.col(Eigen::Index(a)) = v / n;
    }
  }
}

ProbeSettings read_probe(const json& j, const Where& w, std::size_t index) {
  const Obj o(j, w, {"name", "shape", "radius_mm", "length_mm", "axis", "normal", "path", "joystick", "live"});
  ProbeSettings p;
  p.name = o.string("name", "probe" + std::to_string(index));
  require(!p.name.empty() && p.name.find_first_of(",\"\n") == std::string::npos, o.at_where("name"),
          "must be a non-empty name without commas, quotes or newlines");
  if (!o.has("shape")) w.fail("missing \"shape\": sphere, cylinder, capsule or plane");
  try {
    p.geometry.shape = parse_probe_shape(o.string("shape", ""));
  } catch (const Error& e) {
    o.at_where("shape").fail(e.what());
  }
  const ProbeShape s = p.geometry.shape;
  if (s == ProbeShape::plane) {
    o.forbid("radius_mm", "a plane has no radius (it is an unbounded plate)");
    o.forbid("length_mm", "a plane has no length");
    o.forbid("axis", "a plane has a \"normal\", not an axis");
    if (!o.has("normal")) w.fail("a plane needs \"normal\" [x, y, z]: pointing out of the plate, towards the tissue");
    p.geometry.axis = o.vec3("normal");
  } else {
    p.geometry.radius_mm = o.required_number("radius_mm", "the probe's radius, mm");
    require(p.geometry.radius_mm > 0 && p.geometry.radius_mm <= 1000, o.at_where("radius_mm"),
            fmt::format("must be > 0 and at most 1000 mm (got {})", p.geometry.radius_mm));
    o.forbid("normal", "only a plane has a normal; a " + std::string(to_string(s)) + " has an \"axis\"");
    if (s == ProbeShape::sphere) {
      o.forbid("length_mm", "a sphere has no length");
      o.forbid("axis", "a sphere has no axis");
    } else {
      p.geometry.length_mm = o.required_number(
          "length_mm", s == ProbeShape::cylinder ? "the cylinder's length, mm" : "the rod's length behind the tip, mm");
      require(s == ProbeShape::capsule ? p.geometry.length_mm >= 0 : p.geometry.length_mm > 0, o.at_where("length_mm"),
              s == ProbeShape::capsule ? "must be >= 0 mm" : "must be > 0 mm");
      p.geometry.axis = o.vec3("axis", Eigen::Vector3d(0, 0, 1));
    }
  }
  {
    const std::string k = s == ProbeShape::plane ? "normal" : "axis";
    const double n = p.geometry.axis.norm();
    if (!(n > 0)) o.at_where(k).fail("must not be the zero vector");
    p.geometry.axis /= n;
  }

  const std::string drive = o.one_of({"path", "joystick", "live"}, "a probe's motion");
  if (drive == "path") {
    p.drive = ProbeDrive::path;
    p.path = read_path(o.at("path"), o.at_where("path"));
  } else if (drive == "joystick") {
    p.drive = ProbeDrive::joystick;
    const Obj js(o.at("joystick"), o.at_where("joystick"),
                 {"start_mm", "mode", "speed_mm_s", "range_mm", "dead_zone", "directions", "input"});
    if (!js.has("start_mm")) js.where().fail("missing \"start_mm\" [x, y, z]: where the probe is at t = 0 (LPS mm)");
    p.start_mm = js.vec3("start_mm");
    read_mapping(js, p.mapping);
    if (!js.has("input")) js.where().fail("missing \"input\": [{\"t_s\": 0, \"axes\": [x, y]}, ...] stick deflections in [-1, 1]");
    const json& in = array_at(js, "input", 1, "samples {\"t_s\": .., \"axes\": [..]}");
    for (std::size_t i = 0; i < in.size(); ++i) {
      const Obj k(in[i], js.at_where("input").index(i), {"t_s", "axes"});
      JoystickKey key;
      key.t_s = k.required_number("t_s", "the sample's time, s");
      require(key.t_s >= 0, k.at_where("t_s"), "must be >= 0 s");
      if (!p.joystick.empty())
        require(key.t_s > p.joystick.back().t_s, k.at_where("t_s"),
                fmt::format("sample times must increase ({} s after {} s)", key.t_s, p.joystick.back().t_s));
      if (!k.has("axes")) k.where().fail("missing \"axes\": 1 to 3 deflections in [-1, 1]");
      const json& a = k.at("axes");
      if (!a.is_array() || a.empty() || a.size() > 3) k.at_where("axes").fail("expected 1 to 3 deflections in [-1, 1]");
      for (std::size_t c = 0; c < a.size(); ++c) {
        key.axes[Eigen::Index(c)] = Obj::as_number(a[c], k.at_where("axes").index(c), "");
        require(std::abs(key.axes[Eigen::Index(c)]) <= 1.0, k.at_where("axes").index(c),
                "a stick deflection must be in [-1, 1]");
      }
      p.joystick.push_back(key);
    }
  } else {
    p.drive = ProbeDrive::live;
    const Obj lv(o.at("live"), o.at_where("live"),
                 {"start_mm", "max_speed_mm_s", "mode", "speed_mm_s", "range_mm", "dead_zone", "directions"});
    if (!lv.has("start_mm")) lv.where().fail("missing \"start_mm\" [x, y, z]: where the probe is at t = 0 (LPS mm)");
    p.start_mm = lv.vec3("start_mm");
    p.max_speed_mm_s = lv.number("max_speed_mm_s", p.max_speed_mm_s);
    require(p.max_speed_mm_s > 0 && p.max_speed_mm_s <= 1e5, lv.at_where("max_speed_mm_s"), "must be > 0 mm/s");
    read_mapping(lv, p.mapping);
  }
  if (const std::string bad = p.validate(); !bad.empty()) w.fail(bad);
  return p;
}

SceneOutputs read_outputs(const Obj& o) {
  SceneOutputs out;
  out.forces_csv = o.boolean("forces_csv", out.forces_csv);
  out.forces_interval_s = o.number("forces_interval_s", out.forces_interval_s);
  require(out.forces_interval_s > 0 && out.forces_interval_s <= 1e3, o.at_where("forces_interval_s"), "must be > 0 s");
  out.plot = o.boolean("plot", out.plot);
  if (o.has("pvd")) {
    const json& p = o.at("pvd");
    if (p.is_boolean()) {
      out.pvd_model = out.pvd_surface = p.get<bool>();
    } else {
      const Obj v(p, o.at_where("pvd"), {"model", "surface", "interval_s", "surface_method"});
      out.pvd_model = v.boolean("model", true);
      out.pvd_surface = v.boolean("surface", true);
      out.pvd_interval_s = v.number("interval_s", out.pvd_interval_s);
      require(out.pvd_interval_s > 0, v.at_where("interval_s"), "must be > 0 s");
      const std::string m = v.string("surface_method", "paper");
      try {
        out.surface_method = parse_surface_method(m);
      } catch (const Error&) {
        v.at_where("surface_method").fail("unknown surface method \"" + m + "\"; use paper or staircase");
      }
      if (out.surface_method == SurfaceMethod::iso)
        v.at_where("surface_method").fail("the iso surface is not available in simulations yet; use paper or staircase");
    }
  }
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

Scene parse_scene(const json& j, const fs::path& base, const std::string& name) {
  const Where root{name, "$"};
  const Obj o(j, root,
              {"description", "object", "material", "fixed", "gravity", "workspace_mm", "integrator", "contact", "device",
               "probes", "duration_s", "outputs", "threads"});
  Scene s;
  s.description = o.string("description", "");
  if (!o.has("object"))
    root.fail("missing \"object\": {\"phantom\": NAME}, {\"volume\": PATH}, {\"model\": PATH.vtu} or {\"box_mm\": {..}}");
  s.object = read_object(Obj(o.at("object"), o.at_where("object"),
                             {"phantom", "volume", "model", "box_mm", "voxel_mm", "threshold", "resolution", "max_level",
                              "largest_component", "fill_holes", "crop", "series_uid", "any_modality", "size",
                              "spacing_mm", "tissue_hu", "air_hu", "lesion_hu", "noise_hu", "seed"}),
                         base);
  if (o.has("material"))
    s.material = read_material(Obj(o.at("material"), o.at_where("material"),
                                   {"youngs_modulus_kpa", "poisson_ratio", "density_kg_m3", "damping",
                                    "hounsfield_table", "inclusions"}),
                               s.object.source);
  if (o.has("fixed")) s.fixed = read_fixed(o.at("fixed"), o.at_where("fixed"));
  if (o.has("gravity")) {
    s.gravity_m_s2 = o.vec3("gravity");
    require(s.gravity_m_s2.norm() <= 1000, o.at_where("gravity"),
            fmt::format("{:.4g} m/s^2 is not a gravity; the unit is m/s^2 (e.g. [0, 0, -9.81]), not mm/s^2",
                        s.gravity_m_s2.norm()));
  }
  if (o.has("workspace_mm")) {
    const Obj w(o.at("workspace_mm"), o.at_where("workspace_mm"), {"min", "max"});
    if (!w.has("min") || !w.has("max")) w.where().fail("needs \"min\" and \"max\" corners [x, y, z] in mm");
    s.workspace.enabled = true;
    s.workspace.min_mm = w.vec3("min");
    s.workspace.max_mm = w.vec3("max");
    require((s.workspace.min_mm.array() < s.workspace.max_mm.array()).all(), w.where(),
            "min must be below max on every axis");
  }
  if (o.has("integrator")) {
    const Obj in(o.at("integrator"), o.at_where("integrator"), {"type", "dt_s"});
    const std::string t = in.string("type", "symplectic_euler");
    try {
      s.integrator = parse_integrator(t);
    } catch (const Error&) {
      in.at_where("type").fail("unknown integrator \"" + t + "\"; use explicit_euler (the paper), symplectic_euler or implicit");
    }
    if (in.has("dt_s")) {
      const json& d = in.at("dt_s");
      if (d.is_string() && d.get<std::string>() == "auto") {
        s.dt_s = 0.0;
      } else {
        s.dt_s = in.number("dt_s");
        require(s.dt_s > 0, in.at_where("dt_s"), "must be > 0 s (or \"auto\")");
        require(s.dt_s <= 0.1, in.at_where("dt_s"),
                fmt::format("{} s is far too long for a physics step; the unit is s (e.g. 1e-4), or use \"auto\"", s.dt_s));
      }
    }
  }
  if (o.has("contact")) {
    const Obj c(o.at("contact"), o.at_where("contact"), {"restitution", "friction", "skin_mm"});
    s.contact.restitution = c.number("restitution", s.contact.restitution);
    require(s.contact.restitution >= 0 && s.contact.restitution <= 1, c.at_where("restitution"),
            "must be in [0, 1] (1: elastic collision, the paper)");
    s.contact.friction = c.number("friction", s.contact.friction);
    require(s.contact.friction >= 0 && s.contact.friction <= 10, c.at_where("friction"),
            "must be in [0, 10] (a Coulomb coefficient; 0 = frictionless, the paper)");
    s.contact.skin_mm = c.number("skin_mm", s.contact.skin_mm);
    require(s.contact.skin_mm >= 0, c.at_where("skin_mm"), "must be >= 0 mm (0: automatic)");
  }
  if (o.has("device")) {
    const Obj d(o.at("device"), o.at_where("device"), {"update_interval_s", "average_steps", "mean_preserving"});
    DeviceForceSettings dev;
    dev.update_interval_s = d.number("update_interval_s", dev.update_interval_s);
    require(dev.update_interval_s > 0 && dev.update_interval_s <= 10, d.at_where("update_interval_s"),
            "must be > 0 s (e.g. 0.02 for a 50 Hz device)");
    dev.average_steps = d.integer("average_steps", dev.average_steps);
    require(dev.average_steps >= 0, d.at_where("average_steps"), "must be >= 0 (0: every step since the last update)");
    dev.mean_preserving = d.boolean("mean_preserving", dev.mean_preserving);
    s.device = dev;
  }
  if (o.has("probes")) {
    const json& list = o.at("probes");
    if (!list.is_array()) o.at_where("probes").fail("expected an array of probes, got " + type_name(list));
    std::set<std::string> names;
    for (std::size_t i = 0; i < list.size(); ++i) {
      s.probes.push_back(read_probe(list[i], o.at_where("probes").index(i), i));
      if (!names.insert(s.probes.back().name).second)
        o.at_where("probes").index(i).key("name").fail("probe names must be unique (\"" + s.probes.back().name +
                                                        "\" is used twice)");
    }
  }
  s.duration_s = o.required_number("duration_s", "how long to simulate, s");
  require(s.duration_s > 0 && s.duration_s <= 1e5, o.at_where("duration_s"),
          fmt::format("must be > 0 s (got {}); the unit is s", s.duration_s));
  if (o.has("outputs"))
    s.outputs = read_outputs(Obj(o.at("outputs"), o.at_where("outputs"), {"forces_csv", "forces_interval_s", "plot", "pvd"}));
  s.threads = o.integer("threads", 0);
  require(s.threads >= 0 && s.threads <= 1024, o.at_where("threads"), "must be >= 0 (0: all cores)");
  return s;
}

Scene parse_scene(const std::string& text, const fs::path& base, const std::string& name) {
  json j;
  try {
    j = json::parse(text, nullptr, true, /*ignore_comments=*/true);
  } catch (const json::parse_error& e) {
    // e.what(): "[json.exception.parse_error.101] parse error at line 3, column 5: ..."
    std::string msg = e.what();
    if (const auto p = msg.find("] "); p != std::string::npos) msg = msg.substr(p + 2);
    throw Error(name + ": not valid JSON: " + msg);
  }
  return parse_scene(j, base, name);
}

Scene load_scene(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    if (!fs::exists(path)) throw Error(path.string() + ": no such scene file");
    throw Error(path.string() + ": cannot be read (check its permissions)");
  }
  std::ostringstream text;
  text << in.rdbuf();
  Scene s = parse_scene(text.str(), fs::absolute(path).parent_path(), path.string());
  s.file = path;
  return s;
}

// ---------------------------------------------------------------------------------------------
// building

double modulus_from_hu(const std::vector<HuModulus>& t, double hu) {
  if (t.empty()) return 0.0;
  if (hu <= t.front().hu) return t.front().youngs_modulus_kpa;
  if (hu >= t.back().hu) return t.back().youngs_modulus_kpa;
  const auto it = std::upper_bound(t.begin(), t.end(), hu, [](double h, const HuModulus& r) { return h < r.hu; });
  const HuModulus& b = *it;
  const HuModulus& a = *(it - 1);
  const double u = (hu - a.hu) / (b.hu - a.hu);
  return (1 - u) * a.youngs_modulus_kpa + u * b.youngs_modulus_kpa;
}

namespace {

/// Calls fn(i, j, k) for every voxel covered by element e of the model.
template <class Fn>
void for_each_voxel(const Model& m, int e, Fn&& fn) {
  const int w = m.element_cell_voxels[std::size_t(e)];
  const Eigen::Vector3i a = m.element_anchor.col(e);
  const std::uint8_t cells = m.element_cells[std::size_t(e)];
  for (int c = 0; c < 8; ++c) {
    if (!(cells & (1u << c))) continue;
    const Eigen::Vector3i lo = a + w * Eigen::Vector3i(c & 1, (c >> 1) & 1, (c >> 2) & 1);
    for (int k = lo.z(); k < lo.z() + w; ++k)
      for (int j = lo.y(); j < lo.y() + w; ++j)
        for (int i = lo.x(); i < lo.x() + w; ++i) fn(i, j, k);
  }
}

float sample_hu(const Volume& v, const Eigen::Vector3d& p) {
  const Eigen::Vector3d ijk = v.geometry.lps_to_index(p);
  const Eigen::Vector3i& d = v.geometry.dims;
  const int i = std::clamp(int(std::lround(ijk.x())), 0, d.x() - 1);
  const int j = std::clamp(int(std::lround(ijk.y())), 0, d.y() - 1);
  const int k = std::clamp(int(std::lround(ijk.z())), 0, d.z() - 1);
  return v.at(i, j, k);
}

}  // namespace

MaterialField material_field(const Model& m, const SceneMaterial& mat, const Volume* hu) {
  MaterialField field;
  if (mat.hounsfield.empty() && mat.inclusions.empty()) return field;
  if (!mat.hounsfield.empty() && !hu) throw Error("material: the Hounsfield table needs the object's volume");
  const int ne = m.num_elements();
  const bool any_density = std::any_of(mat.inclusions.begin(), mat.inclusions.end(),
                                       [](const Inclusion& i) { return i.density_kg_m3 > 0; });
  field.youngs_modulus_kpa.assign(std::size_t(ne), mat.base.youngs_modulus_kpa);
  if (any_density) field.density_kg_m3.assign(std::size_t(ne), mat.base.density_kg_m3);
#pragma omp parallel for schedule(dynamic, 64)
  for (int e = 0; e < ne; ++e) {
    // Voigt average over the element's voxels (voxel centres)
    double sum_e = 0, sum_rho = 0;
    std::int64_t n = 0;
    for_each_voxel(m, e, [&](int i, int j, int k) {
      const Eigen::Vector3d p = m.grid.index_to_lps(Eigen::Vector3d(i, j, k));
      double e_kpa = hu && !mat.hounsfield.empty() ? modulus_from_hu(mat.hounsfield, sample_hu(*hu, p))
                                                   : mat.base.youngs_modulus_kpa;
      double rho = mat.base.density_kg_m3;
      for (const Inclusion& inc : mat.inclusions)  // the last inclusion holding the voxel wins
        if ((p - inc.center_mm).squaredNorm() < inc.radius_mm * inc.radius_mm) {
          e_kpa = inc.youngs_modulus_kpa;
          if (inc.density_kg_m3 > 0) rho = inc.density_kg_m3;
        }
      sum_e += e_kpa;
      sum_rho += rho;
      ++n;
    });
    if (n > 0) {
      field.youngs_modulus_kpa[std::size_t(e)] = sum_e / double(n);
      if (any_density) field.density_kg_m3[std::size_t(e)] = sum_rho / double(n);
    }
  }
  return field;
}

VoxelGrid grid_from_model(const Model& m) {
  VoxelGrid grid(m.grid);
  for (int e = 0; e < m.num_elements(); ++e)
    for_each_voxel(m, e, [&](int i, int j, int k) {
      if (grid.inside(i, j, k)) grid.set(i, j, k, 1);
    });
  return grid;
}

PreparedScene prepare_scene(const Scene& scene, const PrepareSceneOptions& options) {
  PreparedScene out;
  const std::string where = scene.file.empty() ? std::string("scene") : scene.file.string();
  const auto fail = [&](const std::string& path, const std::string& what) -> void {
    throw Error(where + ": " + path + ": " + what);
  };

  // the object
  const SceneObject& obj = scene.object;
  std::optional<Volume> volume;
  Model model;
  switch (obj.source) {
    case ObjectSource::phantom: {
      PhantomShape shape;
      volume = make_phantom(obj.phantom, &shape);
      out.log.push_back(fmt::format("phantom {} ({}^3 voxels of {:g} mm)", obj.phantom.name, obj.phantom.size,
                                    obj.phantom.spacing_mm));
      break;
    }
    case ObjectSource::volume:
      volume = read_volume(obj.path, obj.read);
      out.log.push_back(fmt::format("volume {} ({}x{}x{} voxels)", obj.path.string(), volume->geometry.dims.x(),
                                    volume->geometry.dims.y(), volume->geometry.dims.z()));
      break;
    case ObjectSource::model:
      model = load_model(obj.path);
      out.grid = grid_from_model(model);
      out.log.push_back(fmt::format("model {} ({} elements)", obj.path.string(), model.num_elements()));
      break;
    case ObjectSource::box: {
      GridGeometry g;
      const Eigen::Vector3d size = obj.box_max_mm - obj.box_min_mm;
      for (int c = 0; c < 3; ++c) g.dims[c] = int(std::lround(size[c] / obj.box_voxel_mm));
      g.spacing_mm = Eigen::Vector3d::Constant(obj.box_voxel_mm);
      g.origin_mm = obj.box_min_mm + Eigen::Vector3d::Constant(0.5 * obj.box_voxel_mm);
      out.grid = VoxelGrid(g);
      std::fill(out.grid.data().begin(), out.grid.data().end(), std::uint8_t(1));
      out.log.push_back(fmt::format("box {}x{}x{} voxels of {:g} mm", g.dims.x(), g.dims.y(), g.dims.z(), obj.box_voxel_mm));
      break;
    }
  }
  if (volume) {
    PrepareReport report;
    out.grid = prepare_grid(*volume, obj.prepare, &report);
    out.log.push_back(report.summary());
  }
  if (obj.source != ObjectSource::model) {
    BuildReport report;
    model = build_model(out.grid, obj.build, &report);
  }
  out.model = std::make_shared<const Model>(std::move(model));
  const Model& m = *out.model;
  out.bounds_min_mm = m.rest_positions.rowwise().minCoeff();
  out.bounds_max_mm = m.rest_positions.rowwise().maxCoeff();
  out.log.push_back(fmt::format("{} model: {} elements, {} nodes, {} vertex entries; bounds [{:.4g}, {:.4g}, {:.4g}] .. "
                                "[{:.4g}, {:.4g}, {:.4g}] mm",
                                to_string(m.layout), m.num_elements(), m.num_nodes(), m.num_vertex_entries(),
                                out.bounds_min_mm.x(), out.bounds_min_mm.y(), out.bounds_min_mm.z(),
                                out.bounds_max_mm.x(), out.bounds_max_mm.y(), out.bounds_max_mm.z()));

  // the material, per element when heterogeneous
  const MaterialField field = material_field(m, scene.material, volume ? &*volume : nullptr);
  out.physics = make_physics_model(out.model, scene.material.base, field);
  out.min_modulus_kpa = out.max_modulus_kpa = scene.material.base.youngs_modulus_kpa;
  if (!field.youngs_modulus_kpa.empty()) {
    const auto [lo, hi] = std::minmax_element(field.youngs_modulus_kpa.begin(), field.youngs_modulus_kpa.end());
    out.min_modulus_kpa = *lo;
    out.max_modulus_kpa = *hi;
    for (double e : field.youngs_modulus_kpa)
      if (std::abs(e - scene.material.base.youngs_modulus_kpa) > 1e-12 * scene.material.base.youngs_modulus_kpa)
        ++out.heterogeneous_elements;
    out.log.push_back(fmt::format("material: modulus {:.4g} to {:.4g} kPa per element ({} elements differ from {:g} kPa)",
                                  out.min_modulus_kpa, out.max_modulus_kpa, out.heterogeneous_elements,
                                  scene.material.base.youngs_modulus_kpa));
    for (std::size_t i = 0; i < scene.material.inclusions.size(); ++i) {
      const Inclusion& inc = scene.material.inclusions[i];
      if ((inc.center_mm.array() + inc.radius_mm < out.bounds_min_mm.array()).any() ||
          (inc.center_mm.array() - inc.radius_mm > out.bounds_max_mm.array()).any())
        out.warnings.push_back(fmt::format("material.inclusions[{}] lies outside the object's bounds: it changes nothing", i));
    }
  }

  // the simulation settings
  SimulationSettings& s = out.settings;
  s.integrator.kind = scene.integrator;
  const TimeStepEstimate est = estimate_time_steps(*out.physics);
  out.dt_stable_estimate_s = est.limit(scene.integrator);
  const double automatic_dt_s = automatic_time_step(est, scene.integrator);
  if (scene.dt_s > 0) {
    s.integrator.time_step_s = scene.dt_s;
  } else if (automatic_dt_s > 0) {
    s.integrator.time_step_s = automatic_dt_s;
  } else {
    fail("$.integrator", "explicit_euler without damping is unstable at any time step (MODEL.md 2); set material.damping > 0 "
                         "or use symplectic_euler or implicit");
  }
  if (scene.integrator != IntegratorKind::implicit) {
    if (out.dt_stable_estimate_s == 0.0)
      out.warnings.push_back("explicit_euler without damping gains energy every step at any dt_s: the run will blow up");
    else if (s.integrator.time_step_s > 1.25 * out.dt_stable_estimate_s)
      // the estimate is close to the real limit (a block blew up at 1.3x within 40 steps)
      fail("$.integrator.dt_s",
           fmt::format("{:.3g} s is {:.2g} times the estimated stable step {:.3g} s of {} for this model and material: the "
                       "run would blow up within a few steps; use \"auto\" (half the estimate) or at most {:.3g} s, or the "
                       "implicit integrator",
                       s.integrator.time_step_s, s.integrator.time_step_s / out.dt_stable_estimate_s,
                       out.dt_stable_estimate_s, to_string(scene.integrator), out.dt_stable_estimate_s));
    else if (s.integrator.time_step_s > out.dt_stable_estimate_s)
      out.warnings.push_back(fmt::format("integrator.dt_s {:.3g} s exceeds the estimated stable step {:.3g} s of {}: the run "
                                         "may blow up (the summary's \"stable\" will say)",
                                         s.integrator.time_step_s, out.dt_stable_estimate_s, to_string(scene.integrator)));
  }
  if (scene.integrator == IntegratorKind::implicit && scene.contact.friction > 0)
    out.warnings.push_back(fmt::format("contact.friction {:g} is ignored by the implicit integrator (its contact is "
                                       "frictionless and inelastic, solved inside the step); use symplectic_euler to "
                                       "grasp and lift",
                                       scene.contact.friction));
  if (scene.duration_s / s.integrator.time_step_s > 2e9)
    fail("$.duration_s", fmt::format("{} s at dt {:.3g} s is more than 2e9 steps", scene.duration_s, s.integrator.time_step_s));
  s.integrator.threads = options.threads_override >= 0 ? options.threads_override : scene.threads;
  s.gravity_mm_s2 = scene.gravity_m_s2 * 1000.0;

  // fixed nodes
  std::vector<std::uint8_t> fixed(std::size_t(m.num_nodes()), 0);
  for (std::size_t r = 0; r < scene.fixed.size(); ++r) {
    const FixedRegion& f = scene.fixed[r];
    const std::vector<int> nodes = f.is_face ? nodes_on_face(m, f.face, std::max(f.within_mm, 1e-6 * m.grid.spacing_mm.minCoeff()))
                                             : nodes_in_box(m, f.box_min_mm, f.box_max_mm);
    if (nodes.empty())
      fail(fmt::format("$.fixed[{}]", r),
           fmt::format("\"{}\" holds no node of the object (bounds [{:.4g}, {:.4g}, {:.4g}] .. [{:.4g}, {:.4g}, {:.4g}] mm)",
                       f.label, out.bounds_min_mm.x(), out.bounds_min_mm.y(), out.bounds_min_mm.z(), out.bounds_max_mm.x(),
                       out.bounds_max_mm.y(), out.bounds_max_mm.z()));
    if (f.is_face && nodes.size() < 3)
      out.warnings.push_back(fmt::format("fixed[{}] \"{}\" holds only {} node(s) (a rounded object touches its bounding box in "
                                         "a point); use {{\"face\": \"{}\", \"within_mm\": 2}}",
                                         r, f.label, nodes.size(), f.label));
    for (int i : nodes) fixed[std::size_t(i)] = 1;
  }
  for (int i = 0; i < m.num_nodes(); ++i)
    if (fixed[std::size_t(i)]) s.fixed_nodes.push_back(i);
  out.fixed_nodes = int(s.fixed_nodes.size());

  // walls, contact, device, probes
  s.workspace = scene.workspace;
  if (s.workspace.enabled && ((out.bounds_min_mm.array() < s.workspace.min_mm.array()).any() ||
                              (out.bounds_max_mm.array() > s.workspace.max_mm.array()).any()))
    out.warnings.push_back("the object does not fit in workspace_mm: the walls push it in at the first step");
  s.contact = scene.contact;
  s.device = scene.device;
  s.probes = scene.probes;
  const double spacing = m.grid.spacing_mm.minCoeff();
  const double dt = s.integrator.time_step_s;
  if (s.device && s.device->update_interval_s < 1.5 * dt)
    fail("$.device.update_interval_s", fmt::format("{:.3g} s spans less than 2 physics steps of {:.3g} s; a half sine needs "
                                                   "room: raise it (e.g. 0.02 s) or lower integrator.dt_s",
                                                   s.device->update_interval_s, dt));
  const std::vector<std::int32_t> surface_nodes = collidable_nodes(m, fixed);
  for (std::size_t i = 0; i < s.probes.size(); ++i) {
    const ProbeSettings& p = s.probes[i];
    const std::string at = fmt::format("$.probes[{}]", i);
    const double speed = p.max_scripted_speed_mm_s();
    if (p.geometry.shape != ProbeShape::plane) {
      // nodes are pushed to the nearest surface point: a probe moving more than about half its
      // radius per step would push them out of its far side (tunnelling)
      if (speed * dt > 0.5 * p.geometry.radius_mm)
        fail(at, fmt::format("the probe moves up to {:.4g} mm/s, {:.3g} mm per step of {:.3g} s: more than half its radius "
                             "({:g} mm), so it would pass through the surface; slow it down or lower integrator.dt_s",
                             speed, speed * dt, dt, p.geometry.radius_mm));
      if (p.geometry.radius_mm < spacing)
        out.warnings.push_back(fmt::format("probes[{}] \"{}\": radius {:g} mm is below the node spacing {:g} mm; it can pass "
                                           "between surface nodes",
                                           i, p.name, p.geometry.radius_mm, spacing));
    } else if (speed * dt > spacing) {
      out.warnings.push_back(fmt::format("probes[{}] \"{}\": the plate moves {:.3g} mm per step, more than a voxel", i, p.name,
                                         speed * dt));
    }
    const Eigen::Vector3d start = p.initial_position();
    int inside = 0;
    for (const std::int32_t n : surface_nodes)
      if (probe_signed_distance(p.geometry, start, m.rest_positions.col(n)) < 0) ++inside;
    if (inside > 0)
      out.warnings.push_back(fmt::format("probes[{}] \"{}\" starts with {} surface nodes inside it: they are pushed out at "
                                         "the first step",
                                         i, p.name, inside));
  }

  // the surface, only when someone will show or write it
  if (options.surface) {
    const bool paper = scene.outputs.surface_method != SurfaceMethod::staircase;
    VoxelSurfaceReport rep;
    out.surface = std::make_shared<const EmbeddedSurface>(make_voxel_surface(m, out.grid, paper, &rep));
    out.log.push_back(fmt::format("surface ({}): {} vertices, {} triangles", to_string(out.surface->method),
                                  out.surface->num_vertices(), out.surface->num_triangles()));
  }
  s.surface = out.surface;
  s.skip_unneeded = options.skip_unneeded;
  return out;
}

}  // namespace vx
