// CanvasService's streamed strokes: stroke_begin / samples / end, strokes of several artists
// taking turns (a stroke held open, an artist past its cell budget), pick-ups ordered after the
// strokes before them, and the strokes the server ends or refuses (idle, extent, stamp limits).
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>
#include <mutex>
#include <random>
#include <thread>
#include <vector>

#include "canvas_service_test_util.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

using server_core::CanvasService;
using server_core::Subscription;

TEST(CanvasService, StreamedStrokeIsPaintedAndAcked) {
  auto svc = make_service();
  ASSERT_TRUE(svc);
  std::mt19937_64 rng(5);
  auto s = random_stroke(rng, 9);
  std::promise<Result<server_core::StrokeDone>> p;
  auto f = p.get_future();
  std::vector<protocol::StrokeSample> first(s.samples.begin(), s.samples.begin() + 3);
  const auto rules = svc->stroke_rules();
  auto brush = protocol::ValidatedBrush::make(s.brush);
  auto head = protocol::ValidatedSamples::make(first, rules);
  auto middle =
      protocol::ValidatedSamples::make({s.samples.begin() + 3, s.samples.begin() + 6}, rules);
  auto tail = protocol::ValidatedSamples::make({s.samples.begin() + 6, s.samples.end()}, rules);
  ASSERT_TRUE(brush && head && middle && tail);
  auto key = svc->begin_stroke(*brush, std::move(*head), server_core::Clock::now(),
                               [&](Result<server_core::StrokeDone> r) { p.set_value(r); });
  ASSERT_TRUE(key.ok());
  ASSERT_TRUE(svc->add_samples(*key, std::move(*middle)).ok());
  ASSERT_TRUE(svc->add_samples(*key, std::move(*tail)).ok());
  ASSERT_TRUE(svc->end_stroke(*key).ok());
  ASSERT_EQ(f.wait_for(std::chrono::seconds(30)), std::future_status::ready);
  auto r = f.get();
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->stroke_id, *key);
  auto q = svc->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_GT(q->live_cells, 64u);
}

// A pick-up is ordered after the strokes queued before it: with tiny steps a stroke takes many
// stroke-thread iterations, and the pick-up submitted right behind it still sees its paint (and
// the same colour as a pick-up made once the canvas is quiet).
// One artist resting the pen (a streamed stroke held open) does not hold another up: B's whole
// stroke and a pick-up sent after it are answered while A's stroke is still open, and A goes on
// painting afterwards.
TEST(CanvasService, AStrokeHeldOpenDoesNotDelayAnotherArtistsStroke) {
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.idle_stroke_timeout = std::chrono::minutes(10);  // A stays open for the whole test
  auto created = CanvasService::create(cfg);
  ASSERT_TRUE(created.ok());
  auto& svc = **created;
  std::mt19937_64 rng(11);
  auto a = random_stroke(rng, 8);
  const auto rules = svc.stroke_rules();
  auto brush = protocol::ValidatedBrush::make(a.brush);
  auto head = protocol::ValidatedSamples::make({a.samples.begin(), a.samples.begin() + 4}, rules);
  auto tail = protocol::ValidatedSamples::make({a.samples.begin() + 4, a.samples.end()}, rules);
  ASSERT_TRUE(brush && head && tail);
  std::promise<Result<server_core::StrokeDone>> a_done, b_done;
  std::promise<Result<protocol::PickUpReply>> picked;
  auto key = svc.begin_stroke(
      *brush, std::move(*head), server_core::Clock::now(),
      [&](Result<server_core::StrokeDone> r) { a_done.set_value(r); }, 1);
  ASSERT_TRUE(key.ok());
  ASSERT_TRUE(submit(
                  svc, random_stroke(rng, 20),
                  [&](Result<server_core::StrokeDone> r) { b_done.set_value(r); }, 2)
                  .ok());
  protocol::PickUp pick;
  pick.request_id = 3;
  ASSERT_TRUE(
      svc.pick_up(pick, [&](Result<protocol::PickUpReply> r) { picked.set_value(std::move(r)); })
          .ok());
  auto bf = b_done.get_future();
  ASSERT_EQ(bf.wait_for(std::chrono::seconds(60)), std::future_status::ready);
  auto b = bf.get();
  ASSERT_TRUE(b.ok()) << b.error().message;
  EXPECT_FALSE(b->idle_ended);
  auto pf = picked.get_future();
  ASSERT_EQ(pf.wait_for(std::chrono::seconds(60)), std::future_status::ready);
  EXPECT_TRUE(pf.get().ok());
  auto af = a_done.get_future();
  EXPECT_EQ(af.wait_for(std::chrono::milliseconds(0)), std::future_status::timeout);  // still open
  ASSERT_TRUE(svc.add_samples(*key, std::move(*tail)).ok());
  ASSERT_TRUE(svc.end_stroke(*key).ok());
  ASSERT_EQ(af.wait_for(std::chrono::seconds(60)), std::future_status::ready);
  auto ar = af.get();
  ASSERT_TRUE(ar.ok());
  EXPECT_FALSE(ar->idle_ended);
  EXPECT_LT(ar->stroke_id, b->stroke_id);
  auto q = svc.quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->strokes, 2u);
}

// An artist past its cell growth budget waits for it to refill while another artist paints: B's
// stroke, sent after A's two, is acked before A's first (whose end waits for A's budget).
TEST(CanvasService, AnArtistPastItsCellBudgetWaitsAndOthersPaint) {
  base::set_log_level(base::LogLevel::warn);
  std::mt19937_64 rng(17);
  const auto a1 = random_stroke(rng, 12), b = random_stroke(rng, 4);
  const auto a2 = a1;  // over a1's cells: creates few
  auto cfg = small_canvas("c");
  // What a1 creates, painted alone: the budget is a quarter of it, so a1's first turn (two thirds
  // of its samples) leaves A in debt for about a second or more.
  std::uint64_t cells = 0;
  {
    auto tree = server_core::Octree::create(cfg.octree);
    ASSERT_TRUE(tree.ok());
    auto painter = server_core::Painter::create(**tree);
    ASSERT_TRUE(painter.ok());
    auto st = (*painter)->apply_stroke(a1);
    ASSERT_TRUE(st.ok());
    cells = st->cells_created;
  }
  ASSERT_GT(cells, 1000u);
  cfg.max_cells_per_second_per_artist = static_cast<double>(cells) / 4;
  // a1 takes two turns: its begin with 8 samples, then its last 4 with its end.
  cfg.samples_per_turn = 8;
  cfg.turn_seconds = 0;
  auto created = CanvasService::create(cfg);
  ASSERT_TRUE(created.ok());
  auto& svc = **created;
  std::mutex m;
  std::vector<std::uint64_t> order;  // stroke ids as acked
  auto ack = [&](Result<server_core::StrokeDone> r) {
    ASSERT_TRUE(r.ok()) << r.error().message;
    std::lock_guard lock(m);
    order.push_back(r->stroke_id);
  };
  ASSERT_TRUE(submit(svc, a1, ack, 1).ok());
  ASSERT_TRUE(submit(svc, a2, ack, 1).ok());
  ASSERT_TRUE(submit(svc, b, ack, 2).ok());
  auto q = svc.quiesce(std::chrono::seconds(120));
  ASSERT_TRUE(q.ok());
  std::lock_guard lock(m);
  ASSERT_EQ(order.size(), 3u);
  EXPECT_EQ(order[0], 3u);  // B's
  EXPECT_EQ(order[1], 1u);
  EXPECT_EQ(order[2], 2u);
  EXPECT_GE(svc.metrics().throttled_turns.value(), 1u);
}

// A heavy stroke's turns shrink to what fits turn_seconds while another artist's stroke waits
// (to one sample here: the bound is far below any sample's cost), and grow back to
// samples_per_turn once it is alone. The split is what the events record, so a replay paints
// the same turns.
TEST(CanvasService, AHeavyStrokesTurnsShrinkWhileAnotherArtistWaits) {
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.samples_per_turn = 64;
  cfg.turn_seconds = 1e-9;
  EventLog log;
  log.attach(cfg);
  auto created = CanvasService::create(cfg);
  ASSERT_TRUE(created.ok());
  auto& svc = **created;
  const auto line = [](std::size_t n, float radius, double y) {
    protocol::Stroke s;
    s.brush.mode = protocol::BrushMode::paint;
    s.brush.colour[0] = 1;
    s.brush.colour[3] = 1;
    s.brush.opacity = 1;
    s.brush.hardness = 1;
    for (std::size_t i = 0; i < n; ++i)
      s.samples.push_back({-0.4 + 0.8 * static_cast<double>(i) / static_cast<double>(n), y, 0.05,
                           radius, 1.0f, static_cast<std::uint32_t>(i)});
    return s;
  };
  std::atomic<int> acked{0};
  const auto ack = [&](Result<server_core::StrokeDone> r) {
    EXPECT_TRUE(r.ok());
    ++acked;
  };
  ASSERT_TRUE(submit(svc, line(200, 0.1f, 0.0), ack, 1).ok());   // heavy: stroke 1
  ASSERT_TRUE(submit(svc, line(100, 0.01f, 0.3), ack, 2).ok());  // light: stroke 2
  ASSERT_TRUE(svc.quiesce(std::chrono::seconds(120)).ok());
  EXPECT_EQ(acked.load(), 2);
  std::lock_guard lock(log.mutex);
  const auto& events = log.events;
  using Kind = server_core::StrokeEvent::Kind;
  std::size_t light_begin = events.size(), light_end = events.size();
  for (std::size_t i = 0; i < events.size(); ++i) {
    if (events[i].stroke_id != 2) continue;
    if (events[i].kind == Kind::begin) light_begin = i;
    if (events[i].kind == Kind::end) light_end = i;
  }
  ASSERT_LT(light_begin, light_end);
  std::size_t shrunk = 0, grown = 0, heavy_samples = 0;
  for (std::size_t i = 0; i < events.size(); ++i) {
    if (events[i].stroke_id != 1) continue;
    heavy_samples += events[i].samples.size();
    if (events[i].kind != Kind::samples) continue;
    if (i > light_begin && i < light_end) {
      EXPECT_EQ(events[i].samples.size(), 1u) << "event " << i << ": the light stroke waits";
      ++shrunk;
    } else if (i > light_end && events[i].samples.size() > 1) {
      ++grown;
    }
  }
  EXPECT_EQ(heavy_samples, 200u);
  EXPECT_GE(shrunk, 10u);
  EXPECT_GE(grown, 1u) << "alone again, the heavy stroke gets whole turns";
}

TEST(CanvasService, PickUpIsAnsweredAfterTheStrokesBeforeIt) {
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.max_cells_per_step = 8;  // hundreds of steps per stroke
  auto created = CanvasService::create(cfg);
  ASSERT_TRUE(created.ok());
  auto& svc = **created;
  for (int round = 0; round < 3; ++round) {
    protocol::Stroke s;
    s.brush.mode = protocol::BrushMode::paint;
    const float rgb[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (int c = 0; c < 3; ++c) s.brush.colour[c] = rgb[round][c];
    s.brush.colour[3] = 1.0f;
    s.brush.opacity = 1;
    s.brush.hardness = 1;
    for (int i = 0; i < 5; ++i)
      s.samples.push_back({-0.2 + 0.1 * i, 0.05, 0.05, 0.15f, 1.0f, static_cast<std::uint32_t>(i)});
    std::promise<Result<server_core::StrokeDone>> acked;
    std::promise<Result<protocol::PickUpReply>> picked;
    ASSERT_TRUE(submit(svc, s, [&](Result<server_core::StrokeDone> r) {
                  acked.set_value(std::move(r));
                }).ok());
    protocol::PickUp pick;
    pick.request_id = 7;
    pick.position[0] = 0.0;
    pick.position[1] = 0.05;
    pick.position[2] = 0.05;
    ASSERT_TRUE(
        svc.pick_up(pick, [&](Result<protocol::PickUpReply> r) { picked.set_value(std::move(r)); })
            .ok());
    auto pf = picked.get_future();
    ASSERT_EQ(pf.wait_for(std::chrono::seconds(60)), std::future_status::ready);
    auto reply = pf.get();
    ASSERT_TRUE(reply.ok()) << reply.error().message;
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(reply->colour[c], rgb[round][c], 0.02) << "round " << round << " channel " << c;
    EXPECT_GT(reply->density, 0.5f);
    ASSERT_TRUE(acked.get_future().get().ok());
    ASSERT_TRUE(svc.quiesce().ok());
    std::promise<Result<protocol::PickUpReply>> again;
    ASSERT_TRUE(
        svc.pick_up(pick, [&](Result<protocol::PickUpReply> r) { again.set_value(std::move(r)); })
            .ok());
    auto a = again.get_future().get();
    ASSERT_TRUE(a.ok());
    for (int c = 0; c < 3; ++c) EXPECT_EQ(a->colour[c], reply->colour[c]);
    EXPECT_EQ(a->density, reply->density);
    EXPECT_EQ(a->depth, reply->depth);
  }
}


// ---- streamed strokes the server ends, and bounded strokes (issue 26) ----

using AckPromise = std::promise<Result<server_core::StrokeDone>>;

protocol::ValidatedSamples valid_samples(const CanvasService& svc,
                                         std::vector<protocol::StrokeSample> samples) {
  auto v = protocol::ValidatedSamples::make(std::move(samples), svc.stroke_rules());
  EXPECT_TRUE(v.ok()) << (v ? "" : v.error().message);
  return v ? std::move(*v) : protocol::ValidatedSamples{};
}

// An idle streamed stroke is ended by the server: its sender gets the ack (idle_ended, its paint
// is kept), the stroke is no longer open (so a session can release its slot), and a piece or an
// end sent for it later is answered at once with an error naming the idle end.
TEST(CanvasService, IdleEndedStrokeIsAckedAndItsLatePiecesGetAnError) {
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.idle_stroke_timeout = std::chrono::milliseconds(50);
  auto created = CanvasService::create(cfg);
  ASSERT_TRUE(created.ok());
  auto& svc = **created;
  std::mt19937_64 rng(11);
  auto s = random_stroke(rng, 4);
  auto brush = protocol::ValidatedBrush::make(s.brush);
  ASSERT_TRUE(brush.ok());
  AckPromise acked;
  auto f = acked.get_future();
  auto key = svc.begin_stroke(*brush, valid_samples(svc, s.samples), server_core::Clock::now(),
                              [&](Result<server_core::StrokeDone> r) { acked.set_value(r); });
  ASSERT_TRUE(key.ok());
  ASSERT_EQ(f.wait_for(std::chrono::seconds(60)), std::future_status::ready);
  auto r = f.get();
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r->stroke_id, *key);
  EXPECT_TRUE(r->idle_ended);
  auto late = svc.add_samples(*key, valid_samples(svc, {s.samples.back()}));
  ASSERT_FALSE(late.ok());
  EXPECT_EQ(late.error().code, Errc::refused);
  EXPECT_NE(late.error().message.find("without samples"), std::string::npos)
      << late.error().message;
  auto end = svc.end_stroke(*key);
  ASSERT_FALSE(end.ok());
  EXPECT_EQ(end.error().code, Errc::refused);
  // A key never begun, and one its sender ended, are not_found.
  auto unknown = svc.add_samples(*key + 1000, valid_samples(svc, {s.samples.back()}));
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.error().code, Errc::not_found);
  auto q = svc.quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->strokes, 1u);
  EXPECT_GT(q->live_cells, 64u);  // its paint was kept
}

// A stroke that keeps getting samples within the timeout is not ended, however long it lasts.
TEST(CanvasService, AStrokeWithSamplesWithinTheTimeoutIsNotIdleEnded) {
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.idle_stroke_timeout = std::chrono::seconds(30);
  auto created = CanvasService::create(cfg);
  ASSERT_TRUE(created.ok());
  auto& svc = **created;
  std::mt19937_64 rng(12);
  auto s = random_stroke(rng, 8);
  auto brush = protocol::ValidatedBrush::make(s.brush);
  ASSERT_TRUE(brush.ok());
  AckPromise acked;
  auto f = acked.get_future();
  auto key = svc.begin_stroke(*brush, valid_samples(svc, {s.samples[0]}),
                              server_core::Clock::now(),
                              [&](Result<server_core::StrokeDone> r) { acked.set_value(r); });
  ASSERT_TRUE(key.ok());
  for (std::size_t i = 1; i < s.samples.size(); ++i)
    ASSERT_TRUE(svc.add_samples(*key, valid_samples(svc, {s.samples[i]})).ok());
  ASSERT_TRUE(svc.end_stroke(*key).ok());
  ASSERT_EQ(f.wait_for(std::chrono::seconds(60)), std::future_status::ready);
  auto r = f.get();
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->idle_ended);
  auto again = svc.end_stroke(*key);  // ended by its sender: no longer open
  ASSERT_FALSE(again.ok());
  EXPECT_EQ(again.error().code, Errc::not_found);
}

// A piece that would take a streamed stroke's box past max_extent_m is refused at once; the
// stroke keeps what it has, goes on and is acked.
TEST(CanvasService, AStreamedPiecePastTheExtentIsRefused) {
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.stroke_limits.max_extent_m = 1.0;
  auto created = CanvasService::create(cfg);
  ASSERT_TRUE(created.ok());
  auto& svc = **created;
  protocol::Brush b;
  auto brush = protocol::ValidatedBrush::make(b);
  ASSERT_TRUE(brush.ok());
  AckPromise acked;
  auto f = acked.get_future();
  auto key = svc.begin_stroke(*brush, valid_samples(svc, {{0.0, 0.1, 0.1, 0.05f, 1.0f, 0}}),
                              server_core::Clock::now(),
                              [&](Result<server_core::StrokeDone> r) { acked.set_value(r); });
  ASSERT_TRUE(key.ok());
  auto far = svc.add_samples(*key, valid_samples(svc, {{0.0, 0.1, 1.5, 0.05f, 1.0f, 1}}));
  ASSERT_FALSE(far.ok());
  EXPECT_EQ(far.error().code, Errc::limit_exceeded);
  EXPECT_NE(far.error().message.find("max_extent_m"), std::string::npos) << far.error().message;
  ASSERT_TRUE(svc.add_samples(*key, valid_samples(svc, {{0.5, 0.1, 0.1, 0.05f, 1.0f, 2}})).ok());
  ASSERT_TRUE(svc.end_stroke(*key).ok());
  ASSERT_EQ(f.wait_for(std::chrono::seconds(60)), std::future_status::ready);
  EXPECT_TRUE(f.get().ok());
}

// The issue's stroke: 2 samples from (10,10,10) to (-10000,10,10), radius 0.05. Refused up front
// by its extent; with the extent limit lifted, stopped by the per-stroke cell limit with
// limit_exceeded, the canvas bounded and valid, and the next stroke acked.
TEST(CanvasService, TheIssuesAttackStrokeIsRefusedOrStoppedAndOthersGoOn) {
  base::set_log_level(base::LogLevel::error);
  protocol::Stroke attack;
  attack.brush.mode = protocol::BrushMode::paint;
  attack.samples = {{10, 10, 10, 0.05f, 1.0f, 0}, {-10000, 10, 10, 0.05f, 1.0f, 16}};
  auto cfg = small_canvas("c");
  cfg.octree.edge_m = 20000.0;  // the server's default canvas
  cfg.octree.max_depth = 24;
  cfg.octree.max_cells = 1u << 22;
  {
    auto created = CanvasService::create(cfg);
    ASSERT_TRUE(created.ok());
    auto r = submit(**created, attack, [](auto) {});
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::limit_exceeded);
    EXPECT_NE(r.error().message.find("max_extent_m"), std::string::npos) << r.error().message;
  }
  cfg.stroke_limits.max_extent_m = 1e9;
  cfg.stroke_limits.max_stroke_cells = 100000;
  auto created = CanvasService::create(cfg);
  ASSERT_TRUE(created.ok());
  auto& svc = **created;
  const auto before = svc.quiesce();
  ASSERT_TRUE(before.ok());
  AckPromise stopped, next;
  ASSERT_TRUE(submit(svc, attack, [&](Result<server_core::StrokeDone> r) {
                stopped.set_value(r);
              }).ok());
  protocol::Stroke ok;
  ok.samples = {{1, 1, 1, 0.05f, 1.0f, 0}, {1.5, 1, 1, 0.05f, 1.0f, 1}};
  ASSERT_TRUE(submit(svc, ok, [&](Result<server_core::StrokeDone> r) { next.set_value(r); }).ok());
  auto sf = stopped.get_future();
  ASSERT_EQ(sf.wait_for(std::chrono::seconds(120)), std::future_status::ready);
  auto sr = sf.get();
  ASSERT_FALSE(sr.ok());
  EXPECT_EQ(sr.error().code, Errc::limit_exceeded);
  EXPECT_NE(sr.error().message.find("max_stroke_cells"), std::string::npos)
      << sr.error().message;
  auto nf = next.get_future();
  ASSERT_EQ(nf.wait_for(std::chrono::seconds(120)), std::future_status::ready);
  EXPECT_TRUE(nf.get().ok());
  const auto after = svc.quiesce();
  ASSERT_TRUE(after.ok());
  EXPECT_LE(after->live_cells, before->live_cells + 100000 + 20000);
}

// Streamed samples that take a stroke past its stamp limit stop it: its sender gets the
// error instead of the ack, the canvas keeps what it painted, and later pieces are refused.
TEST(CanvasService, SamplesPastTheStampLimitStopTheStrokeWithAnError) {
  base::set_log_level(base::LogLevel::error);
  auto cfg = small_canvas("c");
  cfg.stamps.max_stamps = 64;
  auto created = CanvasService::create(cfg);
  ASSERT_TRUE(created.ok());
  auto& svc = **created;
  protocol::Brush b;
  auto brush = protocol::ValidatedBrush::make(b);
  ASSERT_TRUE(brush.ok());
  AckPromise acked;
  auto f = acked.get_future();
  auto key = svc.begin_stroke(*brush,
                              valid_samples(svc, {{0.0, 0.1, 0.1, 0.05f, 1.0f, 0},
                                                  {0.2, 0.1, 0.1, 0.05f, 1.0f, 1}}),
                              server_core::Clock::now(),
                              [&](Result<server_core::StrokeDone> r) { acked.set_value(r); });
  ASSERT_TRUE(key.ok());
  // The first piece is being painted once an epoch carries its blocks (else both pieces could
  // reach the painter together, and the stroke be refused at its start instead).
  const auto deadline = server_core::Clock::now() + std::chrono::seconds(60);
  while (svc.published_epoch() == 0 && server_core::Clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  ASSERT_GT(svc.published_epoch(), 0u);
  // 3 m at a 0.01 m radius: ~300 stamps.
  ASSERT_TRUE(svc.add_samples(*key, valid_samples(svc, {{3.0, 0.1, 0.1, 0.01f, 1.0f, 2},
                                                        {3.1, 0.1, 0.1, 0.01f, 1.0f, 3}}))
                  .ok());
  ASSERT_EQ(f.wait_for(std::chrono::seconds(60)), std::future_status::ready);
  auto r = f.get();
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::limit_exceeded);
  auto late = svc.add_samples(*key, valid_samples(svc, {{3.2, 0.1, 0.1, 0.01f, 1.0f, 4}}));
  ASSERT_FALSE(late.ok());
  EXPECT_EQ(late.error().code, Errc::refused);
  EXPECT_NE(late.error().message.find("stopped"), std::string::npos) << late.error().message;
  auto q = svc.quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_GT(q->live_cells, 64u);  // the first samples' paint was kept
}

}  // namespace
}  // namespace deepcanvas::test
