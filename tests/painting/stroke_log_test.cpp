#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"

namespace deepcanvas {
namespace {

using server_core::read_stroke_log;

std::vector<protocol::Stroke> random_strokes(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<protocol::Stroke> out;
  for (int i = 0; i < n; ++i) {
    protocol::Stroke s;
    s.id = rng();
    s.brush.mode = static_cast<protocol::BrushMode>(rng() % protocol::kBrushModeCount);
    for (float& c : s.brush.colour) c = static_cast<float>(0.5 + 0.5 * u(rng));
    s.brush.opacity = 0.75f;
    s.brush.hardness = 0.25f;
    const int m = static_cast<int>(rng() % 5);
    for (int k = 0; k < m; ++k) {
      protocol::StrokeSample p;
      p.x = u(rng) * 1e3, p.y = u(rng), p.z = u(rng) * 1e-3;
      p.radius = 0.01f;
      p.pressure = 0.5f;
      p.t_ms = rng();
      s.samples.push_back(p);
    }
    out.push_back(s);
  }
  return out;
}

std::vector<std::uint8_t> encode(const std::vector<protocol::Stroke>& strokes) {
  auto b = server_core::stroke_log_header();
  for (const auto& s : strokes) {
    const auto r = server_core::encode_stroke_record(s);
    b.insert(b.end(), r.begin(), r.end());
  }
  return b;
}

void expect_same(const protocol::Stroke& a, const protocol::Stroke& b) {
  EXPECT_EQ(a.id, b.id);
  EXPECT_EQ(a.brush.mode, b.brush.mode);
  for (int i = 0; i < 4; ++i) EXPECT_EQ(a.brush.colour[i], b.brush.colour[i]);
  EXPECT_EQ(a.brush.opacity, b.brush.opacity);
  EXPECT_EQ(a.brush.hardness, b.brush.hardness);
  ASSERT_EQ(a.samples.size(), b.samples.size());
  for (std::size_t i = 0; i < a.samples.size(); ++i) {
    EXPECT_EQ(a.samples[i].x, b.samples[i].x);
    EXPECT_EQ(a.samples[i].y, b.samples[i].y);
    EXPECT_EQ(a.samples[i].z, b.samples[i].z);
    EXPECT_EQ(a.samples[i].radius, b.samples[i].radius);
    EXPECT_EQ(a.samples[i].pressure, b.samples[i].pressure);
    EXPECT_EQ(a.samples[i].t_ms, b.samples[i].t_ms);
  }
}

TEST(StrokeLog, RoundTrip) {
  const auto strokes = random_strokes(20, 1);
  const auto bytes = encode(strokes);
  auto r = read_stroke_log(bytes);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_FALSE(r->tail);
  EXPECT_EQ(r->valid_bytes, bytes.size());
  ASSERT_EQ(r->strokes.size(), strokes.size());
  for (std::size_t i = 0; i < strokes.size(); ++i) expect_same(strokes[i], r->strokes[i]);
}

TEST(StrokeLog, EveryTruncatedPrefixRecoversTheRecordsBeforeIt) {
  const auto strokes = random_strokes(6, 2);
  const auto bytes = encode(strokes);
  std::vector<std::size_t> ends{server_core::kStrokeLogHeaderBytes};
  for (const auto& s : strokes)
    ends.push_back(ends.back() + server_core::encode_stroke_record(s).size());
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    auto r = read_stroke_log(std::span(bytes.data(), n));
    if (n < server_core::kStrokeLogHeaderBytes) {
      ASSERT_FALSE(r) << n;
      EXPECT_EQ(r.error().code, Errc::malformed);
      continue;
    }
    ASSERT_TRUE(r) << n;
    // Complete records before n are all recovered; a partial record is reported as the tail.
    std::size_t complete = 0;
    while (complete + 1 < ends.size() && ends[complete + 1] <= n) ++complete;
    EXPECT_EQ(r->strokes.size(), complete) << n;
    EXPECT_EQ(r->valid_bytes, ends[complete]) << n;
    if (n == ends[complete]) {
      EXPECT_FALSE(r->tail) << n;
    } else {
      ASSERT_TRUE(r->tail) << n;
      EXPECT_EQ(r->tail->offset, ends[complete]);
      EXPECT_NE(r->tail->reason.find("torn"), std::string::npos) << r->tail->reason;
    }
  }
}

TEST(StrokeLog, EveryCorruptedByteIsDetected) {
  const auto strokes = random_strokes(3, 3);
  const auto bytes = encode(strokes);
  const std::size_t first_end =
      server_core::kStrokeLogHeaderBytes + server_core::encode_stroke_record(strokes[0]).size();
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    for (std::uint8_t flip : {std::uint8_t{0x01}, std::uint8_t{0x80}}) {
      auto b = bytes;
      b[i] ^= flip;
      auto r = read_stroke_log(b);
      if (i < 12) {  // magic or version
        EXPECT_FALSE(r) << i;
        continue;
      }
      if (i < server_core::kStrokeLogHeaderBytes) continue;  // reserved header word
      ASSERT_TRUE(r) << i;
      ASSERT_TRUE(r->tail) << "corruption at byte " << i << " went unnoticed";
      EXPECT_LT(r->strokes.size(), strokes.size());
      if (i >= first_end) {
        EXPECT_GE(r->strokes.size(), 1u);
      }
    }
  }
}

TEST(StrokeLog, WriterAppendsAndRecoversATornTail) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("dc_stroke_log_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "log.dcs").string();
  const auto strokes = random_strokes(5, 4);
  {
    auto w =
        server_core::StrokeLogWriter::open(path, false, server_core::FsyncPolicy::every_record);
    ASSERT_TRUE(w) << w.error().message;
    for (int i = 0; i < 3; ++i) ASSERT_TRUE(w->append(strokes[static_cast<std::size_t>(i)]));
  }
  // Simulate a crash mid-append: half a record at the end.
  {
    const auto rec = server_core::encode_stroke_record(strokes[3]);
    std::ofstream f(path, std::ios::binary | std::ios::app);
    f.write(reinterpret_cast<const char*>(rec.data()),
            static_cast<std::streamsize>(rec.size() / 2));
  }
  auto torn = server_core::read_stroke_log_file(path);
  ASSERT_TRUE(torn);
  EXPECT_EQ(torn->strokes.size(), 3u);
  ASSERT_TRUE(torn->tail);
  {
    auto w = server_core::StrokeLogWriter::open(path, true, server_core::FsyncPolicy::on_flush);
    ASSERT_TRUE(w) << w.error().message;
    EXPECT_TRUE(w->recovered_tail());
    ASSERT_TRUE(w->append(strokes[4]));
    ASSERT_TRUE(w->close());
  }
  auto r = server_core::read_stroke_log_file(path);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_FALSE(r->tail);
  ASSERT_EQ(r->strokes.size(), 4u);
  expect_same(r->strokes[3], strokes[4]);
  EXPECT_FALSE(server_core::read_stroke_log_file((dir / "missing").string()));
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace deepcanvas
