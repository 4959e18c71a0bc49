// CanvasService without a network: ordering, acks, epochs, snapshots, coalescing subscriptions,
// and the consistency rule (a replica that applies whole batches never has a dangling reachable
// cell). Streamed strokes, turns and the strokes the server ends or refuses:
// canvas_service_strokes_test.cpp.
#include <gtest/gtest.h>

#include <atomic>
#include <condition_variable>
#include <future>
#include <map>
#include <mutex>
#include <algorithm>
#include <set>
#include <thread>

#include "deepcanvas/client_core/replica.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/density_model.hpp"
#include "deepcanvas/protocol/frame_bundle.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "canvas_service_test_util.hpp"
#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

using server_core::CanvasService;
using server_core::Subscription;

client_core::Replica make_replica(const CanvasService& svc) {
  return client_core::Replica(client_core::ReplicaGeometry{svc.config().octree.roots_per_axis,
                                                           svc.config().octree.edge_m,
                                                           svc.config().octree.block_cells});
}

// The block frames of a batch, decoded in order (those in bundles one by one).
std::vector<protocol::BlockFrame> decode_batch(const Subscription::Batch& b,
                                               std::uint32_t block_cells) {
  protocol::BlockDecoder dec;
  protocol::BundleDecoder bundles;
  protocol::BlockDecodeLimits lim{block_cells, block_cells};
  std::vector<protocol::BlockFrame> out;
  for (const auto& f : b.frames) {
    protocol::BlockFrame frame;
    if (protocol::is_bundle(*f)) {
      auto d = bundles.decode(*f, {lim}, frame, [&](protocol::BlockFrame& one) -> Result<void> {
        out.push_back(std::move(one));
        return {};
      });
      EXPECT_TRUE(d.ok()) << d.error().message;
      continue;
    }
    auto d = dec.decode(*f, frame, lim);
    EXPECT_TRUE(d.ok()) << d.error().message;
    out.push_back(std::move(frame));
  }
  return out;
}

// Decodes a batch into the replica and commits it (what a client does at epoch_end).
void apply(client_core::Replica& r, const Subscription::Batch& b, std::uint32_t block_cells) {
  auto frames = decode_batch(b, block_cells);
  EXPECT_EQ(frames.size(), b.block_frames);
  for (auto& frame : frames) ASSERT_TRUE(r.stage(std::move(frame)).ok());
  r.commit();
}

// Every cell reachable from the roots names a received, live group that points back at it.
::testing::AssertionResult no_dangling_cells(const client_core::Replica& r) {
  const auto v = r.view();
  std::vector<std::uint32_t> stack;
  for (std::uint32_t c = 0; c < v.root_count(); ++c) {
    if (c >= v.cell_count()) return ::testing::AssertionFailure() << "root " << c << " missing";
    stack.push_back(c);
  }
  while (!stack.empty()) {
    const std::uint32_t c = stack.back();
    stack.pop_back();
    const std::uint32_t fc = v.first_child[c];
    if (fc == client_core::PoolView::kNoCell) continue;
    if (fc % 8 || std::uint64_t{fc} + 8 > v.cell_count())
      return ::testing::AssertionFailure()
             << "cell " << c << " points at " << fc << " beyond the received pools";
    const std::uint32_t g = fc / 8;
    if (v.group_depth_flags[g] & client_core::PoolView::kFreeFlag)
      return ::testing::AssertionFailure() << "cell " << c << " points at a free group";
    if (v.group_parent[g] != c)
      return ::testing::AssertionFailure() << "group " << g << " does not point back at " << c;
    if (v.depth(fc) != v.depth(c) + 1)
      return ::testing::AssertionFailure() << "group " << g << " has the wrong depth";
    for (std::uint32_t i = 0; i < 8; ++i) stack.push_back(fc + i);
  }
  return ::testing::AssertionSuccess();
}

// Replays `events` on a fresh painter with the service's step schedule: after each event a small
// first step (so that the turn's first epoch is small), then full steps to completion. The canvas
// does not depend on the schedule; the cell allocation order (pool_hash) does.
void replay_events(const CanvasService& svc, const std::vector<server_core::StrokeEvent>& events,
                   server_core::Octree& tree) {
  server_core::PainterConfig pc;
  pc.max_cells_per_step = svc.config().max_cells_per_step;
  pc.limits = svc.config().stroke_limits;
  auto painter = server_core::Painter::create(tree, pc);
  ASSERT_TRUE(painter.ok());
  const std::uint64_t first =
      std::min(svc.config().max_cells_first_step, svc.config().max_cells_per_step);
  using Kind = server_core::StrokeEvent::Kind;
  for (const auto& e : events) {
    const auto r = e.kind == Kind::begin     ? (*painter)->begin_stroke(e.brush, e.stroke_id, e.samples)
                   : e.kind == Kind::samples ? (*painter)->add_samples(e.stroke_id, e.samples)
                                             : (*painter)->end_stroke(e.stroke_id);
    ASSERT_TRUE(r.ok()) << r.error().message;
    auto more = (*painter)->step(first);
    ASSERT_TRUE(more.ok());
    while (*more) {
      more = (*painter)->step();
      ASSERT_TRUE(more.ok());
    }
  }
}

// Six artists' strokes sent whole at once take turns of three samples: the painter gets them
// interleaved, every stroke is acked once, and replaying the recorded events gives the same
// canvas, cell for cell (the server adds nothing of its own). A seventh stroke, from the first
// artist again, waits for that artist's first to finish. Each stroke's end is given with its
// last samples.
TEST(CanvasService, InterleavedStrokesAreAckedAndTheirEventsReplayExactly) {
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.samples_per_turn = 3;
  cfg.turn_seconds = 0;  // turns of exactly 3, however long they take to paint
  std::mutex m;  // the acks
  EventLog log;
  log.attach(cfg);
  auto& events = log.events;  // read once the service has quiesced
  auto created = CanvasService::create(cfg);
  ASSERT_TRUE(created.ok());
  auto& svc = **created;
  std::mt19937_64 rng(1);
  std::vector<protocol::Stroke> strokes;
  for (int i = 0; i < 7; ++i) strokes.push_back(random_stroke(rng, 12));
  std::vector<server_core::StrokeDone> acks;
  for (std::size_t i = 0; i < strokes.size(); ++i)
    ASSERT_TRUE(submit(
                    svc, strokes[i],
                    [&](Result<server_core::StrokeDone> r) {
                      ASSERT_TRUE(r.ok());
                      std::lock_guard lock(m);
                      acks.push_back(*r);
                    },
                    1 + i % 6)
                    .ok());
  auto q = svc.quiesce();
  ASSERT_TRUE(q.ok());
  std::lock_guard lock(m);
  ASSERT_EQ(acks.size(), strokes.size());
  std::set<std::uint64_t> ids;
  for (std::size_t i = 0; i < acks.size(); ++i) {
    ids.insert(acks[i].stroke_id);
    if (i) {
      EXPECT_GE(acks[i].epoch, acks[i - 1].epoch);  // acks go out in epoch order
    }
    EXPECT_LE(acks[i].epoch, q->epoch);
  }
  EXPECT_EQ(ids.size(), strokes.size());
  EXPECT_EQ(q->strokes, strokes.size());
  // Each stroke: one begin, its samples in order, one end; 12 samples in turns of 3.
  std::map<std::uint64_t, std::size_t> samples_seen;
  for (const auto& e : events) {
    samples_seen[e.stroke_id] += e.samples.size();
    EXPECT_LE(e.samples.size(), 3u);
  }
  for (const auto& [id, n] : samples_seen) EXPECT_EQ(n, 12u) << "stroke " << id;
  EXPECT_EQ(events.size(), 7u * (4 + 1));
  // Stroke 7 (artist 1's second) begins only after stroke 1 has ended.
  auto at = [&](std::uint64_t id, server_core::StrokeEvent::Kind k) {
    for (std::size_t i = 0; i < events.size(); ++i)
      if (events[i].stroke_id == id && events[i].kind == k) return i;
    return events.size();
  };
  using Kind = server_core::StrokeEvent::Kind;
  EXPECT_LT(at(1, Kind::end), at(7, Kind::begin));
  // A stroke's end rides with its last samples, in the same turn: no other stroke's event
  // comes between them, so an ended stroke waits for one other artist's turn, not two.
  for (std::uint64_t id = 1; id <= strokes.size(); ++id) {
    const std::size_t end = at(id, Kind::end);
    ASSERT_LT(end, events.size());
    ASSERT_GT(end, 0u);
    EXPECT_EQ(events[end - 1].stroke_id, id) << "stroke " << id;
    EXPECT_EQ(events[end - 1].kind, Kind::samples) << "stroke " << id;
  }

  auto tree = server_core::Octree::create(svc.config().octree);
  ASSERT_TRUE(tree.ok());
  replay_events(svc, events, **tree);
  (*tree)->refresh_interior_colours();  // as the service's epochs did
  EXPECT_EQ((*tree)->pool_hash(), q->pool_hash);
  EXPECT_EQ((*tree)->canvas_hash(), q->canvas_hash);
}

// The waits the compress thread's histogram counts are real ones: epoch 0, staged at creation,
// is one of them (it once counted the time since the clock's epoch, hours).
TEST(CanvasService, CompressWaitsAreMeasuredFromWhenEachEpochWasStaged) {
  auto svc = make_service();
  ASSERT_TRUE(svc);
  const auto& h = svc->metrics().compress_wait_seconds;
  ASSERT_GE(h.count(), 1u);
  EXPECT_LT(h.sum_seconds(), 60.0);
}

TEST(CanvasService, InvalidStrokeIsRefusedAndChangesNothing) {
  auto svc = make_service();
  ASSERT_TRUE(svc);
  auto before = svc->quiesce();
  ASSERT_TRUE(before.ok());
  std::mt19937_64 rng(2);
  auto s = random_stroke(rng);
  s.samples[1].x = std::numeric_limits<double>::quiet_NaN();
  bool called = false;
  auto r = submit(*svc, s, [&](Result<server_core::StrokeDone>) { called = true; });
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::invalid_argument);
  s = random_stroke(rng);
  s.samples[0].z = 100.0;  // outside the 8 m canvas
  r = submit(*svc, s, [&](auto) { called = true; });
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::invalid_argument);
  auto after = svc->quiesce();
  ASSERT_TRUE(after.ok());
  EXPECT_EQ(before->pool_hash, after->pool_hash);
  EXPECT_FALSE(called);
}

// A joiner's snapshot comes shallowest block first (PROTOCOL.md 4.4, progressive join): the
// shallowest live group of each block frame never decreases along the batch, and the replica
// that applies it equals the server.
TEST(CanvasService, ASnapshotSendsItsShallowestBlocksFirst) {
  auto svc = make_service();
  ASSERT_TRUE(svc);
  std::mt19937_64 rng(31);
  for (int i = 0; i < 30; ++i) ASSERT_TRUE(submit(*svc, random_stroke(rng, 8), {}).ok());
  auto q = svc->quiesce();
  ASSERT_TRUE(q.ok());
  auto joiner = svc->subscribe({});
  auto snap = joiner->take();
  ASSERT_TRUE(snap.has_value());
  ASSERT_TRUE(snap->snapshot);
  protocol::BlockDecoder dec;
  const std::uint32_t bc = svc->config().octree.block_cells;
  std::uint32_t last = 0, blocks = 0;
  std::set<std::uint32_t> depths;
  for (const auto& f : snap->frames) {
    protocol::BlockFrame frame;
    ASSERT_TRUE(dec.decode(*f, frame, {bc, bc}).ok());
    if (!frame.has(protocol::kFieldDepthFlags)) continue;  // the mask-only frames at the end
    std::uint32_t shallowest = 255;
    for (const std::uint8_t df : frame.depth_flags)
      if (!(df & 0x80)) shallowest = std::min<std::uint32_t>(shallowest, df & 31);
    EXPECT_GE(shallowest, last) << "block " << frame.header.block_id;
    last = shallowest;
    depths.insert(shallowest);
    ++blocks;
  }
  EXPECT_GT(blocks, 3u);
  EXPECT_GT(depths.size(), 1u) << "every block starts at one depth: the order shows nothing";
  auto replica = make_replica(*svc);
  apply(replica, *snap, bc);
  EXPECT_EQ(replica.pool_hash(), q->pool_hash);
}

// With a camera (hello "camera", Subscription::set_camera), of the blocks of one depth those in
// front of it come first, nearest first (PROTOCOL.md 4.4). Two clusters of strokes, left (x < 0)
// and right (x > 0). A camera standing between them looking at one side gets, at every depth,
// each block whose shallowest groups all lie on that side before any whose shallowest groups all
// lie on the other (behind it). A camera far out on one side, looking at both, gets the near
// cluster's blocks first at every depth from 4 on (where a group is 25 cm: the clusters' groups
// are then apart in distance). Depth still goes first, and every replica converges.
TEST(CanvasService, ASnapshotSendsTheBlocksNearTheCameraFirstAtEachDepth) {
  auto svc = make_service();
  ASSERT_TRUE(svc);
  std::mt19937_64 rng(77);
  for (const double shift : {-2.2, 2.2})
    for (int i = 0; i < 12; ++i) {
      protocol::Stroke st = random_stroke(rng, 8);
      for (auto& p : st.samples) p.x += shift;
      ASSERT_TRUE(submit(*svc, std::move(st), {}).ok());
    }
  auto q = svc->quiesce();
  ASSERT_TRUE(q.ok());
  std::promise<Result<std::shared_ptr<const server_core::Octree>>> copied;
  ASSERT_TRUE(svc->copy_tree([&](auto r) { copied.set_value(std::move(r)); }).ok());
  auto tree = copied.get_future().get();
  ASSERT_TRUE(tree.ok()) << tree.error().message;
  const std::uint32_t bc = svc->config().octree.block_cells;

  // The side (-1 left, +1 right, 0 both) of a block frame's shallowest groups, and their depth.
  struct Placed {
    std::uint32_t depth = 255;
    int side = 0;
  };
  const auto place = [&](const protocol::BlockFrame& f) {
    Placed pl;
    for (const std::uint8_t df : f.depth_flags)
      if (!(df & 0x80)) pl.depth = std::min<std::uint32_t>(pl.depth, df & 31);
    bool left = false, right = false;
    for (std::size_t g = 0; g < f.depth_flags.size(); ++g) {
      const std::uint8_t df = f.depth_flags[g];
      if ((df & 0x80) || (df & 31u) != pl.depth) continue;
      for (const std::uint32_t corner : {0u, 7u}) {
        const auto c = static_cast<server_core::CellIndex>(f.header.first_cell + 8 * g + corner);
        const auto box = (*tree)->bounds_m((*tree)->coord(c));
        if (box.max.x > 0) right = true;
        if (box.min.x < 0) left = true;
      }
    }
    pl.side = left && right ? 0 : (left ? -1 : 1);
    return pl;
  };
  struct Case {
    protocol::JoinCamera camera;
    int near_side;
    std::uint32_t from_depth;
  };
  const Case cases[] = {{{{-0.3, 0, 0}, {-5, 0, 0}}, -1, 0},
                        {{{0.3, 0, 0}, {5, 0, 0}}, 1, 0},
                        {{{-30, 0, 0}, {0, 0, 0}}, -1, 4},
                        {{{30, 0, 0}, {0, 0, 0}}, 1, 4}};
  for (const Case& cs : cases) {
    SCOPED_TRACE("near side " + std::to_string(cs.near_side) + ", eye x " +
                 std::to_string(cs.camera.eye[0]));
    auto sub = svc->subscribe({});
    sub->set_camera(cs.camera);
    auto snap = sub->take();
    ASSERT_TRUE(snap.has_value());
    protocol::BlockDecoder dec;
    std::uint32_t last_depth = 0;
    std::map<std::uint32_t, int> far_seen;          // depth -> far-side blocks so far
    std::map<std::uint32_t, std::pair<int, int>> count;  // depth -> (near, far) blocks
    for (const auto& f : snap->frames) {
      protocol::BlockFrame frame;
      ASSERT_TRUE(dec.decode(*f, frame, {bc, bc}).ok());
      if (!frame.has(protocol::kFieldDepthFlags)) continue;
      const Placed pl = place(frame);
      EXPECT_GE(pl.depth, last_depth) << "block " << frame.header.block_id;
      last_depth = pl.depth;
      if (pl.depth < cs.from_depth || pl.side == 0) continue;
      if (pl.side == cs.near_side) {
        ++count[pl.depth].first;
        EXPECT_EQ(far_seen[pl.depth], 0) << "block " << frame.header.block_id << " at depth "
                                         << pl.depth << " came after one on the far side";
      } else {
        ++count[pl.depth].second;
        ++far_seen[pl.depth];
      }
    }
    // The order was tested only where one depth holds blocks of both sides; looking right, the
    // right cluster's blocks (painted second, higher ids) then overtook the left's, which block
    // order alone would not do.
    int depths_with_both = 0;
    for (const auto& [d, nf] : count) depths_with_both += nf.first > 0 && nf.second > 0;
    EXPECT_GT(depths_with_both, 0) << "no depth holds blocks of both clusters: nothing to order";
    auto replica = make_replica(*svc);
    apply(replica, *snap, bc);
    EXPECT_EQ(replica.pool_hash(), q->pool_hash);
  }
}

// A subscriber that never takes while strokes are painted gets, in one take, each changed
// block once (newest version) with OR-ed masks, and converges, links included.
TEST(CanvasService, SlowSubscriberCoalescesToNewestVersions) {
  auto svc = make_service();
  ASSERT_TRUE(svc);
  auto slow = svc->subscribe({});
  auto replica = make_replica(*svc);
  auto snap = slow->take();
  ASSERT_TRUE(snap.has_value());
  EXPECT_TRUE(snap->snapshot);
  apply(replica, *snap, svc->config().octree.block_cells);
  std::mt19937_64 rng(3);
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(submit(*svc, random_stroke(rng, 8), {}).ok());
  auto q = svc->quiesce();
  ASSERT_TRUE(q.ok());
  EXPECT_GT(q->epoch, 3u);  // several epochs happened while the subscriber slept
  auto batch = slow->take();
  ASSERT_TRUE(batch.has_value());
  EXPECT_EQ(batch->epoch, q->epoch);
  EXPECT_FALSE(slow->take().has_value());  // nothing new since
  // Full block frames: one per block (the newest); mask-only frames may follow.
  std::set<std::uint32_t> full_blocks;
  std::size_t mask_only = 0;
  for (const auto& f : batch->frames) {
    auto h = protocol::parse_block_header(*f);
    ASSERT_TRUE(h.ok());
    EXPECT_EQ(h->epoch <= q->epoch, true);
    if (h->fields == protocol::kFieldNeighbourMask) {
      ++mask_only;
      continue;
    }
    EXPECT_TRUE(full_blocks.insert(h->block_id).second) << "block " << h->block_id << " twice";
  }
  apply(replica, *batch, svc->config().octree.block_cells);
  EXPECT_EQ(replica.pool_hash(), q->pool_hash);
  EXPECT_EQ(replica.links_hash(), q->links_hash);
  EXPECT_TRUE(no_dangling_cells(replica));
  std::printf("[ info ] %zu epochs coalesced into %zu block frames + %zu mask frames\n",
              static_cast<std::size_t>(q->epoch), full_blocks.size(), mask_only);
}

// A block painted again gets a delta frame at publish and its full frame only when someone
// needs it (PublishedFrame::full_bytes): a subscriber without delta frames that joins later
// still gets every block whole and converges, and the idle compress thread encodes the newest
// versions nobody asked for yet.
TEST(CanvasService, DeferredFullFramesAreMadeOnDemandAndWhenIdle) {
  auto svc = make_service();
  ASSERT_TRUE(svc);
  auto with_deltas = svc->subscribe({}, true);
  ASSERT_TRUE(with_deltas->take().has_value());  // the snapshot
  std::mt19937_64 rng(11);
  protocol::Stroke stroke = random_stroke(rng, 8);
  const auto repaint = [&](int times) {
    for (int i = 0; i < times; ++i) {
      stroke.brush.colour[0] = static_cast<float>(i % 7) / 7.0f;  // the same cells, recoloured
      ASSERT_TRUE(submit(*svc, stroke, {}).ok());
      auto q = svc->quiesce();
      ASSERT_TRUE(q.ok());
      if (with_deltas) {
        ASSERT_TRUE(with_deltas->take().has_value());
      }
    }
  };
  repaint(4);
  EXPECT_GT(svc->metrics().bytes_delta.value(), 0u);  // delta frames were encoded at publish
  // Every repaint's epochs had painting steps: their bytes are counted as painting.
  EXPECT_GT(svc->metrics().epoch_bytes_painting.value(), 0u);
  std::printf("[ info ] delta %llu full %llu bytes, deferred %llu\n",
              static_cast<unsigned long long>(svc->metrics().bytes_delta.value()),
              static_cast<unsigned long long>(svc->metrics().bytes_compressed.value()),
              static_cast<unsigned long long>(svc->metrics().full_frames_deferred.value()));
  auto q = svc->quiesce();
  ASSERT_TRUE(q.ok());
  // On demand: a late joiner without delta frames, at once (before the idle fill is due).
  auto late = svc->subscribe({});
  auto snap = late->take();
  ASSERT_TRUE(snap.has_value());
  EXPECT_EQ(snap->delta_frames, 0u);
  auto replica = make_replica(*svc);
  apply(replica, *snap, svc->config().octree.block_cells);
  EXPECT_EQ(replica.pool_hash(), q->pool_hash);
  EXPECT_EQ(replica.links_hash(), q->links_hash);
  EXPECT_TRUE(no_dangling_cells(replica));
  // When idle: with no subscriber left to ask for full frames, recolour again (deltas at
  // publish); the compress thread encodes the newest versions' full frames after a short delay.
  late.reset();
  with_deltas.reset();
  const auto filled_before = svc->metrics().full_frames_filled.value();
  repaint(3);
  const auto before = svc->metrics().bytes_compressed.value();
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (svc->metrics().bytes_compressed.value() == before &&
         std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_GT(svc->metrics().bytes_compressed.value(), before);
  EXPECT_GT(svc->metrics().full_frames_filled.value(), filled_before);
}

// Frame bundles (PROTOCOL.md 4.12): a bundles subscriber's snapshot comes as frames, its live
// batches as bundles (and whole blocks alone) holding exactly the frames a subscriber without
// bundles takes at the same epochs, in order; two bundles subscribers in step share one
// encoding; every replica converges.
TEST(CanvasService, BundlesHoldTheSameFramesAndSubscribersInStepShareThem) {
  auto svc = make_service();
  ASSERT_TRUE(svc);
  const std::uint32_t bc = svc->config().octree.block_cells;
  auto plain = svc->subscribe({}, true);
  auto a = svc->subscribe({}, true, false, true);
  auto b = svc->subscribe({}, true, false, true);
  auto rp = make_replica(*svc), ra = make_replica(*svc), rb = make_replica(*svc);
  std::mt19937_64 rng(31);
  ASSERT_TRUE(submit(*svc, random_stroke(rng, 8), {}).ok());
  ASSERT_TRUE(svc->quiesce().ok());
  // The snapshot: frames alone, for every subscriber.
  for (auto* s : {plain.get(), a.get(), b.get()}) {
    auto snap = s->take();
    ASSERT_TRUE(snap.has_value());
    ASSERT_TRUE(snap->snapshot);
    for (const auto& f : snap->frames) EXPECT_FALSE(protocol::is_bundle(*f));
    apply(s == plain.get() ? rp : s == a.get() ? ra : rb, *snap, bc);
  }
  int live = 0, bundles = 0;
  for (int i = 0; i < 4; ++i) {
    ASSERT_TRUE(submit(*svc, random_stroke(rng, 6), {}).ok());
    auto q = svc->quiesce();
    ASSERT_TRUE(q.ok());
    auto bp = plain->take(), ba = a->take(), bb = b->take();
    ASSERT_TRUE(bp && ba && bb);
    ++live;
    EXPECT_EQ(ba->block_frames, bp->frames.size());
    ASSERT_FALSE(ba->frames.empty());
    // Small frames in bundles; a frame alone is a large one (a whole block), in its place.
    for (const auto& f : ba->frames) {
      if (protocol::is_bundle(*f)) {
        ++bundles;
        continue;
      }
      auto h = protocol::parse_block_header(*f);
      ASSERT_TRUE(h.ok());
      EXPECT_GT(h->raw_size, 16u * 1024);
    }
    // In step: b took the very bundles a made.
    ASSERT_EQ(bb->frames.size(), ba->frames.size());
    for (std::size_t k = 0; k < ba->frames.size(); ++k)
      EXPECT_EQ(bb->frames[k].get(), ba->frames[k].get());
    // The records are the plain subscriber's frames, in order.
    const auto fp = decode_batch(*bp, bc), fa = decode_batch(*ba, bc);
    ASSERT_EQ(fp.size(), fa.size());
    for (std::size_t k = 0; k < fp.size(); ++k) {
      EXPECT_EQ(fa[k].header.block_id, fp[k].header.block_id);
      EXPECT_EQ(fa[k].header.version, fp[k].header.version);
      EXPECT_EQ(fa[k].header.flags & ~protocol::kFlagCompressed,
                fp[k].header.flags & ~protocol::kFlagCompressed);
      EXPECT_EQ(fa[k].colour, fp[k].colour);
      EXPECT_EQ(fa[k].first_child, fp[k].first_child);
      EXPECT_EQ(fa[k].changed_cells, fp[k].changed_cells);
    }
    apply(rp, *bp, bc);
    apply(ra, *ba, bc);
    apply(rb, *bb, bc);
    for (const auto* r : {&rp, &ra, &rb}) {
      EXPECT_EQ(r->pool_hash(), q->pool_hash);
      EXPECT_EQ(r->links_hash(), q->links_hash);
    }
  }
  EXPECT_GT(bundles, 0);
  EXPECT_GE(svc->metrics().bundles_encoded.value(), 1u);
  EXPECT_EQ(svc->metrics().bundles_reused.value(), static_cast<std::uint64_t>(live));
  EXPECT_LT(svc->metrics().bundle_bytes.value(), svc->metrics().bundled_frame_bytes.value());
}

// A delta subscriber that skipped versions of a block (it took nothing while strokes repainted
// it) gets the chain of deltas from the version it holds, oldest first, instead of the full
// frame; one that asked for composed deltas gets one delta from the version it holds to the
// newest (the union of the chain's changed cells). Either replica converges.
TEST(CanvasService, SkippedVersionsArriveAsAChainOrAsOneDeltaFromTheHeldVersion) {
  for (bool compose : {false, true}) {
    SCOPED_TRACE(compose ? "composed" : "chain");
    auto svc = make_service();
    ASSERT_TRUE(svc);
    auto sub = svc->subscribe({}, true, compose);
    auto replica = make_replica(*svc);
    std::mt19937_64 rng(12);
    // Detail first (full frames of some size), then a one-stamp stroke recoloured inside it:
    // each repaint is an epoch or two and changes few cells (small deltas).
    protocol::Stroke detail = random_stroke(rng, 8);
    ASSERT_TRUE(submit(*svc, detail, {}).ok());
    protocol::Stroke stroke = detail;
    stroke.samples.resize(1);
    stroke.samples[0].radius *= 0.5f;
    ASSERT_TRUE(svc->quiesce().ok());
    auto first = sub->take();  // the snapshot, after the first stroke
    ASSERT_TRUE(first.has_value());
    apply(replica, *first, svc->config().octree.block_cells);
    for (int i = 1; i <= 2; ++i) {  // recoloured twice: every changed block has several versions
      stroke.brush.colour[1] = static_cast<float>(i) / 3.0f;
      ASSERT_TRUE(submit(*svc, stroke, {}).ok());
      ASSERT_TRUE(svc->quiesce().ok());
    }
    auto q = svc->quiesce();
    ASSERT_TRUE(q.ok());
    auto batch = sub->take();
    ASSERT_TRUE(batch.has_value());
    EXPECT_GT(batch->delta_frames, 0u);
    std::map<std::uint32_t, int> frames_per_block;
    int skipping = 0;
    for (const auto& f : batch->frames) {
      auto h = protocol::parse_block_header(*f);
      ASSERT_TRUE(h.ok());
      if (h->fields != protocol::kFieldNeighbourMask) ++frames_per_block[h->block_id];
      if ((h->flags & protocol::kFlagDelta) && h->version - h->base_version >= 2) ++skipping;
    }
    int chained = 0;
    for (const auto& [b, n] : frames_per_block) chained += n > 1 ? 1 : 0;
    if (compose) {
      EXPECT_EQ(chained, 0) << "a block came as a chain";
      EXPECT_GT(skipping, 0) << "no delta spans the skipped versions";
      EXPECT_GT(svc->metrics().composed_delta_frames.value(), 0u);
    } else {
      EXPECT_GT(chained, 0) << "no block came as a chain of deltas";
      EXPECT_EQ(svc->metrics().composed_delta_frames.value(), 0u);
    }
    apply(replica, *batch, svc->config().octree.block_cells);
    EXPECT_EQ(replica.pool_hash(), q->pool_hash);
    EXPECT_EQ(replica.links_hash(), q->links_hash);
    EXPECT_TRUE(no_dangling_cells(replica));
  }
}

// Adversarial timing: a consumer takes batches as fast as it can (and at random pauses) while
// strokes refine and coarsen; after every commit the replica has no dangling reachable cell.
TEST(CanvasService, EveryCommittedBatchIsConsistent) {
  auto svc = make_service();
  ASSERT_TRUE(svc);
  std::atomic<bool> done{false};
  std::atomic<int> batches{0};
  std::string failure;
  auto sub = svc->subscribe({});
  std::thread consumer([&] {
    auto replica = make_replica(*svc);
    std::mt19937 r(7);
    for (;;) {
      auto b = sub->take();
      if (b) {
        apply(replica, *b, svc->config().octree.block_cells);
        ++batches;
        auto ok = no_dangling_cells(replica);
        if (!ok && failure.empty()) failure = ok.message();
      } else if (done.load()) {
        break;
      }
      std::this_thread::sleep_for(std::chrono::microseconds(r() % 300));
    }
  });
  std::mt19937_64 rng(4);
  for (int i = 0; i < 12; ++i) {
    auto mode = i % 4 == 3 ? protocol::BrushMode::erase : protocol::BrushMode::paint;
    ASSERT_TRUE(submit(*svc, random_stroke(rng, 6, mode), {}).ok());
  }
  auto q = svc->quiesce();
  ASSERT_TRUE(q.ok());
  done = true;
  consumer.join();
  EXPECT_TRUE(failure.empty()) << failure;
  EXPECT_GT(batches.load(), 1);
}

// Interior values may lag while strokes are open (CanvasServiceConfig::
// interior_refresh_interval, Octree::InteriorRefresh): after every batch a subscriber's interior
// cells are 0 exactly over empty subtrees, and some nonzero ones lag their children; once every
// stroke is acked and none is open an epoch makes them all exact, with no quiesce to force it.
// With the interval 0 none ever lags.
struct InteriorCount {
  std::size_t interiors = 0, lagging = 0, zero_wrong = 0;
};

InteriorCount count_interiors(const client_core::Replica& r) {
  InteriorCount n;
  const auto v = r.view();
  for (std::size_t c = 0; c < v.cell_count(); ++c) {
    const std::uint32_t fc = v.first_child[c];
    if ((v.group_depth_flags[c / 8] & client_core::PoolView::kFreeFlag) ||
        fc == client_core::PoolView::kNoCell || std::size_t{fc} + 8 > v.cell_count())
      continue;
    const std::uint32_t filtered = protocol::density::filter_rgba(&v.colour[fc]);
    ++n.interiors;
    n.lagging += v.colour[c] != filtered;
    n.zero_wrong += (v.colour[c] == 0) != (filtered == 0);
  }
  return n;
}

void check_interior_lag(std::chrono::milliseconds interval) {
  SCOPED_TRACE("interior_refresh_interval " + std::to_string(interval.count()) + " ms");
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.max_cells_per_step = 64;  // many epochs per stroke
  cfg.min_epoch_interval = std::chrono::milliseconds(0);
  cfg.interior_refresh_interval = interval;
  auto made = CanvasService::create(cfg);
  ASSERT_TRUE(made.ok()) << made.error().message;
  auto& svc = **made;
  std::mutex m;
  InteriorCount during, last;
  std::size_t batches = 0;
  std::atomic<bool> done{false};
  auto sub = svc.subscribe({});
  std::thread consumer([&] {
    auto replica = make_replica(svc);
    while (!done.load()) {
      auto b = sub->take();
      if (!b) {
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
        continue;
      }
      apply(replica, *b, svc.config().octree.block_cells);
      const InteriorCount n = count_interiors(replica);
      std::lock_guard l(m);
      ++batches;
      during.interiors += n.interiors;
      during.lagging += n.lagging;
      during.zero_wrong += n.zero_wrong;
      last = n;
    }
  });
  std::mt19937_64 rng(19);
  std::atomic<int> acked{0};
  const int strokes = 8;
  for (int i = 0; i < strokes; ++i) {
    const auto mode = i % 4 == 3 ? protocol::BrushMode::erase : protocol::BrushMode::paint;
    ASSERT_TRUE(submit(svc, random_stroke(rng, 12, mode), [&](Result<server_core::StrokeDone> d) {
                  EXPECT_TRUE(d.ok());
                  ++acked;
                }).ok());
  }
  const auto deadline = std::chrono::steady_clock::now() + 60s;
  while (acked.load() < strokes && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(1ms);
  ASSERT_EQ(acked.load(), strokes);
  // No stroke is open now: an epoch brings the lagging values (not a quiesce: it would refresh
  // them itself).
  bool exact = false;
  const auto exact_by = std::chrono::steady_clock::now() + 10s;
  while (!exact && std::chrono::steady_clock::now() < exact_by) {
    std::this_thread::sleep_for(5ms);
    std::lock_guard l(m);
    exact = last.interiors > 0 && last.lagging == 0;
  }
  done = true;
  consumer.join();
  EXPECT_TRUE(exact) << last.lagging << " interior values still lag after every stroke ended";
  EXPECT_EQ(during.zero_wrong, 0u) << "an interior 0 over paint, or nonzero over nothing";
  EXPECT_GT(batches, 20u);
  if (interval.count() == 0) {
    EXPECT_EQ(during.lagging, 0u);
  } else {
    EXPECT_GT(during.lagging, 0u) << "the strokes' epochs left no value lagging";
  }
  auto q = svc.quiesce();
  ASSERT_TRUE(q.ok()) << q.error().message;
}

TEST(CanvasService, InteriorValuesLagOnlyWhileStrokesAreOpenAndNeverAtZero) {
  check_interior_lag(std::chrono::milliseconds(60000));
  check_interior_lag(std::chrono::milliseconds(0));
}

// Replies first (CanvasServiceConfig::replies_first): with the compress thread held busy on one
// of a stroke's epochs, the epoch carrying the stroke's ack is staged as soon as the paint is
// complete (two epochs queued or in progress), not after the compress thread is free; with the
// option off it waits (one stays queued). Either way the ack names that epoch and the published
// state converges.
void check_replies_first(bool replies_first) {
  SCOPED_TRACE(replies_first ? "replies_first" : "replies wait");
  base::set_log_level(base::LogLevel::warn);
  auto cfg = small_canvas("c");
  cfg.max_cells_per_step = 64;  // many steps: the stroke's paint spans several epochs
  cfg.replies_first = replies_first;
  // An epoch per step while the stroke paints, so the compress thread is held on one of them
  // before the paint completes (with the epoch interval the paint may complete first).
  cfg.min_epoch_interval = std::chrono::milliseconds(0);
  std::mutex m;
  std::condition_variable cv;
  bool held = false, release = false;
  std::uint64_t held_epoch = 0;
  cfg.before_compress = [&](std::uint64_t epoch) {
    std::unique_lock l(m);
    // Only the first epoch of the stroke the compress thread takes (create() waits for epoch
    // 0, the initial blocks).
    if (epoch == 0 || held_epoch != 0) return;
    held_epoch = epoch;
    held = true;
    cv.notify_all();
    cv.wait(l, [&] { return release; });
  };
  const auto let_go = [&] {
    {
      std::lock_guard l(m);
      release = true;
    }
    cv.notify_all();
  };
  auto made = CanvasService::create(cfg);
  ASSERT_TRUE(made.ok()) << made.error().message;
  // Released on every way out (a failed assertion returns early; the service's destructor
  // joins the compress thread).
  struct Release {
    const decltype(let_go)& f;
    ~Release() { f(); }
  } release_on_exit{let_go};
  auto& svc = **made;
  std::promise<Result<server_core::StrokeDone>> acked;
  std::mt19937_64 rng(11);
  ASSERT_TRUE(submit(svc, random_stroke(rng, 8), [&](Result<server_core::StrokeDone> d) {
                acked.set_value(d);
              }).ok());
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  {
    std::unique_lock l(m);
    ASSERT_TRUE(cv.wait_until(l, deadline, [&] { return held; }))
        << "the compress thread never took an epoch";
  }
  // The stroke's paint completes while the compress thread is held.
  while (svc.metrics().end_to_painted_seconds.count() == 0 &&
         std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(1ms);
  const bool painted = svc.metrics().end_to_painted_seconds.count() == 1;
  std::int64_t queued = svc.metrics().compress_queue.value();
  if (replies_first) {
    while (queued < 2 && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(1ms);
      queued = svc.metrics().compress_queue.value();
    }
  } else {
    std::this_thread::sleep_for(100ms);  // it would have been staged by now
    queued = svc.metrics().compress_queue.value();
  }
  let_go();
  ASSERT_TRUE(painted) << "the stroke was not painted while the compress thread was held";
  EXPECT_EQ(queued, replies_first ? 2 : 1);
  auto ack = acked.get_future();
  ASSERT_EQ(ack.wait_for(20s), std::future_status::ready);
  auto done = ack.get();
  ASSERT_TRUE(done.ok()) << done.error().message;
  // The ack's epoch is the one staged right after the held one with replies first.
  if (replies_first) {
    EXPECT_EQ(done->epoch, held_epoch + 1);
  }
  EXPECT_GT(done->epoch, held_epoch);
  auto q = svc.quiesce();
  ASSERT_TRUE(q.ok()) << q.error().message;
  auto sub = svc.subscribe({});
  auto replica = make_replica(svc);
  auto b = sub->take();
  ASSERT_TRUE(b);
  apply(replica, *b, svc.config().octree.block_cells);
  EXPECT_TRUE(no_dangling_cells(replica));
  EXPECT_GT(replica.view().cell_count(), 0u);
}

TEST(CanvasService, RepliesAreStagedWhileTheCompressThreadIsBusy) {
  check_replies_first(true);
  check_replies_first(false);
}

}  // namespace
}  // namespace deepcanvas::test
