#include "scene/strict_json.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <utility>

#include "base/error.h"
#include "util/text.h"

namespace vx::strict_json {
namespace {

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

/// The keys in double quotes, for messages.
std::vector<std::string> quoted(const std::vector<std::string>& v) {
  std::vector<std::string> q;
  for (const auto& s : v) q.push_back("\"" + s + "\"");
  return q;
}

}  // namespace

std::string type_name(const json& j) {
  if (j.is_null()) return "null";
  if (j.is_boolean()) return "a boolean";
  if (j.is_number()) return "a number";
  if (j.is_string()) return "the string \"" + j.get<std::string>() + "\"";
  if (j.is_array()) return "an array";
  return "an object";
}

void Where::fail(const std::string& what) const { throw Error(file + ": " + path + ": " + what); }

void require(bool ok, const Where& w, const std::string& what) {
  if (!ok) w.fail(what);
}

Obj::Obj(const json& j, Where where, std::vector<std::string> allowed)
    : j_(j), where_(std::move(where)), allowed_(std::move(allowed)) {
  if (!j_.is_object()) where_.fail("expected an object { ... }, got " + type_name(j_));
  for (auto it = j_.begin(); it != j_.end(); ++it) check_key(it.key());
}

std::string Obj::one_of(const std::vector<std::string>& keys, const std::string& what) const {
  std::vector<std::string> present;
  for (const auto& k : keys)
    if (has(k)) present.push_back(k);
  if (present.size() != 1)
    where_.fail(fmt::format("{} needs exactly one of {}, found {}", what, fmt::join(quoted(keys), ", "),
                            present.empty() ? std::string("none") : fmt::format("{}", fmt::join(quoted(present), " and "))));
  return present.front();
}

void Obj::forbid(const std::string& k, const std::string& why) const {
  if (has(k)) where_.key(k).fail(why);
}

double Obj::number(const std::string& k) const { return as_number(j_.at(k), where_.key(k), unit_of(k)); }

double Obj::required_number(const std::string& k, const std::string& hint) const {
  if (!has(k)) where_.fail(fmt::format("missing \"{}\" ({})", k, hint));
  return number(k);
}

int Obj::integer(const std::string& k, int def) const {
  if (!has(k)) return def;
  const json& v = j_.at(k);
  if (!v.is_number_integer()) where_.key(k).fail("expected a whole number, got " + type_name(v));
  return v.get<int>();
}

bool Obj::boolean(const std::string& k, bool def) const {
  if (!has(k)) return def;
  const json& v = j_.at(k);
  if (!v.is_boolean()) where_.key(k).fail("expected true or false, got " + type_name(v));
  return v.get<bool>();
}

std::string Obj::string(const std::string& k, const std::string& def) const {
  if (!has(k)) return def;
  const json& v = j_.at(k);
  if (!v.is_string()) where_.key(k).fail("expected a string, got " + type_name(v));
  return v.get<std::string>();
}

Eigen::Vector3d Obj::vec3(const std::string& k) const { return as_vec3(j_.at(k), where_.key(k), unit_of(k)); }

double Obj::as_number(const json& v, const Where& w, const std::string& unit) {
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

Eigen::Vector3d Obj::as_vec3(const json& v, const Where& w, const std::string& unit) {
  if (!v.is_array() || v.size() != 3)
    w.fail(fmt::format("expected 3 numbers [x, y, z]{}, got {}{}", unit.empty() ? "" : " in " + unit, type_name(v),
                       v.is_array() ? fmt::format(" of {} values", v.size()) : ""));
  Eigen::Vector3d out;
  for (int c = 0; c < 3; ++c) out[c] = as_number(v[std::size_t(c)], w.index(std::size_t(c)), unit);
  return out;
}

void Obj::check_key(const std::string& k) const {
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
  const std::string best = nearest_word(k, allowed_);
  if (!best.empty()) w.fail(fmt::format("unknown key \"{}\"; did you mean \"{}\"?", k, best));
  w.fail(fmt::format("unknown key \"{}\"; allowed here: {}", k, fmt::join(quoted(allowed_), ", ")));
}

const json& array_at(const Obj& o, const std::string& k, std::size_t min_size, const std::string& what) {
  const json& v = o.at(k);
  if (!v.is_array()) o.at_where(k).fail("expected an array [ ... ] of " + what + ", got " + type_name(v));
  if (v.size() < min_size)
    o.at_where(k).fail(fmt::format("needs at least {} {} (got {})", min_size, what, v.size()));
  return v;
}

}  // namespace vx::strict_json
