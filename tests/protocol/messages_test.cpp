// Control messages: property round trips over random contents, every truncated prefix and
// corrupted byte rejected without a crash, missing and mistyped fields named, limits, versions.
#include <gtest/gtest.h>

#include <array>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "deepcanvas/protocol/messages.hpp"
#include "presence_gen.hpp"

namespace dp = deepcanvas::protocol;
using deepcanvas::Errc;
using nlohmann::json;

namespace {

class Gen {
 public:
  explicit Gen(std::uint64_t seed) : rng_(seed) {}

  std::uint64_t u64(std::uint64_t max = dp::kMaxJsonInteger) {
    // Mix small values, the maximum and anything in between.
    switch (rng_() % 4) {
      case 0:
        return std::min<std::uint64_t>(rng_() % 10, max);
      case 1:
        return max;
      default:
        return std::uniform_int_distribution<std::uint64_t>(0, max)(rng_);
    }
  }
  double real(double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng_); }
  float unit() {
    switch (rng_() % 5) {
      case 0:
        return 0.0f;
      case 1:
        return 1.0f;
      default:
        return static_cast<float>(real(0, 1));
    }
  }
  // 1..max_len bytes of whole UTF-8 characters from `alphabet`.
  std::string text(std::size_t max_len, std::string_view alphabet) {
    std::vector<std::string_view> chars;
    for (std::size_t i = 0; i < alphabet.size();) {
      const auto lead = static_cast<unsigned char>(alphabet[i]);
      const std::size_t n = lead < 0x80 ? 1 : lead < 0xE0 ? 2 : lead < 0xF0 ? 3 : 4;
      chars.push_back(alphabet.substr(i, n));
      i += n;
    }
    const std::size_t want = 1 + rng_() % max_len;
    std::string s;
    while (true) {
      const auto c = chars[rng_() % chars.size()];
      if (s.size() + c.size() > want) break;
      s += c;
    }
    return s.empty() ? std::string(chars[0].substr(0, 1)) : s;
  }
  std::string canvas() { return text(64, "abcdefghijklmnopqrstuvwxyzABCZ0123456789._-"); }
  std::string token() {
    std::string s(1 + rng_() % 256, ' ');
    for (auto& c : s) c = static_cast<char>(0x21 + rng_() % (0x7F - 0x21));
    return s;
  }
  dp::Role role() { return rng_() % 2 ? dp::Role::painter : dp::Role::viewer; }

  dp::Brush brush() {
    dp::Brush b;
    b.mode = static_cast<dp::BrushMode>(rng_() % dp::kBrushModeCount);
    for (auto& c : b.colour) c = unit();
    b.opacity = unit();
    b.hardness = unit();
    return b;
  }
  std::vector<dp::StrokeSample> samples(std::size_t min, std::size_t max) {
    std::vector<dp::StrokeSample> v(min + rng_() % (max - min + 1));
    for (auto& s : v) {
      s.x = real(-10000, 10000);
      s.y = rng_() % 7 == 0 ? 10000.0 : real(-10000, 10000);  // on the boundary too
      s.z = real(-1e-3, 1e-3);
      s.radius = static_cast<float>(real(2e-5, 1000));
      s.pressure = rng_() % 3 ? static_cast<float>(real(1e-6, 1)) : 1.0f;
      s.t_ms = static_cast<std::uint32_t>(u64(0xFFFFFFFFu));
    }
    return v;
  }

  dp::Message message(std::size_t kind) {
    switch (kind) {
      case 0: {
        dp::Hello m;
        m.role = role();
        m.token = token();
        m.canvas = canvas();
        m.client_name = rng_() % 3 ? text(128, "aé \"\\\n\t{}[]") : std::string();
        m.delta_frames = rng_() % 2;
        m.frame_bundles = rng_() % 2;
        m.block_frames = rng_() % 2;
        if (rng_() % 2) m.client_id = text(64, "azAZ09_-");
        if (rng_() % 2) m.batch_interval_ms = static_cast<std::uint32_t>(rng_() % (dp::kMaxBatchIntervalMs + 1));
        if (rng_() % 2) {
          dp::JoinCamera c;
          for (auto& v : c.eye) v = real(-1e12, 1e12);
          for (auto& v : c.target) v = real(-1e4, 1e4);
          m.camera = c;
        }
        return m;
      }
      case 1: {
        dp::Welcome m;
        m.role = role();
        m.canvas = canvas();
        m.geometry = {static_cast<std::uint32_t>(2 * (1 + rng_() % 32)), real(1e-3, 1e9),
                      static_cast<int>(1 + rng_() % 24)};
        m.block_cells = 64u << (rng_() % 15);
        m.texture_width = 1u << (rng_() % 17);
        m.epoch = u64();
        m.pool_layout = {text(64, "abc-_.0"), static_cast<std::uint32_t>(u64(0xFFFFFFFFu))};
        m.limits = {u64(),
                    static_cast<std::uint32_t>(u64(0xFFFFFFFFu)),
                    static_cast<std::uint32_t>(u64(0xFFFFFFFFu)),
                    static_cast<std::uint32_t>(u64(0xFFFFFFFFu)),
                    real(0, 1),
                    real(1, 1e6),
                    static_cast<std::uint32_t>(u64(0xFFFFFFFFu)),
                    real(0, 1e6),
                    u64(),
                    static_cast<std::uint32_t>(u64(0xFFFFFFFFu)),
                    u64()};
        return m;
      }
      case 2: {
        dp::StrokeMessage m;
        m.handle = u64();
        m.stroke.brush = brush();
        m.stroke.samples = samples(1, 40);
        return m;
      }
      case 3:
        return dp::StrokeBegin{u64(), brush(), samples(0, 5)};
      case 4:
        return dp::StrokeSamples{u64(), samples(1, 40)};
      case 5:
        return dp::StrokeEnd{u64()};
      case 6:
        return dp::Ack{u64(), u64(), u64()};
      case 7: {
        dp::PickUp m;
        m.request_id = u64();
        for (auto& p : m.position) p = real(-10000, 10000);
        return m;
      }
      case 8: {
        dp::PickUpReply m;
        m.request_id = u64();
        for (auto& c : m.colour) c = static_cast<float>((rng_() % 256) / 255.0);
        m.density = unit();
        m.depth = static_cast<int>(rng_() % 25);
        return m;
      }
      case 9: {
        dp::ErrorMessage m;
        m.code = static_cast<Errc>(rng_() % 11);
        m.message = text(200, "xyz é\"\n");
        if (rng_() % 2) m.in_reply_to = text(20, "abc_");
        if (rng_() % 2) m.handle = u64();
        m.fatal = rng_() % 2;
        return m;
      }
      case 10:
        return dp::StatsRequest{};
      case 11:
        return dp::Stats{u64(), u64(), u64(), u64(), u64(), u64(), u64()};
      case 12:
        return dp::EpochEnd{u64(), static_cast<std::uint32_t>(u64(0xFFFFFFFFu)), rng_() % 2 == 0};
      case 13:
        return deepcanvas::test::random_presence(rng_);
      case 18:
        return dp::Undo{u64()};
      case 19:
        return dp::Redo{u64()};
      case 20:
        return dp::UndoReply{u64(), u64(), u64(), rng_() % 2 == 0};
      case 21: {
        dp::Import m;
        m.request_id = u64();
        const char* formats[] = {"vdb", "gltf", "glb", "ply"};
        m.format = formats[rng_() % 4];
        for (auto& p : m.at) p = real(-10000, 10000);
        m.scale = real(1e-6, 1e6);
        m.voxel_size_m = rng_() % 2 ? 0.0 : real(1e-6, 10);
        for (auto& c : m.colour) c = static_cast<float>((rng_() % 256) / 255.0);
        m.density_scale = real(1e-3, 1e3);
        m.data.resize(1 + rng_() % 300);  // every length mod 3: the base64 padding cases
        for (auto& b : m.data) b = static_cast<std::uint8_t>(rng_());
        return m;
      }
      case 22:
        return dp::ImportReply{u64(), u64(), u64(), u64()};
      case 23: {
        dp::ExportRequest m;
        m.request_id = u64();
        const char* formats[] = {"vdb", "gltf", "glb", "ply"};
        m.format = formats[rng_() % 4];
        m.voxel_size_m = rng_() % 2 ? 0.0 : real(1e-6, 10);
        m.max_bytes = u64();
        if (rng_() % 2) m.box = std::array<double, 6>{-1, -2, -3, 1, 2, 3};
        return m;
      }
      case 24: {
        dp::ExportReply m;
        m.request_id = u64();
        m.format = "glb";
        m.data.resize(rng_() % 100);
        for (auto& b : m.data) b = static_cast<std::uint8_t>(rng_());
        return m;
      }
      case 25: {
        dp::PlaybackStep m;
        m.request_id = u64();
        if (rng_() % 2)
          m.strokes = u64();
        else
          m.seconds = rng_() % 2 ? 0.0 : real(1e-3, 1e6);
        return m;
      }
      case 26: {
        dp::PlaybackPosition m;
        m.request_id = u64();
        m.epoch = u64();
        m.events_total = u64();
        m.events = m.events_total / 2;
        m.strokes_total = u64() % 100000;
        m.strokes = m.strokes_total / 3;
        m.painting_seconds_total = real(0, 1e6);
        m.painting_seconds = m.painting_seconds_total / 2;
        m.timed = rng_() % 2;
        if (rng_() % 2) m.bounds = std::array<double, 6>{-1, -2, -3, 1, 2, 3};
        return m;
      }
      default:
        return deepcanvas::test::random_presence_update(rng_);
    }
  }

  std::mt19937_64& rng() { return rng_; }

 private:
  std::mt19937_64 rng_;
};

// The plain message kinds a sender builds (every alternative of Message but the three Decoded*
// ones, 15 to 17). The decoder returns the stroke kinds in their validated form (DecodedStroke,
// ...), the others as they are.
constexpr std::size_t kDecodedFirst = 15;
constexpr std::array<std::size_t, std::variant_size_v<dp::Message> - 3> kPlainKinds = {
    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 18, 19, 20, 21, 22, 23, 24, 25, 26};
static_assert(std::variant_size_v<dp::Message> == 27, "a new message kind: add it to the lists");
std::size_t decoded_kind(std::size_t kind) {
  const dp::Message plain[3] = {dp::StrokeMessage{}, dp::StrokeBegin{}, dp::StrokeSamples{}};
  for (std::size_t i = 0; i < 3; ++i)
    if (plain[i].index() == kind) return kDecodedFirst + i;
  return kind;
}

}  // namespace

// The generator's strokes span the whole canvas: these tests are about the JSON, not about
// StrokeLimits::max_extent_m (stroke_rules_test.cpp tests StrokeRules).
dp::DecodeOptions any_extent() {
  dp::DecodeOptions o;
  o.stroke_limits.max_extent_m = std::numeric_limits<double>::infinity();
  return o;
}

TEST(Messages, RoundTripEveryTypeWithRandomContents) {
  Gen g(1);
  for (int iter = 0; iter < 300; ++iter) {
    for (std::size_t kind : kPlainKinds) {
      const dp::Message m = g.message(kind);
      const std::string text = dp::encode_message(m);
      auto d = dp::decode_message(text, any_extent());
      ASSERT_TRUE(d.ok()) << text << "\n-> " << d.error().message;
      ASSERT_EQ(d->index(), decoded_kind(kind));
      // The encoder writes every field, so re-encoding equal bytes means nothing was lost.
      ASSERT_EQ(dp::encode_message(*d), text);
      EXPECT_EQ(dp::message_type(*d), json::parse(text)["type"].get<std::string>());
    }
  }
}

TEST(Messages, RoundTripPreservesValuesExactly) {
  dp::StrokeMessage m;
  m.handle = dp::kMaxJsonInteger;
  m.stroke.brush.mode = dp::BrushMode::smudge;
  m.stroke.brush.colour[0] = 0.1f;
  m.stroke.brush.colour[3] = 0.333333343f;
  m.stroke.samples = {{-10000.0, 1.0 / 3.0, 9999.999999999, 2e-5f, 0.1f, 0xFFFFFFFFu},
                      {1e-300, -0.0, 5e3, 1000.0f, 1.0f, 0}};
  auto d = dp::decode_message(dp::encode_message(m), any_extent());
  ASSERT_TRUE(d.ok()) << d.error().message;
  const auto& s = std::get<dp::DecodedStroke>(*d);
  EXPECT_EQ(s.handle, m.handle);
  EXPECT_EQ(s.stroke.id(), 0u);
  EXPECT_EQ(s.stroke.brush().mode(), dp::BrushMode::smudge);
  EXPECT_EQ(s.stroke.brush().get().colour[0], 0.1f);
  EXPECT_EQ(s.stroke.brush().get().colour[3], 0.333333343f);
  ASSERT_EQ(s.stroke.samples().size(), 2u);
  for (std::size_t i = 0; i < 2; ++i) {
    const dp::StrokeSample& got = s.stroke.samples()[i];
    EXPECT_EQ(got.x, m.stroke.samples[i].x);
    EXPECT_EQ(got.y, m.stroke.samples[i].y);
    EXPECT_EQ(got.z, m.stroke.samples[i].z);
    EXPECT_EQ(got.radius, m.stroke.samples[i].radius);
    EXPECT_EQ(got.pressure, m.stroke.samples[i].pressure);
    EXPECT_EQ(got.t_ms, m.stroke.samples[i].t_ms);
  }
}

TEST(Messages, EveryTruncatedPrefixIsRejected) {
  Gen g(2);
  for (std::size_t kind : kPlainKinds) {
    for (int rep = 0; rep < 3; ++rep) {
      const std::string text = dp::encode_message(g.message(kind));
      for (std::size_t n = 0; n < text.size(); ++n) {
        auto d = dp::decode_message(std::string_view(text).substr(0, n));
        ASSERT_FALSE(d.ok()) << "prefix of " << n << " bytes accepted: " << text.substr(0, n);
        EXPECT_EQ(d.error().code, Errc::malformed);
      }
    }
  }
}

TEST(Messages, CorruptedBytesNeverCrashAndWhatDecodesIsValid) {
  Gen g(3);
  auto& rng = g.rng();
  int rejected = 0, total = 0;
  for (std::size_t kind : kPlainKinds) {
    const std::string text = dp::encode_message(g.message(kind));
    for (int rep = 0; rep < 300; ++rep) {
      std::string bad = text;
      const int flips = 1 + static_cast<int>(rng() % 3);
      for (int f = 0; f < flips; ++f) bad[rng() % bad.size()] = static_cast<char>(rng() % 256);
      ++total;
      auto d = dp::decode_message(bad);
      if (!d.ok()) {
        ++rejected;
        EXPECT_FALSE(d.error().message.empty());
        continue;
      }
      // Anything accepted must survive its own round trip (it is a valid message).
      auto again = dp::decode_message(dp::encode_message(*d));
      ASSERT_TRUE(again.ok()) << bad;
    }
  }
  EXPECT_GT(rejected, total / 2);
}

TEST(Messages, PlaybackStepIsStrokesOrSecondsNotBoth) {
  auto both = dp::decode_message(
      R"({"type":"playback_step","request_id":1,"strokes":2,"seconds":3})");
  ASSERT_FALSE(both.ok());
  EXPECT_EQ(both.error().code, Errc::invalid_argument);
  for (const char* bad : {R"({"type":"playback_step","request_id":1,"strokes":0,"seconds":-1})",
                          R"({"type":"playback_step","request_id":1,"strokes":0,"seconds":2e9})",
                          R"({"type":"playback_step","request_id":1,"strokes":-1,"seconds":0})"})
    EXPECT_FALSE(dp::decode_message(bad).ok()) << bad;
  auto query = dp::decode_message(R"({"type":"playback_step","request_id":9,"strokes":0,"seconds":0})");
  ASSERT_TRUE(query.ok()) << query.error().message;
  EXPECT_EQ(std::get<dp::PlaybackStep>(*query).request_id, 9u);
  // A position past its history's end is refused.
  auto past = dp::decode_message(
      R"({"type":"playback_position","request_id":1,"epoch":3,"events":5,"events_total":4,)"
      R"("strokes":1,"strokes_total":1,"painting_seconds":0,"painting_seconds_total":0,"timed":false})");
  EXPECT_FALSE(past.ok());
}

TEST(Messages, MissingFieldIsNamed) {
  Gen g(4);
  // Fields a sender may leave out.
  const std::vector<std::pair<std::string, std::string>> optional = {
      {"hello", "delta_frames"}, {"hello", "frame_bundles"}, {"hello", "block_frames"}, {"hello", "client_id"},
      {"hello", "batch_interval_ms"}, {"hello", "camera"},
      {"stroke_begin", "samples"}, {"error", "in_reply_to"}, {"error", "handle"},
      {"error", "fatal"},          {"welcome", "limits.stroke_receipts"},
      {"welcome", "limits.max_stroke_extent_m"}, {"welcome", "limits.max_stroke_cells"},
      {"welcome", "limits.undo_depth"}, {"welcome", "limits.undo_max_stroke_bytes"},
      {"export", "box"}, {"playback_position", "bounds"}};
  for (std::size_t kind : kPlainKinds) {
    dp::Message m = g.message(kind);
    if (auto* e = std::get_if<dp::ErrorMessage>(&m)) {
      e->in_reply_to = "stroke";
      e->handle = 7;
      e->fatal = true;
    }
    if (auto* b = std::get_if<dp::StrokeBegin>(&m)) b->samples = g.samples(1, 2);
    if (auto* h = std::get_if<dp::Hello>(&m)) {
      h->client_id = "id";
      h->batch_interval_ms = 50;
      h->camera = dp::JoinCamera{{1, 2, 3}, {0, 0, 0}};
    }
    const json full = json::parse(dp::encode_message(m));
    const std::string type = full["type"];
    // A presence without "artist" is the client's form (PresenceFieldsAreValidated covers it).
    const bool update = std::holds_alternative<dp::PresenceUpdate>(m);
    // Every key at every object level (paths like geometry.edge_m).
    std::vector<std::vector<std::string>> paths;
    for (const auto& [k, v] : full.items()) {
      if (k == "type") continue;
      paths.push_back({k});
      if (v.is_object())
        for (const auto& [k2, v2] : v.items()) paths.push_back({k, k2});
    }
    for (const auto& path : paths) {
      if (update && path[0] == "artist") continue;
      json j = full;
      if (path.size() == 1)
        j.erase(path[0]);
      else
        j[path[0]].erase(path[1]);
      const std::string name = path.size() == 1 ? path[0] : path[0] + "." + path[1];
      auto d = dp::decode_message(j.dump());
      const bool is_optional =
          std::find(optional.begin(), optional.end(), std::make_pair(type, name)) !=
          optional.end();
      if (is_optional) {
        EXPECT_TRUE(d.ok()) << type << " without " << name;
        continue;
      }
      ASSERT_FALSE(d.ok()) << type << " without " << name;
      EXPECT_EQ(d.error().code, Errc::malformed) << d.error().message;
      EXPECT_NE(d.error().message.find("missing field '" + name + "'"), std::string::npos)
          << d.error().message;
    }
    // And every field with the wrong JSON type.
    for (const auto& path : paths) {
      json j = full;
      auto& slot = path.size() == 1 ? j[path[0]] : j[path[0]][path[1]];
      slot = slot.is_string() ? json(12) : json("x");
      auto d = dp::decode_message(j.dump());
      EXPECT_FALSE(d.ok()) << type << " with a mistyped " << path.back() << ": " << j.dump();
    }
  }
}

TEST(Messages, VersionMismatchIsUnsupportedAndAnswerable) {
  dp::Hello h;
  h.token = "secret";
  h.canvas = "main";
  h.protocol_version = dp::kProtocolVersion + 1;
  dp::MessageRef about;
  auto d = dp::decode_message(dp::encode_message(h), {}, &about);
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.error().code, Errc::unsupported);
  EXPECT_NE(d.error().message.find("protocol version 2"), std::string::npos) << d.error().message;
  EXPECT_EQ(about.type, "hello");

  // The server's answer decodes on any client as a fatal "unsupported" error.
  const auto answer = dp::encode_message(dp::to_error_message(d.error(), about, true));
  auto e = dp::decode_message(answer);
  ASSERT_TRUE(e.ok()) << e.error().message;
  const auto& em = std::get<dp::ErrorMessage>(*e);
  EXPECT_EQ(em.code, Errc::unsupported);
  EXPECT_EQ(em.in_reply_to, "hello");
  EXPECT_TRUE(em.fatal);
  EXPECT_NE(answer.find("\"code\":\"unsupported\""), std::string::npos);

  // A future hello may carry fields we do not know; the version check comes first.
  auto v3 = dp::decode_message(R"({"type":"hello","protocol_version":3})");
  ASSERT_FALSE(v3.ok());
  EXPECT_EQ(v3.error().code, Errc::unsupported);

  dp::Welcome w;
  w.canvas = "c";
  w.protocol_version = 0;
  auto wd = dp::decode_message(dp::encode_message(w));
  ASSERT_FALSE(wd.ok());
  EXPECT_EQ(wd.error().code, Errc::unsupported);
}

namespace {
std::string stroke_with(const std::string& brush, const std::string& samples,
                        const std::string& handle = "1") {
  return R"({"type":"stroke","handle":)" + handle + R"(,"brush":)" + brush + R"(,"samples":)" +
         samples + "}";
}
const std::string kBrush = R"({"mode":"paint","colour":[1,0.5,0,1],"opacity":1,"hardness":0.5})";
const std::string kSample = "[[0,0,0,0.1,1,0]]";

Errc code_of(const std::string& text, const dp::DecodeOptions& opt = {}) {
  auto d = dp::decode_message(text, opt);
  return d.ok() ? Errc::ok : d.error().code;
}
}  // namespace

TEST(Messages, StrokeValuesAreValidated) {
  EXPECT_EQ(code_of(stroke_with(kBrush, kSample)), Errc::ok);
  // positions outside the canvas, bad radius / pressure, out-of-float-range numbers
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[10000.001,0,0,0.1,1,0]]")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,-1e300,0,0.1,1,0]]")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,0,0,1,0]]")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,0,1e39,1,0]]")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,0,0.1,0,0]]")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,0,0.1,1.5,0]]")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,0,0.1,1,-1]]")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,0,0.1,1,4294967296]]")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,0,0.1,1,0.5]]")), Errc::malformed);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,0,0.1,1]]")), Errc::malformed);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,0,0.1,1,0,7]]")), Errc::malformed);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,\"0\",0.1,1,0]]")), Errc::malformed);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[0,0,1e999,0.1,1,0]]")), Errc::malformed);  // not JSON
  EXPECT_EQ(code_of(stroke_with(kBrush, "[]")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, "{}")), Errc::malformed);
  // brush
  EXPECT_EQ(code_of(stroke_with(R"({"mode":"spray","colour":[1,1,1,1],"opacity":1,"hardness":0})",
                                kSample)),
            Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(
                R"({"mode":"paint","colour":[1,1,1.01,1],"opacity":1,"hardness":0})", kSample)),
            Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(R"({"mode":"paint","colour":[1,1,1],"opacity":1,"hardness":0})",
                                kSample)),
            Errc::malformed);
  EXPECT_EQ(code_of(stroke_with(
                R"({"mode":"paint","colour":[1,1,1,1],"opacity":-0.1,"hardness":0})", kSample)),
            Errc::invalid_argument);
  // handles
  EXPECT_EQ(code_of(stroke_with(kBrush, kSample, "-1")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, kSample, "9007199254740992")), Errc::invalid_argument);
  EXPECT_EQ(code_of(stroke_with(kBrush, kSample, "9007199254740991")), Errc::ok);
  EXPECT_EQ(code_of(stroke_with(kBrush, kSample, "1.5")), Errc::malformed);
  EXPECT_EQ(code_of(stroke_with(kBrush, kSample, "true")), Errc::malformed);
  // canvas bounds and sample limits come from the options
  dp::DecodeOptions small;
  small.bounds.edge_m = 2.0;
  small.stroke_limits.max_samples = 2;
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[1,1,-1,0.1,1,0]]"), small), Errc::ok);
  EXPECT_EQ(code_of(stroke_with(kBrush, "[[1.5,0,0,0.1,1,0]]"), small), Errc::invalid_argument);
  EXPECT_EQ(
      code_of(stroke_with(kBrush, "[[0,0,0,0.1,1,0],[0,0,0,0.1,1,0],[0,0,0,0.1,1,0]]"), small),
      Errc::limit_exceeded);
  EXPECT_EQ(
      code_of(
          R"({"type":"stroke_samples","handle":1,"samples":[[0,0,0,0.1,1,0],[0,0,0,0.1,1,0],[0,0,0,0.1,1,0]]})",
          small),
      Errc::limit_exceeded);
  EXPECT_EQ(code_of(R"({"type":"pick_up","request_id":1,"position":[0,0,1.01]})", small),
            Errc::invalid_argument);
  EXPECT_EQ(code_of(R"({"type":"stroke_samples","handle":1,"samples":[]})"),
            Errc::invalid_argument);
  EXPECT_EQ(code_of(R"({"type":"stroke_begin","handle":1,"brush":)" + kBrush + "}"), Errc::ok);
}

TEST(Messages, BadSampleIsNamedWithItsIndex) {
  auto d =
      dp::decode_message(stroke_with(kBrush, "[[0,0,0,0.1,1,0],[0,0,0,0.1,1,0],[0,0,0,0.1,2,0]]"));
  ASSERT_FALSE(d.ok());
  EXPECT_NE(d.error().message.find("samples[2]"), std::string::npos) << d.error().message;
  EXPECT_NE(d.error().message.find("pressure"), std::string::npos) << d.error().message;
}

TEST(Messages, MessageRefCarriesTypeAndHandleOfARejectedMessage) {
  dp::MessageRef about;
  auto d = dp::decode_message(stroke_with(kBrush, "[[0,0,0,0,1,0]]", "42"), {}, &about);
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(about.type, "stroke");
  ASSERT_TRUE(about.handle.has_value());
  EXPECT_EQ(*about.handle, 42u);
  const auto e = dp::to_error_message(d.error(), about);
  EXPECT_EQ(e.code, Errc::invalid_argument);
  EXPECT_EQ(e.in_reply_to, "stroke");
  EXPECT_EQ(e.handle, std::optional<std::uint64_t>(42));
  EXPECT_FALSE(e.fatal);

  (void)dp::decode_message(R"({"type":"launch_missiles","handle":1})", {}, &about);
  EXPECT_TRUE(about.type.empty());
}

TEST(Messages, EnvelopeErrors) {
  EXPECT_EQ(code_of(""), Errc::malformed);
  EXPECT_EQ(code_of("[]"), Errc::malformed);
  EXPECT_EQ(code_of("\"hello\""), Errc::malformed);
  EXPECT_EQ(code_of("{}"), Errc::malformed);
  EXPECT_EQ(code_of(R"({"type":7})"), Errc::malformed);
  EXPECT_EQ(code_of(R"({"type":"nope"})"), Errc::malformed);
  EXPECT_EQ(code_of(R"({"type":"stats_request"})"), Errc::ok);
  EXPECT_EQ(code_of(R"({"type":"stats_request","future_field":[1,2]})"), Errc::ok);
  EXPECT_EQ(code_of("{\"type\":\"stats_request\"}\xff"), Errc::malformed);
  EXPECT_EQ(code_of("{\"type\":\"stats\xff\"}"), Errc::malformed);  // invalid UTF-8
  EXPECT_EQ(code_of(R"({"type":"stats_request"} {"type":"stats_request"})"), Errc::malformed);
  // nesting is bounded before parsing; brackets inside strings do not count
  EXPECT_EQ(code_of(std::string(100000, '[') + std::string(100000, ']')), Errc::limit_exceeded);
  EXPECT_EQ(code_of(R"({"type":"stats_request","x":"[[[[[[[[[[[[[[[[[[[[[[[[[[[["})"), Errc::ok);
  EXPECT_EQ(code_of(R"({"type":"stats_request","x":"\"[[[[[[[[[[[[[[[[[[[[[[[[[[[["})"), Errc::ok);
  dp::DecodeOptions tiny;
  tiny.max_bytes = 10;
  EXPECT_EQ(code_of(R"({"type":"stats_request"})", tiny), Errc::limit_exceeded);
}

TEST(Messages, WelcomeAndHelloRanges) {
  dp::Welcome w;
  w.canvas = "c";
  auto base = json::parse(dp::encode_message(w));
  const auto with = [&](const std::string& a, const std::string& b, json v) {
    json j = base;
    if (b.empty())
      j[a] = v;
    else
      j[a][b] = v;
    return code_of(j.dump());
  };
  EXPECT_EQ(code_of(base.dump()), Errc::ok);
  EXPECT_EQ(with("geometry", "roots_per_axis", 3), Errc::invalid_argument);
  EXPECT_EQ(with("geometry", "roots_per_axis", 66), Errc::invalid_argument);
  EXPECT_EQ(with("geometry", "edge_m", 0), Errc::invalid_argument);
  EXPECT_EQ(with("geometry", "max_depth", 25), Errc::invalid_argument);
  EXPECT_EQ(with("geometry", "max_depth", 0), Errc::invalid_argument);
  EXPECT_EQ(with("block_cells", "", 4000), Errc::invalid_argument);
  EXPECT_EQ(with("block_cells", "", 32), Errc::invalid_argument);
  EXPECT_EQ(with("texture_width", "", 0), Errc::invalid_argument);
  EXPECT_EQ(with("role", "", "admin"), Errc::invalid_argument);
  EXPECT_EQ(with("canvas", "", "a b"), Errc::invalid_argument);
  EXPECT_EQ(with("canvas", "", ""), Errc::invalid_argument);

  dp::Hello h;
  h.token = "t";
  h.canvas = "c";
  EXPECT_EQ(code_of(dp::encode_message(h)), Errc::ok);
  h.token = "has space";
  EXPECT_EQ(code_of(dp::encode_message(h)), Errc::invalid_argument);
  h.token = std::string(257, 'a');
  EXPECT_EQ(code_of(dp::encode_message(h)), Errc::invalid_argument);
  h.token = "t";
  h.client_name = std::string(129, 'a');
  EXPECT_EQ(code_of(dp::encode_message(h)), Errc::invalid_argument);
  h.client_name = "bad utf8 \xc3";  // the encoder replaces it, the result decodes
  EXPECT_EQ(code_of(dp::encode_message(h)), Errc::ok);
}

TEST(Messages, HelloClientIdIsOptionalAndChecked) {
  dp::Hello h;
  h.token = "t";
  h.canvas = "c";
  auto base = json::parse(dp::encode_message(h));
  EXPECT_FALSE(base.contains("client_id"));  // absent when empty
  const auto with_id = [&](json v) {
    json j = base;
    j["client_id"] = std::move(v);
    return j.dump();
  };
  for (const std::string& ok : std::vector<std::string>{"a", "A-z_09", std::string(64, 'x')}) {
    auto d = dp::decode_message(with_id(ok));
    ASSERT_TRUE(d.ok()) << ok << ": " << d.error().message;
    EXPECT_EQ(std::get<dp::Hello>(*d).client_id, ok);
  }
  for (const std::string& bad :
       std::vector<std::string>{"", "a b", "a.b", "\xc3\xa9", std::string(65, 'x'), "a/b"})
    EXPECT_EQ(code_of(with_id(bad)), Errc::invalid_argument) << bad;
  EXPECT_EQ(code_of(with_id(7)), Errc::malformed);
  // Every byte outside [A-Za-z0-9_-] is refused, alone and inside a valid id.
  for (int c = 1; c < 256; ++c) {
    const char ch = static_cast<char>(c);
    const bool allowed = std::isalnum(c) || ch == '_' || ch == '-';
    EXPECT_EQ(dp::is_valid_client_id(std::string("ab") + ch), allowed) << c;
  }
  auto d = dp::decode_message(base.dump());
  ASSERT_TRUE(d.ok());
  EXPECT_TRUE(std::get<dp::Hello>(*d).client_id.empty());
}

TEST(Messages, HelloBatchIntervalIsOptionalAndBounded) {
  dp::Hello h;
  h.token = "t";
  h.canvas = "c";
  auto base = json::parse(dp::encode_message(h));
  EXPECT_FALSE(base.contains("batch_interval_ms"));  // absent when 0
  const auto with = [&](json v) {
    json j = base;
    j["batch_interval_ms"] = std::move(v);
    return j.dump();
  };
  for (std::uint32_t ok : {0u, 1u, 100u, dp::kMaxBatchIntervalMs}) {
    auto d = dp::decode_message(with(ok));
    ASSERT_TRUE(d.ok()) << ok << ": " << d.error().message;
    EXPECT_EQ(std::get<dp::Hello>(*d).batch_interval_ms, ok);
  }
  EXPECT_EQ(code_of(with(dp::kMaxBatchIntervalMs + 1)), Errc::invalid_argument);
  EXPECT_EQ(code_of(with(-1)), Errc::invalid_argument);
  EXPECT_EQ(code_of(with(2.5)), Errc::malformed);
  EXPECT_EQ(code_of(with("50")), Errc::malformed);
}

TEST(Messages, HelloCameraIsOptionalAndChecked) {
  dp::Hello h;
  h.token = "t";
  h.canvas = "c";
  auto base = json::parse(dp::encode_message(h));
  EXPECT_FALSE(base.contains("camera"));  // absent when none
  ASSERT_TRUE(dp::decode_message(base.dump()).ok());
  EXPECT_FALSE(std::get<dp::Hello>(*dp::decode_message(base.dump())).camera.has_value());
  const auto with = [&](json eye, json target) {
    json j = base;
    j["camera"] = {{"eye", std::move(eye)}, {"target", std::move(target)}};
    return j.dump();
  };
  auto d = dp::decode_message(with({1.5, -2, 1e12}, {0, 0, 0}));
  ASSERT_TRUE(d.ok()) << d.error().message;
  ASSERT_TRUE(std::get<dp::Hello>(*d).camera.has_value());
  EXPECT_EQ(*std::get<dp::Hello>(*d).camera, (dp::JoinCamera{{1.5, -2, 1e12}, {0, 0, 0}}));
  EXPECT_EQ(code_of(with({1, 2, 3}, {1, 2, 3})), Errc::invalid_argument);  // eye == target
  EXPECT_EQ(code_of(with({1, 2, 2e12}, {0, 0, 0})), Errc::invalid_argument);
  EXPECT_EQ(code_of(with({1, 2}, {0, 0, 0})), Errc::malformed);
  EXPECT_EQ(code_of(with({1, 2, "3"}, {0, 0, 0})), Errc::malformed);
  json no_target = base;
  no_target["camera"] = {{"eye", {1, 2, 3}}};
  EXPECT_EQ(code_of(no_target.dump()), Errc::malformed);
  json not_object = base;
  not_object["camera"] = json::array({1, 2, 3});
  EXPECT_EQ(code_of(not_object.dump()), Errc::malformed);
}

TEST(Messages, WelcomeLimitsAddedLaterAreOptional) {
  dp::Welcome w;
  w.canvas = "c";
  w.limits.stroke_receipts = 77;
  auto j = json::parse(dp::encode_message(w));
  EXPECT_EQ(j["limits"]["stroke_receipts"], 77);
  auto d = dp::decode_message(j.dump());
  ASSERT_TRUE(d.ok()) << d.error().message;
  EXPECT_EQ(std::get<dp::Welcome>(*d).limits.stroke_receipts, 77u);
  EXPECT_EQ(j["limits"]["max_stroke_extent_m"], 100.0);
  EXPECT_EQ(j["limits"]["max_stroke_cells"], 4000000);
  for (const char* f : {"stroke_receipts", "max_stroke_extent_m", "max_stroke_cells"})
    j["limits"].erase(f);  // a server from before these fields
  d = dp::decode_message(j.dump());
  ASSERT_TRUE(d.ok()) << d.error().message;
  EXPECT_EQ(std::get<dp::Welcome>(*d).limits.stroke_receipts, 0u);  // it remembers none
  EXPECT_EQ(std::get<dp::Welcome>(*d).limits.max_stroke_extent_m, 0.0);  // not stated
  EXPECT_EQ(std::get<dp::Welcome>(*d).limits.max_stroke_cells, 0u);
  j["limits"]["max_stroke_extent_m"] = -1;
  EXPECT_EQ(code_of(j.dump()), Errc::invalid_argument);
  j["limits"].erase("max_stroke_extent_m");
  j["limits"]["stroke_receipts"] = -1;
  EXPECT_EQ(code_of(j.dump()), Errc::invalid_argument);
}

TEST(Messages, ErrcNamesRoundTrip) {
  for (int i = 0; i <= 10; ++i) {
    const auto e = static_cast<Errc>(i);
    auto p = dp::parse_errc(deepcanvas::errc_name(e));
    ASSERT_TRUE(p.ok());
    EXPECT_EQ(*p, e);
  }
  EXPECT_FALSE(dp::parse_errc("unknown").ok());
  EXPECT_EQ(code_of(R"({"type":"error","code":"weird","message":""})"), Errc::invalid_argument);
}

TEST(Messages, StrokeMessagesDecodeToTheirValidatedForms) {
  auto begin = dp::decode_message(R"({"type":"stroke_begin","handle":3,"brush":)" + kBrush + "}");
  ASSERT_TRUE(begin.ok());
  const auto* b = std::get_if<dp::DecodedStrokeBegin>(&*begin);
  ASSERT_NE(b, nullptr);
  EXPECT_EQ(b->handle, 3u);
  EXPECT_TRUE(b->samples.empty());
  EXPECT_EQ(b->brush.get().colour[1], 0.5f);
  auto samples = dp::decode_message(
      R"({"type":"stroke_samples","handle":3,"samples":[[0,0,0,0.1,1,0],[1,0,0,0.1,1,5]]})");
  ASSERT_TRUE(samples.ok());
  const auto* s = std::get_if<dp::DecodedStrokeSamples>(&*samples);
  ASSERT_NE(s, nullptr);
  ASSERT_EQ(s->samples.size(), 2u);
  EXPECT_EQ(s->samples[1].t_ms, 5u);
  EXPECT_EQ(dp::message_type(*samples), "stroke_samples");
}
