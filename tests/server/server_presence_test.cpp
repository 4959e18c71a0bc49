// Presence (PROTOCOL.md 3.9) on loopback: two painters and a viewer through the real server and
// client_core. A painter's presence reaches the others and never itself, at most one per 50 ms
// with the last one kept, a late joiner sees who is there, a painter that leaves is gone for the
// others, and a viewer's presence is refused.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <thread>

#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

using client_core::Client;
using protocol::Role;

std::unique_ptr<Client> connect_as(const TestServer& s, Role role, const std::string& token,
                                   const std::string& name) {
  auto o = client_options(s, "c", role, token);
  o.client_name = name;
  o.block_frames = false;  // presence needs no canvas stream
  auto c = Client::connect(o);
  EXPECT_TRUE(c.ok()) << (c ? "" : c.error().message);
  return c ? std::move(*c) : nullptr;
}

bool eventually(const std::function<bool()>& done, std::chrono::milliseconds timeout = 10s) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!done()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(2ms);
  }
  return true;
}

// A presence inside the test canvas (8 m), different for every `i`.
protocol::Presence presence_at(int i) {
  protocol::Presence p;
  p.cursor_on_canvas = i % 7 != 3;
  if (p.cursor_on_canvas) p.cursor = {-3.0 + 0.01 * i, 0.5, 1.0 / (i + 1)};
  p.eye = {0.1 * i, 2.0, 6.0};
  p.target = {0.0, 0.0, 0.001 * i};
  p.vfov_deg = 30 + (i % 100);
  p.colour = {static_cast<float>(i % 256) / 255.0f, 0.5f, 0.25f, 1.0f};
  p.size_m = 0.001 * (i + 1);
  p.mode = static_cast<protocol::BrushMode>(i % protocol::kBrushModeCount);
  p.painting = i % 2 == 0;
  return p;
}

// The presence `c` shows of the artist named `name`, if any.
std::optional<protocol::PresenceUpdate> shown(const Client& c, const std::string& name) {
  for (auto& u : c.presence())
    if (u.name == name) return u;
  return std::nullopt;
}

bool same(const protocol::Presence& a, const protocol::Presence& b) {
  return protocol::encode_message(a) == protocol::encode_message(b);
}

TEST(ServerPresence, APaintersPresenceReachesTheOthersNotItself) {
  auto s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  auto a = connect_as(s, Role::painter, "paint-token", "ann");
  auto b = connect_as(s, Role::painter, "paint-token", "bob");
  auto v = connect_as(s, Role::viewer, "view-token", "vic");
  ASSERT_TRUE(a && b && v);
  const auto pa = presence_at(5);
  ASSERT_TRUE(a->send_presence(pa).ok());
  for (Client* c : {b.get(), v.get()}) {
    ASSERT_TRUE(eventually([&] { return shown(*c, "ann").has_value(); }));
    const auto u = *shown(*c, "ann");
    EXPECT_FALSE(u.gone);
    EXPECT_TRUE(same(u.presence, pa));
    EXPECT_EQ(c->presence().size(), 1u);
  }
  // Both ways: bob's reaches ann and the viewer.
  ASSERT_TRUE(b->send_presence(presence_at(9)).ok());
  ASSERT_TRUE(eventually([&] { return shown(*a, "bob").has_value(); }));
  ASSERT_TRUE(eventually([&] { return v->presence().size() == 2; }));
  EXPECT_TRUE(same(shown(*v, "bob")->presence, presence_at(9)));
  // ann never sees her own, and her artist id differs from bob's.
  std::this_thread::sleep_for(100ms);
  EXPECT_FALSE(shown(*a, "ann").has_value());
  EXPECT_EQ(a->presence().size(), 1u);
  EXPECT_NE(shown(*v, "ann")->artist, shown(*v, "bob")->artist);
  EXPECT_EQ(shown(*b, "ann")->artist, shown(*v, "ann")->artist);
  const auto [status, body] = http_get(s, "/metrics");
  EXPECT_EQ(status, 200);
  EXPECT_NE(body.find("deepcanvas_presence_published_total 2"), std::string::npos) << body;
}

TEST(ServerPresence, TwoHundredInOneSecondArriveAtTwentyPerSecondWithTheLastKept) {
  auto s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  auto a = connect_as(s, Role::painter, "paint-token", "ann");
  auto b = connect_as(s, Role::painter, "paint-token", "bob");
  auto v = connect_as(s, Role::viewer, "view-token", "vic");
  ASSERT_TRUE(a && b && v);
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < 200; ++i) {
    ASSERT_TRUE(a->send_presence(presence_at(i)).ok());
    std::this_thread::sleep_until(t0 + i * 5ms);
  }
  const double sent_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  const auto last = presence_at(199);
  for (Client* c : {b.get(), v.get()}) {
    ASSERT_TRUE(eventually([&] {
      auto u = shown(*c, "ann");
      return u && same(u->presence, last);
    })) << "the last presence sent never arrived";
    // At most one per 50 ms while sending, and the held last one after it.
    const auto n = c->presence_updates_received();
    RecordProperty(c == b.get() ? "painter_updates" : "viewer_updates", static_cast<int>(n));
    RecordProperty("sent_ms", static_cast<int>(sent_ms));
    EXPECT_LE(static_cast<double>(n), std::floor(sent_ms / 50.0) + 3) << "over " << sent_ms << " ms";
    EXPECT_GE(n, 5u);
  }
  // Nothing more comes after the last one.
  const auto settled = b->presence_updates_received();
  std::this_thread::sleep_for(200ms);
  EXPECT_EQ(b->presence_updates_received(), settled);
}

TEST(ServerPresence, ALateJoinerSeesWhoIsThereAndALeaverIsGone) {
  auto s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  auto a = connect_as(s, Role::painter, "paint-token", "ann");
  auto b = connect_as(s, Role::painter, "paint-token", "bob");
  ASSERT_TRUE(a && b);
  ASSERT_TRUE(a->send_presence(presence_at(3)).ok());
  ASSERT_TRUE(eventually([&] { return shown(*b, "ann").has_value(); }));
  auto late = connect_as(s, Role::viewer, "view-token", "late");
  ASSERT_TRUE(late);
  ASSERT_TRUE(eventually([&] { return shown(*late, "ann").has_value(); }));
  EXPECT_TRUE(same(shown(*late, "ann")->presence, presence_at(3)));
  const auto before = b->presence_updates_received();
  a->close();
  for (Client* c : {b.get(), late.get()})
    ASSERT_TRUE(eventually([&] { return c->presence().empty(); })) << "ann is not gone";
  EXPECT_EQ(b->presence_updates_received(), before + 1);
}

TEST(ServerPresence, AViewersPresenceIsRefusedAndRelayedToNobody) {
  auto s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  auto a = connect_as(s, Role::painter, "paint-token", "ann");
  auto v = connect_as(s, Role::viewer, "view-token", "vic");
  ASSERT_TRUE(a && v);
  ASSERT_TRUE(v->send_presence(presence_at(1)).ok());  // valid: the server refuses it
  auto e = v->wait_for_error(10s);
  ASSERT_TRUE(e.has_value());
  EXPECT_EQ(e->code, Errc::unauthorized);
  EXPECT_EQ(e->in_reply_to, "presence");
  EXPECT_FALSE(e->fatal);
  EXPECT_TRUE(v->is_open());
  // Ordered after the viewer's: a painter's presence arrives, and it is the only one.
  ASSERT_TRUE(a->send_presence(presence_at(2)).ok());
  ASSERT_TRUE(eventually([&] { return shown(*v, "ann").has_value(); }));
  std::this_thread::sleep_for(100ms);
  EXPECT_EQ(a->presence_updates_received(), 0u);
  EXPECT_EQ(v->presence().size(), 1u);
}

TEST(ServerPresence, TheClientRefusesWhatTheServerWouldAndSendsNothing) {
  auto s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  auto a = connect_as(s, Role::painter, "paint-token", "ann");
  auto b = connect_as(s, Role::painter, "paint-token", "bob");
  ASSERT_TRUE(a && b);
  auto p = presence_at(4);
  p.cursor = {4.5, 0, 0};  // outside the 8 m canvas
  p.cursor_on_canvas = true;
  auto r = a->send_presence(p);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::invalid_argument);
  EXPECT_NE(r.error().message.find("cursor[0]"), std::string::npos) << r.error().message;
  p = presence_at(4);
  p.target = p.eye;
  EXPECT_FALSE(a->send_presence(p).ok());
  // A hand-made bad one reaches the server's own check.
  ASSERT_TRUE(a->send_text(R"({"type":"presence","cursor_on_canvas":false,"eye":[0,0,0],)"
                           R"("target":[0,0,1],"vfov_deg":0,"colour":[1,1,1,1],"size_m":0,)"
                           R"("mode":"paint","painting":false})")
                  .ok());
  auto e = a->wait_for_error(10s);
  ASSERT_TRUE(e.has_value());
  EXPECT_EQ(e->code, Errc::invalid_argument);
  EXPECT_EQ(e->in_reply_to, "presence");
  EXPECT_NE(e->message.find("vfov_deg"), std::string::npos) << e->message;
  std::this_thread::sleep_for(100ms);
  EXPECT_EQ(b->presence_updates_received(), 0u);
}

}  // namespace
}  // namespace deepcanvas::test
