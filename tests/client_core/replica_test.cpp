// Replica: frames encoded from a real octree painted by the real painter (server_core), decoded
// by BlockDecoder and applied as a client does. The reference is the octree itself: after a
// commit the replica's pool and link hashes must equal the tree's.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <random>
#include <vector>

#include "deepcanvas/client_core/replica.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/pool_hash.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas::test {
namespace {

namespace dp = protocol;
using server_core::BlockId;
using server_core::Octree;

// One block's pools copied out of the tree (what the server's staging does).
struct BlockCopy {
  BlockId block = 0;
  std::uint64_t version = 0;
  std::uint32_t first_cell = 0, cell_count = 0;
  std::vector<std::uint32_t> first_child, colour, group_parent;
  std::vector<std::uint8_t> depth_flags;
  std::vector<std::uint64_t> mask;

  dp::BlockView view(std::uint64_t epoch) const {
    dp::BlockView v;
    v.block_id = block;
    v.version = version;
    v.epoch = epoch;
    v.first_cell = first_cell;
    v.cell_count = cell_count;
    v.first_child = first_child;
    v.colour = colour;
    v.group_parent = group_parent;
    v.depth_flags = depth_flags;
    v.neighbour_mask = {mask.data(), (cell_count / 8 + 63) / 64};
    return v;
  }
};

BlockCopy copy_block(Octree& tree, BlockId b) {
  BlockCopy c;
  const std::uint32_t bc = tree.config().block_cells;
  c.block = b;
  c.version = tree.block_state(b).version;
  c.first_cell = b * bc;
  const std::uint64_t end =
      std::min<std::uint64_t>(std::uint64_t{b + 1} * bc, tree.high_water_cells());
  c.cell_count = static_cast<std::uint32_t>(end - c.first_cell);
  const std::size_t c0 = c.first_cell, n = c.cell_count;
  c.first_child.assign(tree.first_child_pool().begin() + c0,
                       tree.first_child_pool().begin() + c0 + n);
  c.colour.assign(tree.colour_pool().begin() + c0, tree.colour_pool().begin() + c0 + n);
  c.group_parent.assign(tree.group_parent_pool().begin() + c0 / 8,
                        tree.group_parent_pool().begin() + (c0 + n) / 8);
  c.depth_flags.assign(tree.group_depth_flags_pool().begin() + c0 / 8,
                       tree.group_depth_flags_pool().begin() + (c0 + n) / 8);
  const auto m = tree.neighbour_mask(b);
  c.mask.assign(m.begin(), m.end());
  tree.clear_neighbour_mask(b);
  return c;
}

dp::BlockFrame decode(const std::vector<std::uint8_t>& bytes, std::uint32_t block_cells) {
  dp::BlockDecoder dec;
  dp::BlockFrame f;
  auto r = dec.decode(bytes, f, {block_cells, block_cells});
  EXPECT_TRUE(r.ok()) << r.error().message;
  return f;
}

std::uint64_t tree_links_hash(const Octree& tree) {
  dp::PoolHasher h;
  const std::uint64_t groups = tree.high_water_cells() / 8;
  h.add(groups);
  h.add_bytes(tree.group_link_pool().data(), groups * 6 * 4);
  return h.finish();
}

protocol::Stroke stroke_at(std::mt19937_64& rng, float r, float g, float b) {
  protocol::Stroke s;
  s.brush.colour[0] = r;
  s.brush.colour[1] = g;
  s.brush.colour[2] = b;
  s.brush.colour[3] = 1;
  std::uniform_real_distribution<double> u(-1.5, 1.5);
  for (int i = 0; i < 4; ++i)
    s.samples.push_back({u(rng), u(rng), u(rng), 0.2f, 1.0f, static_cast<std::uint32_t>(16 * i)});
  return s;
}

// A painted tree and a replica fed with its frames. Tracks the version of every block the
// replica was sent, as a server session does.
struct Fixture {
  std::unique_ptr<Octree> tree;
  std::unique_ptr<server_core::Painter> painter;
  client_core::Replica replica{client_core::ReplicaGeometry{4, 8.0, 4096}};
  std::vector<BlockCopy> sent;  // by block id: the copy last sent (version 0 + empty: none)
  dp::BlockEncoder enc;
  std::uint64_t epoch = 0;

  Fixture() {
    server_core::OctreeConfig oc;
    oc.roots_per_axis = 4;
    oc.edge_m = 8.0;
    oc.max_depth = 10;
    oc.block_cells = 4096;
    oc.max_cells = 1u << 22;
    auto t = Octree::create(oc);
    EXPECT_TRUE(t.ok());
    tree = std::move(t).value();
    auto p = server_core::Painter::create(*tree);
    EXPECT_TRUE(p.ok());
    painter = std::move(p).value();
  }

  // Frames of every block dirtied since the last call: delta frames where the replica holds the
  // previous version (when `deltas`), full frames otherwise.
  std::vector<std::vector<std::uint8_t>> frames(bool deltas, bool everything = false) {
    ++epoch;
    std::vector<BlockId> dirty = tree->take_dirty_blocks();
    if (everything) {
      dirty.clear();
      for (BlockId b = 0; b < tree->block_count(); ++b) dirty.push_back(b);
    }
    std::vector<std::vector<std::uint8_t>> out;
    for (BlockId b : dirty) {
      BlockCopy c = copy_block(*tree, b);
      if (everything) std::fill(c.mask.begin(), c.mask.end(), ~std::uint64_t{0});
      std::vector<std::uint8_t> bytes;
      if (b >= sent.size()) sent.resize(b + 1);
      const BlockCopy& prev = sent[b];
      if (deltas && !prev.first_child.empty() && prev.cell_count <= c.cell_count &&
          prev.version < c.version) {
        EXPECT_TRUE(enc.encode_delta(c.view(epoch), prev.view(epoch), bytes).ok());
      } else {
        EXPECT_TRUE(enc.encode(c.view(epoch), bytes).ok());
      }
      out.push_back(std::move(bytes));
      sent[b] = std::move(c);
    }
    return out;
  }

  void stage_all(const std::vector<std::vector<std::uint8_t>>& fs) {
    for (const auto& bytes : fs) {
      auto r = replica.stage(decode(bytes, 4096));
      ASSERT_TRUE(r.ok()) << r.error().message;
    }
  }

  void paint(std::mt19937_64& rng, float r, float g, float b) {
    ASSERT_TRUE(painter->apply_stroke(stroke_at(rng, r, g, b)).ok());
  }

  // Every block, sent and applied as a client's first snapshot (with every neighbour mask bit
  // set, so all links are computed).
  void apply_snapshot(bool deltas = false) {
    stage_all(frames(deltas, true));
    replica.commit();
  }

  // The replica holds the tree's bytes and computed the tree's links.
  void expect_replica_equals_tree() const {
    EXPECT_EQ(replica.pool_hash(), tree->pool_hash());
    EXPECT_EQ(replica.links_hash(), tree_links_hash(*tree));
  }
};

TEST(Replica, FullFramesReproduceTheTreeAtCommitOnly) {
  Fixture fx;
  std::mt19937_64 rng(1);
  fx.apply_snapshot();
  fx.expect_replica_equals_tree();
  const std::uint64_t before = fx.replica.pool_hash();
  fx.paint(rng, 1, 0, 0);
  auto fs = fx.frames(false);
  ASSERT_FALSE(fs.empty());
  fx.stage_all(fs);
  // Staged, not applied: a reader still sees the previous epoch, whole.
  EXPECT_EQ(fx.replica.staged_frames(), fs.size());
  EXPECT_EQ(fx.replica.pool_hash(), before);
  EXPECT_EQ(fx.replica.commit(), fs.size());
  fx.expect_replica_equals_tree();
}

TEST(Replica, DeltaFramesReproduceTheTree) {
  Fixture fx;
  std::mt19937_64 rng(2);
  fx.apply_snapshot(true);
  std::size_t deltas = 0;
  for (int i = 0; i < 8; ++i) {
    fx.paint(rng, 0.1f * static_cast<float>(i), 1.0f - 0.1f * static_cast<float>(i), 0.5f);
    auto fs = fx.frames(true);
    for (const auto& bytes : fs) deltas += decode(bytes, 4096).is_delta();
    fx.stage_all(fs);
    fx.replica.commit();
    ASSERT_EQ(fx.replica.pool_hash(), fx.tree->pool_hash()) << "after stroke " << i;
    ASSERT_EQ(fx.replica.links_hash(), tree_links_hash(*fx.tree)) << "after stroke " << i;
    for (BlockId b = 0; b < fx.tree->block_count(); ++b)
      EXPECT_EQ(fx.replica.block_version(b), fx.tree->block_state(b).version);
  }
  EXPECT_GT(deltas, 4u);  // the repainted blocks really went as deltas
}

TEST(Replica, DeltaAgainstAFrameStagedInTheSameBatch) {
  Fixture fx;
  std::mt19937_64 rng(3);
  fx.apply_snapshot();
  fx.paint(rng, 1, 1, 0);
  auto first = fx.frames(false);  // full frames, staged, not committed
  fx.paint(rng, 0, 1, 1);
  auto second = fx.frames(true);  // deltas against the staged versions where the same block
  fx.stage_all(first);
  fx.stage_all(second);
  fx.replica.commit();
  fx.expect_replica_equals_tree();
}

TEST(Replica, DeltaWithAWrongBaseIsRejectedAndChangesNothing) {
  Fixture fx;
  std::mt19937_64 rng(4);
  fx.apply_snapshot();
  fx.paint(rng, 1, 0, 0);
  auto v1 = fx.frames(false);
  fx.paint(rng, 0, 0, 1);
  auto v2 = fx.frames(true);  // deltas against v1, which the replica never applies
  std::vector<dp::BlockFrame> deltas;
  for (const auto& bytes : v2) {
    auto f = decode(bytes, 4096);
    // Blocks that v1 did not change are deltas against what the replica holds: not wrong.
    if (f.is_delta() && fx.replica.block_version(f.header.block_id) != f.header.base_version)
      deltas.push_back(std::move(f));
  }
  ASSERT_FALSE(deltas.empty());
  const std::uint64_t before = fx.replica.pool_hash();
  for (auto& f : deltas) {
    const auto held = fx.replica.block_version(f.header.block_id);
    auto r = fx.replica.stage(f);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::invalid_argument);
    EXPECT_NE(r.error().message.find("needs base version " + std::to_string(f.header.base_version)),
              std::string::npos)
        << r.error().message;
    EXPECT_EQ(fx.replica.block_version(f.header.block_id), held);
  }
  EXPECT_EQ(fx.replica.staged_frames(), 0u);
  fx.replica.commit();
  EXPECT_EQ(fx.replica.pool_hash(), before);
  // A delta for a block the replica never received at all.
  client_core::Replica empty(client_core::ReplicaGeometry{4, 8.0, 4096});
  auto r = empty.stage(deltas.front());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::invalid_argument);
  // Once v1 is applied, the same deltas go through and reproduce the tree.
  fx.stage_all(v1);
  fx.replica.commit();
  fx.stage_all(v2);
  fx.replica.commit();
  EXPECT_EQ(fx.replica.pool_hash(), fx.tree->pool_hash());
}

TEST(Replica, NeighbourMasksOfOneBatchAreOred) {
  Fixture fx;
  std::mt19937_64 rng(5);
  fx.apply_snapshot();
  fx.paint(rng, 1, 0.5f, 0);
  fx.stage_all(fx.frames(false));
  fx.replica.commit();
  ASSERT_EQ(fx.replica.links_hash(), tree_links_hash(*fx.tree));
  // Two mask-only frames for block 0 with disjoint bits: the links of exactly the union of the
  // groups are recomputed at commit (and the links stay right).
  const BlockCopy& b0 = fx.sent[0];
  const std::uint32_t groups = b0.cell_count / 8;
  ASSERT_GE(groups, 64u);
  std::vector<std::uint64_t> a((groups + 63) / 64, 0), b = a;
  a[0] = 0x00000000000000F1ull;
  b[0] = 0x0000000000000F10ull;  // overlaps a in bit 4
  for (const auto* m : {&a, &b}) {
    dp::BlockView v;
    v.block_id = 0;
    v.version = b0.version;
    v.epoch = fx.epoch;
    v.first_cell = 0;
    v.cell_count = b0.cell_count;
    v.neighbour_mask = *m;
    dp::BlockEncoder plain({1, false, false});
    auto bytes = plain.encode(v);
    ASSERT_TRUE(bytes.ok());
    ASSERT_TRUE(fx.replica.stage(decode(*bytes, 4096)).ok());
  }
  const std::uint64_t before = fx.replica.links_recomputed();
  fx.replica.commit();
  const int want = std::popcount(a[0] | b[0]);
  EXPECT_EQ(fx.replica.links_recomputed() - before, static_cast<std::uint64_t>(want));
  fx.expect_replica_equals_tree();
}


// ---- progressive join (Replica::commit_partial) ----------------------------------------------

// The cell at (depth, x, y, z) as the replica's pools show it: the cell itself, or the leaf
// above it where the tree stops (kNoCell outside the canvas).
std::uint32_t shown_cell(const client_core::PoolView& v, std::uint32_t n, std::uint32_t depth,
                         std::int64_t x, std::int64_t y, std::int64_t z) {
  const std::int64_t extent = std::int64_t{n} << depth;
  if (x < 0 || y < 0 || z < 0 || x >= extent || y >= extent || z >= extent)
    return client_core::PoolView::kNoCell;
  std::uint32_t c = static_cast<std::uint32_t>((x >> depth) + n * ((y >> depth) + n * (z >> depth)));
  for (std::uint32_t level = 1; level <= depth; ++level) {
    const std::uint32_t fc = v.first_child[c];
    if (fc == client_core::PoolView::kNoCell) break;
    const std::uint32_t sh = depth - level;
    c = fc + static_cast<std::uint32_t>(((x >> sh) & 1) | (((y >> sh) & 1) << 1) | (((z >> sh) & 1) << 2));
  }
  return c;
}

// What a renderer of a partial replica relies on, checked against the tree it came from by
// brute force: every cell reachable from the roots lies in a block the replica holds and has
// the tree's colour (a cell shown as a leaf in place of a missing subtree carries the tree's
// filtered value); a cell shown as a leaf where the tree has children has them in a block not
// received; every reachable group's links name what the shown tree has across each face of its
// parent (found by descending from the roots).
::testing::AssertionResult partial_view_is_sound(const client_core::Replica& r, const Octree& tree) {
  const auto v = r.view();
  const auto tfc = tree.first_child_pool();
  const auto tcol = tree.colour_pool();
  const std::uint32_t n = 4, bc = 4096;
  struct Item {
    std::uint32_t cell, depth;
    std::int64_t x, y, z;
  };
  std::vector<Item> stack;
  for (std::uint32_t z = 0; z < n; ++z)
    for (std::uint32_t y = 0; y < n; ++y)
      for (std::uint32_t x = 0; x < n; ++x) stack.push_back({x + n * (y + n * z), 0, x, y, z});
  std::size_t checked_links = 0;
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    const std::uint32_t c = it.cell;
    if (!r.block_version(c / bc))
      return ::testing::AssertionFailure() << "cell " << c << " reachable in a block not received";
    if (v.colour[c] != tcol[c])
      return ::testing::AssertionFailure() << "cell " << c << " colour differs from the tree's";
    const std::uint32_t fc = v.first_child[c];
    if (fc == client_core::PoolView::kNoCell) {
      if (tfc[c] != client_core::PoolView::kNoCell && r.block_version(tfc[c] / bc))
        return ::testing::AssertionFailure() << "cell " << c << " hidden though its children came";
      continue;
    }
    if (fc != tfc[c]) return ::testing::AssertionFailure() << "cell " << c << " first_child differs";
    const std::uint32_t g = fc / 8;
    for (std::uint32_t f = 0; f < 6; ++f) {
      const std::uint32_t axis = f / 2;
      const std::int64_t step = (f & 1) ? 1 : -1;
      const std::uint32_t want = shown_cell(v, n, it.depth, it.x + (axis == 0 ? step : 0),
                                            it.y + (axis == 1 ? step : 0), it.z + (axis == 2 ? step : 0));
      if (r.group_links()[6 * g + f] != want)
        return ::testing::AssertionFailure()
               << "group " << g << " face " << f << ": link " << r.group_links()[6 * g + f]
               << ", shown neighbour " << want;
      ++checked_links;
    }
    for (std::uint32_t i = 0; i < 8; ++i)
      stack.push_back({fc + i, it.depth + 1, 2 * it.x + (i & 1), 2 * it.y + ((i >> 1) & 1),
                       2 * it.z + ((i >> 2) & 1)});
  }
  return ::testing::AssertionSuccess() << checked_links << " links checked";
}

TEST(Replica, APartialSnapshotShowsFilteredParentsInPlaceOfMissingBlocks) {
  for (const bool shallow_first : {true, false}) {
    SCOPED_TRACE(shallow_first ? "shallowest blocks first" : "random block order");
    Fixture fx;
    std::mt19937_64 rng(shallow_first ? 11 : 12);
    for (int i = 0; i < 40; ++i)
      fx.paint(rng, 0.02f * static_cast<float>(i), 0.5f, 1.0f - 0.02f * static_cast<float>(i));
    auto fs = fx.frames(false, true);  // take_dirty_blocks refreshes the filtered values
    ASSERT_GE(fs.size(), 6u) << "too few blocks for the test to mean anything";
    // The order: as the server sends a snapshot (shallowest live group first), or shuffled.
    std::vector<std::pair<std::uint32_t, std::size_t>> order;
    for (std::size_t i = 0; i < fs.size(); ++i) {
      const auto f = decode(fs[i], 4096);
      std::uint32_t shallowest = 255;
      for (const std::uint8_t df : f.depth_flags)
        if (!(df & 0x80)) shallowest = std::min<std::uint32_t>(shallowest, df & 31);
      order.emplace_back(shallow_first ? shallowest : static_cast<std::uint32_t>(rng()), i);
    }
    std::stable_sort(order.begin(), order.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    std::size_t next = 0, commits = 0, hidden_seen = 0;
    while (next < order.size()) {
      const std::size_t chunk = 1 + rng() % 3;
      for (std::size_t k = 0; k < chunk && next < order.size(); ++k)
        ASSERT_TRUE(fx.replica.stage(decode(fs[order[next++].second], 4096)).ok());
      if (next == order.size()) break;
      if (fx.replica.commit_partial() == 0) {
        EXPECT_FALSE(fx.replica.block_version(0)) << "applied nothing though the roots came";
        continue;
      }
      ++commits;
      EXPECT_TRUE(fx.replica.partial());
      hidden_seen += fx.replica.changed_cells().size();
      ASSERT_TRUE(partial_view_is_sound(fx.replica, *fx.tree)) << "after " << next << " blocks";
    }
    EXPECT_GT(commits, 1u);
    EXPECT_GT(hidden_seen, 0u) << "no subtree was ever missing: the test shows nothing";
    fx.replica.commit();  // the snapshot's epoch_end
    EXPECT_FALSE(fx.replica.partial());
    fx.expect_replica_equals_tree();
  }
}

}  // namespace
}  // namespace deepcanvas::test
