// The stroke rules and the validated stroke types (stroke.hpp): each rule refuses with the
// offending field named; validated parts (brush, samples) keep what they were made from.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <utility>

#include "deepcanvas/protocol/stroke.hpp"

namespace dp = deepcanvas::protocol;
using deepcanvas::Errc;

namespace {
dp::Stroke good_stroke() {
  dp::Stroke s;
  s.brush.colour[0] = 0.5f;
  s.samples = {{0, 0, 0, 0.1f, 1.0f, 0}, {1, 0, 0, 0.1f, 0.5f, 10}};
  return s;
}

// The error of making `s` a ValidatedStroke (ok when it passes).
std::pair<Errc, std::string> refusal(const dp::Stroke& s, const dp::StrokeRules& rules = {}) {
  auto v = dp::ValidatedStroke::make(s, rules);
  if (v) return {Errc::ok, ""};
  return {v.error().code, v.error().message};
}
}  // namespace

TEST(StrokeRules, EachRuleRefusesWithTheFieldNamed) {
  EXPECT_EQ(refusal(good_stroke()).first, Errc::ok);
  const auto expect = [](const dp::Stroke& s, Errc code, const std::string& field,
                         const dp::StrokeRules& rules = {}) {
    const auto [c, message] = refusal(s, rules);
    EXPECT_EQ(c, code) << field << ": " << message;
    EXPECT_NE(message.find(field), std::string::npos) << message;
  };
  auto s = good_stroke();
  s.brush.mode = static_cast<dp::BrushMode>(9);
  expect(s, Errc::invalid_argument, "brush.mode");
  s = good_stroke();
  s.brush.colour[2] = 1.01f;
  expect(s, Errc::invalid_argument, "brush.colour[2]");
  s = good_stroke();
  s.brush.opacity = std::nanf("");
  expect(s, Errc::invalid_argument, "brush.opacity");
  s = good_stroke();
  s.brush.hardness = -0.1f;
  expect(s, Errc::invalid_argument, "brush.hardness");
  s = good_stroke();
  s.samples.clear();
  expect(s, Errc::invalid_argument, "samples");
  s = good_stroke();
  s.samples[1].y = std::numeric_limits<double>::infinity();
  expect(s, Errc::invalid_argument, "samples[1].position");
  s = good_stroke();
  s.samples[1].z = -10000.001;  // outside the default 20 km canvas
  expect(s, Errc::invalid_argument, "samples[1].position");
  s = good_stroke();
  s.samples[0].radius = 1e-6f;
  expect(s, Errc::invalid_argument, "samples[0].radius");
  s = good_stroke();
  s.samples[0].pressure = 0.0f;
  expect(s, Errc::invalid_argument, "samples[0].pressure");
  // The rules come from StrokeRules: bounds, count and radius limits.
  dp::StrokeRules small;
  small.bounds.edge_m = 2.0;
  small.limits = {1, 0.05, 0.01};
  s = good_stroke();
  expect(s, Errc::limit_exceeded, "samples", small);
  s.samples.resize(1);
  expect(s, Errc::invalid_argument, "samples[0].radius", small);
  s.samples[0].radius = 0.04f;
  EXPECT_EQ(refusal(s, small).first, Errc::ok);
  s.samples[0].x = 1.0;  // on the boundary
  EXPECT_EQ(refusal(s, small).first, Errc::ok);
  s.samples[0].x = 1.001;
  expect(s, Errc::invalid_argument, "samples[0].position", small);
}

TEST(StrokeRules, ValidatedPartsKeepTheirSamples) {
  const auto s = good_stroke();
  auto whole = dp::ValidatedStroke::make(s, {});
  ASSERT_TRUE(whole.ok());
  EXPECT_EQ(whole->to_stroke().samples.size(), 2u);
  EXPECT_EQ(whole->brush().get().colour[0], 0.5f);
  auto samples = dp::ValidatedSamples::make(s.samples, {});
  ASSERT_TRUE(samples.ok());
  auto empty = dp::ValidatedSamples::make({}, {});  // a stroke_begin may carry none
  ASSERT_TRUE(empty.ok());
  EXPECT_TRUE(empty->empty());
  const auto tail = samples->slice(1, 5);  // clamped to what there is
  ASSERT_EQ(tail.size(), 1u);
  EXPECT_EQ(tail[0].t_ms, 10u);
  dp::ValidatedSamples joined = *samples;
  joined.append(tail);
  EXPECT_EQ(joined.size(), 3u);
  auto brush = dp::ValidatedBrush::make(s.brush);
  ASSERT_TRUE(brush.ok());
  EXPECT_FALSE(dp::ValidatedStroke::make(*brush, *empty).ok());  // a whole stroke needs a sample
  auto from_parts = dp::ValidatedStroke::make(*brush, joined);
  ASSERT_TRUE(from_parts.ok());
  EXPECT_EQ(from_parts->samples().size(), 3u);
  // validate_stroke applies the same rules.
  EXPECT_TRUE(dp::validate_stroke(s, {}, {}).ok());
  auto bad = s;
  bad.samples[0].pressure = 2.0f;
  EXPECT_EQ(dp::validate_stroke(bad, {}, {}).error().code, Errc::invalid_argument);
}
