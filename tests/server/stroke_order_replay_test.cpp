// The recorded stroke order replays to the same canvas (issue 26, "Fair, concurrent strokes"):
// a real server records its canvas's stroke events with the recorder `serve --stroke-log` uses
// (server_core::StrokeLogRecorder on CanvasServiceConfig::on_stroke_event); two painters stream
// strokes over the same cells, taking turns batch by batch, with whole strokes in between; then
// the log is replayed with a Painter alone, each event painted to completion before the next,
// and the canvas_hash must equal the served canvas's.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <mutex>
#include <set>
#include <thread>

#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"
#include "child_process.hpp"
#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

using client_core::Client;
using server_core::StrokeEvent;

std::unique_ptr<Client> connect_ok(const client_core::ClientOptions& o) {
  auto c = Client::connect(o);
  EXPECT_TRUE(c.ok()) << (c ? "" : c.error().message);
  return c ? std::move(*c) : nullptr;
}

// Returns once the server has read everything `c` sent before (a request answered in order).
void sync(Client& c) {
  ASSERT_TRUE(c.request_stats().ok());
  ASSERT_TRUE(c.wait_for_stats(60s).ok());
}

// The canvas the server paints: small_canvas with an idle timeout no loaded machine reaches
// (the painters pause between batches on purpose), and turns of at most the painters' batch of
// 3 samples. Then the strokes interleave however late the stroke thread takes them: even when a
// stroke's begin, samples and end all wait for its first turn, that turn gives 3 samples and
// leaves it open, and round robin gives the other painter's stroke the next turn.
server_core::CanvasServiceConfig canvas_config() {
  auto c = small_canvas("c");
  c.idle_stroke_timeout = std::chrono::minutes(10);
  c.samples_per_turn = 3;
  return c;
}

struct ReplayResult {
  std::uint64_t canvas_hash = 0;
  std::size_t refused = 0;          // events the painter refused (none expected)
  std::size_t stopped = 0;          // strokes an error stopped while painting
  std::size_t most_open = 0;        // the most strokes open at once
  std::set<std::uint64_t> painted;  // strokes that ended and painted to completion
};

// What a replay does (deepcanvas-server replay): each event given to the painter and painted to
// completion before the next, on a canvas configured as the server's.
ReplayResult replay(const std::vector<StrokeEvent>& events,
                    const server_core::CanvasServiceConfig& cfg) {
  ReplayResult out;
  auto tree = server_core::Octree::create(cfg.octree);
  EXPECT_TRUE(tree) << tree.error().message;
  if (!tree) return out;
  server_core::PainterConfig pc;
  pc.max_cells_per_step = cfg.max_cells_per_step;
  pc.limits = cfg.stroke_limits;
  pc.capacity_reserve = cfg.capacity_reserve;
  pc.stamps = cfg.stamps;
  auto painter = server_core::Painter::create(**tree, pc);
  EXPECT_TRUE(painter) << painter.error().message;
  if (!painter) return out;
  auto& p = **painter;
  for (const auto& e : events) {
    Result<void> r = e.kind == StrokeEvent::Kind::begin
                         ? p.begin_stroke(e.brush, e.stroke_id, e.samples)
                     : e.kind == StrokeEvent::Kind::samples ? p.add_samples(e.stroke_id, e.samples)
                                                            : p.end_stroke(e.stroke_id);
    if (!r) {
      ADD_FAILURE() << "stroke " << e.stroke_id << " event " << static_cast<int>(e.kind)
                    << " refused: " << r.error().message;
      ++out.refused;
      continue;
    }
    out.most_open = std::max(out.most_open, p.open_strokes());
    for (;;) {
      auto more = p.step();
      if (!more) {  // a limit stopped the stroke: deterministic, the server did the same
        ++out.stopped;
        break;
      }
      if (!*more) {
        if (e.kind == StrokeEvent::Kind::end) out.painted.insert(e.stroke_id);
        break;
      }
    }
  }
  out.canvas_hash = (*tree)->canvas_hash();
  return out;
}

// `base` moved by (dx, dy, dz) with another brush: a stroke over the same cells.
protocol::Stroke beside(const protocol::Stroke& base, double d, protocol::BrushMode mode,
                        float red) {
  protocol::Stroke s = base;
  s.brush.mode = mode;
  s.brush.colour[0] = red;
  s.brush.colour[1] = 1.0f - red;
  for (auto& p : s.samples) {
    p.x += d;
    p.y -= d / 2;
    p.z += d / 3;
  }
  return s;
}

// a and b each open a stroke over the same cells, then take turns batch by batch (the server
// has read each batch before the other painter sends its next); some rounds add a whole stroke
// while both are open, one erases, and the first begun ends last in odd rounds. The handles
// to wait for are added to `handles`.
void paint_interleaved(Client& a, Client& b, std::uint64_t seed, int rounds,
                       std::vector<std::pair<Client*, std::uint64_t>>& handles) {
  std::mt19937_64 rng(seed);
  constexpr int kSamples = 14, kBatch = 3;
  for (int round = 0; round < rounds; ++round) {
    const auto sa = random_stroke(rng, kSamples);
    const auto sb = beside(sa, 0.02 * (round + 1),
                           round == 2 ? protocol::BrushMode::erase : protocol::BrushMode::paint,
                           0.25f * static_cast<float>(round));
    auto ha = a.begin_stroke(sa.brush, {sa.samples.begin(), sa.samples.begin() + 2});
    ASSERT_TRUE(ha.ok());
    sync(a);
    auto hb = b.begin_stroke(sb.brush, {sb.samples.begin(), sb.samples.begin() + 2});
    ASSERT_TRUE(hb.ok());
    sync(b);
    for (int i = 2; i < kSamples; i += kBatch) {
      const int j = std::min(i + kBatch, kSamples);
      ASSERT_TRUE(a.add_samples(*ha, {sa.samples.begin() + i, sa.samples.begin() + j}).ok());
      sync(a);
      ASSERT_TRUE(b.add_samples(*hb, {sb.samples.begin() + i, sb.samples.begin() + j}).ok());
      sync(b);
      if (i == 5 && round % 2 == 1) {
        auto hw = a.send_stroke(beside(sa, -0.03, protocol::BrushMode::paint, 0.9f));
        ASSERT_TRUE(hw.ok());
        handles.emplace_back(&a, *hw);
        sync(a);
      }
    }
    if (round % 2 == 0) {
      ASSERT_TRUE(a.end_stroke(*ha).ok());
      ASSERT_TRUE(b.end_stroke(*hb).ok());
    } else {
      ASSERT_TRUE(b.end_stroke(*hb).ok());
      sync(b);
      ASSERT_TRUE(a.end_stroke(*ha).ok());
    }
    handles.emplace_back(&a, *ha);
    handles.emplace_back(&b, *hb);
  }
}

// Two painters interleave strokes on a server with canvas `cfg`; the recorded events replay to
// the served canvas (`tag` names the temporary files).
void expect_the_replay_reproduces_the_canvas(const server_core::CanvasServiceConfig& cfg,
                                             const std::string& tag) {
  const auto dir = std::filesystem::path(::testing::TempDir()) /
                   ("dc_stroke_order_" + tag + "_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string log_path = (dir / "c.dcs").string();
  auto recorder = server_core::StrokeLogRecorder::open(log_path, "c");
  ASSERT_TRUE(recorder) << recorder.error().message;

  std::set<std::uint64_t> acked;
  std::uint64_t served_hash = 0;
  {
    protocol::SessionLimits limits;
    limits.max_strokes_per_second = 0;  // unlimited: the painters' pace is the test's
    auto s = start_server({"c"}, "", limits, 0, [&](server_net::ServerConfig& sc) {
      sc.canvases[0] = cfg;
      sc.canvases[0].on_stroke_event = server_core::StrokeLogRecorder::callback(*recorder);
    });
    ASSERT_TRUE(s.server);
    auto opts = client_options(s);
    opts.block_frames = false;  // painters only: the canvas is checked on the server
    auto a = connect_ok(opts);
    auto b = connect_ok(opts);
    ASSERT_TRUE(a && b);
    std::vector<std::pair<Client*, std::uint64_t>> handles;
    paint_interleaved(*a, *b, 26, 4, handles);
    if (::testing::Test::HasFatalFailure()) return;
    for (const auto& [c, h] : handles) {
      auto ack = c->wait_for_ack(h, 120s);
      ASSERT_TRUE(ack.ok()) << ack.error().message;
      acked.insert(ack->stroke_id);
    }
    auto q = s.canvas()->quiesce(120s);
    ASSERT_TRUE(q.ok()) << q.error().message;
    served_hash = q->canvas_hash;
    a->close();
    b->close();
    s.server->stop();
  }
  ASSERT_TRUE((*recorder)->close());
  EXPECT_FALSE((*recorder)->failed());
  EXPECT_EQ((*recorder)->dropped(), 0u);

  auto log = server_core::read_stroke_log_file(log_path);
  ASSERT_TRUE(log) << log.error().message;
  EXPECT_FALSE(log->tail) << log->tail->reason;
  EXPECT_EQ(log->version, server_core::kStrokeLogVersion);
  ASSERT_FALSE(log->events.empty()) << "the server recorded no stroke events";
  // Sample batches are separate events when the painter took a stroke's begin before its next
  // batch arrived; on a starved machine a begin may take them all (the order is still the
  // canvas's, which the replay below checks), so this is reported, not required.
  std::size_t sample_events = 0;
  for (const auto& e : log->events) sample_events += e.kind == StrokeEvent::Kind::samples;
  std::printf("%zu of %zu recorded events are sample batches\n", sample_events, log->events.size());

  const auto r = replay(log->events, cfg);
  EXPECT_EQ(r.refused, 0u);
  EXPECT_EQ(r.stopped, 0u);
  // The server painted the two painters' strokes interleaved, and the log says so.
  EXPECT_GE(r.most_open, 2u) << "no two strokes were open at once in the recorded order";
  EXPECT_EQ(r.painted, acked) << "every acked stroke, and only those, ends in the log";
  EXPECT_EQ(r.canvas_hash, served_hash)
      << "replaying the recorded order did not reproduce the served canvas";
  // The strokes overlap while open, so their order matters: the same strokes painted one after
  // another (whole, in the order of their begins) give another canvas. This is what makes the
  // check above able to fail for a replay that loses the interleaving.
  std::vector<StrokeEvent> serial;
  for (const auto& s : server_core::assemble_strokes(log->events))
    for (auto& e : server_core::stroke_events(s)) serial.push_back(std::move(e));
  const auto one_by_one = replay(serial, cfg);
  EXPECT_EQ(one_by_one.refused, 0u);
  EXPECT_NE(one_by_one.canvas_hash, served_hash);
  std::filesystem::remove_all(dir);
}

TEST(StrokeOrderReplay, InterleavedStrokesReplayToTheSameCanvasHash) {
  expect_the_replay_reproduces_the_canvas(canvas_config(), "default");
}

// Turns sized by cost (CanvasServiceConfig::turn_seconds) at their extreme: while the other
// stroke is open every turn holds one sample, so each stroke takes back, sample by sample, cells
// the other took. The server steps each turn with a small first step, the replay with full ones:
// the canvas must not depend on that (Painter, "Concurrent strokes"; before it did, and this
// replay gave another canvas in about half the runs).
TEST(StrokeOrderReplay, TurnsOfOneSampleReplayToTheSameCanvasHash) {
  auto cfg = canvas_config();
  cfg.turn_seconds = 1e-9;
  expect_the_replay_reproduces_the_canvas(cfg, "one_sample");
}

// `serve --stroke-log` as an operator runs it: two canvases, so each gets FILE.<canvas>; the
// logs are complete after SIGTERM, and `replay` repaints canvas c to the canvas_hash the
// recorded order gives (the served canvas's, by the test above).
TEST(StrokeOrderReplay, ServeRecordsEachCanvasAndReplayRepaintsIt) {
  const auto dir = std::filesystem::path(::testing::TempDir()) /
                   ("dc_serve_stroke_log_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string file = (dir / "art.dcs").string();
  // Turns of the painters' batch of 3 samples, as canvas_config(): the two streamed strokes
  // are then open at once in the recorded order however late the stroke thread takes them (with
  // the default 64, a stroke thread that found a whole stroke queued painted it in one turn).
  Child server({"serve", "--in-memory", "--listen", "127.0.0.1:0", "--canvas", "c", "--canvas", "d", "--edge", "8",
                "--max-depth", "12", "--max-strokes-per-second", "0", "--samples-per-turn", "3",
                "--stroke-log", file});
  ASSERT_TRUE(server.wait_for("event=listening", 60s)) << server.output();
  const std::string text = server.output();
  const auto at = text.find("port=", text.find("event=listening"));
  const int port = std::stoi(text.substr(at + 5));
  {
    client_core::ClientOptions o;
    o.url = "ws://127.0.0.1:" + std::to_string(port) + "/";
    o.canvas = "c";
    o.block_frames = false;
    auto a = connect_ok(o);
    auto b = connect_ok(o);
    o.canvas = "d";
    auto d = connect_ok(o);
    ASSERT_TRUE(a && b && d);
    std::vector<std::pair<Client*, std::uint64_t>> handles;
    paint_interleaved(*a, *b, 27, 3, handles);
    if (HasFatalFailure()) return;
    std::mt19937_64 rng(28);
    auto hd = d->send_stroke(random_stroke(rng));
    ASSERT_TRUE(hd.ok());
    handles.emplace_back(d.get(), *hd);
    for (const auto& [c, h] : handles) ASSERT_TRUE(c->wait_for_ack(h, 120s).ok());
  }
  server.signal(SIGTERM);
  ASSERT_EQ(server.wait_exit(120s), 0) << server.output();
  const std::string log_text = server.output();
  EXPECT_NE(log_text.find("event=stroke_log_closed canvas=c"), std::string::npos) << log_text;
  EXPECT_NE(log_text.find("event=stroke_log_closed canvas=d"), std::string::npos) << log_text;
  EXPECT_EQ(log_text.find("stroke_log_failed"), std::string::npos) << log_text;

  auto c_log = server_core::read_stroke_log_file(file + ".c");
  auto d_log = server_core::read_stroke_log_file(file + ".d");
  ASSERT_TRUE(c_log) << c_log.error().message;
  ASSERT_TRUE(d_log) << d_log.error().message;
  EXPECT_FALSE(c_log->tail);
  EXPECT_FALSE(d_log->tail);
  EXPECT_EQ(d_log->events.size(), 3u);  // one whole stroke of 6 samples: begin, samples, end
  EXPECT_FALSE(std::filesystem::exists(file));

  server_core::CanvasServiceConfig served;  // serve's defaults with the options above
  served.octree.edge_m = 8;
  served.octree.max_depth = 12;
  served.samples_per_turn = 3;
  const auto r = replay(c_log->events, served);
  EXPECT_GE(r.most_open, 2u);
  EXPECT_EQ(r.painted.size(), 3u * 2 + 1);  // two streamed strokes a round, one whole one
  char want[64];
  std::snprintf(want, sizeof want, "\"canvas_hash\":\"%016llx\"",
                static_cast<unsigned long long>(r.canvas_hash));
  Child replayer({"replay", "--json", "--quiet", "--edge", "8", "--max-depth", "12", file + ".c"},
                 true);
  ASSERT_EQ(replayer.wait_exit(300s), 0) << replayer.output();
  EXPECT_NE(replayer.output().find(want), std::string::npos)
      << "want " << want << " in " << replayer.output();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace deepcanvas::test
