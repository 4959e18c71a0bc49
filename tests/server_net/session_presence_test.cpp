// Presence (PROTOCOL.md 3.9) through SessionHandlers without sockets: several sessions of one
// canvas share a PresenceRelay as the server's do; a fake clock and the fake transport's timer
// drive the 50 ms interval, and a transport that never reports writes is a slow reader.
#include <gtest/gtest.h>

#include <cinttypes>
#include <cstdio>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/server_net/presence_relay.hpp"
#include "deepcanvas/server_net/session_handler.hpp"
#include "fake_session.hpp"

namespace deepcanvas::test {
namespace {

namespace dp = protocol;
using server_core::Clock;
using server_net::SessionHandler;
using namespace std::chrono_literals;

using Connection = FakeConnection;

dp::Presence at(double x) {
  dp::Presence p;
  p.cursor_on_canvas = true;
  p.cursor = {x, 0.25, -0.5};
  p.eye = {0, 1, 3};
  p.target = {x, 0, 0};
  p.colour = {1.0f, 0.25f, 0.0f, 1.0f};
  p.size_m = 0.05;
  p.painting = x > 0;
  return p;
}

class SessionPresenceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    base::set_log_level(base::LogLevel::warn);
    server_core::CanvasServiceConfig cc;
    cc.name = "c";
    cc.octree.edge_m = 8.0;
    cc.octree.max_depth = 10;
    auto c = server_core::CanvasService::create(cc);
    ASSERT_TRUE(c.ok()) << c.error().message;
    canvas_ = std::move(*c);
  }
  void TearDown() override {
    for (auto& c : connections_)
      if (c->handler) c->cut();
    connections_.clear();
  }

  Connection& connect(dp::Role role, const std::string& name) {
    auto c = std::make_unique<Connection>();
    c->id = next_id_++;
    server_net::SessionContext ctx;
    ctx.config = &config_;
    ctx.metrics = &metrics_;
    ctx.find_canvas = [this](std::string_view n) { return n == "c" ? canvas_.get() : nullptr; };
    ctx.now = [this] { return now_; };
    ctx.presence = &relay_;
    c->handler = std::make_unique<SessionHandler>(std::move(ctx), c->out, c->strand.poster(),
                                                  c->id, "test");
    dp::Hello h;
    h.role = role;
    h.token = "t";
    h.canvas = "c";
    h.client_name = name;
    h.block_frames = false;
    c->text(dp::encode_message(h));
    EXPECT_FALSE(c->handler->awaiting_hello());
    connections_.push_back(std::move(c));
    return *connections_.back();
  }
  void run_all() {
    for (auto& c : connections_)
      if (c->handler) c->run();
  }

  server_net::ServerConfig config_;
  server_net::ServerMetrics metrics_;
  server_net::PresenceRelay relay_{{&metrics_.presence_published, &metrics_.presence_coalesced}};
  std::unique_ptr<server_core::CanvasService> canvas_;
  Clock::time_point now_ = Clock::now();
  std::uint64_t next_id_ = 1;
  std::vector<std::unique_ptr<Connection>> connections_;  // last: gone before the canvas
};

TEST_F(SessionPresenceTest, APaintersPresenceReachesEveryOtherSessionButItself) {
  Connection& a = connect(dp::Role::painter, "ann");
  Connection& b = connect(dp::Role::painter, "bob");
  Connection& v = connect(dp::Role::viewer, "vic");
  a.text(dp::encode_message(at(0.5)));
  run_all();
  EXPECT_TRUE(a.presence().empty());
  for (Connection* c : {&b, &v}) {
    const auto got = c->presence();
    ASSERT_EQ(got.size(), 1u);
    EXPECT_EQ(got[0].artist, a.id);
    EXPECT_EQ(got[0].name, "ann");
    EXPECT_FALSE(got[0].gone);
    EXPECT_EQ(dp::encode_message(got[0].presence), dp::encode_message(at(0.5)));
  }
  EXPECT_EQ(metrics_.presence_published.value(), 1u);
  EXPECT_EQ(metrics_.presence_sent.value(), 2u);
}

TEST_F(SessionPresenceTest, OnePerIntervalAndTheLastOneIsNeverLost) {
  Connection& a = connect(dp::Role::painter, "ann");
  Connection& b = connect(dp::Role::viewer, "bob");
  a.text(dp::encode_message(at(0.1)));  // relayed at once
  now_ += 10ms;
  a.text(dp::encode_message(at(0.2)));  // held: 40 ms of the interval are left
  ASSERT_TRUE(a.out.timer);
  EXPECT_EQ(a.out.timer_delay, 40ms);
  now_ += 20ms;
  a.text(dp::encode_message(at(0.3)));  // replaces the held one
  run_all();
  ASSERT_EQ(b.presence().size(), 1u);
  EXPECT_EQ(metrics_.presence_held.value(), 1u);
  now_ += 20ms;
  ASSERT_TRUE(a.out.fire_timer());
  run_all();
  auto got = b.presence();
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[1].presence.cursor[0], 0.3);
  // The next one within 50 ms of that is held again; one after the interval goes at once.
  now_ += 60ms;
  a.text(dp::encode_message(at(0.4)));
  EXPECT_FALSE(a.out.timer);
  run_all();
  got = b.presence();
  ASSERT_EQ(got.size(), 3u);
  EXPECT_EQ(got[2].presence.cursor[0], 0.4);
}

TEST_F(SessionPresenceTest, AViewersPresenceIsRefusedAndGoesNowhere) {
  Connection& a = connect(dp::Role::painter, "ann");
  Connection& v = connect(dp::Role::viewer, "vic");
  v.text(dp::encode_message(at(0.5)));
  run_all();
  EXPECT_TRUE(a.presence().empty());
  const auto e = v.errors();
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].code, Errc::unauthorized);
  EXPECT_EQ(e[0].in_reply_to, "presence");
  EXPECT_FALSE(e[0].fatal);
  EXPECT_EQ(metrics_.presence_published.value(), 0u);
  // The server-to-client form from a client is malformed, and relayed nowhere either.
  a.text(R"({"type":"presence","artist":1,"name":"x","gone":true})");
  run_all();
  ASSERT_EQ(a.errors().size(), 1u);
  EXPECT_EQ(a.errors()[0].code, Errc::malformed);
  EXPECT_TRUE(v.presence().empty());
}

TEST_F(SessionPresenceTest, ALateJoinerGetsTheLatestAndEveryoneGetsGone) {
  Connection& a = connect(dp::Role::painter, "ann");
  Connection& b = connect(dp::Role::painter, "bob");
  a.text(dp::encode_message(at(0.1)));
  now_ += 100ms;
  a.text(dp::encode_message(at(0.2)));
  run_all();
  Connection& late = connect(dp::Role::viewer, "late");
  run_all();
  auto got = late.presence();
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].presence.cursor[0], 0.2);
  EXPECT_EQ(got[0].artist, a.id);
  a.cut();
  run_all();
  for (Connection* c : {&b, &late}) {
    got = c->presence();
    ASSERT_FALSE(got.empty());
    EXPECT_TRUE(got.back().gone);
    EXPECT_EQ(got.back().artist, a.id);
    EXPECT_EQ(got.back().name, "ann");
  }
  // b never published: its end sends nothing.
  const std::size_t before = late.presence().size();
  b.cut();
  run_all();
  EXPECT_EQ(late.presence().size(), before);
  EXPECT_EQ(relay_.members("c"), 1u);
}

TEST_F(SessionPresenceTest, ASlowReaderHoldsAtMostTheLatestPerArtist) {
  Connection& a = connect(dp::Role::painter, "ann");
  Connection& slow = connect(dp::Role::viewer, "slow");
  // The slow reader's transport never reports a write: after kPresenceInFlight updates the
  // rest wait in its inbox, one per artist.
  for (int i = 0; i < 40; ++i) {
    a.text(dp::encode_message(at(0.01 * i)));
    now_ += 50ms;
    run_all();
  }
  EXPECT_EQ(slow.presence().size(), SessionHandler::kPresenceInFlight);
  EXPECT_EQ(metrics_.presence_coalesced.value(), 40 - SessionHandler::kPresenceInFlight - 1);
  // Another artist comes and goes unseen: both its updates are dropped.
  Connection& c = connect(dp::Role::painter, "cat");
  c.text(dp::encode_message(at(-0.5)));
  c.cut();
  run_all();
  // The reader catches up: the next it gets is ann's latest, then nothing.
  for (std::size_t i = 0; i < SessionHandler::kPresenceInFlight; ++i)
    slow.handler->on_presence_written();
  const auto got = slow.presence();
  ASSERT_EQ(got.size(), SessionHandler::kPresenceInFlight + 1);
  EXPECT_EQ(got.back().artist, a.id);
  EXPECT_DOUBLE_EQ(got.back().presence.cursor[0], 0.39);
  for (const auto& u : got) EXPECT_NE(u.artist, c.id);
}

TEST(PresenceInbox, KeepsOnePerArtistInArrivalOrderAndWakesOnce) {
  server_core::Counter coalesced;
  server_net::PresenceInbox inbox(&coalesced);
  auto text = [](const char* s) { return std::make_shared<const std::string>(s); };
  EXPECT_TRUE(inbox.put(1, text("a1"), false));
  EXPECT_FALSE(inbox.put(2, text("b1"), false));  // a wake is outstanding
  EXPECT_FALSE(inbox.put(1, text("a2"), false));
  EXPECT_EQ(coalesced.value(), 1u);
  auto got = inbox.take(1);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(*got[0], "a2");
  EXPECT_TRUE(inbox.put(3, text("c1"), false));  // take() cleared the wake
  EXPECT_FALSE(inbox.put(2, text("b-gone"), true));  // never told of 2: dropped with its b1
  EXPECT_FALSE(inbox.put(1, text("a-gone"), true));  // told of 1: kept
  got = inbox.take(10);
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(*got[0], "c1");
  EXPECT_EQ(*got[1], "a-gone");
  EXPECT_EQ(inbox.pending(), 0u);
}

}  // namespace
}  // namespace deepcanvas::test

namespace deepcanvas::test {
namespace {

// PresenceRelay under random joins, leaves, publishes and readers that take at random paces:
// every update a member takes is newer than the last it took of that artist, a gone only comes
// for an artist it holds, nothing of its own comes back, an inbox never holds more than one
// update per artist, and once everyone has read everything each member holds exactly the latest
// presence of every other artist present.
TEST(PresenceRelayProperty, MembersEndWithTheLatestOfEveryArtistPresent) {
  for (std::uint64_t seed = 1; seed <= 40; ++seed) {
    std::mt19937_64 rng(seed);
    server_core::Counter coalesced;
    server_net::PresenceRelay relay({nullptr, &coalesced});
    struct Member {
      std::shared_ptr<server_net::PresenceInbox> inbox;
      std::map<std::uint64_t, std::uint64_t> view;  // artist -> seq of the presence held
      bool woken = false;
    };
    std::map<std::uint64_t, std::unique_ptr<Member>> members;
    std::map<std::uint64_t, std::uint64_t> latest;  // published artists present -> seq
    std::uint64_t next_id = 1, seq = 0;
    auto text = [](char kind, std::uint64_t artist, std::uint64_t s) {
      return std::make_shared<const std::string>(std::string(1, kind) + " " +
                                                 std::to_string(artist) + " " + std::to_string(s));
    };
    auto read = [&](std::uint64_t id, Member& m, std::size_t max) {
      for (const auto& t : m.inbox->take(max)) {
        char kind = 0;
        std::uint64_t artist = 0, s = 0;
        ASSERT_EQ(std::sscanf(t->c_str(), "%c %" SCNu64 " %" SCNu64, &kind, &artist, &s), 3) << *t;
        ASSERT_NE(artist, id) << "a member was given its own presence";
        if (kind == 'G') {
          ASSERT_TRUE(m.view.count(artist)) << "gone for an artist never given";
          m.view.erase(artist);
        } else {
          auto it = m.view.find(artist);
          if (it != m.view.end()) {
            ASSERT_GT(s, it->second) << "an older presence after a newer";
          }
          m.view[artist] = s;
        }
      }
      m.woken = false;
    };
    for (int step = 0; step < 400; ++step) {
      const int op = static_cast<int>(rng() % 10);
      if (op == 0 || members.size() < 2) {
        const std::uint64_t id = next_id++;
        auto m = std::make_unique<Member>();
        Member* raw = m.get();
        m->inbox = relay.join("c", id, [raw] { raw->woken = true; });
        members.emplace(id, std::move(m));
      } else if (op == 1) {
        auto it = std::next(members.begin(), static_cast<long>(rng() % members.size()));
        const std::uint64_t id = it->first;
        relay.leave("c", id, text('G', id, ++seq));
        latest.erase(id);
        members.erase(it);
      } else if (op < 6) {
        auto it = std::next(members.begin(), static_cast<long>(rng() % members.size()));
        relay.publish("c", it->first, text('P', it->first, ++seq));
        latest[it->first] = seq;
      } else {
        auto it = std::next(members.begin(), static_cast<long>(rng() % members.size()));
        read(it->first, *it->second, rng() % 3);
        if (HasFatalFailure()) return;
      }
      for (const auto& [id, m] : members)
        ASSERT_LE(m->inbox->pending(), latest.size() + m->view.size()) << "seed " << seed;
    }
    for (auto& [id, m] : members) {
      read(id, *m, 1u << 20);
      if (HasFatalFailure()) return;
      std::map<std::uint64_t, std::uint64_t> want = latest;
      want.erase(id);
      EXPECT_EQ(m->view, want) << "seed " << seed << ", member " << id;
    }
    for (auto& [id, m] : members) relay.leave("c", id, nullptr);
    EXPECT_EQ(relay.members("c"), 0u);
  }
}

}  // namespace
}  // namespace deepcanvas::test
