// Scene files: strict JSON reading (strict_json.h) of each section, with JSON paths in every
// message. Building a loaded scene is prepare_scene.cpp.
#include "scene/scene.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "base/error.h"
#include "convert/threshold.h"
#include "scene/strict_json.h"

namespace vx {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

using strict_json::array_at;
using strict_json::Obj;
using strict_json::require;
using strict_json::type_name;
using strict_json::Where;

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
      o.at_where(k).fail(fmt::format(
          "\"{}\" does not exist (looked for {}; relative paths start at the scene's folder)", p, full.string()));
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
    w.fail(
        "expected a number (lowest tissue HU), a string \"LO:HI\" or a preset name, or {\"lo\": .., \"hi\": ..}; got " +
        type_name(t));
  };

  if (src == "phantom") {
    obj.source = ObjectSource::phantom;
    obj.phantom.name = o.string("phantom", "");
    const auto names = phantom_names();
    if (std::find(names.begin(), names.end(), obj.phantom.name) == names.end())
      o.at_where("phantom").fail(
          fmt::format("unknown phantom \"{}\"; choose one of: {}", obj.phantom.name, fmt::join(names, ", ")));
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
    obj.phantom.thickness_mm = o.number("thickness_mm", 0.0);
    require(obj.phantom.thickness_mm >= 0 && obj.phantom.thickness_mm <= 50, o.at_where("thickness_mm"),
            "must be 0 (the spacing) or a slice thickness up to 50 mm");
    // block-lesion, disk-lesion: the lesion placed and sized (inside the block or disk)
    if (o.has("lesion_center_mm")) obj.phantom.lesion_center_mm = o.vec3("lesion_center_mm");
    obj.phantom.lesion_radius_mm = o.number("lesion_radius_mm", 0.0);
    if (o.has("lesion_radius_mm"))
      require(obj.phantom.lesion_radius_mm > 0, o.at_where("lesion_radius_mm"), "must be > 0 mm");
    if (const std::string e = lesion_settings_error(obj.phantom); !e.empty())
      o.at_where(o.has("lesion_center_mm") ? "lesion_center_mm" : "lesion_radius_mm").fail(e);
    {
      PhantomShape probe_shape;
      probe_shape.name = obj.phantom.name;
      if (!probe_shape.is_2d() && o.has("thickness_mm"))
        o.at_where("thickness_mm").fail("applies to the one-slice phantoms (disk, rectangle, disk-lesion) only");
    }
    // between air and tissue by default
    obj.prepare.range =
        read_threshold({0.5 * (obj.phantom.air_hu + obj.phantom.tissue_hu), std::numeric_limits<double>::infinity()});
    o.forbid("series_uid", "series_uid applies to a DICOM \"volume\" only");
  } else if (src == "volume") {
    obj.source = ObjectSource::volume;
    obj.path = path_of("volume");
    obj.prepare.range = read_threshold(HuRange{});
    obj.read.series_uid = o.string("series_uid", "");
    obj.read.any_modality = o.boolean("any_modality", false);
    for (const char* k : {"size", "spacing_mm", "tissue_hu", "air_hu", "lesion_hu", "noise_hu", "seed", "thickness_mm",
                          "lesion_center_mm", "lesion_radius_mm"})
      o.forbid(k, std::string(k) + " applies to a \"phantom\" object only");
  } else if (src == "model") {
    obj.source = ObjectSource::model;
    obj.path = path_of("model");
    for (const char* k : {"threshold", "resolution", "max_level", "largest_component", "fill_holes", "voxel_mm", "crop",
                          "lattice_origin", "size", "spacing_mm", "tissue_hu", "air_hu", "lesion_hu", "noise_hu",
                          "seed", "series_uid", "thickness_mm", "lesion_center_mm", "lesion_radius_mm"})
      o.forbid(k, std::string(k) +
                      " does not apply to a model file: it was set when the model was converted "
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
      require(
          std::abs(n - std::round(n)) < 1e-6 * std::max(1.0, n), b.where(),
          fmt::format("the box is {} mm along axis {}, not a whole number of {} mm voxels; adjust min/max or voxel_mm",
                      size[c], "xyz"[c], obj.box_voxel_mm));
      require(std::round(n) >= 2, b.where(), fmt::format("the box needs at least 2 voxels along {}", "xyz"[c]));
      require(std::round(n) <= 1024, b.where(), fmt::format("the box is more than 1024 voxels along {}", "xyz"[c]));
    }
    for (const char* k : {"threshold", "largest_component", "fill_holes", "crop", "lattice_origin", "size",
                          "spacing_mm", "tissue_hu", "air_hu", "lesion_hu", "noise_hu", "seed", "series_uid",
                          "thickness_mm", "lesion_center_mm", "lesion_radius_mm"})
      o.forbid(k, std::string(k) + " does not apply to a box (it is all tissue; its voxel size is voxel_mm)");
  }
  if (src == "phantom" || src == "volume") {
    obj.prepare.largest_component = o.boolean("largest_component", false);
    obj.prepare.fill_holes = o.boolean("fill_holes", false);
    obj.prepare.crop = o.boolean("crop", true);
    obj.prepare.voxel_mm = o.number("voxel_mm", 0.0);
    require(obj.prepare.voxel_mm >= 0 && obj.prepare.voxel_mm <= 50, o.at_where("voxel_mm"),
            "resampling voxel size must be 0 (keep) or up to 50 mm");
    // docs/model.md section 3.5: the crop's first voxel where the model has the fewest vertex entries
    const std::string origin = o.string("lattice_origin", "best");
    if (origin != "best" && origin != "crop")
      o.at_where("lattice_origin")
          .fail("unknown lattice origin \"" + origin +
                "\"; use best (the fewest vertex "
                "entries) or crop (the crop's 1-voxel margin)");
    obj.prepare.lattice_period = origin == "best" && obj.prepare.crop ? 4 : 0;
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
    obj.prepare.lattice_build = obj.build;
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
  if (o.has("element")) {
    const std::string e = o.string("element", to_string(m.element));
    try {
      m.element = element_kind_from_string(e);
    } catch (const Error&) {
      o.at_where("element").fail("unknown element \"" + e +
                                 "\"; use hourglass (the default: bending modes at linear elasticity's stiffness) or "
                                 "paper (the paper's element, stiffer in bending)");
    }
  }
  b.damping_ratio = o.number("damping", b.damping_ratio);
  require(b.damping_ratio >= 0 && b.damping_ratio <= 10, o.at_where("damping"),
          fmt::format("must be in [0, 10] (got {}): a ratio of each element's critical damping (e.g. 0.1)",
                      b.damping_ratio));
  if (o.has("mass_scaling")) {
    const Obj ms(o.at("mass_scaling"), o.at_where("mass_scaling"), {"factor", "time_step_s"});
    m.mass_scaling.factor = ms.number("factor", 1.0);
    require(m.mass_scaling.factor >= 1 && m.mass_scaling.factor <= 1e6, ms.at_where("factor"),
            fmt::format("must be in [1, 1e6] (got {}): every node's mass is multiplied by it", m.mass_scaling.factor));
    m.mass_scaling.time_step_s = ms.number("time_step_s", 0.0);
    require(m.mass_scaling.time_step_s >= 0 && m.mass_scaling.time_step_s <= 0.01, ms.at_where("time_step_s"),
            fmt::format("must be in [0, 0.01] s (got {}): the explicit step the mass floor is for, e.g. 2.5e-4",
                        m.mass_scaling.time_step_s));
  }

  if (o.has("hounsfield_table")) {
    const Where w = o.at_where("hounsfield_table");
    if (source == ObjectSource::model || source == ObjectSource::box)
      w.fail(
          "needs the object's HU values: use an object with \"volume\" or \"phantom\" (a model file or a box has "
          "none)");
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
  w.fail("unknown face \"" + s +
         "\"; use x_min, x_max, y_min, y_max, z_min or z_max (faces of the object's bounding box, LPS)");
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
      wi.fail(
          "expected a face name such as \"z_min\" or an object {\"face\": .., \"within_mm\": ..} / {\"box_mm\": ..}; "
          "got " +
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
    require(key.t_s <= kMaxSceneTime_s, k.at_where("t_s"),
            fmt::format("{} s is beyond the longest scene ({:g} s); the unit is s", key.t_s, kMaxSceneTime_s));
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
    o.at_where("mode").fail("unknown mode \"" + mode +
                            "\"; use \"rate\" (velocity proportional to tilt, the paper) or \"position\"");
  }
  m.max_speed_mm_s = o.number("speed_mm_s", m.max_speed_mm_s);
  require(m.max_speed_mm_s > 0 && m.max_speed_mm_s <= 1e5, o.at_where("speed_mm_s"),
          "must be > 0 mm/s (speed at full tilt)");
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
    if (!js.has("input"))
      js.where().fail("missing \"input\": [{\"t_s\": 0, \"axes\": [x, y]}, ...] stick deflections in [-1, 1]");
    const json& in = array_at(js, "input", 1, "samples {\"t_s\": .., \"axes\": [..]}");
    for (std::size_t i = 0; i < in.size(); ++i) {
      const Obj k(in[i], js.at_where("input").index(i), {"t_s", "axes"});
      JoystickKey key;
      key.t_s = k.required_number("t_s", "the sample's time, s");
      require(key.t_s >= 0, k.at_where("t_s"), "must be >= 0 s");
      require(key.t_s <= kMaxSceneTime_s, k.at_where("t_s"),
              fmt::format("{} s is beyond the longest scene ({:g} s); the unit is s", key.t_s, kMaxSceneTime_s));
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
        v.at_where("surface_method")
            .fail("the iso surface is not available in simulations yet; use paper or staircase");
    }
  }
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

Scene parse_scene(const json& j, const fs::path& base, const std::string& name) {
  const Where root{name, "$"};
  const Obj o(j, root,
              {"description", "object", "material", "fixed", "gravity", "workspace_mm", "integrator", "contact",
               "device", "probes", "duration_s", "outputs", "threads"});
  Scene s;
  s.description = o.string("description", "");
  if (!o.has("object"))
    root.fail(
        "missing \"object\": {\"phantom\": NAME}, {\"volume\": PATH}, {\"model\": PATH.vtu} or {\"box_mm\": {..}}");
  s.object = read_object(Obj(o.at("object"), o.at_where("object"),
                             {"phantom",
                              "volume",
                              "model",
                              "box_mm",
                              "voxel_mm",
                              "threshold",
                              "resolution",
                              "max_level",
                              "largest_component",
                              "fill_holes",
                              "crop",
                              "lattice_origin",
                              "series_uid",
                              "any_modality",
                              "size",
                              "spacing_mm",
                              "tissue_hu",
                              "air_hu",
                              "lesion_hu",
                              "noise_hu",
                              "seed",
                              "thickness_mm",
                              "lesion_center_mm",
                              "lesion_radius_mm"}),
                         base);
  if (o.has("material"))
    s.material = read_material(Obj(o.at("material"), o.at_where("material"),
                                   {"youngs_modulus_kpa", "poisson_ratio", "density_kg_m3", "damping", "element",
                                    "mass_scaling", "hounsfield_table", "inclusions"}),
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
    const Obj in(o.at("integrator"), o.at_where("integrator"),
                 {"type", "dt_s", "iterations", "residual_tolerance_n", "region_radius_mm", "region_far_field",
                  "sweep_precision"});
    s.integrator_given = true;
    const std::string t = in.string("type", "symplectic_euler");
    try {
      s.integrator = parse_integrator(t);
    } catch (const Error&) {
      in.at_where("type").fail("unknown integrator \"" + t +
                               "\"; use explicit_euler (the paper), symplectic_euler or implicit");
    }
    if (in.has("dt_s")) {
      const json& d = in.at("dt_s");
      if (d.is_string() && d.get<std::string>() == "auto") {
        s.dt_s = 0.0;
      } else {
        s.dt_s = in.number("dt_s");
        require(s.dt_s > 0, in.at_where("dt_s"), "must be > 0 s (or \"auto\")");
        require(
            s.dt_s <= 0.1, in.at_where("dt_s"),
            fmt::format("{} s is far too long for a physics step; the unit is s (e.g. 1e-4), or use \"auto\"", s.dt_s));
      }
    }
    s.iterations = in.integer("iterations", 0);
    require(s.iterations >= 0 && s.iterations <= 10000, in.at_where("iterations"),
            "must be in [1, 10000] local/global iterations per step (0: the default, 10)");
    s.residual_tolerance_n = in.number("residual_tolerance_n", 0.0);
    require(s.residual_tolerance_n >= 0, in.at_where("residual_tolerance_n"), "must be >= 0 N (0: off)");
    s.region_radius_mm = in.number("region_radius_mm", 0.0);
    require(s.region_radius_mm >= 0, in.at_where("region_radius_mm"), "must be >= 0 mm (0: every node every step)");
    const std::string far = in.string("region_far_field", "held");
    if (far != "held" && far != "carried")
      in.at_where("region_far_field")
          .fail("unknown \"" + far + "\"; use held (the default) or carried (docs/model.md section 7)");
    s.region_far_field_degree = far == "carried" ? 1 : 0;
    const std::string precision = in.string("sweep_precision", "auto");
    if (precision != "auto" && precision != "single" && precision != "double")
      in.at_where("sweep_precision")
          .fail("unknown \"" + precision +
                "\"; use auto (the default: single on a large model), single or double (docs/bench.md, "
                "\"Single-precision sweeps\")");
    if (precision != "auto") s.single_precision_sweeps = precision == "single";
    if ((s.iterations > 0 || s.residual_tolerance_n > 0 || s.region_radius_mm > 0 || in.has("region_far_field") ||
         in.has("sweep_precision")) &&
        s.integrator != IntegratorKind::implicit)
      in.where().fail(
          "iterations, residual_tolerance_n, region_radius_mm, region_far_field and sweep_precision are settings of "
          "the implicit integrator");
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
  // without an integrator key: the fast configuration, unless the contact needs friction
  // (grasping), which only the explicit schemes' contact has
  if (!s.integrator_given && s.contact.friction > 0) s.integrator = IntegratorKind::symplectic_euler;
  if (o.has("device")) {
    const Obj d(o.at("device"), o.at_where("device"),
                {"update_interval_s", "average_steps", "mean_preserving", "force_shaping", "device_damping_n_s_m"});
    DeviceForceSettings dev;
    dev.update_interval_s = d.number("update_interval_s", dev.update_interval_s);
    require(dev.update_interval_s > 0 && dev.update_interval_s <= 10, d.at_where("update_interval_s"),
            "must be > 0 s (e.g. 0.02 for a 50 Hz device)");
    dev.average_steps = d.integer("average_steps", dev.average_steps);
    require(dev.average_steps >= 0, d.at_where("average_steps"), "must be >= 0 (0: every step since the last update)");
    dev.mean_preserving = d.boolean("mean_preserving", dev.mean_preserving);
    if (d.has("force_shaping")) {
      const std::string f = d.string("force_shaping", "paper");
      require(
          f == "paper" || f == "local", d.at_where("force_shaping"),
          "unknown force shaping \"" + f + "\"; use local (the local contact model at 1 kHz) or paper (half sines)");
      dev.shaping = parse_force_shaping(f);
    }
    const double b = d.number("device_damping_n_s_m", 1e3 * dev.device_damping_n_s_mm);
    require(b > 0 && b <= 1000, d.at_where("device_damping_n_s_m"),
            "must be > 0 N s/m (the device's own damping; 1.5 for a modest desktop device)");
    dev.device_damping_n_s_mm = 1e-3 * b;
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
  require(s.duration_s > 0 && s.duration_s <= kMaxSceneTime_s, o.at_where("duration_s"),
          fmt::format("must be > 0 s and at most {:g} s (got {}); the unit is s", kMaxSceneTime_s, s.duration_s));
  if (o.has("outputs"))
    s.outputs =
        read_outputs(Obj(o.at("outputs"), o.at_where("outputs"), {"forces_csv", "forces_interval_s", "plot", "pvd"}));
  s.threads = o.integer("threads", 0);
  require(s.threads >= 0 && s.threads <= 1024, o.at_where("threads"), "must be >= 0 (0: all cores)");
  return s;
}

Scene parse_scene(const std::string& text, const fs::path& base, const std::string& name) {
  json j;
  try {
    j = json::parse(text, nullptr, true, /*ignore_comments=*/true);
  } catch (const json::exception& e) {
    // e.what(): "[json.exception.parse_error.101] parse error at line 3, column 5: ..." (a number
    // too large for a double, 1e999, is an out_of_range.406, found by fuzzing)
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

}  // namespace vx
