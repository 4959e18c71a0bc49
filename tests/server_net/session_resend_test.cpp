// Strokes resent with a client id (hello "client_id") over simulated reconnects, and the slots of
// streamed strokes the server ends: SessionHandler without sockets (fake_session.hpp) on a real
// CanvasService, several sessions sharing one StrokeReceipts as the server's sessions do.
#include <gtest/gtest.h>

#include <map>
#include <memory>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/server_net/session_handler.hpp"
#include "deepcanvas/server_net/stroke_receipts.hpp"
#include "fake_session.hpp"

namespace deepcanvas::test {
namespace {

namespace dp = protocol;
using server_core::Clock;
using server_net::SessionHandler;
using namespace std::chrono_literals;

using Connection = FakeConnection;

std::string hello(const std::string& client_id) {
  dp::Hello h;
  h.role = dp::Role::painter;
  h.token = "t";
  h.canvas = "c";
  h.client_name = "test";
  h.block_frames = false;
  h.client_id = client_id;
  return dp::encode_message(h);
}

// Overlapping strokes with translucent paint: painting one twice, or two in another order,
// changes the canvas.
dp::Stroke stroke_at(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> pos(-0.6, 0.6);
  std::uniform_real_distribution<float> unit(0.1f, 1.0f);
  dp::Stroke s;
  s.brush.colour[0] = unit(rng);
  s.brush.colour[1] = unit(rng);
  s.brush.colour[2] = unit(rng);
  s.brush.colour[3] = unit(rng);
  s.brush.opacity = 0.5f;
  const double x = pos(rng), y = pos(rng), z = pos(rng);
  for (int i = 0; i < 3; ++i)
    s.samples.push_back({x + 0.05 * i, y, z, 0.08f, 1.0f, static_cast<std::uint32_t>(i)});
  return s;
}

std::string stroke_message(std::uint64_t handle, const dp::Stroke& s) {
  return dp::encode_message(dp::StrokeMessage{handle, s});
}

class SessionResendTest : public ::testing::Test {
 protected:
  void SetUp() override {
    base::set_log_level(base::LogLevel::warn);
    config_.limits.max_strokes_per_second = 100000;
    config_.limits.max_samples_per_stroke = 20;
    config_.limits.max_open_strokes = 2;
  }

  std::unique_ptr<server_core::CanvasService> make_canvas() {
    server_core::CanvasServiceConfig cc;
    cc.name = "c";
    cc.octree.edge_m = 8.0;
    cc.octree.max_depth = 12;
    cc.stroke_limits.max_samples = config_.limits.max_samples_per_stroke;
    auto c = server_core::CanvasService::create(cc);
    EXPECT_TRUE(c.ok()) << c.error().message;
    return c ? std::move(*c) : nullptr;
  }

  // A new connection to `canvas` that has said hello (with `client_id`, may be empty).
  std::unique_ptr<Connection> connect(server_core::CanvasService* canvas,
                                      const std::string& client_id, bool with_receipts = true) {
    auto c = std::make_unique<Connection>();
    server_net::SessionContext ctx;
    ctx.config = &config_;
    ctx.metrics = &metrics_;
    ctx.find_canvas = [canvas](std::string_view name) { return name == "c" ? canvas : nullptr; };
    ctx.now = [] { return Clock::now(); };
    ctx.receipts = with_receipts ? receipts_.get() : nullptr;
    c->handler = std::make_unique<SessionHandler>(std::move(ctx), c->out, c->strand.poster(),
                                                  next_id_++, "test");
    c->text(hello(client_id));
    EXPECT_EQ(c->out.sent.size(), 1u);
    auto w = c->messages();
    EXPECT_TRUE(!w.empty() && std::holds_alternative<dp::Welcome>(w[0]));
    c->out.sent.clear();
    return c;
  }

  server_net::ServerConfig config_;
  server_net::ServerMetrics metrics_;
  std::unique_ptr<server_net::StrokeReceipts> receipts_ =
      std::make_unique<server_net::StrokeReceipts>();
  std::uint64_t next_id_ = 1;
};

TEST_F(SessionResendTest, WelcomeStatesTheReceiptWindowAndTheStrokeLimits) {
  auto canvas = make_canvas();
  for (bool with : {true, false}) {
    Connection c;
    server_net::SessionContext ctx;
    ctx.config = &config_;
    ctx.metrics = &metrics_;
    ctx.find_canvas = [&](std::string_view) { return canvas.get(); };
    ctx.receipts = with ? receipts_.get() : nullptr;
    c.handler = std::make_unique<SessionHandler>(std::move(ctx), c.out, c.strand.poster(), 1, "t");
    c.text(hello("p1"));
    auto m = c.messages();
    ASSERT_EQ(m.size(), 1u);
    const auto& limits = std::get<dp::Welcome>(m[0]).limits;
    EXPECT_EQ(limits.stroke_receipts, with ? receipts_->limits().per_client : 0u);
    // The canvas's limits on one stroke's work.
    EXPECT_EQ(limits.max_stroke_extent_m, canvas->stroke_rules().limits.max_extent_m);
    EXPECT_EQ(limits.max_stroke_cells, canvas->stroke_rules().limits.max_stroke_cells);
  }
}

TEST_F(SessionResendTest, AResentStrokeGetsTheFirstAckAndIsNotPaintedAgain) {
  auto canvas = make_canvas();
  std::mt19937_64 rng(1);
  const dp::Stroke s1 = stroke_at(rng), s2 = stroke_at(rng);
  auto a = connect(canvas.get(), "painter-1");
  a->text(stroke_message(1, s1));
  a->text(stroke_message(2, s2));
  ASSERT_TRUE(a->strand.run_until([&] { return a->acks().size() == 2; }));
  const auto first = a->acks();
  a->cut();
  // Reconnected: both resent, and a new one.
  auto b = connect(canvas.get(), "painter-1");
  b->text(stroke_message(1, s1));
  b->text(stroke_message(2, s2));
  b->text(stroke_message(3, stroke_at(rng)));
  ASSERT_TRUE(b->strand.run_until([&] { return b->acks().size() == 3; }));
  const auto again = b->acks();
  EXPECT_EQ(again[0].handle, 1u);
  EXPECT_EQ(again[0].stroke_id, first[0].stroke_id);
  EXPECT_EQ(again[0].epoch, first[0].epoch);
  EXPECT_EQ(again[1].stroke_id, first[1].stroke_id);
  EXPECT_EQ(again[2].handle, 3u);
  EXPECT_TRUE(b->errors().empty());
  auto q = canvas->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->strokes, 3u);

  // Another client id, the same handle: another stroke.
  auto other = connect(canvas.get(), "painter-2");
  other->text(stroke_message(1, s1));
  ASSERT_TRUE(other->strand.run_until([&] { return other->acks().size() == 1; }));
  EXPECT_NE(other->acks()[0].stroke_id, first[0].stroke_id);
  // Without a client id nothing is remembered: a resend is painted again.
  auto anon = connect(canvas.get(), "");
  anon->text(stroke_message(1, s1));
  anon->text(stroke_message(1, s1));
  ASSERT_TRUE(anon->strand.run_until([&] { return anon->acks().size() == 2; }));
  q = canvas->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->strokes, 6u);
}

TEST_F(SessionResendTest, AResendOfAStrokeInFlightGetsItsAckWhenItComes) {
  auto canvas = make_canvas();
  std::mt19937_64 rng(2);
  const dp::Stroke s = stroke_at(rng);
  auto a = connect(canvas.get(), "p");
  // A streamed stroke stays in flight until its end.
  a->text(dp::encode_message(dp::StrokeBegin{5, s.brush, s.samples}));
  auto b = connect(canvas.get(), "p");
  b->text(stroke_message(5, s));  // the same stroke, sent whole
  b->text(dp::encode_message(dp::StrokeBegin{5, s.brush, s.samples}));  // already claimed
  b->text(dp::encode_message(dp::StrokeSamples{5, s.samples}));         // dropped
  b->text(dp::encode_message(dp::StrokeEnd{5}));
  EXPECT_TRUE(b->out.sent.empty());  // nothing painted, nothing answered yet
  a->text(dp::encode_message(dp::StrokeEnd{5}));
  ASSERT_TRUE(a->strand.run_until([&] { return a->acks().size() == 1; }));
  ASSERT_TRUE(b->strand.run_until([&] { return b->acks().size() == 2; }));
  for (const auto& ack : b->acks()) {
    EXPECT_EQ(ack.handle, 5u);
    EXPECT_EQ(ack.stroke_id, a->acks()[0].stroke_id);
  }
  EXPECT_TRUE(b->errors().empty());
  auto q = canvas->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->strokes, 1u);
}

TEST_F(SessionResendTest, ABadStrokeIsNotRemembered) {
  auto canvas = make_canvas();
  std::mt19937_64 rng(3);
  dp::Stroke bad = stroke_at(rng);
  bad.samples[0].pressure = 0;
  auto a = connect(canvas.get(), "p");
  a->text(stroke_message(1, bad));  // refused by the decoder: never claimed
  ASSERT_EQ(a->errors().size(), 1u);
  a->text(stroke_message(1, stroke_at(rng)));  // a corrected stroke with the same handle
  ASSERT_TRUE(a->strand.run_until([&] { return a->acks().size() == 1; }));
  auto q = canvas->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->strokes, 1u);
}

// The property: a painter sends N strokes (handles 1..N, in order) over connections that break
// at random points. Each connection first resends, in order, every stroke it has no ack for,
// then sends new ones; the server reads a random prefix of what was sent (the rest is lost with
// the connection), and the client hears a random prefix of the replies the server wrote before
// the break. The last connection runs until every handle is acked. Then: every stroke painted
// exactly once (the canvas's stroke count, and its hash equal to a canvas that got each stroke
// once, in order), every ack of a handle names the same stroke_id, and no errors.
TEST_F(SessionResendTest, RandomReconnectsPaintEachStrokeExactlyOnce) {
  for (std::uint64_t seed = 1; seed <= 12; ++seed) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    std::mt19937_64 rng(seed);
    const std::size_t n = 10 + rng() % 20;
    std::vector<dp::Stroke> strokes;
    for (std::size_t i = 0; i < n; ++i) strokes.push_back(stroke_at(rng));

    receipts_ = std::make_unique<server_net::StrokeReceipts>();
    auto canvas = make_canvas();
    const std::string id = "painter-" + std::to_string(seed);
    std::map<std::uint64_t, std::uint64_t> acked;        // handle -> stroke_id, as the client heard
    std::map<std::uint64_t, std::set<std::uint64_t>> ids;  // every stroke_id seen per handle
    std::uint64_t next = 1;                                // the next new handle
    const int cuts = 2 + static_cast<int>(rng() % 2);

    const auto hear = [&](const Connection& c, std::size_t heard) {
      auto msgs = c.messages();
      for (std::size_t i = 0; i < msgs.size(); ++i) {
        if (const auto* e = std::get_if<dp::ErrorMessage>(&msgs[i]))
          ADD_FAILURE() << "error: " << e->message;
        const auto* a = std::get_if<dp::Ack>(&msgs[i]);
        if (!a) continue;
        ids[a->handle].insert(a->stroke_id);
        if (i < heard) acked[a->handle] = a->stroke_id;
      }
    };

    for (int k = 0; k <= cuts; ++k) {
      const bool last = k == cuts;
      auto c = connect(canvas.get(), id);
      std::vector<std::uint64_t> send;
      for (std::uint64_t h = 1; h < next; ++h)
        if (!acked.count(h)) send.push_back(h);
      const std::uint64_t until = last ? n + 1 : std::min<std::uint64_t>(n + 1, next + rng() % 12);
      for (; next < until; ++next) send.push_back(next);
      const std::size_t delivered = last ? send.size() : rng() % (send.size() + 1);
      for (std::size_t i = 0; i < delivered; ++i) {
        c->text(stroke_message(send[i], strokes[send[i] - 1]));
        if (rng() % 3 == 0) c->strand.run_queued(rng() % 3);  // some acks meanwhile
      }
      if (last) {
        ASSERT_TRUE(c->strand.run_until([&] {
          hear(*c, c->out.sent.size());
          std::size_t have = 0;
          for (std::uint64_t h = 1; h <= n; ++h) have += acked.count(h);
          return have == n;
        })) << acked.size() << " of " << n << " acked";
      } else {
        c->strand.run_queued(rng() % 4);
        hear(*c, rng() % (c->out.sent.size() + 1));
      }
      c->cut();
    }

    auto q = canvas->quiesce();
    ASSERT_TRUE(q.ok());
    EXPECT_EQ(q->strokes, n);
    std::set<std::uint64_t> distinct;
    for (const auto& [h, s] : ids) {
      EXPECT_EQ(s.size(), 1u) << "handle " << h << " acked with different stroke ids";
      distinct.insert(*s.begin());
    }
    EXPECT_EQ(distinct.size(), n);

    // The same strokes, each once, in order, on a fresh canvas.
    auto reference = make_canvas();
    auto r = connect(reference.get(), "");
    for (std::uint64_t h = 1; h <= n; ++h) r->text(stroke_message(h, strokes[h - 1]));
    ASSERT_TRUE(r->strand.run_until([&] { return r->acks().size() == n; }));
    auto rq = reference->quiesce();
    ASSERT_TRUE(rq.ok());
    EXPECT_EQ(q->canvas_hash, rq->canvas_hash);
    r->cut();
  }
}

// A streamed stroke whose connection closed before its end is ended by the canvas with the
// samples that came; its resend (the whole stroke, same client id and handle) takes that part
// back and paints the whole stroke, so the canvas is as if the whole stroke had come once.
TEST_F(SessionResendTest, AStrokeCutByAClosedConnectionIsPaintedWholeByItsResend) {
  std::mt19937_64 rng(6);
  dp::Stroke s = stroke_at(rng);
  s.samples.clear();
  for (std::uint32_t i = 0; i < 12; ++i)
    s.samples.push_back({0.05 * i - 0.3, 0.1, -0.2, 0.08f, 1.0f, i});
  const auto part = [&](std::size_t from, std::size_t n) {
    return std::vector<dp::StrokeSample>(s.samples.begin() + from, s.samples.begin() + from + n);
  };
  auto canvas = make_canvas();
  auto a = connect(canvas.get(), "p");
  a->text(dp::encode_message(dp::StrokeBegin{9, s.brush, part(0, 4)}));
  a->text(dp::encode_message(dp::StrokeSamples{9, part(4, 3)}));
  a->cut();
  auto cut = canvas->quiesce();  // the canvas ended it with 7 samples
  ASSERT_TRUE(cut.ok());
  ASSERT_EQ(cut->strokes, 1u);

  auto b = connect(canvas.get(), "p");
  b->text(stroke_message(9, s));
  ASSERT_TRUE(b->strand.run_until([&] { return b->acks().size() == 1; }));
  EXPECT_TRUE(b->errors().empty());
  auto q = canvas->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_NE(q->canvas_hash, cut->canvas_hash);

  auto reference = make_canvas();
  auto r = connect(reference.get(), "");
  r->text(stroke_message(1, s));
  ASSERT_TRUE(r->strand.run_until([&] { return r->acks().size() == 1; }));
  auto rq = reference->quiesce();
  ASSERT_TRUE(rq.ok());
  EXPECT_EQ(q->canvas_hash, rq->canvas_hash) << "the cut part was not withdrawn, or the rest is missing";

  // A second resend gets the same ack and paints nothing.
  auto c = connect(canvas.get(), "p");
  c->text(stroke_message(9, s));
  ASSERT_TRUE(c->strand.run_until([&] { return c->acks().size() == 1; }));
  EXPECT_EQ(c->acks()[0].stroke_id, b->acks()[0].stroke_id);
  auto q2 = canvas->quiesce();
  ASSERT_TRUE(q2.ok());
  EXPECT_EQ(q2->canvas_hash, q->canvas_hash);
}

// A connection that went silently still looks open to the server, while its client reconnects
// and resends the stroke it was painting: the resend waits for the first sending, and when that
// is ended short (the idle timeout, or its connection closing), the resend takes the stroke over:
// it withdraws the part and paints the stroke whole. The canvas ends as if the whole stroke had
// come once. A resend that closes before it could take over gives the claim back, and the next
// resend paints the stroke whole instead.
TEST_F(SessionResendTest, AResendWhileTheFirstSendingIsStillOpenPaintsTheStrokeWhole) {
  std::mt19937_64 rng(8);
  dp::Stroke s = stroke_at(rng);
  s.samples.clear();
  for (std::uint32_t i = 0; i < 12; ++i)
    s.samples.push_back({0.05 * i - 0.3, -0.1, 0.2, 0.08f, 1.0f, i});
  const auto part = [&](std::size_t from, std::size_t n) {
    return std::vector<dp::StrokeSample>(s.samples.begin() + from, s.samples.begin() + from + n);
  };
  auto reference = make_canvas();
  {
    auto r = connect(reference.get(), "");
    r->text(stroke_message(1, s));
    ASSERT_TRUE(r->strand.run_until([&] { return r->acks().size() == 1; }));
  }
  auto whole = reference->quiesce();
  ASSERT_TRUE(whole.ok());

  enum class Case { streamed_resend_idle_end, whole_resend_close, resend_closes_first };
  for (Case k : {Case::streamed_resend_idle_end, Case::whole_resend_close,
                 Case::resend_closes_first}) {
    SCOPED_TRACE(static_cast<int>(k));
    receipts_ = std::make_unique<server_net::StrokeReceipts>();
    auto canvas = make_canvas();
    auto a = connect(canvas.get(), "p");
    a->text(dp::encode_message(dp::StrokeBegin{9, s.brush, part(0, 4)}));
    a->text(dp::encode_message(dp::StrokeSamples{9, part(4, 3)}));
    // No quiesce here: it would wait for the idle timeout to end a's stroke. The resend below
    // claims it while it is open (the claim is made at once, on this thread).

    auto b = connect(canvas.get(), "p");
    if (k == Case::streamed_resend_idle_end) {
      b->text(dp::encode_message(dp::StrokeBegin{9, s.brush, part(0, 5)}));
      b->text(dp::encode_message(dp::StrokeSamples{9, part(5, 7)}));
      b->text(dp::encode_message(dp::StrokeEnd{9}));
    } else {
      b->text(stroke_message(9, s));
    }
    b->run();
    EXPECT_TRUE(b->acks().empty()) << "answered before the first sending settled";

    std::unique_ptr<Connection> answered_on;
    if (k == Case::streamed_resend_idle_end) {
      // a stays open and silent: the canvas's idle timeout ends its stroke.
      answered_on = std::move(b);
    } else if (k == Case::whole_resend_close) {
      a->cut();
      answered_on = std::move(b);
    } else {
      b->cut();  // the resend's own connection goes before it could take over
      a->cut();
      ASSERT_TRUE(canvas->quiesce().ok());
      answered_on = connect(canvas.get(), "p");
      answered_on->text(stroke_message(9, s));
    }
    ASSERT_TRUE(answered_on->strand.run_until([&] { return answered_on->acks().size() == 1; }));
    EXPECT_TRUE(answered_on->errors().empty());
    auto q = canvas->quiesce();
    ASSERT_TRUE(q.ok());
    EXPECT_EQ(q->canvas_hash, whole->canvas_hash)
        << "the cut part was not withdrawn, or the rest of the stroke is missing";

    // Another resend is answered with the same ack and paints nothing.
    auto c = connect(canvas.get(), "p");
    c->text(stroke_message(9, s));
    ASSERT_TRUE(c->strand.run_until([&] { return c->acks().size() == 1; }));
    EXPECT_EQ(c->acks()[0].stroke_id, answered_on->acks()[0].stroke_id);
    auto q2 = canvas->quiesce();
    ASSERT_TRUE(q2.ok());
    EXPECT_EQ(q2->canvas_hash, whole->canvas_hash);
    if (a->handler) a->cut();
  }
}

// A streamed stroke the server ends (here: no samples within the idle timeout) frees its slot
// at once; its late samples and its end are refused with the reason.
TEST_F(SessionResendTest, AStrokeTheServerEndedFreesItsSlot) {
  auto canvas = make_canvas();
  std::mt19937_64 rng(4);
  const dp::Stroke s = stroke_at(rng);
  auto a = connect(canvas.get(), "");
  a->text(dp::encode_message(dp::StrokeBegin{1, s.brush, s.samples}));
  a->text(dp::encode_message(dp::StrokeBegin{2, s.brush, s.samples}));
  a->text(dp::encode_message(dp::StrokeBegin{3, s.brush, s.samples}));  // over max_open_strokes
  ASSERT_EQ(a->errors().size(), 1u);
  EXPECT_EQ(a->errors()[0].code, Errc::limit_exceeded);
  // Both are ended by the canvas's idle timeout and acked.
  ASSERT_TRUE(a->strand.run_until([&] { return a->acks().size() == 2; }));
  a->out.sent.clear();
  a->text(dp::encode_message(dp::StrokeSamples{1, s.samples}));
  a->text(dp::encode_message(dp::StrokeEnd{2}));
  a->text(dp::encode_message(dp::StrokeEnd{2}));  // the handle is forgotten once ended
  a->text(dp::encode_message(dp::StrokeBegin{3, s.brush, s.samples}));  // room again
  a->text(dp::encode_message(dp::StrokeBegin{4, s.brush, s.samples}));
  auto errors = a->errors();
  ASSERT_EQ(errors.size(), 3u);
  EXPECT_EQ(errors[0].code, Errc::refused);
  EXPECT_EQ(errors[0].handle, 1u);
  EXPECT_NE(errors[0].message.find("is over: the server ended it after its idle timeout"),
            std::string::npos)
      << errors[0].message;
  EXPECT_EQ(errors[1].code, Errc::refused);
  EXPECT_EQ(errors[1].handle, 2u);
  EXPECT_EQ(errors[2].code, Errc::not_found);
  a->text(dp::encode_message(dp::StrokeEnd{3}));
  a->text(dp::encode_message(dp::StrokeEnd{4}));
  ASSERT_TRUE(a->strand.run_until([&] { return a->acks().size() == 2; }));
  EXPECT_EQ(a->errors().size(), 3u);
  auto q = canvas->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->strokes, 4u);
}

// A stroke the canvas answers with an error frees its slot too (here: too long).
TEST_F(SessionResendTest, AStrokeEndedForLengthFreesItsSlot) {
  auto canvas = make_canvas();
  std::mt19937_64 rng(5);
  const dp::Stroke s = stroke_at(rng);
  auto a = connect(canvas.get(), "");
  a->text(dp::encode_message(dp::StrokeBegin{1, s.brush, s.samples}));
  a->text(dp::encode_message(dp::StrokeBegin{2, s.brush, s.samples}));
  std::vector<dp::StrokeSample> many(18, s.samples[0]);
  a->text(dp::encode_message(dp::StrokeSamples{1, many}));  // past 20 in all: ended
  a->text(dp::encode_message(dp::StrokeBegin{3, s.brush, s.samples}));  // its slot is free
  a->text(dp::encode_message(dp::StrokeSamples{1, s.samples}));
  auto errors = a->errors();
  ASSERT_EQ(errors.size(), 2u);
  EXPECT_EQ(errors[0].code, Errc::limit_exceeded);
  EXPECT_EQ(errors[1].code, Errc::refused);
  EXPECT_EQ(errors[1].handle, 1u);
  EXPECT_NE(errors[1].message.find("when it passed 20 samples"), std::string::npos)
      << errors[1].message;
  a->text(dp::encode_message(dp::StrokeEnd{2}));
  a->text(dp::encode_message(dp::StrokeEnd{3}));
  ASSERT_TRUE(a->strand.run_until([&] { return a->acks().size() == 3; }));
}

}  // namespace
}  // namespace deepcanvas::test
