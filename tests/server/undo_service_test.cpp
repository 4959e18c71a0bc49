// Undo and redo through the canvas (CanvasService::undo) and over the wire (PROTOCOL.md 3.10):
// each artist takes back its own strokes whoever painted since, redo restores, the errors
// (nothing to undo, redo after a new stroke, the history bound, a viewer), the events replay to
// the same canvas, and the history survives a restart and a reconnect.
#include <gtest/gtest.h>

#include <future>
#include <random>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/server_core/event_replay.hpp"
#include "deepcanvas/storage/durable_canvas.hpp"
#include "../storage/storage_test_util.hpp"
#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

using server_core::CanvasService;
using server_core::StrokeEvent;
using server_core::UndoDone;

// A stroke of `n` samples at height z (strokes at different heights do not touch).
protocol::Stroke stroke_at(double z, float r = 0.1f, float red = 1.0f) {
  protocol::Stroke s;
  s.brush.colour[0] = red;
  s.brush.colour[1] = 0.3f;
  s.brush.colour[2] = 0.2f;
  for (int i = 0; i < 6; ++i) s.samples.push_back({-0.5 + 0.2 * i, 0.1 * i, z, r, 1.0f, 0});
  return s;
}

// Paints `s` as `artist` and waits for the ack; returns the stroke id.
std::uint64_t paint(CanvasService& svc, protocol::Stroke s, std::uint64_t artist) {
  auto v = protocol::ValidatedStroke::make(std::move(s), svc.stroke_rules());
  EXPECT_TRUE(v.ok());
  std::promise<Result<server_core::StrokeDone>> p;
  auto f = p.get_future();
  auto r = svc.submit_stroke(
      std::move(*v), server_core::Clock::now(),
      [&p](Result<server_core::StrokeDone> d) { p.set_value(std::move(d)); }, artist);
  EXPECT_TRUE(r.ok()) << (r ? "" : r.error().message);
  if (!r) return 0;
  EXPECT_EQ(f.wait_for(30s), std::future_status::ready);
  auto d = f.get();
  EXPECT_TRUE(d.ok()) << (d ? "" : d.error().message);
  return d ? d->stroke_id : 0;
}

Result<UndoDone> undo(CanvasService& svc, std::uint64_t artist, bool redo = false) {
  std::promise<Result<UndoDone>> p;
  auto f = p.get_future();
  auto r = svc.undo(artist, redo, server_core::Clock::now(),
                    [&p](Result<UndoDone> d) { p.set_value(std::move(d)); });
  if (!r) return std::move(r).error();
  if (f.wait_for(30s) != std::future_status::ready) return make_error(Errc::internal, "timeout");
  return f.get();
}

std::uint64_t canvas_hash(CanvasService& svc) {
  auto q = svc.quiesce();
  EXPECT_TRUE(q.ok());
  return q ? q->canvas_hash : 0;
}

TEST(UndoService, EachArtistUndoesItsOwnStrokesAndRedoRestoresThem) {
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  std::vector<StrokeEvent> events;
  std::mutex events_mutex;
  cfg.on_stroke_event = [&](const StrokeEvent& e) {
    std::lock_guard lock(events_mutex);
    events.push_back(e);
  };
  auto made = CanvasService::create(cfg);
  ASSERT_TRUE(made.ok());
  CanvasService& svc = **made;
  const std::uint64_t A = 1, B = 2;
  const std::uint64_t empty = canvas_hash(svc);
  const std::uint64_t a1 = paint(svc, stroke_at(-1.0), A);
  const std::uint64_t after_a1 = canvas_hash(svc);
  const std::uint64_t b1 = paint(svc, stroke_at(0.0, 0.1f, 0.2f), B);
  const std::uint64_t after_b1 = canvas_hash(svc);
  const std::uint64_t a2 = paint(svc, stroke_at(1.0), A);
  const std::uint64_t after_a2 = canvas_hash(svc);

  auto u = undo(svc, A);  // a2, the latest of A's
  ASSERT_TRUE(u.ok()) << u.error().message;
  EXPECT_EQ(u->stroke_id, a2);
  EXPECT_FALSE(u->redo);
  EXPECT_EQ(canvas_hash(svc), after_b1);
  u = undo(svc, A);  // a1, though B painted after it: B's stroke stays
  ASSERT_TRUE(u.ok()) << u.error().message;
  EXPECT_EQ(u->stroke_id, a1);
  const std::uint64_t only_b1 = canvas_hash(svc);
  EXPECT_NE(only_b1, after_b1);
  auto none = undo(svc, A);
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.error().code, Errc::not_found);

  u = undo(svc, A, true);  // redo a1
  ASSERT_TRUE(u.ok()) << u.error().message;
  EXPECT_EQ(u->stroke_id, a1);
  EXPECT_TRUE(u->redo);
  EXPECT_EQ(canvas_hash(svc), after_b1);
  u = undo(svc, A, true);  // redo a2
  ASSERT_TRUE(u.ok());
  EXPECT_EQ(u->stroke_id, a2);
  EXPECT_EQ(canvas_hash(svc), after_a2);
  auto no_redo = undo(svc, A, true);
  ASSERT_FALSE(no_redo.ok());
  EXPECT_EQ(no_redo.error().code, Errc::not_found);

  // B undoes b1 under A's strokes; a new stroke of A clears A's redo side, not B's.
  u = undo(svc, B);
  ASSERT_TRUE(u.ok());
  EXPECT_EQ(u->stroke_id, b1);
  ASSERT_TRUE(undo(svc, A).ok());
  (void)paint(svc, stroke_at(1.5), A);
  auto cleared = undo(svc, A, true);
  ASSERT_FALSE(cleared.ok());
  EXPECT_EQ(cleared.error().code, Errc::not_found);
  EXPECT_NE(cleared.error().message.find("new stroke"), std::string::npos);
  u = undo(svc, B, true);
  ASSERT_TRUE(u.ok()) << u.error().message;
  EXPECT_EQ(u->stroke_id, b1);
  const std::uint64_t final_hash = canvas_hash(svc);
  (void)empty;
  (void)after_a1;

  // The recorded events (undo and redo included) replay to the same canvas.
  svc.stop();
  auto tree = server_core::Octree::create(cfg.octree);
  ASSERT_TRUE(tree.ok());
  auto painter = server_core::Painter::create(**tree, server_core::painter_config(cfg));
  ASSERT_TRUE(painter.ok());
  const auto t = server_core::replay_stroke_events(**painter, events);
  EXPECT_EQ(t.rejected, 0u);
  EXPECT_EQ(t.undos, 7u);
  EXPECT_EQ((*tree)->canvas_hash(), final_hash);
}

TEST(UndoService, TheHistoryKeepsTheLastDepthStrokes) {
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.undo.depth = 3;
  auto made = CanvasService::create(cfg);
  ASSERT_TRUE(made.ok());
  CanvasService& svc = **made;
  for (int i = 0; i < 5; ++i) (void)paint(svc, stroke_at(-1.5 + 0.5 * i), 9);
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(undo(svc, 9).ok());
  auto past = undo(svc, 9);
  ASSERT_FALSE(past.ok());
  EXPECT_EQ(past.error().code, Errc::limit_exceeded);
  EXPECT_NE(past.error().message.find("last 3 strokes"), std::string::npos);
}

TEST(UndoService, AStrokeTooLargeToKeepCannotBeUndone) {
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.undo.max_stroke_bytes = 64;  // every stroke's change is larger
  auto made = CanvasService::create(cfg);
  ASSERT_TRUE(made.ok());
  CanvasService& svc = **made;
  (void)paint(svc, stroke_at(0), 3);
  const std::uint64_t h = canvas_hash(svc);
  auto r = undo(svc, 3);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::limit_exceeded);
  EXPECT_EQ(canvas_hash(svc), h);
}

// The history is in the checkpoint and in the events: after a restart the artist undoes what it
// painted before it, and the whole history replays to the same canvas.
TEST(UndoService, TheHistorySurvivesARestart) {
  base::set_log_level(base::LogLevel::warn);
  TempDir dir;
  const std::uint64_t A = 42;
  std::uint64_t s2 = 0, after_s1 = 0, after_s2 = 0, after_s3_undone = 0;
  {
    auto svc = storage::open_durable_canvas(dir.path(), small_canvas("c"), {}, false, nullptr);
    ASSERT_TRUE(svc.ok()) << svc.error().message;
    (void)paint(**svc, stroke_at(-1.0), A);
    after_s1 = canvas_hash(**svc);
    s2 = paint(**svc, stroke_at(0.0), A);
    after_s2 = canvas_hash(**svc);
    (void)paint(**svc, stroke_at(1.0), A);
    ASSERT_TRUE(undo(**svc, A).ok());
    after_s3_undone = canvas_hash(**svc);
    EXPECT_EQ(after_s3_undone, after_s2);
  }
  storage::RestoreReport rep;
  auto svc = storage::open_durable_canvas(dir.path(), small_canvas("c"), {}, false, &rep);
  ASSERT_TRUE(svc.ok()) << svc.error().message;
  EXPECT_NE(rep.checkpoint_id, 0u);
  EXPECT_EQ(canvas_hash(**svc), after_s2);
  auto u = undo(**svc, A);
  ASSERT_TRUE(u.ok()) << u.error().message;
  EXPECT_EQ(u->stroke_id, s2);
  EXPECT_EQ(canvas_hash(**svc), after_s1);
  auto r = undo(**svc, A, true);  // redo s2
  ASSERT_TRUE(r.ok()) << r.error().message;
  r = undo(**svc, A, true);  // redo s3, undone before the restart
  ASSERT_TRUE(r.ok()) << r.error().message;
  const std::uint64_t final_hash = canvas_hash(**svc);
  (*svc)->stop();
  svc->reset();
  auto replayed = storage::replay_history(dir.path() + "/c.canvas", small_canvas("c"), 0);
  ASSERT_TRUE(replayed.ok()) << replayed.error().message;
  EXPECT_EQ(replayed->totals.rejected, 0u);
  EXPECT_EQ(replayed->tree->canvas_hash(), final_hash);
}

// Over the wire: a painter's undo and redo answers, a viewer refused, and a reconnect with the
// same client id undoes the strokes of the connection before.
TEST(UndoService, OverTheWireWithAClientIdAcrossAReconnect) {
  base::set_log_level(base::LogLevel::warn);
  TestServer s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  auto opts = client_options(s);
  opts.client_id = "alice";
  std::uint64_t first_id = 0;
  {
    auto c = client_core::Client::connect(opts);
    ASSERT_TRUE(c.ok()) << c.error().message;
    EXPECT_EQ((*c)->welcome().limits.undo_depth, 100u);
    EXPECT_GT((*c)->welcome().limits.undo_max_stroke_bytes, 0u);
    auto h1 = (*c)->send_stroke(stroke_at(-1.0));
    auto h2 = (*c)->send_stroke(stroke_at(1.0));
    ASSERT_TRUE(h1.ok() && h2.ok());
    auto a1 = (*c)->wait_for_ack(*h1, 30s);
    ASSERT_TRUE(a1.ok());
    first_id = a1->stroke_id;
    ASSERT_TRUE((*c)->wait_for_ack(*h2, 30s).ok());
    auto u = (*c)->request_undo();
    ASSERT_TRUE(u.ok());
    auto r = (*c)->wait_for_undo(*u, 30s);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_EQ(r->stroke_id, first_id + 1);
    EXPECT_FALSE(r->redo);
  }
  {
    auto c = client_core::Client::connect(opts);  // the same client id: the same artist
    ASSERT_TRUE(c.ok());
    auto u = (*c)->request_undo();
    auto r = (*c)->wait_for_undo(*u, 30s);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_EQ(r->stroke_id, first_id);
    u = (*c)->request_undo();
    r = (*c)->wait_for_undo(*u, 30s);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::not_found);
    u = (*c)->request_undo(true);
    r = (*c)->wait_for_undo(*u, 30s);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_TRUE(r->redo);
    EXPECT_EQ(r->stroke_id, first_id);
  }
  auto viewer = client_core::Client::connect(
      client_options(s, "c", protocol::Role::viewer, "view-token"));
  ASSERT_TRUE(viewer.ok());
  auto u = (*viewer)->request_undo();
  auto r = (*viewer)->wait_for_undo(*u, 30s);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::unauthorized);
}

// Undo floods are limited like strokes: past max_strokes_per_second the answer is
// limit_exceeded and nothing changes.
TEST(UndoService, UndoFloodsAreRateLimited) {
  base::set_log_level(base::LogLevel::warn);
  protocol::SessionLimits limits;
  limits.max_strokes_per_second = 5;
  TestServer s = start_server({"c"}, kTokens, limits);
  ASSERT_TRUE(s.server);
  auto c = client_core::Client::connect(client_options(s));
  ASSERT_TRUE(c.ok());
  std::vector<std::uint64_t> ids;
  for (int i = 0; i < 30; ++i) ids.push_back(*(*c)->request_undo());
  int limited = 0, nothing = 0;
  for (std::uint64_t id : ids) {
    auto r = (*c)->wait_for_undo(id, 30s);
    ASSERT_FALSE(r.ok());
    if (r.error().code == Errc::limit_exceeded) ++limited;
    if (r.error().code == Errc::not_found) ++nothing;
  }
  EXPECT_GT(limited, 20);
  EXPECT_EQ(limited + nothing, 30);
}

}  // namespace
}  // namespace deepcanvas::test
