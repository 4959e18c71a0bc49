// Unit tests of the dynamic deep octree: configuration, geometry and locate, refine / coarsen
// rules, allocation and capacity, blocks and masks, hashes, field pools.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <vector>

#include "octree_reference.hpp"

namespace deepcanvas::server_core {
namespace {

std::unique_ptr<Octree> make(OctreeConfig cfg = {}) {
  auto r = Octree::create(cfg);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message);
  return r.ok() ? std::move(r).value() : nullptr;
}

// Refines the leaf at p until it reaches `depth`.
void refine_to(Octree& t, Vec3d p, int depth) {
  for (;;) {
    auto r = t.locate(p, depth);
    ASSERT_TRUE(r.ok());
    if (r->coord.depth >= depth) return;
    auto res = t.refine(r->cell);
    ASSERT_TRUE(res.ok()) << res.error().message;
  }
}

TEST(Octree, RejectsBadConfigs) {
  auto code = [](OctreeConfig c) {
    auto r = Octree::create(c);
    return r.ok() ? Errc::ok : r.error().code;
  };
  OctreeConfig c;
  EXPECT_EQ(code(c), Errc::ok);
  c = {};
  c.roots_per_axis = 3;
  EXPECT_EQ(code(c), Errc::invalid_argument);
  c = {};
  c.roots_per_axis = 0;
  EXPECT_EQ(code(c), Errc::invalid_argument);
  c = {};
  c.roots_per_axis = 66;
  EXPECT_EQ(code(c), Errc::invalid_argument);
  c = {};
  c.edge_m = std::nan("");
  EXPECT_EQ(code(c), Errc::invalid_argument);
  c = {};
  c.edge_m = -1;
  EXPECT_EQ(code(c), Errc::invalid_argument);
  c = {};
  c.max_depth = 0;
  EXPECT_EQ(code(c), Errc::invalid_argument);
  c = {};
  c.max_depth = 25;
  EXPECT_EQ(code(c), Errc::invalid_argument);
  c = {};
  c.block_cells = 1000;
  EXPECT_EQ(code(c), Errc::invalid_argument);
  c = {};
  c.block_cells = 256;
  EXPECT_EQ(code(c), Errc::invalid_argument);
  c = {};
  c.max_cells = (1ull << 28) + 8;
  EXPECT_EQ(code(c), Errc::invalid_argument);
  c = {};
  c.max_cells = 64;
  EXPECT_EQ(code(c), Errc::invalid_argument);
}

TEST(Octree, FreshTreeHasRootsOnly) {
  auto t = make();
  EXPECT_EQ(t->root_count(), 64u);
  EXPECT_EQ(t->live_cells(), 64u);
  EXPECT_EQ(t->high_water_cells(), 64u);
  const auto s = t->stats();
  EXPECT_EQ(s.leaves, 64u);
  EXPECT_EQ(s.max_depth, 0);
  EXPECT_TRUE(t->check_invariants().ok());
  for (CellIndex r = 0; r < 64; ++r) {
    EXPECT_TRUE(t->is_leaf(r));
    EXPECT_EQ(t->parent(r), kNoCell);
    EXPECT_EQ(t->depth(r), 0);
    const CellCoord k = t->coord(r);
    EXPECT_EQ(k.x + 4 * (k.y + 4 * k.z), r);
  }
  // Root-array neighbours.
  EXPECT_EQ(t->face_neighbour(0, kNegX), kNoCell);
  EXPECT_EQ(t->face_neighbour(0, kPosX), 1u);
  EXPECT_EQ(t->face_neighbour(0, kPosY), 4u);
  EXPECT_EQ(t->face_neighbour(0, kPosZ), 16u);
  EXPECT_EQ(t->face_neighbour(63, kPosZ), kNoCell);
}

TEST(Octree, GeometryFinestCellIsAboutAThirdOfAMillimetre) {
  auto t = make();
  EXPECT_DOUBLE_EQ(t->cell_edge_m(0), 5000.0);
  EXPECT_NEAR(t->cell_edge_m(24), 20000.0 / 67108864.0, 1e-18);
  EXPECT_NEAR(t->cell_edge_m(24) * 1000, 0.298, 0.001);
  const Aabb b = t->bounds_m(CellCoord{0, 0, 0, 0});
  EXPECT_DOUBLE_EQ(b.min.x, -10000.0);
  EXPECT_DOUBLE_EQ(b.max.x, -5000.0);
}

TEST(Octree, LocateRejectsNonFiniteAndOutsidePoints) {
  auto t = make();
  const double inf = std::numeric_limits<double>::infinity();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (Vec3d p : {Vec3d{nan, 0, 0}, Vec3d{0, inf, 0}, Vec3d{0, 0, -inf}, Vec3d{10000.001, 0, 0},
                  Vec3d{0, -10000.0001, 0}, Vec3d{0, 0, 1e300}}) {
    auto r = t->locate(p, 24);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::invalid_argument);
  }
  EXPECT_FALSE(t->locate({0, 0, 0}, -1).ok());
  // The canvas faces themselves are inside.
  auto lo = t->locate({-10000, -10000, -10000}, 24);
  ASSERT_TRUE(lo.ok());
  EXPECT_EQ(lo->cell, 0u);
  auto hi = t->locate({10000, 10000, 10000}, 24);
  ASSERT_TRUE(hi.ok());
  EXPECT_EQ(hi->cell, 63u);
}

// A depth-24 cell next to a canvas corner (about 17 km from the centre, 10 km on each axis):
// locate returns exactly the expected integer address, and the point lies inside its bounds.
TEST(Octree, LocateAtDepth24NearTheCorner) {
  auto t = make();
  const std::uint32_t last = (4u << 24) - 1;
  const CellCoord want{24, last - 2, 1, last};
  const Aabb b = t->bounds_m(want);
  const Vec3d centre{(b.min.x + b.max.x) / 2, (b.min.y + b.max.y) / 2, (b.min.z + b.max.z) / 2};
  EXPECT_GT(centre.x, 9999.999);
  EXPECT_LT(centre.y, -9999.999);
  refine_to(*t, centre, 24);
  auto r = t->locate(centre, 24);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->coord, want);
  EXPECT_EQ(t->depth(r->cell), 24);
  EXPECT_EQ(t->coord(r->cell), want);
  EXPECT_TRUE(t->is_leaf(r->cell));
  const Aabb cb = t->bounds_m(r->coord);
  EXPECT_LE(cb.min.x, centre.x);
  EXPECT_LT(centre.x, cb.max.x);
  EXPECT_NEAR(cb.max.x - cb.min.x, 2.98e-4, 1e-6);
  // Points a quarter cell either side of the centre stay in the cell; a cell edge away, not.
  const double e = t->cell_edge_m(24);
  auto q = t->locate({centre.x + e / 4, centre.y - e / 4, centre.z + e / 4}, 24);
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->cell, r->cell);
  auto n = t->locate({centre.x - e, centre.y, centre.z}, 24);
  ASSERT_TRUE(n.ok());
  EXPECT_EQ(n->coord.x, want.x - 1);
  EXPECT_EQ(n->cell, t->face_neighbour(r->cell, kNegX));
  // Max depth on the locate call stops the descent.
  auto s = t->locate(centre, 10);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->coord.depth, 10);
  EXPECT_EQ(s->coord.x, want.x >> 14);
  // find() round trip and deepest-ancestor behaviour.
  EXPECT_EQ(t->find(want).cell, r->cell);
  const CellCoord far{24, 5, 5, 5};
  EXPECT_EQ(t->find(far).coord.depth, 0);
  EXPECT_EQ(t->find(CellCoord{24, 4u << 24, 0, 0}).cell, kNoCell);
  EXPECT_TRUE(t->check_invariants().ok());
}

TEST(Octree, RefineRulesAndErrors) {
  OctreeConfig cfg;
  cfg.max_depth = 2;
  auto t = make(cfg);
  t->set_colour(5, 0x11223344u);
  std::uint64_t made = 0;
  ASSERT_TRUE(t->refine(5, &made).ok());
  EXPECT_EQ(made, 8u);
  const CellIndex fc = t->first_child(5);
  ASSERT_NE(fc, kNoCell);
  EXPECT_EQ(fc % 8, 0u);
  for (CellIndex i = 0; i < 8; ++i) {
    EXPECT_EQ(t->colour(fc + i), 0x11223344u);
    EXPECT_EQ(t->parent(fc + i), 5u);
    EXPECT_EQ(t->depth(fc + i), 1);
  }
  EXPECT_EQ(t->refine(5).error().code, Errc::invalid_argument);         // not a leaf
  EXPECT_EQ(t->refine(1u << 27).error().code, Errc::invalid_argument);  // beyond the pool
  // A depth-1 child on root 5's boundary: its refinement needs no balance (roots are depth 0,
  // one level coarser than the new children's neighbours... two levels: balance refines them).
  made = 0;
  ASSERT_TRUE(t->refine(fc, &made).ok());
  EXPECT_GT(made, 8u);  // root neighbours of child 0 (-x, -y, -z roots) were refined first
  EXPECT_TRUE(t->check_invariants().ok());
  const CellIndex deep = t->first_child(fc);
  EXPECT_EQ(t->depth(deep), 2);
  EXPECT_EQ(t->refine(deep).error().code, Errc::refused);  // at max depth
  // Freed cells are not live: coarsen then refine the freed index.
  ASSERT_TRUE(t->coarsen(fc).ok());
  EXPECT_FALSE(t->is_live(deep));
  EXPECT_EQ(t->refine(deep).error().code, Errc::invalid_argument);
  EXPECT_TRUE(t->check_invariants().ok());
}

TEST(Octree, CoarsenAveragesAndRefusals) {
  auto t = make();
  ASSERT_TRUE(t->refine(0).ok());
  const CellIndex fc = t->first_child(0);
  for (CellIndex i = 0; i < 8; ++i)
    t->set_colour(fc + i, (i * 30u) | (255u - i) << 8 | (i & 1 ? 255u : 0u) << 16 | 7u << 24);
  // Leaf: refused. Out of range: invalid_argument.
  EXPECT_EQ(t->coarsen(5).error().code, Errc::refused);
  EXPECT_EQ(t->coarsen(1u << 27).error().code, Errc::invalid_argument);
  // Internal child: refused.
  ASSERT_TRUE(t->refine(fc + 7).ok());  // the +x+y+z child of root 0 forces roots 1, 4, 16
  EXPECT_FALSE(t->can_coarsen(0));
  EXPECT_EQ(t->coarsen(0).error().code, Errc::refused);
  // Balance: root 1 was refined for balance; coarsening it would put root 0's depth-2 leaves
  // next to a depth-0 leaf.
  ASSERT_FALSE(t->is_leaf(1));
  const std::uint64_t before = t->pool_hash();
  EXPECT_FALSE(t->can_coarsen(1));
  EXPECT_EQ(t->coarsen(1).error().code, Errc::refused);
  EXPECT_EQ(t->pool_hash(), before);  // a refused operation changes nothing
  // Undo in the allowed order, then root 0 averages its children (rounded per channel).
  ASSERT_TRUE(t->coarsen(fc + 7).ok());
  ASSERT_TRUE(t->coarsen(1).ok());
  ASSERT_TRUE(t->coarsen(0).ok());
  std::uint32_t sum[4] = {};
  for (std::uint32_t i = 0; i < 8; ++i) {
    const std::uint32_t v = (i * 30u) | (255u - i) << 8 | (i & 1 ? 255u : 0u) << 16 | 7u << 24;
    for (int k = 0; k < 4; ++k) sum[k] += (v >> (8 * k)) & 255u;
  }
  std::uint32_t want = 0;
  for (int k = 0; k < 4; ++k) want |= ((sum[k] + 4) / 8) << (8 * k);
  EXPECT_EQ(t->colour(0), want);
  EXPECT_TRUE(t->check_invariants().ok());
}

TEST(Octree, NeighboursAndG3MatchBruteForce) {
  OctreeConfig cfg;
  cfg.max_cells = 1u << 20;
  auto t = make(cfg);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-10000, 10000), v(-1, 1);
  for (int i = 0; i < 40; ++i) refine_to(*t, {u(rng), u(rng), u(rng)}, 4 + i % 5);
  for (int i = 0; i < 40; ++i) refine_to(*t, {9999 + v(rng), -3 + v(rng), 5000 + v(rng)}, 16);
  ASSERT_TRUE(t->check_invariants().ok());
  std::uint64_t checked = 0;
  for (CellIndex c = 0; c < t->high_water_cells(); ++c) {
    if (!t->is_live(c)) continue;
    const CellCoord k = t->coord(c);
    ASSERT_EQ(t->find(k).cell, c);
    const std::uint64_t lim = std::uint64_t{4} << k.depth;
    for (int f = 0; f < 6; ++f) {
      const CellCoord nk = testing::ReferenceTree::step(k, f);
      const bool inside = nk.x < lim && nk.y < lim && nk.z < lim;
      const CellIndex want = inside ? t->find(nk).cell : kNoCell;
      ASSERT_EQ(t->face_neighbour(c, f), want) << "cell " << c << " face " << f;
      ++checked;
    }
    if (c >= t->root_count()) {
      for (int axis = 0; axis < 3; ++axis)
        EXPECT_EQ(t->g3(c, axis), t->face_neighbour(c, 2 * axis + ((c >> axis) & 1)));
    }
  }
  EXPECT_GT(checked, 6000u);
}

TEST(Octree, OutOfMemoryLeavesAValidTree) {
  OctreeConfig cfg;
  cfg.roots_per_axis = 2;
  cfg.block_cells = 512;
  cfg.max_cells = 8 + 8 * 60;  // roots + 60 groups
  auto t = make(cfg);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-10000, 10000);
  int ooms = 0;
  for (int i = 0; i < 500; ++i) {
    auto r = t->locate({u(rng), u(rng) / 50, u(rng) / 50}, 99);
    ASSERT_TRUE(r.ok());
    std::uint64_t made = 0;
    const auto res = t->refine(r->cell, &made);
    if (!res.ok() && res.error().code == Errc::out_of_memory) {
      ++ooms;
      EXPECT_TRUE(t->is_leaf(r->cell));
    }
    ASSERT_LE(t->live_cells(), cfg.max_cells);
    const auto inv = t->check_invariants();
    ASSERT_TRUE(inv.ok()) << inv.error().message;
  }
  EXPECT_GT(ooms, 10);
  EXPECT_EQ(t->live_cells(), cfg.max_cells);
  EXPECT_EQ(t->high_water_cells(), cfg.max_cells);
  // Freeing a group makes room again: the freed group is reused.
  CellIndex victim = kNoCell;
  for (CellIndex c = 0; c < t->high_water_cells() && victim == kNoCell; ++c)
    if (t->can_coarsen(c)) victim = c;
  ASSERT_NE(victim, kNoCell);
  const CellIndex freed = t->first_child(victim);
  ASSERT_TRUE(t->coarsen(victim).ok());
  ASSERT_TRUE(t->refine(victim).ok());
  EXPECT_EQ(t->first_child(victim), freed);
  EXPECT_TRUE(t->check_invariants().ok());
}

TEST(Octree, BlocksDirtyOrderVersionsAndMasks) {
  OctreeConfig cfg;
  cfg.block_cells = 512;
  auto t = make(cfg);
  auto first = t->take_dirty_blocks();
  EXPECT_EQ(first, std::vector<BlockId>{0});  // the roots' block
  EXPECT_TRUE(t->dirty_blocks().empty());
  EXPECT_FALSE(t->block_state(0).dirty);
  t->clear_all_neighbour_masks();
  // Fill block 0 so that the next group lands in block 1.
  const std::uint64_t v0 = t->block_state(0).version;
  for (CellIndex r = 0; r < 56; ++r) ASSERT_TRUE(t->refine(r).ok());  // 8 + 56 groups = 512 cells
  EXPECT_EQ(t->high_water_cells(), 512u);
  EXPECT_GT(t->block_state(0).version, v0);
  EXPECT_EQ(t->take_dirty_blocks(), std::vector<BlockId>{0});
  t->clear_all_neighbour_masks();
  // Refining a child in block 0 (a leaf with no coarser neighbours: all roots are refined
  // except 56..63, far away) creates one group in block 1: blocks 0 and 1 dirty, in that order,
  // and exactly that group's mask bit set.
  const CellIndex c = t->first_child(0);
  const std::uint64_t v1 = t->block_state(1).version;
  std::uint64_t made = 0;
  ASSERT_TRUE(t->refine(c, &made).ok());
  ASSERT_EQ(made, 8u);
  const CellIndex fc = t->first_child(c);
  EXPECT_EQ(t->block_of(fc), 1u);
  EXPECT_EQ(t->dirty_blocks().size(), 2u);
  EXPECT_EQ(t->dirty_blocks()[0], 0u);
  EXPECT_EQ(t->dirty_blocks()[1], 1u);
  EXPECT_GT(t->block_state(1).version, v1);
  int bits = 0;
  for (BlockId b = 0; b < t->block_count(); ++b)
    for (std::uint64_t w : t->neighbour_mask(b)) bits += std::popcount(w);
  EXPECT_EQ(bits, 1);
  const GroupIndex g = fc / 8;
  EXPECT_TRUE((t->neighbour_mask(1)[(g % 64) / 64] >> (g % 64)) & 1);
  // Coarsening frees that group: its bit is set again after clearing, block 1 dirtied again.
  t->clear_neighbour_mask(1);
  t->take_dirty_blocks();
  ASSERT_TRUE(t->coarsen(c).ok());
  EXPECT_TRUE((t->neighbour_mask(1)[0] >> (g % 64)) & 1);
  EXPECT_EQ(t->dirty_blocks().size(), 2u);
  for (int f = 0; f < 6; ++f) EXPECT_EQ(t->group_link(g, f), kNoCell);
  // set_colour dirties only when the colour changes.
  t->take_dirty_blocks();
  t->set_colour(c, t->colour(c));
  EXPECT_TRUE(t->dirty_blocks().empty());
  t->set_colour(c, t->colour(c) + 1);
  EXPECT_EQ(t->dirty_blocks().size(), 1u);
}

TEST(Octree, AllocationPrefersTheParentsBlock) {
  OctreeConfig cfg;
  cfg.block_cells = 512;  // 64 groups per block
  auto t = make(cfg);
  for (CellIndex r = 0; r < 56; ++r) ASSERT_TRUE(t->refine(r).ok());  // groups 8..63: block 0
  ASSERT_TRUE(t->refine(56).ok());
  EXPECT_EQ(t->block_of(t->first_child(56)), 1u);  // block 0 is full: bump into block 1
  const CellIndex freed = t->first_child(3);
  ASSERT_TRUE(t->coarsen(3).ok());
  // A child of root 0 lives in block 0, whose only free group is the one just freed.
  const CellIndex c = t->first_child(0);
  ASSERT_EQ(t->block_of(c), 0u);
  ASSERT_TRUE(t->refine(c).ok());
  EXPECT_EQ(t->first_child(c), freed);
  // Block 0 is full again: the next group goes to the open block (1), not to a new block.
  ASSERT_TRUE(t->refine(c + 1).ok());
  EXPECT_EQ(t->block_of(t->first_child(c + 1)), 1u);
  EXPECT_TRUE(t->check_invariants().ok());
}

TEST(Octree, LocalBurstCreatesGroupsInFewBlocks) {
  OctreeConfig cfg;
  cfg.block_cells = 1024;
  auto t = make(cfg);
  // History: scattered refinement, then scattered coarsening (fragmented free lists).
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<double> u(-10000, 10000);
  for (int i = 0; i < 300; ++i) refine_to(*t, {u(rng), u(rng), u(rng)}, 5);
  for (int i = 0; i < 2000; ++i) {
    auto r = t->locate({u(rng), u(rng), u(rng)}, 99);
    if (r->cell >= t->root_count()) (void)t->coarsen(t->parent(r->cell));
  }
  t->clear_all_neighbour_masks();
  std::uint64_t made = 0, total = 0;
  for (int i = 0; i < 30; ++i) {
    auto r = t->locate({1234.5 + i * 0.01, -2345.25, 77.125}, 99);
    if (r->coord.depth >= 14) break;
    ASSERT_TRUE(t->refine(r->cell, &made).ok());
    total += made;
  }
  std::set<BlockId> blocks;
  for (BlockId b = 0; b < t->block_count(); ++b)
    for (std::uint64_t w : t->neighbour_mask(b))
      if (w) blocks.insert(b);
  EXPECT_GT(total, 200u);
  // Created groups (mask bits) land in at most a few blocks: parents' blocks, then one open one.
  EXPECT_LE(blocks.size(), 3u) << total << " cells created";
  EXPECT_TRUE(t->check_invariants().ok());
}

TEST(Octree, CanvasHashIgnoresPoolPositionsPoolHashDoesNot) {
  OctreeConfig cfg;
  cfg.block_cells = 512;
  std::mt19937_64 rng(21);
  std::uniform_real_distribution<double> u(-10000, 10000);
  std::vector<std::pair<Vec3d, int>> targets;
  for (int i = 0; i < 60; ++i) targets.push_back({{u(rng), u(rng), u(rng)}, 2 + i % 6});
  auto colour_of = [](const CellCoord& k) {
    return static_cast<std::uint32_t>(testing::CoordHash{}(k));
  };
  auto paint = [&](Octree& t) {
    for (CellIndex c = 0; c < t.high_water_cells(); ++c)
      if (t.is_live(c) && t.is_leaf(c)) t.set_colour(c, colour_of(t.coord(c)));
  };
  auto a = make(cfg);
  for (auto& [p, d] : targets) refine_to(*a, p, d);
  paint(*a);
  // Same content, another history: scratch work elsewhere first (and undone), reverse order.
  auto b = make(cfg);
  for (int i = 0; i < 30; ++i) refine_to(*b, {u(rng), u(rng), u(rng)}, 3);
  for (auto it = targets.rbegin(); it != targets.rend(); ++it) refine_to(*b, it->first, it->second);
  // Undo the scratch refinements that the targets do not need, leaves first.
  for (int pass = 0; pass < 8; ++pass)
    for (CellIndex c = b->high_water_cells(); c-- > 0;)
      if (b->is_live(c) && b->can_coarsen(c)) {
        const CellCoord k = b->coord(c);
        bool needed = false;
        for (auto& [p, d] : targets) {
          auto r = a->locate(p, 99);
          const CellCoord ak = r->coord;
          const int s = ak.depth - k.depth;
          if (s > 0 && (ak.x >> s) == k.x && (ak.y >> s) == k.y && (ak.z >> s) == k.z)
            needed = true;
        }
        // Keep what tree a has; drop the rest.
        const LocateResult in_a = a->find(k);
        if (!needed && (in_a.coord.depth < k.depth || a->is_leaf(in_a.cell))) (void)b->coarsen(c);
      }
  paint(*b);
  ASSERT_TRUE(a->check_invariants().ok());
  ASSERT_TRUE(b->check_invariants().ok());
  ASSERT_EQ(testing::tree_leaves(*a).size(), testing::tree_leaves(*b).size());
  EXPECT_EQ(a->canvas_hash(), b->canvas_hash());
  EXPECT_NE(a->pool_hash(), b->pool_hash());
  // Determinism: the same operations in the same order give byte-identical pools.
  auto c = make(cfg);
  for (auto& [p, d] : targets) refine_to(*c, p, d);
  paint(*c);
  EXPECT_EQ(c->pool_hash(), a->pool_hash());
  EXPECT_EQ(c->canvas_hash(), a->canvas_hash());
  // Any content change shows in the canvas hash.
  c->set_colour(c->locate(targets[0].first, 99)->cell, 0x01020304u);
  EXPECT_NE(c->canvas_hash(), a->canvas_hash());
}

TEST(Octree, FieldPoolsAreZeroFilledAndClearable) {
  auto t = make();
  EXPECT_EQ(t->add_field_pool("bad", 3).error().code, Errc::invalid_argument);
  auto p = t->add_field_pool("coverage", 4);
  ASSERT_TRUE(p.ok());
  auto& pool = **p;
  EXPECT_EQ(pool.name(), "coverage");
  EXPECT_EQ(pool.bytes_per_cell(), 4u);
  auto* v = pool.as<std::uint32_t>();
  EXPECT_EQ(v[0], 0u);
  EXPECT_EQ(v[(256u << 20) - 1], 0u);  // the whole index range is addressable
  v[12345678] = 42;
  v[0] = 7;
  EXPECT_EQ(v[12345678], 42u);
  pool.clear();
  EXPECT_EQ(v[12345678], 0u);
  EXPECT_EQ(v[0], 0u);
}

TEST(Octree, StatsAndMemoryAccounting) {
  auto t = make();
  refine_to(*t, {1, 2, 3}, 10);
  const auto s = t->stats();
  EXPECT_EQ(s.live_cells, t->live_cells());
  EXPECT_EQ(s.max_depth, 10);
  EXPECT_EQ(s.leaves, s.live_cells - (s.live_cells - 64) / 8);
  EXPECT_EQ(s.pool_bytes, s.high_water_cells * 8 + s.high_water_cells / 8 * 29);
  EXPECT_GE(t->allocated_bytes(), s.pool_bytes);
}

}  // namespace
}  // namespace deepcanvas::server_core
