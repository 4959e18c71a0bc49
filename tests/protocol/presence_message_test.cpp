// The presence message (PROTOCOL.md 3.9), both directions: random round trips keep every value,
// every field's bad values are refused with the field named, and the two forms are told apart by
// "artist".
#include <gtest/gtest.h>

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

void expect_same(const dp::Presence& got, const dp::Presence& want) {
  EXPECT_EQ(got.cursor_on_canvas, want.cursor_on_canvas);
  if (want.cursor_on_canvas) {
    EXPECT_EQ(got.cursor, want.cursor);
  } else {
    EXPECT_EQ(got.cursor, (std::array<double, 3>{0, 0, 0}));  // not sent, read as 0
  }
  EXPECT_EQ(got.eye, want.eye);
  EXPECT_EQ(got.target, want.target);
  EXPECT_EQ(got.vfov_deg, want.vfov_deg);
  EXPECT_EQ(got.colour, want.colour);
  EXPECT_EQ(got.size_m, want.size_m);
  EXPECT_EQ(got.mode, want.mode);
  EXPECT_EQ(got.painting, want.painting);
}

json valid_presence() {
  return json::parse(R"({"type":"presence","cursor_on_canvas":true,"cursor":[1.5,-2,3],
    "eye":[0,1.6,5],"target":[0,1.6,0],"vfov_deg":45,"colour":[1,0.5,0,1],"size_m":0.02,
    "mode":"paint","painting":false})");
}

}  // namespace

TEST(Presence, RandomRoundTripsKeepEveryValue) {
  std::mt19937_64 rng(21);
  for (int i = 0; i < 2000; ++i) {
    const dp::Presence p = deepcanvas::test::random_presence(rng);
    const std::string text = dp::encode_message(p);
    auto d = dp::decode_message(text);
    ASSERT_TRUE(d.ok()) << text << "\n-> " << d.error().message;
    const auto* got = std::get_if<dp::Presence>(&*d);
    ASSERT_NE(got, nullptr) << text;
    expect_same(*got, p);
    EXPECT_EQ(dp::encode_message(*d), text);
    EXPECT_EQ(dp::message_type(*d), "presence");

    const dp::PresenceUpdate u = deepcanvas::test::random_presence_update(rng);
    const std::string utext = dp::encode_message(u);
    auto du = dp::decode_message(utext);
    ASSERT_TRUE(du.ok()) << utext << "\n-> " << du.error().message;
    const auto* gu = std::get_if<dp::PresenceUpdate>(&*du);
    ASSERT_NE(gu, nullptr) << utext;
    EXPECT_EQ(gu->artist, u.artist);
    EXPECT_EQ(gu->name, u.name);
    EXPECT_EQ(gu->gone, u.gone);
    if (!u.gone) expect_same(gu->presence, u.presence);
    EXPECT_EQ(dp::encode_message(*du), utext);
    EXPECT_EQ(dp::message_type(*du), "presence");
  }
}

TEST(Presence, EveryBadFieldIsRefusedWithItsName) {
  ASSERT_TRUE(dp::decode_message(valid_presence().dump()).ok());
  struct Case {
    const char* field;
    json value;
    Errc code;
    const char* named;  // a part of the error message
  };
  const std::vector<Case> cases = {
      {"cursor_on_canvas", 1, Errc::malformed, "cursor_on_canvas"},
      {"cursor", json::array({1, 2}), Errc::malformed, "cursor"},
      {"cursor", json::array({1, 2, "3"}), Errc::malformed, "cursor[2]"},
      {"cursor", json::array({10000.5, 0, 0}), Errc::invalid_argument, "cursor[0]"},
      {"cursor", json::array({0, -1e300, 0}), Errc::invalid_argument, "cursor[1]"},
      {"cursor", "x", Errc::malformed, "cursor"},
      {"eye", json::array({0, 0}), Errc::malformed, "eye"},
      {"eye", json::array({0, 2e12, 0}), Errc::invalid_argument, "eye[1]"},
      {"eye", json::array({0, 1.6, 0}), Errc::invalid_argument, "target"},  // == target
      {"target", json::array({0, 0, -1e13}), Errc::invalid_argument, "target[2]"},
      {"target", json::object(), Errc::malformed, "target"},
      {"vfov_deg", 0, Errc::invalid_argument, "vfov_deg"},
      {"vfov_deg", 179, Errc::invalid_argument, "vfov_deg"},
      {"vfov_deg", -10, Errc::invalid_argument, "vfov_deg"},
      {"vfov_deg", "45", Errc::malformed, "vfov_deg"},
      {"colour", json::array({1, 1, 1}), Errc::malformed, "colour"},
      {"colour", json::array({1, 1, 1, 1.01}), Errc::invalid_argument, "colour[3]"},
      {"colour", json::array({-0.1, 1, 1, 1}), Errc::invalid_argument, "colour[0]"},
      {"size_m", -0.001, Errc::invalid_argument, "size_m"},
      {"size_m", 1e13, Errc::invalid_argument, "size_m"},
      {"size_m", true, Errc::malformed, "size_m"},
      {"mode", "spray", Errc::invalid_argument, "mode"},
      {"mode", 3, Errc::malformed, "mode"},
      {"painting", "yes", Errc::malformed, "painting"},
  };
  for (const auto& c : cases) {
    json j = valid_presence();
    j[c.field] = c.value;
    dp::MessageRef about;
    auto d = dp::decode_message(j.dump(), {}, &about);
    ASSERT_FALSE(d.ok()) << j.dump();
    EXPECT_EQ(d.error().code, c.code) << j.dump() << " -> " << d.error().message;
    EXPECT_NE(d.error().message.find(c.named), std::string::npos)
        << "'" << c.named << "' not named in: " << d.error().message;
    EXPECT_EQ(about.type, "presence");
  }
  // Every field but the cursor is required, and named when missing.
  for (const char* field : {"cursor_on_canvas", "cursor", "eye", "target", "vfov_deg", "colour",
                            "size_m", "mode", "painting"}) {
    json j = valid_presence();
    j.erase(field);
    auto d = dp::decode_message(j.dump());
    ASSERT_FALSE(d.ok()) << field;
    EXPECT_EQ(d.error().code, Errc::malformed);
    EXPECT_NE(d.error().message.find(std::string("missing field '") + field + "'"),
              std::string::npos)
        << d.error().message;
  }
}

TEST(Presence, CursorIsCheckedOnlyOnTheCanvasAndAgainstItsBounds) {
  dp::DecodeOptions small;
  small.bounds.edge_m = 2.0;
  json j = valid_presence();
  j["cursor"] = {1.0, -1.0, 0.5};  // on the boundary: inside
  EXPECT_TRUE(dp::decode_message(j.dump(), small).ok());
  j["cursor"] = {1.0, -1.0001, 0.5};
  EXPECT_EQ(dp::decode_message(j.dump(), small).error().code, Errc::invalid_argument);
  // Off the canvas the cursor is not read: absent, or anything, and it decodes as 0.
  j["cursor_on_canvas"] = false;
  auto d = dp::decode_message(j.dump(), small);
  ASSERT_TRUE(d.ok()) << d.error().message;
  EXPECT_EQ(std::get<dp::Presence>(*d).cursor, (std::array<double, 3>{0, 0, 0}));
  j.erase("cursor");
  EXPECT_TRUE(dp::decode_message(j.dump(), small).ok());
  EXPECT_EQ(json::parse(dp::encode_message(std::get<dp::Presence>(*d))).count("cursor"), 0u);
}

TEST(Presence, TheServerFormCarriesArtistNameAndGone) {
  json j = valid_presence();
  j["artist"] = 7;
  j["name"] = "ann";
  j["gone"] = false;
  auto d = dp::decode_message(j.dump());
  ASSERT_TRUE(d.ok()) << d.error().message;
  const auto& u = std::get<dp::PresenceUpdate>(*d);
  EXPECT_EQ(u.artist, 7u);
  EXPECT_EQ(u.name, "ann");
  EXPECT_FALSE(u.gone);
  EXPECT_EQ(u.presence.cursor[0], 1.5);
  // Its presence fields are checked as the client's are.
  j["vfov_deg"] = 200;
  EXPECT_EQ(dp::decode_message(j.dump()).error().code, Errc::invalid_argument);
  // Gone: the artist's fields only.
  auto g = dp::decode_message(R"({"type":"presence","artist":9,"name":"","gone":true})");
  ASSERT_TRUE(g.ok()) << g.error().message;
  EXPECT_TRUE(std::get<dp::PresenceUpdate>(*g).gone);
  EXPECT_EQ(dp::encode_message(*g), R"({"artist":9,"gone":true,"name":"","type":"presence"})");
  // Its own fields are checked.
  for (const char* bad :
       {R"({"type":"presence","artist":-1,"name":"","gone":true})",
        R"({"type":"presence","artist":9007199254740992,"name":"","gone":true})",
        R"({"type":"presence","artist":"9","name":"","gone":true})",
        R"({"type":"presence","artist":9,"gone":true})",
        R"({"type":"presence","artist":9,"name":"","gone":1})",
        R"({"type":"presence","artist":9,"name":""})"}) {
    auto b = dp::decode_message(bad);
    EXPECT_FALSE(b.ok()) << bad;
  }
  const std::string long_name(129, 'n');
  auto b = dp::decode_message(
      R"({"type":"presence","artist":9,"gone":true,"name":")" + long_name + "\"}");
  ASSERT_FALSE(b.ok());
  EXPECT_EQ(b.error().code, Errc::invalid_argument);
}
