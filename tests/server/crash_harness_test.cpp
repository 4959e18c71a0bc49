// The crash harness: rounds of start the server (`deepcanvas-server serve --data DIR`), two
// painters streaming strokes at full speed, kill -9 at a random moment, restart. Verified each
// round, on a copy of the data directory as the crash left it:
//   * every stroke a painter got an ack for is in the history (its end event is stored);
//   * the canvas a restart restores (newest checkpoint + the events after it) equals a replay of
//     the whole history from nothing (canvas_hash and pool_hash);
//   * the server restarts on the directory and listens within the restart bound.
// The default suite runs DEEPCANVAS_CRASH_ROUNDS (3) rounds; `ctest -L soak` runs 100
// (crash_harness_soak).
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <atomic>
#include <deque>
#include <filesystem>
#include <mutex>
#include <random>
#include <set>
#include <thread>

#include "child_process.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/storage/canvas_store.hpp"
#include "deepcanvas/storage/durable_canvas.hpp"
#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

namespace fs = std::filesystem;

int rounds() {
  const char* v = std::getenv("DEEPCANVAS_CRASH_ROUNDS");
  return v && *v ? std::max(1, std::atoi(v)) : 3;
}

// serve's canvas with --edge 8 --max-depth 12 (what the harness starts it with).
server_core::CanvasServiceConfig served_canvas() {
  server_core::CanvasServiceConfig c;
  c.name = "c";
  c.octree.edge_m = 8;
  c.octree.max_depth = 12;
  return c;
}

// Paints whole strokes as fast as the server acks them (at most 8 unanswered) until the
// connection ends; records the canvas stroke id of every ack.
void painter(int port, std::uint64_t seed, std::set<std::uint64_t>& acked, std::mutex& mutex) {
  client_core::ClientOptions o;
  o.url = "ws://127.0.0.1:" + std::to_string(port) + "/";
  o.canvas = "c";
  o.block_frames = false;
  auto c = client_core::Client::connect(o);
  if (!c) return;
  std::mt19937_64 rng(seed);
  std::deque<std::uint64_t> waiting;
  for (;;) {
    while (waiting.size() < 8) {
      auto h = (*c)->send_stroke(random_stroke(rng, 12));
      if (!h) return;
      waiting.push_back(*h);
    }
    auto a = (*c)->wait_for_ack(waiting.front(), 10s);
    if (!a) return;  // the server is gone
    waiting.pop_front();
    std::lock_guard lock(mutex);
    acked.insert(a->stroke_id);
  }
}

// The stroke ids with an end event in the history.
std::set<std::uint64_t> ended_strokes(const std::string& db) {
  std::set<std::uint64_t> out;
  sqlite3* h = nullptr;
  EXPECT_EQ(sqlite3_open_v2(db.c_str(), &h, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  EXPECT_EQ(sqlite3_prepare_v2(h, "SELECT stroke FROM events WHERE kind = 3", -1, &st, nullptr),
            SQLITE_OK);
  while (sqlite3_step(st) == SQLITE_ROW)
    out.insert(static_cast<std::uint64_t>(sqlite3_column_int64(st, 0)));
  sqlite3_finalize(st);
  sqlite3_close(h);
  return out;
}

void copy_dir(const fs::path& from, const fs::path& to) {
  fs::remove_all(to);
  fs::create_directories(to);
  for (const auto& e : fs::directory_iterator(from))
    if (e.path().filename() != "lock") fs::copy(e.path(), to / e.path().filename());
}

struct Restored {
  std::uint64_t canvas_hash = 0, pool_hash = 0;
  storage::RestoreReport report;
};

// What a restart makes of the directory (restored in-process, then stopped).
Restored restore(const fs::path& dir) {
  Restored r;
  auto svc = storage::open_durable_canvas(dir.string(), served_canvas(), {}, false, &r.report);
  EXPECT_TRUE(svc.ok()) << (svc ? "" : svc.error().message);
  if (!svc) return r;
  auto q = (*svc)->quiesce();
  EXPECT_TRUE(q.ok());
  if (q) {
    r.canvas_hash = q->canvas_hash;
    r.pool_hash = q->pool_hash;
  }
  return r;
}

TEST(CrashHarness, AckedStrokesSurviveKill9AndTheRestoredCanvasIsItsHistory) {
  base::set_log_level(base::LogLevel::off);
  const fs::path base = fs::path(::testing::TempDir()) / ("dc_crash_" + std::to_string(::getpid()));
  const fs::path data = base / "data";
  fs::remove_all(base);
  fs::create_directories(data);
  std::mt19937_64 rng(2026);
  std::set<std::uint64_t> acked_all;
  std::uint64_t acked_lost = 0;
  const int n = rounds();
  for (int round = 0; round < n; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    const auto t0 = std::chrono::steady_clock::now();
    Child server({"serve", "--data", data.string(), "--listen", "127.0.0.1:0", "--canvas", "c",
                  "--edge", "8", "--max-depth", "12", "--max-strokes-per-second", "0",
                  "--checkpoint-every", "0.3"});
    ASSERT_TRUE(server.wait_for("event=listening", 60s)) << server.output();
    const double start_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_LT(start_s, 30.0);
    const int port = listening_port(server.output());
    ASSERT_GT(port, 0) << server.output();

    std::mutex mutex;
    std::set<std::uint64_t> acked;
    std::thread a([&] { painter(port, rng(), acked, mutex); });
    std::thread b([&] { painter(port, rng(), acked, mutex); });
    // Some rounds end before the first checkpoint (the whole history replays), most after one.
    std::this_thread::sleep_for(std::chrono::milliseconds(200 + rng() % 3000));
    server.signal(SIGKILL);
    EXPECT_NE(server.wait_exit(30s), 0);
    a.join();
    b.join();
    {
      std::lock_guard lock(mutex);
      acked_all.insert(acked.begin(), acked.end());
    }

    // Every acked stroke, this round's and earlier ones', is in the history.
    const fs::path image = base / "image";
    copy_dir(data, image);
    const std::set<std::uint64_t> ended = ended_strokes((image / "c.canvas").string());
    for (std::uint64_t id : acked_all) acked_lost += ended.count(id) ? 0 : 1;
    EXPECT_EQ(acked_lost, 0u);

    // The restart's canvas is the history's. Replaying the whole history costs as much as the
    // history is long, so a long soak checks it every tenth round (and the last).
    if (n > 10 && round % 10 != 9 && round != n - 1) {
      std::printf("round %d: %zu acked (%zu in all), history %zu strokes, server listened after "
                  "%.2f s\n",
                  round, acked.size(), acked_all.size(), ended.size(), start_s);
      continue;
    }
    const Restored restored = restore(image);
    const fs::path scratch = base / "scratch";
    copy_dir(data, scratch);
    {
      sqlite3* h = nullptr;
      ASSERT_EQ(sqlite3_open((scratch / "c.canvas").string().c_str(), &h), SQLITE_OK);
      ASSERT_EQ(sqlite3_exec(h, "DELETE FROM checkpoint_blocks; DELETE FROM checkpoints;", nullptr,
                             nullptr, nullptr),
                SQLITE_OK);
      sqlite3_close(h);
    }
    const Restored replayed = restore(scratch);
    EXPECT_EQ(replayed.report.checkpoint_id, 0u);
    EXPECT_EQ(restored.canvas_hash, replayed.canvas_hash);
    EXPECT_EQ(restored.pool_hash, replayed.pool_hash);
    std::printf("round %d: %zu acked (%zu in all), history %zu strokes, restart from checkpoint "
                "%llu + %llu events, server listened after %.2f s\n",
                round, acked.size(), acked_all.size(), ended.size(),
                static_cast<unsigned long long>(restored.report.checkpoint_id),
                static_cast<unsigned long long>(restored.report.events_replayed), start_s);
  }
  EXPECT_GT(acked_all.size(), 0u);
  fs::remove_all(base);
}

// The operator's view of two faults: a second server on a held directory is refused with the
// holder's pid; a corrupt record in the middle of the history stops the start naming canvas,
// file and event, and --salvage starts with the events before it.
TEST(CrashHarness, AHeldDirectoryAndACorruptHistoryAreRefusedClearly) {
  base::set_log_level(base::LogLevel::off);
  const fs::path base = fs::path(::testing::TempDir()) / ("dc_faults_" + std::to_string(::getpid()));
  const fs::path data = base / "data";
  fs::remove_all(base);
  const std::vector<std::string> serve = {"serve", "--data", data.string(), "--listen",
                                          "127.0.0.1:0", "--canvas", "c", "--edge", "8",
                                          "--max-depth", "12"};
  {
    Child first(serve);
    ASSERT_TRUE(first.wait_for("event=listening", 60s)) << first.output();
    const int port = listening_port(first.output());
    client_core::ClientOptions o;
    o.url = "ws://127.0.0.1:" + std::to_string(port) + "/";
    o.canvas = "c";
    o.block_frames = false;
    auto c = client_core::Client::connect(o);
    ASSERT_TRUE(c.ok());
    std::mt19937_64 rng(7);
    for (int i = 0; i < 6; ++i) {
      auto h = (*c)->send_stroke(random_stroke(rng, 6));
      ASSERT_TRUE(h.ok());
      ASSERT_TRUE((*c)->wait_for_ack(*h, 60s).ok());
    }
    Child second(serve);
    EXPECT_EQ(second.wait_exit(60s), 1) << second.output();
    EXPECT_NE(second.output().find("is in use by another server (pid " +
                                   std::to_string(first.pid()) + ")"),
              std::string::npos)
        << second.output();
    first.signal(SIGKILL);
    (void)first.wait_exit(30s);
  }
  // Damage event 3 of the history (the events are the history: a checkpoint does not help).
  const std::string db = (data / "c.canvas").string();
  {
    sqlite3* h = nullptr;
    ASSERT_EQ(sqlite3_open(db.c_str(), &h), SQLITE_OK);
    ASSERT_EQ(sqlite3_exec(h,
                           "DELETE FROM checkpoint_blocks; DELETE FROM checkpoints; UPDATE events "
                           "SET record = CAST(substr(record, 1, 14) || 'X' || substr(record, 16) "
                           "AS BLOB) WHERE seq = 3",
                           nullptr, nullptr, nullptr),
              SQLITE_OK);
    sqlite3_close(h);
  }
  {
    Child refused(serve);
    EXPECT_EQ(refused.wait_exit(60s), 1) << refused.output();
    const std::string out = refused.output();
    EXPECT_NE(out.find("canvas 'c'"), std::string::npos) << out;
    EXPECT_NE(out.find(db), std::string::npos) << out;
    EXPECT_NE(out.find("event 3"), std::string::npos) << out;
    EXPECT_NE(out.find("--salvage"), std::string::npos) << out;
  }
  {
    auto salvage = serve;
    salvage.push_back("--salvage");
    Child started(salvage);
    ASSERT_TRUE(started.wait_for("event=listening", 60s)) << started.output();
    EXPECT_NE(started.output().find("events_replayed=2"), std::string::npos) << started.output();
    started.signal(SIGTERM);
    EXPECT_EQ(started.wait_exit(60s), 0) << started.output();
  }
  fs::remove_all(base);
}

// How many events of `kind` the history holds.
std::uint64_t count_events(const std::string& db, int kind) {
  std::uint64_t n = 0;
  sqlite3* h = nullptr;
  EXPECT_EQ(sqlite3_open_v2(db.c_str(), &h, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  EXPECT_EQ(sqlite3_prepare_v2(h, "SELECT count(*) FROM events WHERE kind = ?", -1, &st, nullptr),
            SQLITE_OK);
  sqlite3_bind_int(st, 1, kind);
  if (sqlite3_step(st) == SQLITE_ROW) n = static_cast<std::uint64_t>(sqlite3_column_int64(st, 0));
  sqlite3_finalize(st);
  sqlite3_close(h);
  return n;
}

// A client that missed its acks when the server was killed resends its strokes after the
// restart with the same client id and handles: the strokes whose end was durable are answered
// with their ack (the same stroke ids) and painted once; a stroke cut off by the kill (begun,
// not ended) is taken back by the restart and painted again whole when resent, and acked as a
// new stroke; so is one that its dropped connection cut short before the kill (the server ended
// it, as the server's end, not its sender's).
TEST(CrashHarness, StrokesResentAfterKill9AreAnsweredNotPaintedTwice) {
  base::set_log_level(base::LogLevel::off);
  const fs::path base = fs::path(::testing::TempDir()) / ("dc_resend_" + std::to_string(::getpid()));
  const fs::path data = base / "data";
  fs::remove_all(base);
  const std::vector<std::string> serve = {"serve", "--data", data.string(), "--listen",
                                          "127.0.0.1:0", "--canvas", "c", "--edge", "8",
                                          "--max-depth", "12"};
  const std::string db = (data / "c.canvas").string();
  const auto connect = [](int port) {
    client_core::ClientOptions o;
    o.url = "ws://127.0.0.1:" + std::to_string(port) + "/";
    o.canvas = "c";
    o.block_frames = false;
    o.client_id = "resending-artist";
    return client_core::Client::connect(o);
  };
  std::mt19937_64 rng(11);
  std::vector<protocol::Stroke> strokes;
  for (int i = 0; i < 6; ++i) strokes.push_back(random_stroke(rng, 6));
  std::vector<std::uint64_t> ids;
  std::uint64_t begins_before = 0;
  {
    Child server(serve);
    ASSERT_TRUE(server.wait_for("event=listening", 60s)) << server.output();
    auto c = connect(listening_port(server.output()));
    ASSERT_TRUE(c.ok()) << c.error().message;
    for (std::uint64_t h = 1; h <= 4; ++h) {
      ASSERT_TRUE(
          (*c)->send_text(protocol::encode_message(protocol::StrokeMessage{h, strokes[h - 1]}))
              .ok());
      auto a = (*c)->wait_for_ack(h, 60s);
      ASSERT_TRUE(a.ok()) << a.error().message;
      ids.push_back(a->stroke_id);
    }
    {
      // Stroke 6 is begun on a second connection that then drops: the server ends it cut short.
      auto dropped = connect(listening_port(server.output()));
      ASSERT_TRUE(dropped.ok()) << dropped.error().message;
      const auto& samples = strokes[5].samples;
      ASSERT_TRUE((*dropped)
                      ->send_text(protocol::encode_message(protocol::StrokeBegin{
                          6, strokes[5].brush, {samples.begin(), samples.begin() + 2}}))
                      .ok());
      std::this_thread::sleep_for(300ms);
    }
    // Stroke 5 is begun and never ended: the kill cuts it off.
    ASSERT_TRUE((*c)->send_text(protocol::encode_message(protocol::StrokeBegin{
                                    5, strokes[4].brush, {strokes[4].samples.front()}}))
                    .ok());
    std::this_thread::sleep_for(500ms);  // its begin reaches the history
    server.signal(SIGKILL);
    EXPECT_NE(server.wait_exit(30s), 0);
    begins_before = count_events(db, 1);
  }
  {
    Child server(serve);
    ASSERT_TRUE(server.wait_for("event=listening", 60s)) << server.output();
    EXPECT_NE(server.output().find("stroke_names=4"), std::string::npos) << server.output();
    EXPECT_NE(server.output().find("strokes_cut_named=2"), std::string::npos) << server.output();
    auto c = connect(listening_port(server.output()));
    ASSERT_TRUE(c.ok()) << c.error().message;
    for (std::uint64_t h = 1; h <= 6; ++h)
      ASSERT_TRUE(
          (*c)->send_text(protocol::encode_message(protocol::StrokeMessage{h, strokes[h - 1]}))
              .ok());
    for (std::uint64_t h = 1; h <= 6; ++h) {
      auto a = (*c)->wait_for_ack(h, 60s);
      ASSERT_TRUE(a.ok()) << "handle " << h << ": " << a.error().message;
      if (h <= 4)
        EXPECT_EQ(a->stroke_id, ids[h - 1]) << "handle " << h;
      else
        EXPECT_GT(a->stroke_id, ids.back());
    }
    // Before the resends of the two cut strokes were painted, what the restart kept of them was
    // taken back.
    EXPECT_TRUE(server.wait_for("event=cut_stroke_withdrawn", 30s)) << server.output();
    const auto withdrawn = [&] {
      const std::string out = server.output();
      std::size_t n = 0;
      for (auto at = out.find("event=cut_stroke_withdrawn"); at != std::string::npos;
           at = out.find("event=cut_stroke_withdrawn", at + 1))
        ++n;
      return n;
    };
    for (int i = 0; i < 300 && withdrawn() < 2; ++i) std::this_thread::sleep_for(100ms);
    EXPECT_EQ(withdrawn(), 2u) << server.output();
    server.signal(SIGTERM);
    EXPECT_EQ(server.wait_exit(60s), 0) << server.output();
  }
  // Only the two cut strokes were painted again.
  EXPECT_EQ(count_events(db, 1), begins_before + 2);
  {
    // The next start names the six strokes their sender ended (the resends); the two cut ones,
    // answered by their resends, are not named cut again.
    Child server(serve);
    ASSERT_TRUE(server.wait_for("event=listening", 60s)) << server.output();
    EXPECT_NE(server.output().find("stroke_names=6"), std::string::npos) << server.output();
    EXPECT_NE(server.output().find("strokes_cut_named=0"), std::string::npos) << server.output();
    server.signal(SIGTERM);
    EXPECT_EQ(server.wait_exit(60s), 0) << server.output();
  }
  fs::remove_all(base);
}

}  // namespace
}  // namespace deepcanvas::test
