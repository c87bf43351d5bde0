// Strict reading of scene JSON (scene/strict_json.h): every message names the file and the
// value's JSON path; an unknown key suggests the key meant (another unit, a typo, or the allowed
// keys); numbers are bare and finite, in the unit the key's suffix names.
#include "scene/strict_json.h"

#include <gtest/gtest.h>

#include <string>

#include "base/error.h"

using namespace vx;
using namespace vx::strict_json;

namespace {

/// The message of the vx::Error `f` throws ("" when it throws none).
template <class F>
std::string error_of(F f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

const Where kTop{"scene.json", "$"};

}  // namespace

TEST(StrictJson, ValuesAreReadWithTheirTypesAndDefaults) {
  const json j = json::parse(R"({"radius_mm": 2.5, "steps": 3, "on": true, "name": "tool", "at_mm": [1, 2, 3]})");
  const Obj o(j, kTop, {"radius_mm", "steps", "on", "name", "at_mm", "absent_s"});
  EXPECT_EQ(o.number("radius_mm"), 2.5);
  EXPECT_EQ(o.number("absent_s", 0.25), 0.25);
  EXPECT_EQ(o.integer("steps", 0), 3);
  EXPECT_TRUE(o.boolean("on", false));
  EXPECT_EQ(o.string("name", ""), "tool");
  EXPECT_EQ(o.vec3("at_mm"), Eigen::Vector3d(1, 2, 3));
  EXPECT_EQ(o.at_where("steps").path, "$.steps");
  EXPECT_EQ(kTop.key("probes").index(1).key("radius_mm").path, "$.probes[1].radius_mm");
}

TEST(StrictJson, AnUnknownKeySuggestsTheKeyMeant) {
  const json unit = json::parse(R"({"youngs_modulus_pa": 5000})");
  EXPECT_EQ(error_of([&] {
              Obj(unit, kTop.key("material"), {"youngs_modulus_kpa", "density_kg_m3"});
            }),
            "scene.json: $.material.youngs_modulus_pa: unknown key \"youngs_modulus_pa\": youngs_modulus is given "
            "in kPa as \"youngs_modulus_kpa\"");
  const json typo = json::parse(R"({"raduis_mm": 2})");
  const std::string t = error_of([&] { Obj(typo, kTop, {"radius_mm", "length_mm"}); });
  EXPECT_NE(t.find("did you mean \"radius_mm\"?"), std::string::npos) << t;
  const json far = json::parse(R"({"zzzzzzzz": 2})");
  const std::string f = error_of([&] { Obj(far, kTop, {"radius_mm", "length_mm"}); });
  EXPECT_NE(f.find("allowed here: \"radius_mm\", \"length_mm\""), std::string::npos) << f;
  EXPECT_EQ(error_of([&] { Obj(json::array(), kTop, {}); }), "scene.json: $: expected an object { ... }, got an array");
}

TEST(StrictJson, NumbersAreBareFiniteAndInTheKeysUnit) {
  const json j = json::parse(R"({"radius_mm": "5 mm", "speed_mm_s": null, "at_mm": [1, 2], "n": 2.5, "flag": 1})");
  const Obj o(j, kTop, {"radius_mm", "speed_mm_s", "at_mm", "n", "flag"});
  EXPECT_EQ(error_of([&] { (void)o.number("radius_mm"); }),
            "scene.json: $.radius_mm: expected a number in mm, got the string \"5 mm\"; write the bare number "
            "(units are fixed by the key)");
  EXPECT_EQ(error_of([&] { (void)o.number("speed_mm_s"); }),
            "scene.json: $.speed_mm_s: expected a number in mm/s, got null");
  EXPECT_EQ(error_of([&] { (void)o.vec3("at_mm"); }),
            "scene.json: $.at_mm: expected 3 numbers [x, y, z] in mm, got an array of 2 values");
  EXPECT_EQ(error_of([&] { (void)o.integer("n", 0); }), "scene.json: $.n: expected a whole number, got a number");
  EXPECT_EQ(error_of([&] { (void)o.boolean("flag", false); }),
            "scene.json: $.flag: expected true or false, got a number");
  EXPECT_EQ(error_of([&] { (void)o.required_number("missing_s", "the duration"); }),
            "scene.json: $: missing \"missing_s\" (the duration)");
}

TEST(StrictJson, ExactlyOneOfAndArraysOfAMinimumSize) {
  const json j = json::parse(R"({"path": [], "joystick": [1]})");
  const Obj o(j, kTop.key("probes").index(0), {"path", "joystick", "live"});
  const std::string both = error_of([&] { (void)o.one_of({"path", "joystick", "live"}, "a probe"); });
  EXPECT_NE(both.find("$.probes[0]: a probe needs exactly one of \"path\", \"joystick\", \"live\""), std::string::npos)
      << both;
  EXPECT_EQ(error_of([&] { (void)array_at(o, "path", 1, "keyframes"); }),
            "scene.json: $.probes[0].path: needs at least 1 keyframes (got 0)");
  EXPECT_EQ(array_at(o, "joystick", 1, "samples").size(), 1u);
  EXPECT_EQ(error_of([&] { o.forbid("joystick", "not with a path"); }),
            "scene.json: $.probes[0].joystick: not with a path");
  EXPECT_EQ(error_of([&] { require(false, kTop, "no"); }), "scene.json: $: no");
  EXPECT_EQ(error_of([&] { require(true, kTop, "no"); }), "");
}
