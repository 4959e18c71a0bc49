#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <map>

#include "deepcanvas/paintings/apa.hpp"
#include "test_support.hpp"

namespace deepcanvas {
namespace {

using paintings::ApaTransform;
using paintings::parse_apa;

struct Builder {
  std::vector<std::uint8_t> b;
  void u8(unsigned v) { b.push_back(static_cast<std::uint8_t>(v)); }
  void u16(unsigned v) { u8(v & 0xFF), u8(v >> 8); }
  void u32(std::uint32_t v) {
    for (int i = 0; i < 4; ++i) u8((v >> (8 * i)) & 0xFF);
  }
  void f32(float v) { u32(std::bit_cast<std::uint32_t>(v)); }
  void str(const std::string& s) {
    u8(static_cast<unsigned>(s.size()));
    for (char c : s) u8(static_cast<unsigned char>(c));
  }
};

// Two brushes, two strokes (3 points, 1 point).
std::vector<std::uint8_t> small_painting() {
  Builder w;
  w.str("apainter");
  w.u16(1);
  w.u8(2);
  w.str("flat");
  w.str("stamp_leaf1");
  w.u32(2);
  const float pts[3][3] = {{0.1f, 1.2f, -0.3f}, {0.2f, 1.25f, -0.3f}, {0.3f, 1.3f, -0.2f}};
  w.u8(1);
  w.f32(1.0f), w.f32(0.5f), w.f32(0.25f);
  w.f32(0.02f);
  w.u32(3);
  for (int p = 0; p < 3; ++p) {
    for (float v : pts[p]) w.f32(v);
    w.f32(0), w.f32(0), w.f32(0), w.f32(1);
    w.f32(0.5f + 0.25f * p);
    w.u32(1000 + 16 * p);
  }
  w.u8(0);
  w.f32(0.0f), w.f32(1.0f), w.f32(0.0f);
  w.f32(0.1f);
  w.u32(1);
  w.f32(0), w.f32(0), w.f32(0);
  w.f32(0), w.f32(0), w.f32(0), w.f32(1);
  w.f32(0.0f);  // a zero pressure: raised to kApaMinPressure
  w.u32(5000);
  return w.b;
}

TEST(Apa, ParsesAndTransforms) {
  const auto bytes = small_painting();
  ApaTransform tf;
  tf.scale = 1000;
  tf.offset[0] = 5, tf.offset[1] = -7, tf.offset[2] = 11;
  auto r = parse_apa(bytes, tf);
  ASSERT_TRUE(r) << r.error().message;
  ASSERT_EQ(r->brush_names.size(), 2u);
  EXPECT_EQ(r->brush_names[1], "stamp_leaf1");
  ASSERT_EQ(r->strokes.size(), 2u);
  EXPECT_EQ(r->sample_count, 4u);
  EXPECT_EQ(r->stroke_brush[0], 1);
  const auto& s0 = r->strokes[0];
  EXPECT_EQ(s0.brush.mode, protocol::BrushMode::paint);
  EXPECT_FLOAT_EQ(s0.brush.colour[1], 0.5f);
  EXPECT_FLOAT_EQ(s0.brush.colour[3], 1.0f);
  EXPECT_FLOAT_EQ(s0.brush.opacity, 1.0f);
  ASSERT_EQ(s0.samples.size(), 3u);
  EXPECT_NEAR(s0.samples[1].x, 0.2f * 1000.0 + 5, 1e-9);
  EXPECT_NEAR(s0.samples[1].y, 1.25f * 1000.0 - 7, 1e-9);
  EXPECT_NEAR(s0.samples[1].z, -0.3f * 1000.0 + 11, 1e-9);
  EXPECT_NEAR(s0.samples[1].radius, 0.01 * 1000.0, 1e-3);
  EXPECT_FLOAT_EQ(s0.samples[2].pressure, 1.0f);
  EXPECT_EQ(s0.samples[2].t_ms, 1032u);
  EXPECT_FLOAT_EQ(r->strokes[1].samples[0].pressure, paintings::kApaMinPressure);
  // Every parsed stroke is a valid stroke for the canvas (scaled by 1000, its extent is past
  // the default max_extent_m: that limit is the canvas's choice, not the reader's).
  for (const auto& s : r->strokes)
    EXPECT_TRUE(protocol::ValidatedStroke::make(s, {{}, {100000, 1000.0, 1e-7, 1e9}}));
}

void expect_rejected(const std::vector<std::uint8_t>& bytes, const std::string& what) {
  auto r = parse_apa(bytes, {});
  ASSERT_FALSE(r) << what;
  EXPECT_NE(r.error().message.find("offset "), std::string::npos) << r.error().message;
}

TEST(Apa, EveryTruncatedPrefixIsRejected) {
  const auto bytes = small_painting();
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    std::vector<std::uint8_t> p(bytes.begin(), bytes.begin() + static_cast<long>(n));
    auto r = parse_apa(p, {});
    ASSERT_FALSE(r) << "prefix " << n;
    EXPECT_EQ(r.error().code, Errc::malformed);
    EXPECT_NE(r.error().message.find("truncated"), std::string::npos) << r.error().message;
    EXPECT_NE(r.error().message.find("offset "), std::string::npos) << r.error().message;
  }
}

TEST(Apa, MalformedFilesNameOffsetAndProblem) {
  const auto good = small_painting();
  {
    auto b = good;
    b.push_back(0);
    auto r = parse_apa(b, {});
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("offset " + std::to_string(good.size())), std::string::npos);
    EXPECT_NE(r.error().message.find("trailing"), std::string::npos);
  }
  {
    auto b = good;
    b[1] = 'X';
    expect_rejected(b, "bad magic");
  }
  {
    auto b = good;
    b[9] = 2;  // version 2
    auto r = parse_apa(b, {});
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, Errc::unsupported);
    EXPECT_NE(r.error().message.find("offset 9"), std::string::npos) << r.error().message;
  }
  // Stroke 0 starts after magic(9) + version(2) + count(1) + "flat"(5) + "stamp_leaf1"(12) +
  // stroke count(4) = 33.
  {
    auto b = good;
    b[33] = 2;
    auto r = parse_apa(b, {});
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("offset 33"), std::string::npos) << r.error().message;
    EXPECT_NE(r.error().message.find("brush index 2 out of range"), std::string::npos);
  }
  {
    auto b = good;
    const float nan = std::nanf("");
    std::memcpy(&b[33 + 1 + 16 + 4], &nan, 4);  // first point's x
    auto r = parse_apa(b, {});
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("offset 54"), std::string::npos) << r.error().message;
    EXPECT_NE(r.error().message.find("not a finite number"), std::string::npos);
  }
  {
    auto b = good;
    b[29] = 0xFF;  // stroke count far beyond the file
    expect_rejected(b, "huge stroke count");
  }
  EXPECT_FALSE(parse_apa(good, ApaTransform{std::nan(""), {0, 0, 0}}));
}

TEST(Apa, RealPaintingsMatchTheReadmeTable) {
  DEEPCANVAS_PAINTINGS_OR_SKIP(dir);
  const std::map<std::string, std::pair<std::size_t, std::size_t>> table = {
      {"ET_logos.apa", {82, 5424}},
      {"allhands.apa", {196, 14847}},
      {"dancer.apa", {101, 6298}},
      {"demo.apa", {28, 1771}},
      {"demon.apa", {195, 14188}},
      {"it_follows.apa", {288, 31317}},
      {"logo_fire.apa", {100, 5433}},
      {"mozdino.apa", {72, 13895}},
      {"mozfest.apa", {43, 2091}},
      {"mozilla.apa", {11, 768}},
      {"palmtree.apa", {55, 2820}},
      {"rose_bush.apa", {229, 4837}},
      {"the_gentle_robot.apa", {192, 10394}},
      {"the_leap.apa", {206, 8808}},
      {"volcano.apa", {77, 9125}},
      {"winner.apa", {78, 3586}},
      {"you_shall_not_pass.apa", {452, 15518}}};
  for (const auto& [name, counts] : table) {
    auto r = paintings::read_apa_file(dir + "/" + name, {});
    ASSERT_TRUE(r) << r.error().message;
    EXPECT_EQ(r->strokes.size(), counts.first) << name;
    EXPECT_EQ(r->sample_count, counts.second) << name;
  }
}

TEST(Apa, EveryTruncatedPrefixOfARealPaintingIsRejected) {
  DEEPCANVAS_PAINTINGS_OR_SKIP(dir);
  auto bytes = paintings::read_file_bytes(dir + "/mozilla.apa");
  ASSERT_TRUE(bytes) << bytes.error().message;
  ASSERT_TRUE(parse_apa(*bytes, {}));
  for (std::size_t n = 0; n < bytes->size(); ++n) {
    auto r = parse_apa(std::span(bytes->data(), n), {});
    ASSERT_FALSE(r) << "prefix " << n;
  }
}

}  // namespace
}  // namespace deepcanvas
