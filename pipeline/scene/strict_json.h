#pragma once
/// @file strict_json.h
/// Private to pipeline/scene: strict reading of JSON for scene files. Every message names the
/// file and the value's JSON path ("scene.json: $.probes[1].radius_mm: must be > 0 mm"); an
/// unknown key is an error that suggests the key meant (a typo, or the same quantity in another
/// unit: "youngs_modulus_pa" -> "youngs_modulus_kpa"). Units are fixed by the key's suffix
/// (_mm, _s, _kpa, _kg_m3, ...), so numbers are bare.

#include <Eigen/Core>
#include <cstddef>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace vx::strict_json {

using json = nlohmann::json;

/// A value's type for messages: "a number", "the string \"x\"", "an array", ...
[[nodiscard]] std::string type_name(const json& j);

/// Where a value is: the file (or name) and the JSON path.
struct Where {
  std::string file;
  std::string path;  ///< "$", "$.probes[0]", ...
  [[nodiscard]] Where key(const std::string& k) const { return {file, path + "." + k}; }
  [[nodiscard]] Where index(std::size_t i) const { return {file, path + "[" + std::to_string(i) + "]"}; }
  /// Throws vx::Error "file: path: what".
  [[noreturn]] void fail(const std::string& what) const;
};

/// Throws vx::Error at `w` unless `ok`.
void require(bool ok, const Where& w, const std::string& what);

/// A JSON object whose keys are checked against the allowed ones when it is made. Its
/// accessors read a key with its type checked (numbers finite, in the key's unit).
class Obj {
 public:
  /// Throws vx::Error unless `j` is an object holding only keys of `allowed`.
  Obj(const json& j, Where where, std::vector<std::string> allowed);

  [[nodiscard]] const Where& where() const { return where_; }
  [[nodiscard]] bool has(const std::string& k) const { return j_.contains(k); }
  [[nodiscard]] const json& at(const std::string& k) const { return j_.at(k); }
  [[nodiscard]] Where at_where(const std::string& k) const { return where_.key(k); }
  /// Fails unless exactly one of `keys` is present; returns it.
  [[nodiscard]] std::string one_of(const std::vector<std::string>& keys, const std::string& what) const;
  /// Fails when `k` is present, saying `why`.
  void forbid(const std::string& k, const std::string& why) const;

  [[nodiscard]] double number(const std::string& k) const;
  [[nodiscard]] double number(const std::string& k, double def) const { return has(k) ? number(k) : def; }
  /// Fails when `k` is missing; `hint` says what it is.
  [[nodiscard]] double required_number(const std::string& k, const std::string& hint) const;
  [[nodiscard]] int integer(const std::string& k, int def) const;
  [[nodiscard]] bool boolean(const std::string& k, bool def) const;
  [[nodiscard]] std::string string(const std::string& k, const std::string& def) const;
  /// Three numbers [x, y, z].
  [[nodiscard]] Eigen::Vector3d vec3(const std::string& k) const;
  [[nodiscard]] Eigen::Vector3d vec3(const std::string& k, const Eigen::Vector3d& def) const {
    return has(k) ? vec3(k) : def;
  }

  /// `v` as a finite number in `unit` (for messages; "" for none).
  static double as_number(const json& v, const Where& w, const std::string& unit);
  /// `v` as three numbers [x, y, z] in `unit`.
  static Eigen::Vector3d as_vec3(const json& v, const Where& w, const std::string& unit);

 private:
  void check_key(const std::string& k) const;

  const json& j_;
  Where where_;
  std::vector<std::string> allowed_;
};

/// The array at key `k` of `o` (of at least `min_size` elements of `what`).
[[nodiscard]] const json& array_at(const Obj& o, const std::string& k, std::size_t min_size, const std::string& what);

}  // namespace vx::strict_json
