// History playback (playback.hpp, CanvasService::play, PROTOCOL.md 3.13): where a step ends,
// against a brute-force reference; painting times and bounds; a playback canvas stepped through
// a history recorded from a live canvas (interleaved strokes, an undo, an import) equals a
// replay of the same prefix after every step and the live canvas at the end; strokes are
// refused there; and a viewer steps it over the wire, its replica converging after each step.
#include <gtest/gtest.h>

#include <future>
#include <mutex>
#include <random>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/server_core/cell_paste.hpp"
#include "deepcanvas/server_core/event_replay.hpp"
#include "deepcanvas/server_core/playback.hpp"
#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

using server_core::CanvasService;
using server_core::PlaybackDone;
using server_core::PlaybackHistory;
using server_core::StrokeEvent;
using Kind = StrokeEvent::Kind;

// ---- where a step ends ----

StrokeEvent event_of(Kind k, std::int64_t t_ms = 0) {
  StrokeEvent e;
  e.kind = k;
  e.time_ms = t_ms;
  return e;
}

// The reference: operations counted one by one; the time mark found by walking the multiples.
std::size_t reference_end(const PlaybackHistory& h, std::size_t cursor, std::uint64_t ops,
                          double seconds) {
  const std::size_t n = h.events.size();
  if (cursor >= n) return n;
  if (ops > 0) {
    std::uint64_t seen = 0;
    for (std::size_t i = cursor; i < n; ++i) {
      if (server_core::ends_operation(h.events[i])) ++seen;
      if (seen == ops) return i + 1;
    }
    return n;
  }
  if (seconds > 0 && h.timed()) {
    double mark = 0;
    while (mark <= static_cast<double>(h.time_ms[cursor])) mark += seconds * 1000;
    std::size_t i = cursor;
    while (i < n && static_cast<double>(h.time_ms[i]) < mark) ++i;
    return i;
  }
  return cursor;
}

TEST(Playback, StepEndsMatchABruteForceReference) {
  std::mt19937_64 rng(11);
  const Kind kinds[] = {Kind::begin, Kind::samples, Kind::end, Kind::undo, Kind::redo, Kind::paste};
  for (int trial = 0; trial < 200; ++trial) {
    std::vector<StrokeEvent> events;
    std::int64_t t = 1'700'000'000'000 + static_cast<std::int64_t>(rng() % 1000);
    const std::size_t n = rng() % 60;
    for (std::size_t i = 0; i < n; ++i) {
      // Bursts and long pauses, like an artist's evening.
      t += rng() % 8 == 0 ? static_cast<std::int64_t>(rng() % 3'600'000) : static_cast<std::int64_t>(rng() % 900);
      events.push_back(event_of(kinds[rng() % 6], t));
    }
    const PlaybackHistory h = server_core::make_playback_history(events, server_core::OctreeConfig{});
    ASSERT_EQ(h.timed(), n > 0);
    std::uint64_t ops = 0;
    for (const auto& e : events) ops += server_core::ends_operation(e) ? 1 : 0;
    EXPECT_EQ(h.operations, ops);
    for (std::size_t cursor = 0; cursor <= n; ++cursor) {
      for (std::uint64_t k : {1ull, 2ull, 5ull, 1000ull})
        ASSERT_EQ(server_core::playback_step_end(h, cursor, k, 0), reference_end(h, cursor, k, 0))
            << "trial " << trial << " cursor " << cursor << " ops " << k;
      for (double s : {0.25, 1.0, 7.5, 600.0}) {
        const std::size_t end = server_core::playback_step_end(h, cursor, 0, s);
        ASSERT_EQ(end, reference_end(h, cursor, 0, s)) << "trial " << trial << " s " << s;
        if (cursor < n) {
          ASSERT_GT(end, cursor) << "a timed step always paints something";
        }
      }
      ASSERT_EQ(server_core::playback_step_end(h, cursor, 0, 0), std::min(cursor, n));
    }
  }
}

TEST(Playback, PaintingTimesAndBounds) {
  // A data directory's history: wall clock, from the first event.
  std::vector<StrokeEvent> wall = {event_of(Kind::begin, 5000), event_of(Kind::end, 7000),
                                   event_of(Kind::undo, 65000)};
  auto h = server_core::make_playback_history(wall, server_core::OctreeConfig{});
  ASSERT_TRUE(h.timed());
  EXPECT_EQ(h.time_ms, (std::vector<std::int64_t>{0, 2000, 60000}));
  EXPECT_DOUBLE_EQ(h.seconds_total(), 60.0);
  EXPECT_FALSE(h.bounds) << "no samples, no imports: nothing painted";

  // A painting's sample times (no wall clock), carried through events without samples.
  std::vector<StrokeEvent> sampled(4);
  sampled[0].kind = Kind::begin;
  sampled[0].samples = {{1, 2, 3, 0.5f, 1, 1000}, {-4, 2, 3, 0.25f, 1, 1500}};
  sampled[1].kind = Kind::end;
  sampled[2].kind = Kind::begin;
  sampled[2].samples = {{0, 0, 0, 0.1f, 1, 4000}};
  sampled[3].kind = Kind::end;
  h = server_core::make_playback_history(sampled, server_core::OctreeConfig{});
  ASSERT_TRUE(h.timed());
  EXPECT_EQ(h.time_ms, (std::vector<std::int64_t>{0, 0, 3000, 3000}));
  ASSERT_TRUE(h.bounds);
  const std::array<double, 6> want{-4.25, -0.1, -0.1, 1.5, 2.5, 3.5};
  for (int i = 0; i < 6; ++i) EXPECT_NEAR((*h.bounds)[i], want[i], 1e-6) << i;

  // Times that go back from one stroke to the next are a client's own per-stroke clock: untimed.
  sampled[2].samples[0].t_ms = 10;
  h = server_core::make_playback_history(sampled, server_core::OctreeConfig{});
  EXPECT_FALSE(h.timed());
  EXPECT_EQ(server_core::playback_step_end(h, 0, 0, 1.0), 0u) << "no painting time: no time step";

  // An import's cells count in the bounds.
  server_core::OctreeConfig oc;
  oc.edge_m = 8;
  oc.max_depth = 12;
  server_core::CellPaste paste;
  paste.cells.push_back({{3, 0, 0, 0}, 0xff0000ffu});  // depth 3 of 4 roots: 0.25 m cells
  ASSERT_TRUE(server_core::normalise_cell_paste(paste, oc));
  StrokeEvent pe = event_of(Kind::paste);
  pe.paste = server_core::encode_cell_paste(paste);
  h = server_core::make_playback_history({pe}, oc);
  ASSERT_TRUE(h.bounds);
  const std::array<double, 6> cell{-4, -4, -4, -3.75, -3.75, -3.75};
  for (int i = 0; i < 6; ++i) EXPECT_NEAR((*h.bounds)[i], cell[i], 1e-9) << i;
}

// ---- a playback canvas ----

protocol::Stroke stroke_near(std::mt19937_64& rng, double z) {
  protocol::Stroke s = random_stroke(rng, 10);
  for (auto& p : s.samples) p.z = z + 0.05 * p.z;
  return s;
}

// A live canvas's history: two artists' streamed strokes interleaved batch by batch over the
// same cells, whole strokes, an undo, and an import; recorded through on_stroke_event.
struct Recorded {
  std::vector<StrokeEvent> events;
  std::uint64_t canvas_hash = 0;
};

Recorded record_live_history(std::uint64_t seed) {
  base::set_log_level(base::LogLevel::warn);
  Recorded out;
  std::mutex mu;
  auto cfg = small_canvas("live");
  // With the wall-clock time a data directory's history keeps (storage stamps it on append).
  cfg.on_stroke_event = [&](const StrokeEvent& e) {
    std::lock_guard lock(mu);
    out.events.push_back(e);
    out.events.back().time_ms = std::chrono::duration_cast<std::chrono::milliseconds>(
                                    std::chrono::system_clock::now().time_since_epoch())
                                    .count();
  };
  auto svc = CanvasService::create(cfg);
  EXPECT_TRUE(svc);
  if (!svc) return out;
  CanvasService& c = **svc;
  std::mt19937_64 rng(seed);
  const auto rules = c.stroke_rules();
  auto samples = [&](const protocol::Stroke& s, std::size_t a, std::size_t b) {
    auto v = protocol::ValidatedSamples::make({s.samples.begin() + a, s.samples.begin() + b}, rules);
    EXPECT_TRUE(v);
    return std::move(*v);
  };
  std::vector<std::future<Result<server_core::StrokeDone>>> acks;
  auto ack_fn = [&]() {
    auto p = std::make_shared<std::promise<Result<server_core::StrokeDone>>>();
    acks.push_back(p->get_future());
    return [p](Result<server_core::StrokeDone> d) { p->set_value(std::move(d)); };
  };
  for (int round = 0; round < 4; ++round) {
    const auto a = stroke_near(rng, 0.0), b = stroke_near(rng, 0.02);
    auto ka = c.begin_stroke(*protocol::ValidatedBrush::make(a.brush), samples(a, 0, 2),
                             server_core::Clock::now(), ack_fn(), 1);
    auto kb = c.begin_stroke(*protocol::ValidatedBrush::make(b.brush), samples(b, 0, 2),
                             server_core::Clock::now(), ack_fn(), 2);
    EXPECT_TRUE(ka && kb);
    for (std::size_t i = 2; i < 10; i += 4) {
      EXPECT_TRUE(c.add_samples(*ka, samples(a, i, std::min<std::size_t>(i + 4, 10))));
      EXPECT_TRUE(c.add_samples(*kb, samples(b, i, std::min<std::size_t>(i + 4, 10))));
    }
    EXPECT_TRUE(c.end_stroke(*kb));
    EXPECT_TRUE(c.end_stroke(*ka));
    auto whole = protocol::ValidatedStroke::make(stroke_near(rng, -0.3), rules);
    EXPECT_TRUE(whole);
    EXPECT_TRUE(c.submit_stroke(std::move(*whole), server_core::Clock::now(), ack_fn(), 2));
  }
  for (auto& f : acks) {
    EXPECT_EQ(f.wait_for(30s), std::future_status::ready);
    EXPECT_TRUE(f.get());
  }
  std::promise<Result<server_core::UndoDone>> undone;
  EXPECT_TRUE(c.undo(1, false, server_core::Clock::now(),
                     [&](Result<server_core::UndoDone> d) { undone.set_value(std::move(d)); }));
  EXPECT_TRUE(undone.get_future().get());
  auto paste = std::make_shared<server_core::CellPaste>();
  for (std::uint32_t x = 0; x < 6; ++x) paste->cells.push_back({{7, 250 + x, 256, 256}, 0x8040c0ffu});
  EXPECT_TRUE(server_core::normalise_cell_paste(*paste, cfg.octree));
  std::promise<Result<server_core::ImportDone>> imported;
  EXPECT_TRUE(c.paste(2, paste, server_core::Clock::now(),
                      [&](Result<server_core::ImportDone> d) { imported.set_value(std::move(d)); }));
  EXPECT_TRUE(imported.get_future().get());
  auto q = c.quiesce();
  EXPECT_TRUE(q);
  out.canvas_hash = q ? q->canvas_hash : 0;
  c.stop();
  std::lock_guard lock(mu);
  return out;
}

Result<PlaybackDone> step(CanvasService& c, std::uint64_t ops, double seconds) {
  std::promise<Result<PlaybackDone>> p;
  auto f = p.get_future();
  if (auto r = c.play(ops, seconds, [&p](Result<PlaybackDone> d) { p.set_value(std::move(d)); }); !r)
    return std::move(r).error();
  if (f.wait_for(30s) != std::future_status::ready) return make_error(Errc::internal, "timeout");
  return f.get();
}

TEST(Playback, EachStepIsTheHistorysCanvasAtThatEvent) {
  const Recorded live = record_live_history(3);
  ASSERT_GT(live.events.size(), 20u);
  auto cfg = small_canvas("playback");
  const auto history = std::make_shared<PlaybackHistory>(
      server_core::make_playback_history(live.events, cfg.octree));
  ASSERT_EQ(history->operations, 4u * 3 + 2) << "12 strokes, an undo, an import";
  cfg.playback = history;
  auto svc = CanvasService::create(cfg);
  ASSERT_TRUE(svc) << svc.error().message;
  CanvasService& c = **svc;

  auto where = step(c, 0, 0);
  ASSERT_TRUE(where) << where.error().message;
  EXPECT_EQ(where->events, 0u);
  const std::uint64_t empty_hash = c.quiesce()->canvas_hash;
  std::uint64_t last_events = 0;
  for (std::uint64_t k : {1, 3, 2, 5, 100}) {
    auto d = step(c, k, 0);
    ASSERT_TRUE(d) << d.error().message;
    ASSERT_GT(d->events, last_events);
    last_events = d->events;
    // The reference: the same prefix replayed on a fresh painter, as a restart would.
    auto tree = server_core::Octree::create(cfg.octree);
    ASSERT_TRUE(tree);
    auto painter = server_core::Painter::create(**tree, server_core::painter_config(cfg));
    ASSERT_TRUE(painter);
    auto undo = server_core::UndoHistory(cfg.undo);
    server_core::replay_stroke_events(
        **painter, std::span<const StrokeEvent>(history->events.data(), d->events),
        cfg.max_cells_first_step, &undo);
    const auto q = c.quiesce();
    ASSERT_TRUE(q);
    EXPECT_GE(q->epoch, d->epoch);
    EXPECT_EQ(q->canvas_hash, (*tree)->canvas_hash()) << "after " << d->events << " events";
    EXPECT_NE(q->canvas_hash, empty_hash);
  }
  EXPECT_EQ(last_events, history->events.size());
  EXPECT_EQ(c.quiesce()->canvas_hash, live.canvas_hash) << "the whole history is the live canvas";
  auto past_end = step(c, 5, 0);
  ASSERT_TRUE(past_end);
  EXPECT_EQ(past_end->events, history->events.size());
  EXPECT_EQ(past_end->operations, history->operations);

  // A playback canvas takes no strokes, undos or imports.
  std::mt19937_64 rng(5);
  auto s = protocol::ValidatedStroke::make(random_stroke(rng), c.stroke_rules());
  ASSERT_TRUE(s);
  auto refused = c.submit_stroke(std::move(*s), server_core::Clock::now(), nullptr, 1);
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code, Errc::refused);
  EXPECT_NE(refused.error().message.find("plays back"), std::string::npos) << refused.error().message;
  EXPECT_FALSE(c.undo(1, false, server_core::Clock::now(), nullptr));
}

TEST(Playback, ErrorsOfPlayAreNamed) {
  auto plain = CanvasService::create(small_canvas("plain"));
  ASSERT_TRUE(plain);
  auto r = step(**plain, 1, 0);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, Errc::unsupported);
  // Seconds for an untimed history (no wall clock, no sample times).
  auto cfg = small_canvas("untimed");
  std::mt19937_64 rng(9);
  protocol::Stroke st = random_stroke(rng);
  for (auto& p : st.samples) p.t_ms = 0;
  cfg.playback = std::make_shared<PlaybackHistory>(
      server_core::make_playback_history(server_core::stroke_events(st), cfg.octree));
  auto untimed = CanvasService::create(cfg);
  ASSERT_TRUE(untimed);
  r = step(**untimed, 0, 2.0);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, Errc::unsupported);
  EXPECT_NE(r.error().message.find("step by strokes"), std::string::npos);
  r = step(**untimed, 1, 0);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_EQ(r->operations, 1u);
}

TEST(Playback, AViewerStepsItOverTheWire) {
  const Recorded live = record_live_history(8);
  std::shared_ptr<const PlaybackHistory> history;
  TestServer s = start_server({"c"}, kTokens, {}, 0, [&](server_net::ServerConfig& cfg) {
    history = std::make_shared<PlaybackHistory>(
        server_core::make_playback_history(live.events, cfg.canvases[0].octree));
    cfg.canvases[0].playback = history;
  });
  ASSERT_TRUE(s.server);
  auto viewer = client_core::Client::connect(
      client_options(s, "c", protocol::Role::viewer, "view-token"));
  ASSERT_TRUE(viewer) << viewer.error().message;
  auto& v = **viewer;
  std::uint64_t events = 0;
  bool first = true;
  while (events < history->events.size()) {
    protocol::PlaybackStep m;
    m.strokes = first ? 0 : 4;
    auto id = v.request_playback_step(m);
    ASSERT_TRUE(id);
    auto pos = v.wait_for_playback(*id, 30s);
    ASSERT_TRUE(pos) << pos.error().message;
    EXPECT_EQ(pos->events_total, history->events.size());
    EXPECT_EQ(pos->strokes_total, history->operations);
    EXPECT_EQ(pos->bounds, history->bounds);
    EXPECT_TRUE(pos->timed);
    if (!first) {
      EXPECT_GT(pos->events, events);
    }
    first = false;
    events = pos->events;
    ASSERT_TRUE(v.wait_for_epoch(pos->epoch, 30s));
    expect_converged(*s.canvas(), {&v});
  }
  EXPECT_EQ(s.canvas()->quiesce()->canvas_hash, live.canvas_hash);

  // A painter's stroke is refused; a step past the end answers the end.
  auto painter = client_core::Client::connect(client_options(s));
  ASSERT_TRUE(painter);
  std::mt19937_64 rng(2);
  auto h = (*painter)->send_stroke(random_stroke(rng));
  ASSERT_TRUE(h);
  auto error = (*painter)->wait_for_error(10s);
  ASSERT_TRUE(error);
  EXPECT_EQ(error->code, Errc::refused);
  EXPECT_NE(error->message.find("plays back"), std::string::npos) << error->message;
  protocol::PlaybackStep both;
  both.seconds = 1;
  auto id = v.request_playback_step(both);
  ASSERT_TRUE(id);
  auto end = v.wait_for_playback(*id, 30s);
  ASSERT_TRUE(end) << end.error().message;
  EXPECT_EQ(end->events, history->events.size());
}

}  // namespace
}  // namespace deepcanvas::test
