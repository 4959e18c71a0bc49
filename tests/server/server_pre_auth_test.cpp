// The pre-authentication budget (ServerConfig): caps on connections without an accepted hello
// (per client address and in total), the hello deadline, the small frame limit before hello, and
// the deadline for finishing a started message. Real sockets on loopback; client addresses are
// told apart by connecting from 127.0.0.2, 127.0.0.3, ... (all loopback on Linux).
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>
#include <thread>

#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

using client_core::Client;
using json = nlohmann::json;

constexpr const char* kHello =
    R"({"type":"hello","protocol_version":1,"role":"painter","token":"paint-token",)"
    R"("canvas":"c","client_name":"pre-auth-test","block_frames":false})";

// The next text message that is an error, or a null json when the connection ended first.
json next_error(RawWs& ws, std::chrono::milliseconds timeout = 20s) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    auto text = ws.read_text(std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now()));
    if (!text) return {};
    auto j = json::parse(*text, nullptr, false);
    if (j.is_object() && j.value("type", "") == "error") return j;
  }
  return {};
}

// A painter from 127.0.0.1 connects, paints one stroke and gets its ack.
void expect_painter_paints(const TestServer& s) {
  auto c = Client::connect(client_options(s));
  ASSERT_TRUE(c.ok()) << c.error().message;
  std::mt19937_64 rng(5);
  auto h = (*c)->send_stroke(random_stroke(rng, 4));
  ASSERT_TRUE(h.ok());
  EXPECT_TRUE((*c)->wait_for_ack(*h, 30s).ok());
  (*c)->close();
}

// Closes the test's connections and waits until the server has finished their sessions, so the
// server stops with none open. Stopping with sessions mid-close can trip Beast's one-write-at-a-
// time assertion in debug builds (a known shutdown race, not what these tests check).
void close_and_settle(const TestServer& s, std::vector<std::unique_ptr<RawWs>>& connections) {
  connections.clear();
  for (int i = 0; i < 1000 && s.server->metrics().sessions.value() != 0; ++i)
    std::this_thread::sleep_for(10ms);
}

TEST(ServerPreAuth, PerAddressCapRefusesTheSeventeenthWhileAPainterPaints) {
  auto s = start_server({"c"}, kTokens, {}, 0, [](server_net::ServerConfig& c) {
    c.hello_timeout = std::chrono::minutes(5);  // the idle connections stay for the whole test
  });
  ASSERT_TRUE(s.server);
  std::vector<std::unique_ptr<RawWs>> idle;
  for (int i = 0; i < 16; ++i) {
    auto ws = RawWs::connect(s, "127.0.0.2");
    ASSERT_TRUE(ws) << "connection " << i;
    idle.push_back(std::move(ws));
  }
  EXPECT_EQ(s.server->metrics().unauthenticated.value(), 16);
  int status = 0;
  EXPECT_FALSE(RawWs::connect(s, "127.0.0.2", &status));
  EXPECT_EQ(status, 503);
  EXPECT_EQ(s.server->metrics().connections_refused.value(), 1u);
  // Another address is not affected, and neither is a painter once it is authenticated.
  expect_painter_paints(s);
  EXPECT_TRUE(RawWs::connect(s, "127.0.0.3"));
  // One of the sixteen says hello: it no longer counts, so 127.0.0.2 may open one more.
  ASSERT_TRUE(idle[0]->send_text(kHello));
  auto welcome = idle[0]->read_text();
  ASSERT_TRUE(welcome.has_value());
  EXPECT_EQ(json::parse(*welcome)["type"], "welcome");
  // The place is released on the server's strand after the welcome is queued: wait for it.
  bool admitted = false;
  for (int i = 0; i < 200 && !admitted; ++i) {
    admitted = RawWs::connect(s, "127.0.0.2") != nullptr;
    if (!admitted) std::this_thread::sleep_for(50ms);
  }
  EXPECT_TRUE(admitted);
  close_and_settle(s, idle);
}

TEST(ServerPreAuth, AtTheTotalCapTheOldestUnauthenticatedConnectionMakesRoom) {
  auto s = start_server({"c"}, kTokens, {}, 0, [](server_net::ServerConfig& c) {
    c.hello_timeout = std::chrono::minutes(5);
    c.max_unauthenticated = 4;
  });
  ASSERT_TRUE(s.server);
  std::vector<std::unique_ptr<RawWs>> idle;
  for (const char* from : {"127.0.0.2", "127.0.0.2", "127.0.0.3", "127.0.0.4"}) {
    idle.push_back(RawWs::connect(s, from));
    ASSERT_TRUE(idle.back()) << from;
  }
  // A fifth address is admitted, and the oldest connection without a hello is closed for it:
  // a flood from many addresses cannot lock artists out until the hello deadline.
  auto fifth = RawWs::connect(s, "127.0.0.5");
  ASSERT_TRUE(fifth);
  const auto t0 = std::chrono::steady_clock::now();
  idle.front()->read_until_closed(20s);  // the first one ends, long before the hello deadline
  EXPECT_LT(std::chrono::steady_clock::now() - t0, 10s);
  EXPECT_EQ(s.server->metrics().connections_evicted.value(), 1u);
  EXPECT_EQ(s.server->metrics().connections_refused.value(), 0u);
  for (int i = 0; i < 200 && s.server->metrics().unauthenticated.value() != 4; ++i)
    std::this_thread::sleep_for(10ms);
  EXPECT_EQ(s.server->metrics().unauthenticated.value(), 4);
  idle.erase(idle.begin());
  idle.push_back(std::move(fifth));
  close_and_settle(s, idle);
}

TEST(ServerPreAuth, NoHelloWithinTheDeadlineIsClosedWithAReason) {
  auto s = start_server({"c"}, kTokens, {}, 0, [](server_net::ServerConfig& c) {
    c.hello_timeout = std::chrono::milliseconds(300);
  });
  ASSERT_TRUE(s.server);
  auto ws = RawWs::connect(s);
  ASSERT_TRUE(ws);
  const auto t0 = std::chrono::steady_clock::now();
  auto e = next_error(*ws);
  ASSERT_TRUE(e.is_object()) << "no error before the close";
  EXPECT_EQ(e["code"], "refused");
  EXPECT_EQ(e["fatal"], true);
  EXPECT_NE(e["message"].get<std::string>().find("no hello within 0.3 s"), std::string::npos)
      << e["message"];
  EXPECT_EQ(ws->read_until_closed(), 1008);
  EXPECT_LT(std::chrono::steady_clock::now() - t0, 20s);
  // The server releases the connection's place once its side of the close is done.
  for (int i = 0; i < 500 && s.server->metrics().unauthenticated.value() != 0; ++i)
    std::this_thread::sleep_for(10ms);
  EXPECT_EQ(s.server->metrics().unauthenticated.value(), 0);
}

// A message larger than the pre-hello limit is refused as soon as the limit is passed: the
// message here never ends, so an answer proves the server did not wait to buffer all of it.
TEST(ServerPreAuth, OversizedPreHelloFrameIsRefusedWithoutBufferingIt) {
  auto s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  auto ws = RawWs::connect(s);
  ASSERT_TRUE(ws);
  ASSERT_TRUE(ws->send_partial(R"({"type":"hello","pad":")" + std::string(20 * 1024, 'x')));
  auto e = next_error(*ws);
  ASSERT_TRUE(e.is_object()) << "no error before the close";
  EXPECT_EQ(e["code"], "limit_exceeded");
  EXPECT_EQ(e["fatal"], true);
  EXPECT_NE(e["message"].get<std::string>().find("16384 bytes allowed before hello"),
            std::string::npos)
      << e["message"];
  EXPECT_EQ(ws->read_until_closed(), 1009);
}

TEST(ServerPreAuth, AfterHelloTheFullFrameLimitApplies) {
  auto s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  auto c = Client::connect(client_options(s));
  ASSERT_TRUE(c.ok()) << c.error().message;
  // About 24 KiB: over the pre-hello limit, well under max_frame_bytes.
  std::mt19937_64 rng(6);
  auto h = (*c)->send_stroke(random_stroke(rng, 400));
  ASSERT_TRUE(h.ok());
  EXPECT_TRUE((*c)->wait_for_ack(*h, 30s).ok());
  EXPECT_TRUE((*c)->is_open());
}

TEST(ServerPreAuth, UnfinishedMessageAfterHelloIsClosedAtTheDeadline) {
  auto s = start_server({"c"}, kTokens, {}, 0, [](server_net::ServerConfig& c) {
    c.message_timeout = std::chrono::milliseconds(400);
  });
  ASSERT_TRUE(s.server);
  auto ws = RawWs::connect(s);
  ASSERT_TRUE(ws);
  ASSERT_TRUE(ws->send_text(kHello));
  auto welcome = ws->read_text();
  ASSERT_TRUE(welcome.has_value());
  ASSERT_EQ(json::parse(*welcome)["type"], "welcome");
  ASSERT_TRUE(ws->send_partial(R"({"type":"stats_request",)"));
  auto e = next_error(*ws);
  ASSERT_TRUE(e.is_object()) << "no error before the close";
  EXPECT_EQ(e["code"], "limit_exceeded");
  EXPECT_NE(e["message"].get<std::string>().find("message not finished within 0.4 s"),
            std::string::npos)
      << e["message"];
  EXPECT_EQ(ws->read_until_closed(), 1008);
}

}  // namespace
}  // namespace deepcanvas::test
