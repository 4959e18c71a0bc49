// Security and limits: every bad input gets its error (and a close where it is fatal) while a
// bystander keeps painting, and nothing a bad client sends changes the canvas.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>
#include <set>
#include <thread>

#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

using client_core::Client;
using protocol::Role;
using json = nlohmann::json;

class ServerLimits : public ::testing::Test {
 protected:
  void SetUp() override {
    limits_.max_frame_bytes = 64 * 1024;
    limits_.max_samples_per_stroke = 50;
    limits_.max_strokes_per_second = 20;
    s_ = start_server({"c"}, kTokens, limits_);
    ASSERT_TRUE(s_.server);
    auto b = Client::connect(client_options(s_));
    ASSERT_TRUE(b.ok()) << b.error().message;
    bystander_ = std::move(*b);
    // The bystander paints throughout, in its own thread.
    painter_ = std::thread([this] {
      std::mt19937_64 rng(99);
      while (!stop_) {
        auto h = bystander_->send_stroke(random_stroke(rng, 4));
        if (!h) return;
        if (!bystander_->wait_for_ack(*h, 30s)) {
          ++bystander_failures_;
          return;
        }
        ++bystander_strokes_;
        std::this_thread::sleep_for(60ms);  // within the rate limit
      }
    });
  }

  void TearDown() override {
    // The bystander must have painted during the test: give it time for one stroke at least.
    for (int i = 0; i < 3000 && bystander_strokes_.load() == 0 && !bystander_failures_; ++i)
      std::this_thread::sleep_for(10ms);
    stop_ = true;
    if (painter_.joinable()) painter_.join();
    if (!s_.server) return;
    EXPECT_EQ(bystander_failures_.load(), 0);
    EXPECT_GT(bystander_strokes_.load(), 0);
    auto q = expect_converged(*s_.canvas(), {bystander_.get()});
    // Only the bystander's strokes (and any the test sent legitimately) were applied.
    EXPECT_EQ(q.strokes, static_cast<std::uint64_t>(bystander_strokes_.load()) + legit_strokes_);
    bystander_->close();
  }

  std::unique_ptr<Client> connect(Role role = Role::painter,
                                  const std::string& token = "paint-token") {
    auto c = Client::connect(client_options(s_, "c", role, token));
    EXPECT_TRUE(c.ok()) << (c ? "" : c.error().message);
    return c ? std::move(*c) : nullptr;
  }

  // Expects the next error on `c` to have `code` (and, if given, the handle and fatality).
  static void expect_error(Client& c, Errc code, std::optional<std::uint64_t> handle = {},
                           bool fatal = false) {
    auto e = c.wait_for_error(10s);
    ASSERT_TRUE(e.has_value()) << "no error arrived";
    EXPECT_EQ(e->code, code) << errc_name(e->code) << ": " << e->message;
    if (handle) {
      EXPECT_EQ(e->handle, handle);
    }
    EXPECT_EQ(e->fatal, fatal) << e->message;
  }

  protocol::SessionLimits limits_;
  TestServer s_;
  std::unique_ptr<Client> bystander_;
  std::thread painter_;
  std::atomic<bool> stop_{false};
  std::atomic<int> bystander_strokes_{0};
  std::atomic<int> bystander_failures_{0};
  std::uint64_t legit_strokes_ = 0;
};

TEST_F(ServerLimits, WrongTokenIsRefused) {
  auto c = Client::connect(client_options(s_, "c", Role::painter, "not-a-token"));
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, Errc::unauthorized);
  // A viewer token cannot be used to paint.
  c = Client::connect(client_options(s_, "c", Role::painter, "view-token"));
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, Errc::unauthorized);
}

TEST_F(ServerLimits, MissingTokenIsRefusedAndClosed) {
  auto raw = RawWs::connect(s_);
  ASSERT_TRUE(raw);
  ASSERT_TRUE(raw->send_text(R"({"type":"hello","protocol_version":1,"role":"painter",)"
                             R"("canvas":"c","client_name":"x"})"));
  auto reply = raw->read_text();
  ASSERT_TRUE(reply.has_value());
  auto j = json::parse(*reply);
  EXPECT_EQ(j["type"], "error");
  EXPECT_EQ(j["fatal"], true);
  EXPECT_NE(raw->read_until_closed(), 0);
}

// RFC 6455 8.1 fails the connection on invalid UTF-8 with close 1007; the client is told why
// first, before its hello and after it, in one frame and across fragments.
TEST_F(ServerLimits, InvalidUtf8GetsMalformedThenClose1007) {
  const std::string hello = R"({"type":"hello","protocol_version":1,"role":"painter",)"
                            R"("token":"paint-token","canvas":"c","client_name":"x"})";
  const std::string bad = "{\"type\":\"stats_request\",\"x\":\"\xc3\x28\"}";
  for (int variant = 0; variant < 4; ++variant) {
    SCOPED_TRACE(variant);
    auto raw = RawWs::connect(s_);
    ASSERT_TRUE(raw);
    const bool after_hello = variant >= 2;
    if (after_hello) {
      ASSERT_TRUE(raw->send_text(hello));
      auto welcome = json::parse(raw->read_text().value_or("{}"));
      ASSERT_EQ(welcome["type"], "welcome");
      // A valid message split into fragments is still read as text and answered.
      ASSERT_TRUE(raw->send_fragmented(R"({"type":"stats_request"})", 5));
      bool answered = false;
      for (int k = 0; k < 20 && !answered; ++k) {
        auto j = json::parse(raw->read_text().value_or("{}"));
        ASSERT_NE(j["type"], "error") << j.dump();
        answered = j["type"] == "stats";
      }
      EXPECT_TRUE(answered);
    }
    const bool fragmented = variant % 2 == 1;
    ASSERT_TRUE(fragmented ? raw->send_fragmented(bad, 3) : raw->send_text(bad));
    std::optional<std::string> reply;
    json j;
    do {  // after the hello, epoch messages may come first
      reply = raw->read_text();
      ASSERT_TRUE(reply.has_value());
      j = json::parse(*reply);
    } while (j["type"] != "error");
    EXPECT_EQ(j["code"], "malformed");
    EXPECT_EQ(j["fatal"], true);
    EXPECT_NE(j["message"].get<std::string>().find("UTF-8"), std::string::npos);
    EXPECT_EQ(raw->read_until_closed(), 1007);
  }
  // The server still serves others.
  auto c = connect();
  ASSERT_TRUE(c);
  ASSERT_TRUE(c->request_stats().ok());
  EXPECT_TRUE(c->wait_for_stats(10s).ok());
}

TEST_F(ServerLimits, UnknownCanvasVersionAndNonHelloAreRefused) {
  auto c = Client::connect(client_options(s_, "nope", Role::painter, "paint-token"));
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, Errc::not_found);
  {
    auto raw = RawWs::connect(s_);
    ASSERT_TRUE(raw);
    ASSERT_TRUE(raw->send_text(R"({"type":"hello","protocol_version":999,"role":"painter",)"
                               R"("token":"paint-token","canvas":"c","client_name":"x"})"));
    auto j = json::parse(raw->read_text().value_or("{}"));
    EXPECT_EQ(j["type"], "error");
    EXPECT_EQ(j["code"], "unsupported");
    EXPECT_EQ(j["fatal"], true);
    EXPECT_NE(raw->read_until_closed(), 0);
  }
  {
    auto raw = RawWs::connect(s_);
    ASSERT_TRUE(raw);
    ASSERT_TRUE(raw->send_text(R"({"type":"stats_request"})"));
    auto j = json::parse(raw->read_text().value_or("{}"));
    EXPECT_EQ(j["type"], "error");
    EXPECT_EQ(j["fatal"], true);
    EXPECT_NE(raw->read_until_closed(), 0);
  }
}

TEST_F(ServerLimits, ViewerStrokesAreRefused) {
  auto v = connect(Role::viewer, "view-token");
  ASSERT_TRUE(v);
  std::mt19937_64 rng(1);
  auto h = v->send_stroke(random_stroke(rng));
  ASSERT_TRUE(h.ok());
  expect_error(*v, Errc::unauthorized, *h);
  auto hb = v->begin_stroke(random_stroke(rng).brush);
  expect_error(*v, Errc::unauthorized, *hb);
  EXPECT_TRUE(v->is_open());  // not fatal: a viewer may keep watching
  ASSERT_TRUE(v->request_stats().ok());
  EXPECT_TRUE(v->wait_for_stats(10s).ok());
}

TEST_F(ServerLimits, OversizedFrameIsRefusedAndClosed) {
  auto c = connect();
  ASSERT_TRUE(c);
  std::string big = R"({"type":"stats_request","pad":")" + std::string(200 * 1024, 'x') + "\"}";
  ASSERT_TRUE(c->send_text(big).ok());
  expect_error(*c, Errc::limit_exceeded, std::nullopt, true);
  EXPECT_TRUE(c->wait_for_close(10s));
  EXPECT_EQ(c->close_code(), 1009);  // message too big
}

TEST_F(ServerLimits, TooManySamplesIsRefused) {
  auto c = connect();
  ASSERT_TRUE(c);
  std::mt19937_64 rng(2);
  auto h = c->send_stroke(random_stroke(rng, 51));
  expect_error(*c, Errc::limit_exceeded, *h);
  // Streamed: the samples that pass the limit are refused and the stroke is ended.
  auto st = random_stroke(rng, 60);
  auto hs = c->begin_stroke(st.brush, {st.samples.begin(), st.samples.begin() + 30});
  ASSERT_TRUE(hs.ok());
  ASSERT_TRUE(c->add_samples(*hs, {st.samples.begin() + 30, st.samples.end()}).ok());
  expect_error(*c, Errc::limit_exceeded, *hs);
  auto ack = c->wait_for_ack(*hs, 30s);  // the first 30 samples were painted
  EXPECT_TRUE(ack.ok());
  legit_strokes_ = 1;
  EXPECT_TRUE(c->is_open());
}

TEST_F(ServerLimits, StrokeRateIsLimited) {
  auto c = connect();
  ASSERT_TRUE(c);
  std::mt19937_64 rng(3);
  std::vector<std::uint64_t> hs;
  for (int i = 0; i < 60; ++i) hs.push_back(*c->send_stroke(random_stroke(rng, 1)));
  int limited = 0;
  std::set<std::uint64_t> refused;
  while (auto e = c->wait_for_error(1500ms)) {
    EXPECT_EQ(e->code, Errc::limit_exceeded) << e->message;
    ASSERT_TRUE(e->handle.has_value());
    refused.insert(*e->handle);
    ++limited;
  }
  int acked = 0;
  for (auto h : hs)
    if (!refused.count(h) && c->wait_for_ack(h, 30s).ok()) ++acked;
  EXPECT_GT(limited, 0);
  EXPECT_EQ(acked + limited, 60);
  EXPECT_LE(acked, 21 + 5);  // the burst (one second's worth) plus what refilled meanwhile
  legit_strokes_ = static_cast<std::uint64_t>(acked);
}

TEST_F(ServerLimits, NonFiniteAndOutsidePositionsChangeNothing) {
  auto c = connect();
  ASSERT_TRUE(c);
  std::mt19937_64 rng(4);
  auto st = random_stroke(rng, 3);
  json j = {
      {"type", "stroke"},
      {"handle", 7},
      {"brush", {{"mode", "paint"}, {"colour", {1, 0, 0, 1}}, {"opacity", 1}, {"hardness", 0.5}}},
      {"samples", json::array({json::array({0.0, 0.0, 0.0, 0.05, 1, 0})})}};
  // First make sure this shape is a valid stroke (it is answered with an ack) ...
  ASSERT_TRUE(c->send_text(j.dump()).ok());
  ASSERT_TRUE(c->wait_for_ack(7, 30s).ok()) << "the reference stroke should be accepted";
  legit_strokes_ = 1;
  // ... then break one number at a time.
  std::string s = j.dump();
  auto with = [&](const std::string& from, const std::string& to) {
    std::string t = s;
    const auto at = t.find(from);
    EXPECT_NE(at, std::string::npos);
    t.replace(at, from.size(), to);
    return t;
  };
  ASSERT_TRUE(c->send_text(with("[[0.0,0.0,0.0,", "[[1e999,0.0,0.0,")).ok());
  auto e = c->wait_for_error(10s);
  ASSERT_TRUE(e.has_value());
  EXPECT_TRUE(e->code == Errc::invalid_argument || e->code == Errc::malformed) << e->message;
  ASSERT_TRUE(c->send_text(with("[[0.0,0.0,0.0,", "[[0.0,5.0,0.0,")).ok());  // outside 8 m
  expect_error(*c, Errc::invalid_argument, 7);
  st.samples[0].x = std::numeric_limits<double>::quiet_NaN();  // JSON encodes NaN as null
  auto h = c->send_stroke(st);
  e = c->wait_for_error(10s);
  ASSERT_TRUE(e.has_value());
  EXPECT_TRUE(e->code == Errc::invalid_argument || e->code == Errc::malformed) << e->message;
  EXPECT_EQ(e->handle, *h);
  auto pick = c->request_pick_up(0, 0, 1e9);
  expect_error(*c, Errc::invalid_argument, *pick);
  EXPECT_TRUE(c->is_open());
}

TEST_F(ServerLimits, MalformedJsonGarbageBinaryAndWrongDirectionAreAnswered) {
  auto c = connect();
  ASSERT_TRUE(c);
  ASSERT_TRUE(c->send_text("{\"type\": \"stroke\", ").ok());
  expect_error(*c, Errc::malformed);
  ASSERT_TRUE(c->send_text("[1,2,3]").ok());
  expect_error(*c, Errc::malformed);
  ASSERT_TRUE(c->send_text(R"({"type":"teleport"})").ok());
  expect_error(*c, Errc::malformed);
  ASSERT_TRUE(c->send_binary({0xde, 0xad, 0xbe, 0xef, 0, 1, 2, 3}).ok());
  expect_error(*c, Errc::malformed);
  ASSERT_TRUE(c->send_text(R"({"type":"epoch_end","epoch":5,"blocks":0,"caught_up":true})").ok());
  expect_error(*c, Errc::malformed);
  ASSERT_TRUE(c->send_text(R"({"type":"stroke_samples","handle":77,"samples":[)"
                           R"([0,0,0,0.05,1,0]]})")
                  .ok());
  expect_error(*c, Errc::not_found, 77);
  EXPECT_TRUE(c->is_open());
  // Still a working session afterwards.
  ASSERT_TRUE(c->request_stats().ok());
  EXPECT_TRUE(c->wait_for_stats(10s).ok());
}

}  // namespace
}  // namespace deepcanvas::test
