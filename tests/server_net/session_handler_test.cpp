// SessionHandler without sockets: a fake transport and strand (fake_session.hpp) and a fake
// clock that drives the rate limit. The canvas is a real CanvasService (no network).
#include <gtest/gtest.h>

#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_net/session_handler.hpp"
#include "fake_session.hpp"

namespace deepcanvas::test {
namespace {

namespace dp = protocol;
using server_core::Clock;
using server_net::CloseCode;
using server_net::SessionHandler;
using namespace std::chrono_literals;

dp::Message decode(const std::string& text) {
  auto m = dp::decode_message(text);
  EXPECT_TRUE(m.ok()) << text;
  return m ? std::move(*m) : dp::Message{};
}

std::string hello(dp::Role role = dp::Role::painter, const std::string& token = "paint-token",
                  const std::string& canvas = "c", bool block_frames = false) {
  dp::Hello h;
  h.role = role;
  h.token = token;
  h.canvas = canvas;
  h.client_name = "test";
  h.block_frames = block_frames;
  return dp::encode_message(h);
}

dp::Stroke stroke(int samples = 3, double x0 = -0.5) {
  dp::Stroke s;
  s.brush.colour[0] = 0.8f;
  for (int i = 0; i < samples; ++i)
    s.samples.push_back({x0 + 0.1 * i, 0.1, -0.2, 0.05f, 1.0f, static_cast<std::uint32_t>(i)});
  return s;
}

std::string stroke_message(std::uint64_t handle, const dp::Stroke& s) {
  return dp::encode_message(dp::StrokeMessage{handle, s});
}

class SessionHandlerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    base::set_log_level(base::LogLevel::warn);
    config_.limits.max_strokes_per_second = 1000;
    config_.limits.max_samples_per_stroke = 20;
    config_.limits.max_open_strokes = 2;
  }

  // A handler on canvas "c" (8 m, depth 12); `tokens`: the tokens file, empty for open access.
  void start(const std::string& tokens = "") {
    if (!tokens.empty()) {
      auto t = server_net::TokenTable::parse(tokens);
      ASSERT_TRUE(t.ok()) << t.error().message;
      config_.tokens = std::move(*t);
    }
    server_core::CanvasServiceConfig cc;
    cc.name = "c";
    cc.octree.edge_m = 8.0;
    cc.octree.max_depth = 12;
    // The server gives every canvas the session limits' stroke limits (Server::create).
    cc.stroke_limits.max_samples = config_.limits.max_samples_per_stroke;
    cc.stroke_limits.min_radius_m = config_.limits.min_radius_m;
    cc.stroke_limits.max_radius_m = config_.limits.max_radius_m;
    auto c = server_core::CanvasService::create(cc);
    ASSERT_TRUE(c.ok()) << c.error().message;
    canvas_ = std::move(*c);
    server_net::SessionContext ctx;
    ctx.config = &config_;
    ctx.metrics = &metrics_;
    ctx.find_canvas = [this](std::string_view name) {
      return name == "c" ? canvas_.get() : nullptr;
    };
    ctx.now = [this] { return now_; };
    ctx.fanout = fanout_;
    handler_ = std::make_unique<SessionHandler>(std::move(ctx), out_, strand_.poster(), 1, "test");
  }

  void text(const std::string& message) { handler_->on_message(true, message); }

  // The sent item at `i` as a decoded message (text, or the close's last message).
  dp::Message at(std::size_t i) {
    EXPECT_LT(i, out_.sent.size());
    return i < out_.sent.size() ? decode(out_.sent[i].text) : dp::Message{};
  }
  // The error at `i`, checked for its code, handle and fatality.
  void expect_error(std::size_t i, Errc code, std::optional<std::uint64_t> handle = {},
                    bool fatal = false) {
    auto m = at(i);
    const auto* e = std::get_if<dp::ErrorMessage>(&m);
    ASSERT_NE(e, nullptr) << "item " << i << ": " << out_.sent[i].text;
    EXPECT_EQ(e->code, code) << e->message;
    EXPECT_EQ(e->handle, handle) << e->message;
    EXPECT_EQ(e->fatal, fatal) << e->message;
    EXPECT_EQ(out_.sent[i].kind == Sent::Kind::close, fatal);
  }
  std::size_t count(Sent::Kind kind) const {
    std::size_t n = 0;
    for (const auto& s : out_.sent) n += s.kind == kind;
    return n;
  }
  // Runs the strand until `n` acks (or errors about strokes) have been sent in all.
  bool wait_for_replies(std::size_t n) {
    return strand_.run_until([&] {
      std::size_t got = 0;
      for (const auto& s : out_.sent) {
        auto m = dp::decode_message(s.text);
        if (m &&
            (std::holds_alternative<dp::Ack>(*m) || std::holds_alternative<dp::PickUpReply>(*m)))
          ++got;
      }
      return got >= n;
    });
  }
  void open_session() {
    start();
    text(hello());
    ASSERT_EQ(out_.sent.size(), 1u);
    ASSERT_TRUE(std::holds_alternative<dp::Welcome>(at(0)));
    out_.sent.clear();
  }

  server_net::ServerConfig config_;
  server_net::ServerMetrics metrics_;
  std::unique_ptr<server_core::CanvasService> canvas_;
  FakeOutput out_;
  FakeStrand strand_;
  Clock::time_point now_ = Clock::now();
  std::shared_ptr<server_net::FanoutGate> fanout_;  // set before start(): the handler's gate
  std::unique_ptr<SessionHandler> handler_;  // declared last: gone before the canvas
};

constexpr const char* kTokens =
    "c painter paint-token\n"
    "c viewer view-token\n";

TEST_F(SessionHandlerTest, HelloIsAnsweredWithWelcomeThenTheSnapshot) {
  start(kTokens);
  EXPECT_TRUE(handler_->awaiting_hello());
  text(hello(dp::Role::viewer, "paint-token", "c", true));  // a painter token may view
  EXPECT_FALSE(handler_->awaiting_hello());
  ASSERT_GE(out_.sent.size(), 1u);
  auto m = at(0);
  const auto* w = std::get_if<dp::Welcome>(&m);
  ASSERT_NE(w, nullptr);
  EXPECT_EQ(w->role, dp::Role::viewer);
  EXPECT_EQ(w->canvas, "c");
  EXPECT_EQ(w->geometry.edge_m, 8.0);
  EXPECT_EQ(w->limits.max_open_strokes, 2u);
  EXPECT_EQ(metrics_.sessions_opened.value(), 1u);
  // The snapshot comes as one batch, posted by the subscription; the next waits for its write.
  ASSERT_TRUE(strand_.run_until([&] { return count(Sent::Kind::batch) == 1; }));
  const Sent& batch = out_.sent.back();
  EXPECT_GT(batch.frames, 0u);
  auto end = decode(batch.text);
  ASSERT_TRUE(std::holds_alternative<dp::EpochEnd>(end));
  EXPECT_EQ(std::get<dp::EpochEnd>(end).blocks, batch.frames);
  handler_->on_batch_written();
  EXPECT_EQ(count(Sent::Kind::batch), 1u);  // nothing new published
}

// hello "batch_interval_ms": the snapshot goes at once; what is published within the interval
// after it waits for the batch timer and then goes as one batch of the newest epoch.
TEST_F(SessionHandlerTest, BatchIntervalCoalescesWhatIsPublishedMeanwhile) {
  start();
  dp::Hello h;
  h.role = dp::Role::painter;
  h.token = "t";
  h.canvas = "c";
  h.block_frames = true;
  h.batch_interval_ms = 100;
  text(dp::encode_message(h));
  ASSERT_TRUE(strand_.run_until([&] { return count(Sent::Kind::batch) == 1; }));
  handler_->on_batch_written();
  EXPECT_TRUE(out_.batch_timer) << "the next batch waits for the interval";
  EXPECT_EQ(out_.batch_timer_delay, 100ms);
  for (std::uint64_t i = 1; i <= 3; ++i) text(stroke_message(i, stroke(3, -0.6 + 0.3 * static_cast<double>(i))));
  ASSERT_TRUE(wait_for_replies(3));
  std::uint64_t last = 0;
  for (const auto& s : out_.sent)
    if (auto m = dp::decode_message(s.text); m && std::holds_alternative<dp::Ack>(*m))
      last = std::max(last, std::get<dp::Ack>(*m).epoch);
  ASSERT_TRUE(strand_.run_until([&] { return canvas_->published_epoch() >= last; }));
  strand_.run_queued(100);
  EXPECT_EQ(count(Sent::Kind::batch), 1u) << "nothing goes before the interval is up";
  now_ += 100ms;
  ASSERT_TRUE(out_.fire_batch_timer());
  ASSERT_EQ(count(Sent::Kind::batch), 2u);
  const Sent* second = nullptr;
  for (const auto& s : out_.sent)
    if (s.kind == Sent::Kind::batch) second = &s;
  auto end = decode(second->text);
  ASSERT_TRUE(std::holds_alternative<dp::EpochEnd>(end));
  EXPECT_GE(std::get<dp::EpochEnd>(end).epoch, last) << "the three strokes' epochs in one batch";
  EXPECT_GT(second->frames, 0u);
  // Written at once: the next one waits for the interval again.
  handler_->on_batch_written();
  EXPECT_EQ(count(Sent::Kind::batch), 2u);
  EXPECT_TRUE(out_.batch_timer);
}

// The fanout gate (fanout_gate.hpp): a batch take waits for a slot while every slot is held,
// replies do not wait for it, and the take runs once the slot comes back, giving it back after.
TEST_F(SessionHandlerTest, BatchesWaitForAFanoutSlotAndRepliesDoNot) {
  fanout_ = std::make_shared<server_net::FanoutGate>(1);
  auto held = fanout_->try_acquire();
  ASSERT_TRUE(held);
  start();
  text(hello(dp::Role::painter, "t", "c", true));
  strand_.run_queued(100);
  EXPECT_EQ(count(Sent::Kind::batch), 0u) << "the snapshot waits for the slot";
  EXPECT_EQ(fanout_->waiting(), 1u);
  text(stroke_message(1, stroke(3, 0.1)));
  ASSERT_TRUE(wait_for_replies(1)) << "the ack does not wait for the gate";
  EXPECT_EQ(count(Sent::Kind::batch), 0u);
  EXPECT_EQ(fanout_->waiting(), 1u) << "one place in the queue however many publishes";
  held.reset();  // the slot goes to the waiting session, which takes on its strand
  ASSERT_TRUE(strand_.run_until([&] { return count(Sent::Kind::batch) == 1; }));
  EXPECT_EQ(fanout_->free_slots(), 1u) << "given back after the take";
  EXPECT_EQ(fanout_->waiting(), 0u);
  // The next batch (the stroke's epoch) takes the free slot at once.
  handler_->on_batch_written();
  ASSERT_TRUE(strand_.run_until([&] { return count(Sent::Kind::batch) == 2; }));
  EXPECT_EQ(fanout_->free_slots(), 1u);
}

// A session that ends while it waits for a slot passes the slot on when its turn comes.
TEST_F(SessionHandlerTest, ASessionGoneWhileWaitingForAFanoutSlotPassesItOn) {
  fanout_ = std::make_shared<server_net::FanoutGate>(1);
  auto held = fanout_->try_acquire();
  start();
  text(hello(dp::Role::viewer, "t", "c", true));
  strand_.run_queued(100);
  ASSERT_EQ(fanout_->waiting(), 1u);
  bool next_got_it = false;
  fanout_->acquire([&](server_net::FanoutGate::SlotRef) { next_got_it = true; });
  strand_.drop();  // the connection is gone; what is posted to it is dropped
  held.reset();
  EXPECT_TRUE(next_got_it) << "the gone session's slot went on to the next waiter";
  EXPECT_EQ(fanout_->free_slots(), 1u);
  EXPECT_EQ(fanout_->waiting(), 0u);
}

TEST_F(SessionHandlerTest, RefusedHellosAreFatal) {
  struct Case {
    std::string message;
    Errc code;
  };
  const std::vector<Case> cases = {
      {hello(dp::Role::painter, "wrong-token"), Errc::unauthorized},
      {hello(dp::Role::painter, "view-token"), Errc::unauthorized},  // role not allowed
      {hello(dp::Role::painter, "paint-token", "elsewhere"), Errc::not_found},
      {R"({"type":"hello","protocol_version":2,"role":"painter","token":"paint-token",)"
       R"("canvas":"c","client_name":"x"})",
       Errc::unsupported},
      {R"({"type":"stats_request"})", Errc::malformed},  // not a hello first
      {"{not json", Errc::malformed},
  };
  for (const auto& c : cases) {
    out_.sent.clear();
    handler_.reset();
    canvas_.reset();
    config_.tokens.reset();
    start(kTokens);
    text(c.message);
    ASSERT_EQ(out_.sent.size(), 1u) << c.message;
    expect_error(0, c.code, std::nullopt, true);
    EXPECT_EQ(out_.sent[0].code, CloseCode::policy_error);
    EXPECT_EQ(out_.sent[0].reason, errc_name(c.code));
    EXPECT_TRUE(handler_->closing());
    text(hello());  // nothing more is read
    EXPECT_EQ(out_.sent.size(), 1u);
  }
  EXPECT_EQ(metrics_.sessions_refused.value(), cases.size());
  EXPECT_EQ(metrics_.sessions_opened.value(), 0u);
}

TEST_F(SessionHandlerTest, NoHelloInTimeAndBinaryFirstAreFatal) {
  start();
  handler_->on_hello_timeout();
  ASSERT_EQ(out_.sent.size(), 1u);
  expect_error(0, Errc::refused, std::nullopt, true);

  out_.sent.clear();
  handler_.reset();
  canvas_.reset();
  start();
  handler_->on_message(false, "\x01\x02");
  ASSERT_EQ(out_.sent.size(), 1u);
  expect_error(0, Errc::malformed, std::nullopt, true);
}

TEST_F(SessionHandlerTest, TimeoutAfterTheHelloIsIgnored) {
  open_session();
  handler_->on_hello_timeout();
  EXPECT_TRUE(out_.sent.empty());
  EXPECT_FALSE(handler_->closing());
}

TEST_F(SessionHandlerTest, OversizedMessageClosesWithTooBig) {
  open_session();
  handler_->on_message_too_big();
  ASSERT_EQ(out_.sent.size(), 1u);
  expect_error(0, Errc::limit_exceeded, std::nullopt, true);
  EXPECT_EQ(out_.sent[0].code, CloseCode::too_big);
}

TEST_F(SessionHandlerTest, BadMessagesAfterTheHelloAreAnsweredAndTheSessionGoesOn) {
  open_session();
  text("{\"type\": \"stroke\", ");                                        // not JSON
  text(R"({"type":"teleport"})");                                         // unknown type
  text(R"({"type":"epoch_end","epoch":5,"blocks":0,"caught_up":true})");  // wrong direction
  text(hello());                                                          // a second hello
  handler_->on_message(false, "\xde\xad");                                // binary
  dp::Stroke outside = stroke();
  outside.samples[1].y = 5.0;  // outside the 8 m canvas
  text(stroke_message(7, outside));
  text(stroke_message(8, stroke(21)));  // more than max_samples_per_stroke (20)
  text(R"({"type":"pick_up","request_id":9,"position":[0,0,100]})");
  text(R"({"type":"stats_request"})");
  ASSERT_EQ(out_.sent.size(), 9u);
  expect_error(0, Errc::malformed);
  expect_error(1, Errc::malformed);
  expect_error(2, Errc::malformed);
  expect_error(3, Errc::refused);
  expect_error(4, Errc::malformed);
  expect_error(5, Errc::invalid_argument, 7);
  expect_error(6, Errc::limit_exceeded, 8);
  expect_error(7, Errc::invalid_argument, 9);
  auto m = at(8);
  const auto* st = std::get_if<dp::Stats>(&m);
  ASSERT_NE(st, nullptr);
  EXPECT_EQ(st->blocks_sent, 3u);  // the transport's counters
  EXPECT_EQ(st->bytes_sent, 300u);
  EXPECT_EQ(st->queue_blocks, 2u);  // no subscription: only the transport's queue
  EXPECT_FALSE(handler_->closing());
  EXPECT_EQ(metrics_.errors_sent.value(), 8u);
  EXPECT_EQ(metrics_.messages_in.value(), 1u + 9u);
  auto q = canvas_->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->strokes, 0u);  // nothing bad reached the canvas
}

TEST_F(SessionHandlerTest, ViewersMayNotPaint) {
  start(kTokens);
  text(hello(dp::Role::viewer, "view-token"));
  out_.sent.clear();
  text(stroke_message(1, stroke()));
  dp::StrokeBegin b{2, stroke().brush, {}};
  text(dp::encode_message(b));
  text(R"({"type":"stats_request"})");
  ASSERT_EQ(out_.sent.size(), 3u);
  expect_error(0, Errc::unauthorized, 1);
  expect_error(1, Errc::unauthorized, 2);
  EXPECT_TRUE(std::holds_alternative<dp::Stats>(at(2)));
  EXPECT_FALSE(handler_->closing());  // a viewer may keep watching
}

TEST_F(SessionHandlerTest, StrokeRateIsLimited) {
  config_.limits.max_strokes_per_second = 2;  // a burst of 2, then 2 a second
  open_session();
  for (std::uint64_t h = 1; h <= 3; ++h) text(stroke_message(h, stroke()));
  ASSERT_EQ(out_.sent.size(), 1u);
  expect_error(0, Errc::limit_exceeded, 3);
  now_ += 500ms;  // one token back
  text(stroke_message(4, stroke()));
  text(stroke_message(5, stroke()));
  ASSERT_EQ(out_.sent.size(), 2u);
  expect_error(1, Errc::limit_exceeded, 5);
  ASSERT_TRUE(wait_for_replies(3));  // 1, 2 and 4 are painted
  auto q = canvas_->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->strokes, 3u);
}

TEST_F(SessionHandlerTest, OpenStreamedStrokesAreLimited) {
  open_session();
  const dp::Stroke s = stroke(6);
  const std::vector<dp::StrokeSample> first(s.samples.begin(), s.samples.begin() + 2);
  text(dp::encode_message(dp::StrokeBegin{1, s.brush, first}));
  text(dp::encode_message(dp::StrokeBegin{2, s.brush, first}));
  text(dp::encode_message(dp::StrokeBegin{3, s.brush, first}));  // a third open one
  text(dp::encode_message(dp::StrokeBegin{2, s.brush, first}));  // already open
  text(dp::encode_message(dp::StrokeSamples{4, first}));         // never begun
  text(dp::encode_message(dp::StrokeEnd{4}));
  ASSERT_EQ(out_.sent.size(), 4u);
  expect_error(0, Errc::limit_exceeded, 3);
  expect_error(1, Errc::invalid_argument, 2);
  expect_error(2, Errc::not_found, 4);
  expect_error(3, Errc::not_found, 4);
  text(dp::encode_message(dp::StrokeEnd{1}));
  text(dp::encode_message(dp::StrokeBegin{3, s.brush, first}));  // room again
  EXPECT_EQ(out_.sent.size(), 4u);
  // A streamed stroke past max_samples_per_stroke (20) is ended with what it has.
  const dp::Stroke long_one = stroke(19);
  text(dp::encode_message(dp::StrokeSamples{2, long_one.samples}));
  ASSERT_EQ(out_.sent.size(), 5u);
  expect_error(4, Errc::limit_exceeded, 2);
  text(dp::encode_message(dp::StrokeEnd{3}));
  ASSERT_TRUE(wait_for_replies(3));  // 1, 2 (ended by the limit) and 3
}

TEST_F(SessionHandlerTest, RepliesKeepTheirOrder) {
  open_session();
  // Immediate replies (errors, stats) come in the order of the requests; acks once painted, in
  // the canvas's stroke order, each naming its handle; the pick-up once the strokes before it
  // are painted (it sees them).
  text(stroke_message(10, stroke(3, -0.5)));
  dp::Stroke bad = stroke();
  bad.samples[0].pressure = 0;
  text(stroke_message(11, bad));
  text(stroke_message(12, stroke(3, 0.0)));
  text(R"({"type":"stats_request"})");
  text(R"({"type":"pick_up","request_id":13,"position":[-0.4,0.1,-0.2]})");
  text(stroke_message(14, stroke(3, 0.5)));
  ASSERT_EQ(out_.sent.size(), 2u);
  expect_error(0, Errc::invalid_argument, 11);
  EXPECT_TRUE(std::holds_alternative<dp::Stats>(at(1)));
  ASSERT_TRUE(wait_for_replies(4));
  ASSERT_EQ(out_.sent.size(), 6u);
  std::vector<std::uint64_t> handles, ids;
  int picks = 0;
  for (std::size_t i = 2; i < 6; ++i) {
    auto m = at(i);
    if (const auto* a = std::get_if<dp::Ack>(&m)) {
      handles.push_back(a->handle);
      ids.push_back(a->stroke_id);
    } else if (const auto* p = std::get_if<dp::PickUpReply>(&m)) {
      ++picks;
      EXPECT_EQ(p->request_id, 13u);
      EXPECT_GT(p->density, 0.5f);
    }
  }
  EXPECT_EQ(picks, 1);
  EXPECT_EQ(handles, (std::vector<std::uint64_t>{10, 12, 14}));
  EXPECT_EQ(ids, (std::vector<std::uint64_t>{1, 2, 3}));
}

TEST_F(SessionHandlerTest, AClientThatDoesNotReadIsDisconnected) {
  open_session();
  out_.full = true;
  text(R"({"type":"stats_request"})");
  ASSERT_EQ(out_.sent.size(), 1u);
  expect_error(0, Errc::limit_exceeded, std::nullopt, true);
  EXPECT_TRUE(handler_->closing());
}

TEST_F(SessionHandlerTest, ClosingEndsOpenStrokesAndDropsLateReplies) {
  open_session();
  const dp::Stroke s = stroke(4);
  text(dp::encode_message(dp::StrokeBegin{1, s.brush, s.samples}));
  handler_->on_shutdown();
  text(R"({"type":"stats_request"})");
  handler_->on_closed({});
  auto q = canvas_->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->strokes, 1u);  // the open stroke was ended, so it was painted
  // Its ack was posted; run on the strand it sends nothing (the session is over).
  strand_.run_until([] { return false; }, 200ms);
  EXPECT_TRUE(out_.sent.empty());
}

}  // namespace
}  // namespace deepcanvas::test
