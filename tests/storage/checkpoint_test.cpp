// Incremental checkpoints: written from a painted tree (Octree::save_allocator / save_block of
// the blocks whose version changed), loaded back to the same pool and canvas hashes, a damaged
// checkpoint falls back to the previous one, replaying the events after it gives the final
// canvas, and a failed checkpoint's blocks are merged into the next one.
#include <atomic>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_core/event_replay.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "storage_test_util.hpp"

namespace deepcanvas::test {
namespace {

using server_core::CheckpointData;
using server_core::Octree;
using server_core::Painter;
using server_core::StrokeEvent;
using storage::CanvasStore;

// The events of one stroke: its begin with a few samples, the rest in one batch, its end.
std::vector<StrokeEvent> stroke(std::mt19937_64& rng, std::uint64_t id) {
  std::uniform_real_distribution<double> pos(-1.0, 1.0), step(-0.06, 0.06);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  StrokeEvent begin;
  begin.kind = StrokeEvent::Kind::begin;
  begin.stroke_id = id;
  begin.brush.colour[0] = u(rng);
  begin.brush.colour[1] = u(rng);
  begin.brush.colour[2] = u(rng);
  begin.brush.colour[3] = 0.5f + u(rng) / 2;
  begin.brush.opacity = 0.5f + u(rng) / 2;
  double x = pos(rng), y = pos(rng), z = pos(rng);
  StrokeEvent more;
  more.kind = StrokeEvent::Kind::samples;
  more.stroke_id = id;
  for (int i = 0; i < 10; ++i) {
    protocol::StrokeSample s;
    s.x = x;
    s.y = y;
    s.z = z;
    s.radius = 0.03f + 0.05f * u(rng);
    s.pressure = 0.6f + 0.4f * u(rng);
    s.t_ms = static_cast<std::uint32_t>(10 * i);
    (i < 3 ? begin.samples : more.samples).push_back(s);
    x += step(rng);
    y += step(rng);
    z += step(rng);
  }
  StrokeEvent end;
  end.kind = StrokeEvent::Kind::end;
  end.stroke_id = id;
  return {begin, more, end};
}

// A canvas being painted, its events appended to a store (like the stroke thread).
struct Live {
  Octree* tree = nullptr;
  std::unique_ptr<Painter> painter;
  std::vector<std::uint64_t> versions;  // block versions at the last checkpoint handed over
  std::uint64_t next_stroke = 1;
  std::uint64_t seq = 0;

  void paint(const StrokeEvent& e) {
    Result<void> r = e.kind == StrokeEvent::Kind::begin
                         ? painter->begin_stroke(e.brush, e.stroke_id, e.samples)
                     : e.kind == StrokeEvent::Kind::samples
                         ? painter->add_samples(e.stroke_id, e.samples)
                         : painter->end_stroke(e.stroke_id);
    ASSERT_TRUE(r.ok()) << r.error().message;
    for (;;) {
      auto more = painter->step();
      ASSERT_TRUE(more.ok()) << more.error().message;
      if (!*more) break;
    }
  }
  // Paints `n` strokes, appending each event first; returns the events.
  std::vector<StrokeEvent> strokes(CanvasStore& store, std::mt19937_64& rng, int n) {
    std::vector<StrokeEvent> out;
    for (int i = 0; i < n; ++i) {
      for (auto& e : stroke(rng, next_stroke)) {
        seq = store.append(e, 1);
        paint(e);
        out.push_back(std::move(e));
      }
      ++next_stroke;
    }
    return out;
  }
  // The blocks changed since the last checkpoint (all of them the first time).
  CheckpointData checkpoint() {
    CheckpointData d;
    d.event_seq = seq;
    d.next_stroke_id = next_stroke;
    d.block_count = tree->block_count();
    d.allocator = tree->save_allocator();
    versions.resize(d.block_count, ~std::uint64_t{0});
    for (server_core::BlockId b = 0; b < d.block_count; ++b) {
      const auto v = tree->block_state(b).version;
      if (versions[b] == v) continue;
      versions[b] = v;
      d.blocks.push_back({b, v, tree->save_block(b)});
    }
    return d;
  }
};

struct Hashes {
  std::uint64_t pool = 0, canvas = 0;
  friend bool operator==(const Hashes&, const Hashes&) = default;
};
Hashes hashes(const Octree& t) { return {t.pool_hash(), t.canvas_hash()}; }

class CheckpointTest : public ::testing::Test {
 protected:
  void SetUp() override { base::set_log_level(base::LogLevel::off); }
  void TearDown() override { base::set_log_level(base::LogLevel::info); }
  TempDir dir;
};

Hashes replayed(storage::LoadedCanvas& l) {
  auto painter = Painter::create(*l.tree);
  EXPECT_TRUE(painter.ok());
  if (!painter) return {};
  const auto totals = server_core::replay_stroke_events(**painter, l.events_after);
  EXPECT_EQ(totals.rejected, 0u);
  EXPECT_EQ(totals.events, l.events_after.size());
  return hashes(*l.tree);
}

TEST_F(CheckpointTest, IncrementalRoundTripAndFallback) {
  std::mt19937_64 rng(42);
  Hashes h1, h2, h3;
  std::size_t after1 = 0, after2 = 0;
  std::uint64_t blocks1 = 0, blocks2 = 0;
  {
    auto s = CanvasStore::open(dir.path(), "c", small_octree(), fast_options());
    ASSERT_TRUE(s.ok()) << s.error().message;
    auto& store = **s;
    auto l = store.load();
    ASSERT_TRUE(l.ok()) << l.error().message;
    store.start();
    Live live;
    live.tree = l->tree.get();
    auto p = Painter::create(*live.tree);
    ASSERT_TRUE(p.ok());
    live.painter = std::move(*p);

    live.strokes(store, rng, 4);
    auto d1 = live.checkpoint();
    blocks1 = d1.blocks.size();
    EXPECT_EQ(blocks1, d1.block_count);  // the first holds every block
    h1 = hashes(*live.tree);
    store.checkpoint(std::move(d1));

    // More strokes: only the blocks they change go into the second checkpoint.
    const auto e2 = live.strokes(store, rng, 3);
    auto d2 = live.checkpoint();
    blocks2 = d2.blocks.size();
    EXPECT_LT(blocks2, d2.block_count);  // incremental: some blocks did not change
    h2 = hashes(*live.tree);
    EXPECT_NE(h1, h2);
    store.checkpoint(std::move(d2));

    const auto e3 = live.strokes(store, rng, 3);
    h3 = hashes(*live.tree);
    after1 = e2.size() + e3.size();
    after2 = e3.size();
    ASSERT_TRUE(wait_until([&] { return store.checkpoints_written() == 2; }));
    store.close();
    EXPECT_EQ(store.checkpoints_failed(), 0u);
  }
  const std::string path = canvas_path(dir.path(), "c");
  {
    auto sum = storage::summarize(path);
    ASSERT_TRUE(sum.ok()) << sum.error().message;
    ASSERT_EQ(sum->checkpoints.size(), 2u);
    EXPECT_EQ(sum->checkpoints[0].blocks_written, blocks1);
    EXPECT_EQ(sum->checkpoints[1].blocks_written, blocks2);
    EXPECT_GT(sum->checkpoints[1].bytes, 0u);
    EXPECT_EQ(sum->integrity, "ok");
  }
  {
    auto s = CanvasStore::open(dir.path(), "c", small_octree(), fast_options());
    ASSERT_TRUE(s.ok());
    auto l = (*s)->load();
    ASSERT_TRUE(l.ok()) << l.error().message;
    EXPECT_EQ(l->checkpoint_id, 2u);
    EXPECT_TRUE(l->notes.empty());
    EXPECT_EQ(hashes(*l->tree), h2);
    ASSERT_TRUE(l->tree->check_invariants().ok());
    EXPECT_EQ(l->events_after.size(), after2);
    EXPECT_EQ(l->next_stroke_id, 11u);
    EXPECT_EQ(replayed(*l), h3);
  }
  // Damage the newest checkpoint: load falls back to the first and the replay still ends at h3.
  flip_blob_byte(path, "checkpoint_blocks", "data",
                 "checkpoint = 2 AND block = (SELECT max(block) FROM checkpoint_blocks WHERE "
                 "checkpoint = 2)",
                 -3);
  {
    auto s = CanvasStore::open(dir.path(), "c", small_octree(), fast_options());
    ASSERT_TRUE(s.ok());
    auto l = (*s)->load();
    ASSERT_TRUE(l.ok()) << l.error().message;
    EXPECT_EQ(l->checkpoint_id, 1u);
    ASSERT_FALSE(l->notes.empty());
    EXPECT_NE(l->notes[0].find("checkpoint 2 of canvas 'c' (" + path + "): block"),
              std::string::npos)
        << l->notes[0];
    EXPECT_NE(l->notes[0].find("falling back to checkpoint 1"), std::string::npos)
        << l->notes[0];
    EXPECT_EQ(hashes(*l->tree), h1);
    EXPECT_EQ(l->events_after.size(), after1);
    EXPECT_EQ(replayed(*l), h3);
  }
  // The bad checkpoint is gone; the good one stays.
  auto sum = storage::summarize(path);
  ASSERT_TRUE(sum.ok());
  EXPECT_EQ(sum->checkpoints.size(), 1u);
  // Damage the last one too: the whole history replays.
  flip_blob_byte(path, "checkpoints", "allocator", "id = 1", 9);
  auto s = CanvasStore::open(dir.path(), "c", small_octree(), fast_options());
  ASSERT_TRUE(s.ok());
  auto l = (*s)->load();
  ASSERT_TRUE(l.ok()) << l.error().message;
  EXPECT_EQ(l->checkpoint_id, 0u);
  EXPECT_NE(l->notes[0].find("allocator: checksum mismatch"), std::string::npos) << l->notes[0];
  EXPECT_EQ(replayed(*l), h3);
}

TEST_F(CheckpointTest, FailedCheckpointIsMergedIntoTheNext) {
  std::mt19937_64 rng(7);
  std::atomic<bool> full{false};
  auto o = fast_options();
  o.before_write = [&]() -> Result<void> {
    if (full) return Error{Errc::io_error, "disk full (injected)"};
    return {};
  };
  Hashes h2;
  {
    auto s = CanvasStore::open(dir.path(), "c", small_octree(), o);
    ASSERT_TRUE(s.ok());
    auto& store = **s;
    auto l = store.load();
    ASSERT_TRUE(l.ok());
    store.start();
    Live live;
    live.tree = l->tree.get();
    live.painter = Painter::create(*live.tree).value();
    live.strokes(store, rng, 4);
    ASSERT_TRUE(wait_until([&] { return store.durable_seq() == live.seq; }));
    full = true;
    store.checkpoint(live.checkpoint());  // the first: every block; fails
    ASSERT_TRUE(wait_until([&] { return store.checkpoints_failed() == 1; }));
    full = false;
    live.strokes(store, rng, 2);
    auto d2 = live.checkpoint();  // only the blocks changed since the failed one
    h2 = hashes(*live.tree);
    store.checkpoint(std::move(d2));
    ASSERT_TRUE(wait_until([&] { return store.checkpoints_written() == 1; }));
    store.close();
  }
  auto s = CanvasStore::open(dir.path(), "c", small_octree(), fast_options());
  ASSERT_TRUE(s.ok());
  auto l = (*s)->load();
  ASSERT_TRUE(l.ok()) << l.error().message;
  EXPECT_EQ(l->checkpoint_id, 1u);
  EXPECT_TRUE(l->events_after.empty());
  EXPECT_EQ(hashes(*l->tree), h2);
}

TEST_F(CheckpointTest, IncompleteFirstCheckpointIsRefused) {
  std::mt19937_64 rng(3);
  auto s = CanvasStore::open(dir.path(), "c", small_octree(), fast_options());
  ASSERT_TRUE(s.ok());
  auto& store = **s;
  auto l = store.load();
  ASSERT_TRUE(l.ok());
  store.start();
  Live live;
  live.tree = l->tree.get();
  live.painter = Painter::create(*live.tree).value();
  live.strokes(store, rng, 2);
  auto d = live.checkpoint();
  ASSERT_FALSE(d.blocks.empty());
  d.blocks.erase(d.blocks.begin());
  store.checkpoint(std::move(d));
  ASSERT_TRUE(wait_until([&] { return store.checkpoints_failed() == 1; }));
  store.close();
  EXPECT_EQ(store.checkpoints_written(), 0u);
}

}  // namespace
}  // namespace deepcanvas::test
