// Durable canvases (storage/durable_canvas.hpp) driven like the server drives them: strokes
// submitted from several artists, acked only once durable; the service stopped and the canvas
// reopened from its database equals the canvas it was (canvas_hash and pool_hash), with or
// without checkpoints, with a corrupt newest checkpoint, and after a write failure that kept
// strokes waiting.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <future>
#include <random>
#include <thread>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/storage/canvas_store.hpp"
#include "deepcanvas/storage/durable_canvas.hpp"
#include "../storage/storage_test_util.hpp"
#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

namespace fs = std::filesystem;
using server_core::CanvasService;


std::unique_ptr<CanvasService> open(const TempDir& d, const storage::StoreOptions& opts = {},
                                    storage::RestoreReport* rep = nullptr) {
  auto svc = storage::open_durable_canvas(d.path(), small_canvas("c"), opts, false, rep);
  EXPECT_TRUE(svc.ok()) << (svc ? "" : svc.error().message);
  return svc ? std::move(*svc) : nullptr;
}

// Submits `n` random strokes from `artists` artists and waits for every ack; returns how many
// were acked.
int paint(CanvasService& svc, std::mt19937_64& rng, int n, int artists = 3) {
  std::atomic<int> acked{0};
  std::vector<std::future<void>> done;
  for (int i = 0; i < n; ++i) {
    auto p = std::make_shared<std::promise<void>>();
    done.push_back(p->get_future());
    auto v = protocol::ValidatedStroke::make(random_stroke(rng, 8), svc.stroke_rules());
    EXPECT_TRUE(v.ok());
    auto r = svc.submit_stroke(
        std::move(*v), server_core::Clock::now(),
        [p, &acked](Result<server_core::StrokeDone> d) {
          if (d) ++acked;
          p->set_value();
        },
        static_cast<std::uint64_t>(i % artists));
    EXPECT_TRUE(r.ok()) << (r ? "" : r.error().message);
    if (!r) p->set_value();
  }
  for (auto& f : done) EXPECT_EQ(f.wait_for(60s), std::future_status::ready);
  return acked.load();
}

// Runs `sql` on the canvas database c.canvas in `dir` (a test's way of making a history that a
// crash or damage leaves).
void exec_on_canvas(const TempDir& dir, const char* sql) {
  sqlite3* h = nullptr;
  ASSERT_EQ(sqlite3_open((fs::path(dir.path()) / "c.canvas").string().c_str(), &h), SQLITE_OK);
  EXPECT_EQ(sqlite3_exec(h, sql, nullptr, nullptr, nullptr), SQLITE_OK) << sqlite3_errmsg(h);
  sqlite3_close(h);
}

struct Hashes {
  std::uint64_t canvas = 0, pool = 0, links = 0;
  friend bool operator==(const Hashes&, const Hashes&) = default;
};

Hashes hashes(CanvasService& svc) {
  auto q = svc.quiesce();
  EXPECT_TRUE(q.ok());
  return q ? Hashes{q->canvas_hash, q->pool_hash, q->links_hash} : Hashes{};
}

TEST(DurableCanvas, AReopenedCanvasEqualsTheOneThatStopped) {
  base::set_log_level(base::LogLevel::warn);
  TempDir dir;
  std::mt19937_64 rng(1);
  Hashes before;
  {
    auto svc = open(dir);
    ASSERT_TRUE(svc);
    EXPECT_EQ(paint(*svc, rng, 40), 40);
    before = hashes(*svc);
  }
  storage::RestoreReport rep;
  auto svc = open(dir, {}, &rep);
  ASSERT_TRUE(svc);
  EXPECT_FALSE(rep.created);
  EXPECT_EQ(hashes(*svc), before);
  // A clean stop leaves a checkpoint: nothing to replay.
  EXPECT_NE(rep.checkpoint_id, 0u);
  EXPECT_EQ(rep.events_replayed, 0u);
  // The restored canvas goes on: its new strokes are kept too.
  EXPECT_EQ(paint(*svc, rng, 10), 10);
  const Hashes after = hashes(*svc);
  svc.reset();
  auto again = open(dir);
  ASSERT_TRUE(again);
  EXPECT_EQ(hashes(*again), after);
}

// The history names the strokes sent with a handle by a client id's artist once their end is
// written (storage stroke_names), newest first, and a reopened canvas reports them; a salvage
// that drops a stroke's end event drops its name, as the stroke is then cut off.
TEST(DurableCanvas, TheHistoryNamesEndedStrokesAndASalvageUnnamesWhatItDrops) {
  base::set_log_level(base::LogLevel::off);
  TempDir dir;
  std::mt19937_64 rng(3);
  const std::uint64_t artist = (std::uint64_t{1} << 63) | 77;  // a client id's artist key
  std::vector<std::uint64_t> ids;
  {
    auto svc = open(dir);
    ASSERT_TRUE(svc);
    // handle 0: not named; then handles 1, 2, 3, one after the other.
    for (std::uint64_t h = 0; h <= 3; ++h) {
      std::promise<Result<server_core::StrokeDone>> p;
      auto v = protocol::ValidatedStroke::make(random_stroke(rng, 8), svc->stroke_rules());
      ASSERT_TRUE(v.ok());
      ASSERT_TRUE(svc->submit_stroke(std::move(*v), server_core::Clock::now(),
                                     [&p](Result<server_core::StrokeDone> d) {
                                       p.set_value(std::move(d));
                                     },
                                     artist, h)
                      .ok());
      auto f = p.get_future();
      ASSERT_EQ(f.wait_for(60s), std::future_status::ready);
      auto d = f.get();
      ASSERT_TRUE(d.ok()) << d.error().message;
      ids.push_back(d->stroke_id);
    }
  }
  {
    storage::RestoreReport rep;
    auto svc = open(dir, {}, &rep);
    ASSERT_TRUE(svc);
    ASSERT_EQ(rep.stroke_names.size(), 3u);
    for (std::size_t i = 0; i < 3; ++i) {
      EXPECT_EQ(rep.stroke_names[i].artist, artist);
      EXPECT_EQ(rep.stroke_names[i].handle, 3 - i);
      EXPECT_EQ(rep.stroke_names[i].stroke_id, ids[3 - i]);
    }
  }
  // Damage the last end event (handle 3's stroke) and start over from the events alone.
  exec_on_canvas(dir,
                 "DELETE FROM checkpoint_blocks; DELETE FROM checkpoints; DELETE FROM "
                 "checkpoint_undo; UPDATE events SET record = CAST(substr(record, 1, 14) || 'X' "
                 "|| substr(record, 16) AS BLOB) WHERE seq = (SELECT max(seq) FROM events WHERE "
                 "kind = 3)");
  storage::RestoreReport rep;
  auto svc = storage::open_durable_canvas(dir.path(), small_canvas("c"), {}, true, &rep);
  ASSERT_TRUE(svc.ok()) << svc.error().message;
  EXPECT_EQ(rep.strokes_ended, 1u);  // handle 3's stroke, cut off by the salvage
  ASSERT_EQ(rep.stroke_names.size(), 2u);
  EXPECT_EQ(rep.stroke_names[0].handle, 2u);
  EXPECT_EQ(rep.stroke_names[1].handle, 1u);
}

// Paints `stroke` as `artist` with the sender's `handle` and waits for the ack; its stroke id.
std::uint64_t paint_named(CanvasService& svc, const protocol::Stroke& stroke, std::uint64_t artist,
                          std::uint64_t handle) {
  std::promise<Result<server_core::StrokeDone>> p;
  auto v = protocol::ValidatedStroke::make(stroke, svc.stroke_rules());
  EXPECT_TRUE(v.ok());
  if (!v) return 0;
  auto r = svc.submit_stroke(
      std::move(*v), server_core::Clock::now(),
      [&p](Result<server_core::StrokeDone> d) { p.set_value(std::move(d)); }, artist, handle);
  EXPECT_TRUE(r.ok()) << (r ? "" : r.error().message);
  if (!r) return 0;
  auto f = p.get_future();
  EXPECT_EQ(f.wait_for(60s), std::future_status::ready);
  auto d = f.get();
  EXPECT_TRUE(d.ok()) << (d ? "" : d.error().message);
  return d ? d->stroke_id : 0;
}

// Takes stroke `id` back as `artist` (a session's withdrawal of a cut stroke before its resend)
// and waits; the stroke id the undo names, 0 on failure.
std::uint64_t withdraw(CanvasService& svc, std::uint64_t artist, std::uint64_t id) {
  std::promise<Result<server_core::UndoDone>> p;
  auto f = p.get_future();
  auto r = svc.undo(
      artist, false, server_core::Clock::now(),
      [&p](Result<server_core::UndoDone> d) { p.set_value(std::move(d)); }, id);
  EXPECT_TRUE(r.ok()) << (r ? "" : r.error().message);
  if (!r) return 0;
  EXPECT_EQ(f.wait_for(60s), std::future_status::ready);
  auto undone = f.get();
  EXPECT_TRUE(undone.ok()) << (undone ? "" : undone.error().message);
  return undone ? undone->stroke_id : 0;
}

// As a stop that cuts the last stroke off leaves the history: its end event never written (the
// salvage test's way of making one), no checkpoint after it.
void cut_off_last_stroke(const TempDir& dir) {
  exec_on_canvas(dir,
                 "DELETE FROM checkpoint_blocks; DELETE FROM checkpoints; DELETE FROM "
                 "checkpoint_undo; UPDATE stroke_names SET ended = 0 WHERE stroke = (SELECT "
                 "stroke FROM events WHERE seq = (SELECT max(seq) FROM events WHERE kind = 3)); "
                 "DELETE FROM events WHERE seq = (SELECT max(seq) FROM events WHERE kind = 3)");
}

// A stroke a client id sent with a handle and the stop cut off is ended at the restart with what
// was durable and named in the report (cut_stroke_names). Its sender, who never had the ack,
// resends it whole; the server's session first takes back what the restart kept (an undo of that
// stroke by the resending artist, StrokeReceipts::restore_cut), then paints the resend: the canvas
// holds the stroke once, as if it had been painted once. Here every sample of it was durable, the
// case where keeping it would double the whole stroke.
TEST(DurableCanvas, AClientsStrokeCutOffByAStopIsNamedAndItsResendShowsOnce) {
  base::set_log_level(base::LogLevel::off);
  TempDir dir;
  std::mt19937_64 rng(5);
  const std::uint64_t artist = (std::uint64_t{1} << 63) | 91;  // a client id's artist key
  std::vector<protocol::Stroke> strokes;
  for (int i = 0; i < 3; ++i) strokes.push_back(random_stroke(rng, 8));
  std::uint64_t before_cut = 0, once = 0, cut_id = 0;
  {
    auto svc = open(dir);
    ASSERT_TRUE(svc);
    paint_named(*svc, strokes[0], artist, 1);
    paint_named(*svc, strokes[1], 7, 0);  // another artist, no client id
    before_cut = hashes(*svc).canvas;
    cut_id = paint_named(*svc, strokes[2], artist, 2);
    once = hashes(*svc).canvas;
    ASSERT_NE(once, before_cut);
  }
  cut_off_last_stroke(dir);
  {
    storage::RestoreReport rep;
    auto svc = open(dir, {}, &rep);
    ASSERT_TRUE(svc);
    EXPECT_EQ(rep.strokes_ended, 1u);
    ASSERT_EQ(rep.cut_stroke_names.size(), 1u);
    EXPECT_EQ(rep.cut_stroke_names[0].artist, artist);
    EXPECT_EQ(rep.cut_stroke_names[0].handle, 2u);
    EXPECT_EQ(rep.cut_stroke_names[0].stroke_id, cut_id);
    ASSERT_EQ(rep.stroke_names.size(), 1u);  // handle 1's; the cut-off one is not named ended
    EXPECT_EQ(rep.stroke_names[0].handle, 1u);
    EXPECT_EQ(hashes(*svc).canvas, once);  // kept with what was durable: all of it
    // The resend, as a session does it: the kept stroke withdrawn, then the stroke painted.
    EXPECT_EQ(withdraw(*svc, artist, cut_id), cut_id);
    EXPECT_EQ(hashes(*svc).canvas, before_cut);
    paint_named(*svc, strokes[2], artist, 2);
    EXPECT_EQ(hashes(*svc).canvas, once);
  }
  {
    // The history holds the withdrawal: it replays to the same canvas, and names nothing cut.
    storage::RestoreReport rep;
    auto svc = open(dir, {}, &rep);
    ASSERT_TRUE(svc);
    EXPECT_EQ(rep.strokes_ended, 0u);
    EXPECT_TRUE(rep.cut_stroke_names.empty());
    EXPECT_EQ(hashes(*svc).canvas, once);
  }
  auto replayed = storage::replay_history((fs::path(dir.path()) / "c.canvas").string(),
                                          small_canvas("c"));
  ASSERT_TRUE(replayed.ok()) << replayed.error().message;
  EXPECT_EQ(replayed->tree->canvas_hash(), once);
}

// A client's streamed stroke that the server cut short before the stop, for its sender's closed
// connection or by the idle timeout, is stored as ended by the server: after a restart it is
// named cut like one the stop cut off, and its resend withdraws it first, so the canvas holds
// the stroke once and whole. A stroke ended by its sender is named ended instead.
TEST(DurableCanvas, AStrokeTheServerCutShortIsNamedCutAfterARestart) {
  base::set_log_level(base::LogLevel::off);
  std::mt19937_64 rng(9);
  const std::uint64_t artist = (std::uint64_t{1} << 63) | 77;
  enum class Cut { connection_closed, idle_timeout };
  for (Cut how : {Cut::connection_closed, Cut::idle_timeout}) {
    SCOPED_TRACE(how == Cut::connection_closed ? "connection closed" : "idle timeout");
    TempDir dir;
    const protocol::Stroke whole = random_stroke(rng, 12);
    const protocol::Stroke ended_by_sender = random_stroke(rng, 8);
    std::uint64_t before = 0, once = 0, cut_id = 0;
    {
      auto svc = open(dir);
      ASSERT_TRUE(svc);
      paint_named(*svc, ended_by_sender, artist, 1);
      before = hashes(*svc).canvas;
      // The first half of `whole`, streamed, then cut.
      auto brush = protocol::ValidatedBrush::make(whole.brush);
      ASSERT_TRUE(brush.ok());
      protocol::Stroke half = whole;
      half.samples.resize(whole.samples.size() / 2);
      auto first = protocol::ValidatedSamples::make(half.samples, svc->stroke_rules());
      ASSERT_TRUE(first.ok());
      std::promise<Result<server_core::StrokeDone>> p;
      auto key = svc->begin_stroke(
          *brush, std::move(*first), server_core::Clock::now(),
          [&p](Result<server_core::StrokeDone> d) { p.set_value(std::move(d)); }, artist, 2);
      ASSERT_TRUE(key.ok()) << key.error().message;
      if (how == Cut::connection_closed) {
        ASSERT_TRUE(svc->end_stroke(*key, server_core::EndedBy::server).ok());
      }
      auto f = p.get_future();  // the idle timeout (2 s) ends it otherwise
      ASSERT_EQ(f.wait_for(60s), std::future_status::ready);
      auto done = f.get();
      ASSERT_TRUE(done.ok()) << done.error().message;
      EXPECT_EQ(done->idle_ended, how == Cut::idle_timeout);
      cut_id = done->stroke_id;
      // The canvas the whole stroke painted once instead (the reference).
      auto ref_dir = std::make_unique<TempDir>();
      auto ref = open(*ref_dir);
      ASSERT_TRUE(ref);
      paint_named(*ref, ended_by_sender, artist, 1);
      paint_named(*ref, whole, artist, 2);
      once = hashes(*ref).canvas;
      ASSERT_NE(hashes(*svc).canvas, once);
    }
    storage::RestoreReport rep;
    auto svc = open(dir, {}, &rep);
    ASSERT_TRUE(svc);
    EXPECT_EQ(rep.strokes_ended, 0u);  // nothing was open at the stop
    ASSERT_EQ(rep.cut_stroke_names.size(), 1u);
    EXPECT_EQ(rep.cut_stroke_names[0].handle, 2u);
    EXPECT_EQ(rep.cut_stroke_names[0].stroke_id, cut_id);
    ASSERT_EQ(rep.stroke_names.size(), 1u);
    EXPECT_EQ(rep.stroke_names[0].handle, 1u);
    // The resend, as a session does it (StrokeReceipts::restore_cut): withdraw, then paint.
    EXPECT_EQ(withdraw(*svc, artist, cut_id), cut_id);
    EXPECT_EQ(hashes(*svc).canvas, before);
    paint_named(*svc, whole, artist, 2);
    EXPECT_EQ(hashes(*svc).canvas, once);
    svc.reset();
    // Restarted again: the resend answers handle 2, nothing is named cut.
    storage::RestoreReport again;
    auto svc2 = open(dir, {}, &again);
    ASSERT_TRUE(svc2);
    EXPECT_TRUE(again.cut_stroke_names.empty());
    EXPECT_EQ(again.stroke_names.size(), 2u);
    EXPECT_EQ(hashes(*svc2).canvas, once);
  }
}

// A streamed stroke that a limit stopped (its second batch takes it past max_stamps) was
// answered with limit_exceeded and keeps what it painted. Its end is stored as stopped
// (EndedBy::stopped), so that after a restart its name says so (StrokeName::stopped): the
// server answers a resend with the error again rather than an ack (StrokeReceipts::restore),
// and the canvas is the one that stopped, from a checkpoint or from the history alone.
TEST(DurableCanvas, AStrokeALimitStoppedIsNamedStoppedAfterARestart) {
  base::set_log_level(base::LogLevel::off);
  TempDir dir;
  std::mt19937_64 rng(11);
  const std::uint64_t artist = (std::uint64_t{1} << 63) | 91;
  auto config = small_canvas("c");
  config.stamps.max_stamps = 40;
  auto open_limited = [&](storage::RestoreReport* rep) {
    auto svc = storage::open_durable_canvas(dir.path(), config, {}, false, rep);
    EXPECT_TRUE(svc.ok()) << (svc ? "" : svc.error().message);
    return svc ? std::move(*svc) : nullptr;
  };
  std::uint64_t first_id = 0, painted = 0;
  {
    auto svc = open_limited(nullptr);
    ASSERT_TRUE(svc);
    first_id = paint_named(*svc, random_stroke(rng, 6), artist, 1);
    ASSERT_NE(first_id, 0u);
    const protocol::Stroke stroke = random_stroke(rng, 60);
    auto brush = protocol::ValidatedBrush::make(stroke.brush);
    ASSERT_TRUE(brush.ok());
    // One sample (one stamp) begins it; the other 59 (far more than 40 stamps) stop it.
    std::vector<protocol::StrokeSample> head(stroke.samples.begin(), stroke.samples.begin() + 1);
    std::vector<protocol::StrokeSample> tail(stroke.samples.begin() + 1, stroke.samples.end());
    auto first = protocol::ValidatedSamples::make(head, svc->stroke_rules());
    auto rest = protocol::ValidatedSamples::make(tail, svc->stroke_rules());
    ASSERT_TRUE(first.ok() && rest.ok());
    std::promise<Result<server_core::StrokeDone>> p;
    auto key = svc->begin_stroke(
        *brush, std::move(*first), server_core::Clock::now(),
        [&p](Result<server_core::StrokeDone> d) { p.set_value(std::move(d)); }, artist, 2);
    ASSERT_TRUE(key.ok()) << key.error().message;
    // Its begin painted before the rest is sent (a pick-up waits for that and not for the
    // stroke's end): otherwise the painter takes all the samples in its first turn and the
    // stroke is refused at its start instead, painting nothing.
    std::promise<void> begun;
    ASSERT_TRUE(svc->pick_up({1, {0, 0, 0}}, [&begun](auto) { begun.set_value(); }).ok());
    ASSERT_EQ(begun.get_future().wait_for(60s), std::future_status::ready);
    ASSERT_TRUE(svc->add_samples(*key, std::move(*rest)).ok());
    (void)svc->end_stroke(*key);  // refused (the limit ended it) or taken: either way it ends
    auto f = p.get_future();
    ASSERT_EQ(f.wait_for(60s), std::future_status::ready);
    auto done = f.get();
    ASSERT_FALSE(done.ok()) << "the stroke was not stopped: raise its samples or lower the limit";
    EXPECT_EQ(done.error().code, Errc::limit_exceeded) << done.error().message;
    painted = hashes(*svc).canvas;
  }
  for (bool from_history : {false, true}) {
    SCOPED_TRACE(from_history ? "history only" : "checkpoint");
    if (from_history)
      exec_on_canvas(dir, "DELETE FROM checkpoint_blocks; DELETE FROM checkpoints; DELETE FROM checkpoint_undo");
    storage::RestoreReport rep;
    auto svc = open_limited(&rep);
    ASSERT_TRUE(svc);
    EXPECT_TRUE(rep.cut_stroke_names.empty());
    ASSERT_EQ(rep.stroke_names.size(), 2u);  // newest first
    EXPECT_EQ(rep.stroke_names[0].handle, 2u);
    EXPECT_GT(rep.stroke_names[0].stroke_id, first_id);
    EXPECT_TRUE(rep.stroke_names[0].stopped);
    EXPECT_EQ(rep.stroke_names[1].handle, 1u);
    EXPECT_EQ(rep.stroke_names[1].stroke_id, first_id);
    EXPECT_FALSE(rep.stroke_names[1].stopped);
    EXPECT_EQ(hashes(*svc).canvas, painted);
  }
}

// A stroke with no sender's name (no client id) that the stop cut off is kept with what was
// durable and not named for a withdrawal: nobody will resend it. It is still its artist's: that
// artist's undo takes it back, after the restart and after a later one that replays the history.
TEST(DurableCanvas, AnUnnamedStrokeCutOffByAStopIsKeptAndItsArtistCanUndoIt) {
  base::set_log_level(base::LogLevel::off);
  TempDir dir;
  std::mt19937_64 rng(6);
  std::uint64_t first = 0, painted = 0, cut_id = 0;
  {
    auto svc = open(dir);
    ASSERT_TRUE(svc);
    paint_named(*svc, random_stroke(rng, 8), 7, 0);
    first = hashes(*svc).canvas;
    cut_id = paint_named(*svc, random_stroke(rng, 8), 7, 0);
    painted = hashes(*svc).canvas;
    ASSERT_NE(first, painted);
  }
  cut_off_last_stroke(dir);
  {
    storage::RestoreReport rep;
    auto svc = open(dir, {}, &rep);
    ASSERT_TRUE(svc);
    EXPECT_EQ(rep.strokes_ended, 1u);
    EXPECT_TRUE(rep.cut_stroke_names.empty());
    EXPECT_EQ(hashes(*svc).canvas, painted);
    EXPECT_EQ(withdraw(*svc, 7, 0), cut_id);  // artist 7's latest stroke
    EXPECT_EQ(hashes(*svc).canvas, first);
  }
  // No checkpoint: the next start replays the whole history, the restart's end included.
  exec_on_canvas(dir, "DELETE FROM checkpoint_blocks; DELETE FROM checkpoints; DELETE FROM checkpoint_undo");
  {
    storage::RestoreReport rep;
    auto svc = open(dir, {}, &rep);
    ASSERT_TRUE(svc);
    EXPECT_EQ(rep.strokes_ended, 0u);
    EXPECT_EQ(hashes(*svc).canvas, first);
  }
  auto replayed = storage::replay_history((fs::path(dir.path()) / "c.canvas").string(),
                                          small_canvas("c"));
  ASSERT_TRUE(replayed.ok()) << replayed.error().message;
  EXPECT_EQ(replayed->tree->canvas_hash(), first);
}

TEST(DurableCanvas, IncrementalCheckpointsAndReplayRebuildTheCanvas) {
  base::set_log_level(base::LogLevel::warn);
  TempDir dir;
  std::mt19937_64 rng(2);
  storage::StoreOptions opts;
  opts.checkpoint_every_events = 40;  // several checkpoints while painting
  Hashes before;
  std::uint64_t checkpoints = 0;
  {
    auto svc = open(dir, opts);
    ASSERT_TRUE(svc);
    // Quiescent between rounds: a checkpoint is taken where no stroke is open, and a painter
    // that never pauses would only get one after the 2 s hold.
    for (int round = 0; round < 4; ++round) {
      EXPECT_EQ(paint(*svc, rng, 25), 25);
      (void)hashes(*svc);
      std::this_thread::sleep_for(50ms);
    }
    before = hashes(*svc);
  }
  auto s = storage::summarize(canvas_path(dir.path(), "c"));
  ASSERT_TRUE(s.ok()) << s.error().message;
  checkpoints = s->checkpoints.size();
  // Several were written; the two newest are kept (the newest and its fallback), with no more
  // block rows than those two need.
  EXPECT_EQ(checkpoints, 2u);
  EXPECT_GE(s->checkpoints.back().id, 3u);
  {
    sqlite3* h = nullptr;
    ASSERT_EQ(sqlite3_open_v2(canvas_path(dir.path(), "c").c_str(), &h, SQLITE_OPEN_READONLY,
                              nullptr),
              SQLITE_OK);
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(h, "SELECT count(*), count(DISTINCT block) FROM checkpoint_blocks",
                                 -1, &st, nullptr),
              SQLITE_OK);
    ASSERT_EQ(sqlite3_step(st), SQLITE_ROW);
    const auto rows = sqlite3_column_int64(st, 0), blocks = sqlite3_column_int64(st, 1);
    sqlite3_finalize(st);
    sqlite3_close(h);
    EXPECT_LE(rows, 2 * blocks);
  }
  EXPECT_EQ(s->strokes, 100u);
  EXPECT_EQ(s->integrity, "ok");
  // Later checkpoints hold only the blocks that changed.
  bool some_partial = false;
  for (const auto& c : s->checkpoints) some_partial |= c.blocks_written < c.block_count;
  EXPECT_TRUE(some_partial);
  auto svc = open(dir, opts);
  ASSERT_TRUE(svc);
  EXPECT_EQ(hashes(*svc), before);
}

TEST(DurableCanvas, StrokesWaitWhileWritesFailAndAreKeptWhenTheyResume) {
  base::set_log_level(base::LogLevel::off);
  TempDir dir;
  std::mt19937_64 rng(3);
  auto failing = std::make_shared<std::atomic<bool>>(false);
  storage::StoreOptions opts;
  opts.before_write = [failing]() -> Result<void> {
    if (failing->load()) return make_error(Errc::io_error, "disk full (injected)");
    return {};
  };
  Hashes before;
  {
    auto svc = open(dir, opts);
    ASSERT_TRUE(svc);
    EXPECT_EQ(paint(*svc, rng, 5), 5);
    failing->store(true);
    // A stroke in flight when the disk fills is painted but not acked until it is written.
    std::promise<bool> acked;
    auto v = protocol::ValidatedStroke::make(random_stroke(rng, 8), svc->stroke_rules());
    ASSERT_TRUE(v.ok());
    ASSERT_TRUE(svc->submit_stroke(std::move(*v), server_core::Clock::now(),
                                   [&acked](Result<server_core::StrokeDone> d) {
                                     acked.set_value(d.ok());
                                   })
                    .ok());
    auto fut = acked.get_future();
    EXPECT_EQ(fut.wait_for(1500ms), std::future_status::timeout);
    // New strokes are refused up front, with a clear error.
    auto w = protocol::ValidatedStroke::make(random_stroke(rng, 8), svc->stroke_rules());
    ASSERT_TRUE(w.ok());
    auto refused = svc->submit_stroke(std::move(*w), server_core::Clock::now(),
                                      [](Result<server_core::StrokeDone>) {});
    ASSERT_FALSE(refused.ok());
    EXPECT_EQ(refused.error().code, Errc::io_error);
    EXPECT_NE(refused.error().message.find("disk full"), std::string::npos);
    failing->store(false);
    ASSERT_EQ(fut.wait_for(10s), std::future_status::ready);
    EXPECT_TRUE(fut.get());
    EXPECT_EQ(paint(*svc, rng, 5), 5);  // painting resumed
    before = hashes(*svc);
  }
  auto svc = open(dir);
  ASSERT_TRUE(svc);
  EXPECT_EQ(hashes(*svc), before);
}

TEST(DurableCanvas, ACorruptNewestCheckpointFallsBackAndReplaysMore) {
  base::set_log_level(base::LogLevel::off);
  TempDir dir;
  std::mt19937_64 rng(4);
  storage::StoreOptions opts;
  opts.checkpoint_every_events = 30;
  Hashes before;
  {
    auto svc = open(dir, opts);
    ASSERT_TRUE(svc);
    for (int round = 0; round < 3; ++round) EXPECT_EQ(paint(*svc, rng, 20), 20);
    before = hashes(*svc);
  }
  const std::string db = canvas_path(dir.path(), "c");
  // Damage one block of the newest checkpoint.
  flip_blob_byte(db, "checkpoint_blocks", "data",
                 "checkpoint = (SELECT max(id) FROM checkpoints) AND block = 0", 40);
  storage::RestoreReport rep;
  auto svc = open(dir, opts, &rep);
  ASSERT_TRUE(svc);
  EXPECT_FALSE(rep.notes.empty());
  EXPECT_GT(rep.events_replayed, 0u);
  EXPECT_EQ(hashes(*svc), before);
}

// A small tmpfs, mounted for the test (root only; skipped where mounting is not allowed).
class SmallDisk {
 public:
  explicit SmallDisk(const std::string& path) : path_(path) {
    fs::create_directories(path_);
    const std::string cmd = "mount -t tmpfs -o size=4m tmpfs '" + path_ + "' 2>/dev/null";
    mounted_ = std::system(cmd.c_str()) == 0;
  }
  ~SmallDisk() {
    if (mounted_) (void)std::system(("umount '" + path_ + "'").c_str());
  }
  bool mounted() const { return mounted_; }
  // Writes a file until the disk is full.
  void fill(const std::string& file) {
    std::FILE* f = std::fopen(file.c_str(), "wb");
    ASSERT_NE(f, nullptr);
    std::vector<char> chunk(16384, 'x');
    while (std::fwrite(chunk.data(), 1, chunk.size(), f) == chunk.size() && std::fflush(f) == 0) {
    }
    std::fclose(f);
  }

 private:
  std::string path_;
  bool mounted_ = false;
};

TEST(DurableCanvas, ARealFullDiskKeepsStrokesWaitingAndCorruptsNothing) {
  base::set_log_level(base::LogLevel::off);
  TempDir dir;
  SmallDisk disk(dir.path() + "/disk");
  if (!disk.mounted()) GTEST_SKIP() << "cannot mount a tmpfs here (not root?)";
  const std::string data = dir.path() + "/disk/data";
  const std::string filler = dir.path() + "/disk/filler";
  std::mt19937_64 rng(5);
  storage::StoreOptions opts;
  opts.checkpoint_every = std::chrono::hours(1);
  opts.checkpoint_every_events = 1u << 30;
  Hashes before;
  {
    auto svc = storage::open_durable_canvas(data, small_canvas("c"), opts, false);
    ASSERT_TRUE(svc.ok()) << svc.error().message;
    EXPECT_EQ(paint(**svc, rng, 5), 5);
    disk.fill(filler);
    // Strokes painted now cannot be written: their acks wait, and soon new strokes are refused.
    std::atomic<int> acked{0};
    int submitted = 0;
    Result<void> refused;
    for (int i = 0; i < 200 && refused.ok(); ++i) {
      auto v = protocol::ValidatedStroke::make(random_stroke(rng, 8), (*svc)->stroke_rules());
      ASSERT_TRUE(v.ok());
      refused = (*svc)->submit_stroke(std::move(*v), server_core::Clock::now(),
                                      [&acked](Result<server_core::StrokeDone> d) {
                                        if (d) ++acked;
                                      });
      if (refused) ++submitted;
      std::this_thread::sleep_for(20ms);
    }
    ASSERT_FALSE(refused.ok()) << "the disk never filled";
    EXPECT_EQ(refused.error().code, Errc::io_error);
    EXPECT_NE(refused.error().message.find("cannot store strokes"), std::string::npos)
        << refused.error().message;
    EXPECT_LT(acked.load(), submitted);  // some wait for the disk
    // Space returns: every stroke painted is written and acked, and painting goes on.
    fs::remove(filler);
    for (int i = 0; i < 500 && acked.load() < submitted; ++i) std::this_thread::sleep_for(20ms);
    EXPECT_EQ(acked.load(), submitted);
    EXPECT_EQ(paint(**svc, rng, 3), 3);
    before = hashes(**svc);
  }
  auto summary = storage::summarize(data + "/c.canvas");
  ASSERT_TRUE(summary.ok()) << summary.error().message;
  EXPECT_EQ(summary->integrity, "ok");
  auto svc = storage::open_durable_canvas(data, small_canvas("c"), opts, false);
  ASSERT_TRUE(svc.ok()) << svc.error().message;
  EXPECT_EQ(hashes(**svc), before);
}

}  // namespace
}  // namespace deepcanvas::test
