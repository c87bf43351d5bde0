// HU windows: parsing (numbers, ranges, presets) and the binary grid they give.
#include "convert/threshold.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "base/error.h"
#include "convert/phantom.h"
#include "util/text.h"

using vx::HuRange;
using vx::parse_threshold;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

void expect_range(const std::string& text, double lo, double hi) {
  const HuRange r = parse_threshold(text);
  EXPECT_EQ(r.lo, lo) << text;
  EXPECT_EQ(r.hi, hi) << text;
}

TEST(ParseThreshold, NumbersAndRanges) {
  expect_range("-200", -200, kInf);
  expect_range("  300.5 ", 300.5, kInf);
  expect_range("-100:300", -100, 300);
  expect_range("-950:-400", -950, -400);
  expect_range("1e2:2e3", 100, 2000);
  expect_range("-inf:-500", -kInf, -500);
  expect_range("0:inf", 0, kInf);
  expect_range("40:40", 40, 40);
}

TEST(ParseThreshold, Presets) {
  expect_range("soft-tissue", -100, 300);
  expect_range("bone", 300, 3000);
  expect_range("fat", -150, -30);
  expect_range("lung", -950, -400);
  expect_range("tissue", -200, kInf);
  expect_range("Bone", 300, 3000);  // case does not matter
  // the default HuRange is the 'tissue' preset
  EXPECT_EQ(HuRange{}.lo, -200);
  EXPECT_EQ(HuRange{}.hi, kInf);
}

TEST(ParseThreshold, BadTextListsPresets) {
  for (const std::string bad : {"", "abc", "300:100", "10:", ":20", "1:2:3", "nan", "inf", "10HU", "bone2"}) {
    try {
      (void)parse_threshold(bad);
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const vx::Error& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find("'" + bad + "'"), std::string::npos) << msg;
      for (const char* preset : {"soft-tissue", "bone", "fat", "lung", "tissue", "LO:HI"})
        EXPECT_NE(msg.find(preset), std::string::npos) << msg;
    }
  }
}

TEST(ParseThreshold, ATypoOfAPresetSuggestsIt) {
  const auto message = [](const std::string& text) {
    try {
      (void)parse_threshold(text);
    } catch (const vx::Error& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_NE(message("sofft-tissue").find("(did you mean 'soft-tissue'?)"), std::string::npos);
  EXPECT_NE(message("LUNGS").find("(did you mean 'lung'?)"), std::string::npos);
  EXPECT_NE(message("bone2").find("(did you mean 'bone'?)"), std::string::npos);
  // nothing near: no suggestion
  EXPECT_EQ(message("cartilage").find("did you mean"), std::string::npos);
  EXPECT_EQ(message("300:100").find("did you mean"), std::string::npos);
}

TEST(NearestWord, EditDistanceAndTheNearestKnownWord) {
  EXPECT_EQ(vx::edit_distance("kitten", "sitting"), 3u);
  EXPECT_EQ(vx::edit_distance("", "abc"), 3u);
  EXPECT_EQ(vx::edit_distance("convert", "convert"), 0u);
  const std::vector<std::string> known = {"phantom", "convert", "simulate", "verify", "verify-merge", "bench"};
  EXPECT_EQ(vx::nearest_word("conver", known), "convert");
  EXPECT_EQ(vx::nearest_word("CONVERT", known), "convert");  // case does not matter
  EXPECT_EQ(vx::nearest_word("verify-merg", known), "verify-merge");
  EXPECT_EQ(vx::nearest_word("verif", known), "verify");
  EXPECT_EQ(vx::nearest_word("palpate", known), "");  // 3 edits or more: no guess
  EXPECT_EQ(vx::nearest_word("bnch", known, 1), "");  // the limit is the caller's
}

TEST(Threshold, InclusiveBoundsAndGeometry) {
  vx::Volume v;
  v.geometry.dims = {4, 2, 1};
  v.geometry.spacing_mm = {0.5, 0.7, 2.0};
  v.geometry.origin_mm = {1, 2, 3};
  v.hu = {-1000.0f, -200.0f, -199.5f, 300.0f, 300.01f, std::nanf(""), 3000.0f, -200.01f};
  const vx::VoxelGrid g = vx::threshold(v, parse_threshold("-200:300"));
  EXPECT_EQ(g.geometry(), v.geometry);
  EXPECT_EQ(g.data(), (std::vector<std::uint8_t>{0, 1, 1, 1, 0, 0, 0, 0}));
  const vx::VoxelGrid t = vx::threshold(v, parse_threshold("tissue"));
  EXPECT_EQ(t.data(), (std::vector<std::uint8_t>{0, 1, 1, 1, 1, 0, 1, 0}));  // NaN is never tissue
}

TEST(Threshold, PhantomTissueAndLesion) {
  vx::PhantomSettings s;
  s.name = "block-lesion";
  s.size = 32;
  vx::PhantomShape shape;
  const vx::Volume v = vx::make_phantom(s, &shape);
  EXPECT_EQ(vx::threshold(v, parse_threshold("tissue")).count(), shape.tissue_voxels);
  EXPECT_EQ(vx::threshold(v, parse_threshold("100")).count(), shape.lesion_voxels);  // lesion 120 HU, tissue 40
  EXPECT_EQ(vx::threshold(v, parse_threshold("bone")).count(), 0);
  EXPECT_EQ(vx::threshold(v, parse_threshold("lung")).count(), 0);
}

TEST(Threshold, BadVolumeIsRefused) {
  vx::Volume v;
  EXPECT_THROW((void)vx::threshold(v, HuRange{}), vx::Error);
  v.geometry.dims = {2, 2, 2};
  v.hu.assign(7, 0.0f);
  EXPECT_THROW((void)vx::threshold(v, HuRange{}), vx::Error);
  v.hu.assign(8, 0.0f);
  EXPECT_THROW((void)vx::threshold(v, HuRange{10, -10}), vx::Error);
}

}  // namespace
