// Property tests: random refine / coarsen / colour sequences on the real octree, checked op by op
// against the brute-force ReferenceTree and periodically with check_invariants() and a full
// leaf-set comparison. DEEPCANVAS_OCTREE_SOAK_OPS raises the operation count (label soak).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <set>
#include <span>
#include <string>
#include <vector>

#include "octree_reference.hpp"

namespace deepcanvas::server_core {
namespace {

using testing::ReferenceTree;
using testing::tree_leaves;

std::uint64_t ops_from_env(std::uint64_t fallback) {
  const char* v = std::getenv("DEEPCANVAS_OCTREE_SOAK_OPS");
  if (!v || !*v) return fallback;
  return std::strtoull(v, nullptr, 10);
}

struct RandomWorkload {
  std::mt19937_64 rng;
  Vec3d focus{};
  double focus_half = 1.0;
  double half_edge;
  explicit RandomWorkload(std::uint64_t seed, double edge) : rng(seed), half_edge(edge / 2) {
    move_focus();
  }

  double uni(double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); }
  void move_focus() {
    // Log-uniform focus sizes from the whole canvas down to a few finest cells; sometimes at a
    // canvas corner or face, where root-array and boundary cases live.
    focus_half = half_edge * std::exp2(-uni(0.0, 23.0));
    auto coord = [&] {
      const double r = uni(0, 1);
      if (r < 0.15) return half_edge - focus_half * uni(0, 1);
      if (r < 0.3) return -half_edge + focus_half * uni(0, 1);
      if (r < 0.4) return 0.0;
      return uni(-half_edge, half_edge);
    };
    focus = {coord(), coord(), coord()};
  }
  Vec3d point() {
    auto c = [&](double v) {
      return std::fmin(half_edge, std::fmax(-half_edge, v + uni(-focus_half, focus_half)));
    };
    return {c(focus.x), c(focus.y), c(focus.z)};
  }
};

// Runs `ops` random operations; checks every op's outcome against the reference, and the whole
// tree every `check_every` ops. Returns the number of successful structural changes.
void run_property(const OctreeConfig& cfg, std::uint64_t seed, std::uint64_t ops,
                  std::uint64_t check_every, std::uint64_t soft_cell_limit) {
  auto created = Octree::create(cfg);
  ASSERT_TRUE(created.ok()) << created.error().message;
  Octree& t = **created;
  ReferenceTree ref(cfg.roots_per_axis, cfg.max_depth);
  RandomWorkload w(seed, cfg.edge_m);
  std::uint64_t refines = 0, coarsens = 0, refused = 0;
  for (std::uint64_t op = 0; op < ops; ++op) {
    if (w.uni(0, 1) < 0.01) w.move_focus();
    const Vec3d p = w.point();
    const double r = w.uni(0, 1);
    const bool big = t.live_cells() > soft_cell_limit;
    // Usually act on the leaf at p; sometimes on a random-depth cell on the way down (an
    // internal cell: refine must say invalid_argument, coarsen usually refused).
    const int depth = w.uni(0, 1) < 0.1 ? static_cast<int>(w.uni(0, cfg.max_depth + 1)) : 99;
    auto loc = t.locate(p, depth);
    ASSERT_TRUE(loc.ok()) << loc.error().message;
    const CellIndex c = loc->cell;
    const CellCoord k = loc->coord;
    ASSERT_EQ(t.coord(c), k);
    if (r < (big ? 0.25 : 0.5)) {
      const bool expect = ref.is_leaf(k) && k.depth < cfg.max_depth;
      const auto res = t.refine(c);
      ASSERT_EQ(res.ok(), expect) << "op " << op << " refine depth " << k.depth;
      if (expect) {
        ASSERT_TRUE(ref.refine(k));
        ++refines;
      } else {
        const Errc want = !ref.is_leaf(k) ? Errc::invalid_argument : Errc::refused;
        ASSERT_EQ(res.error().code, want);
      }
    } else if (r < 0.92) {
      // Coarsen the parent of the leaf (often possible) or the located cell itself.
      CellIndex target = c;
      CellCoord tk = k;
      if (t.is_leaf(c) && c >= t.root_count()) {
        target = t.parent(c);
        tk = CellCoord{k.depth - 1, k.x >> 1, k.y >> 1, k.z >> 1};
      }
      const bool expect = ref.can_coarsen(tk);
      ASSERT_EQ(t.can_coarsen(target), expect) << "op " << op << " depth " << tk.depth;
      const auto res = t.coarsen(target);
      ASSERT_EQ(res.ok(), expect);
      if (expect) {
        ASSERT_TRUE(ref.coarsen(tk));
        ++coarsens;
      } else {
        ASSERT_EQ(res.error().code, Errc::refused);
        ++refused;
      }
    } else if (t.is_leaf(c)) {
      const auto rgba = static_cast<std::uint32_t>(w.rng());
      t.set_colour(c, rgba);
      ASSERT_TRUE(ref.set_colour(k, rgba));
    }
    ASSERT_EQ(t.live_cells(), ref.live_cells()) << "op " << op;
    if ((op + 1) % check_every == 0 || op + 1 == ops) {
      const auto inv = t.check_invariants();
      ASSERT_TRUE(inv.ok()) << "op " << op << ": " << inv.error().message;
      ASSERT_EQ(tree_leaves(t), ref.leaves()) << "op " << op;
    }
  }
  // The run must actually have exercised both directions.
  EXPECT_GT(refines, ops / 20);
  EXPECT_GT(coarsens, ops / 50);
  EXPECT_GT(refused, 0u);
  std::fprintf(
      stderr, "seed %llu: %llu refines, %llu coarsens, %llu refused; %llu live cells, depth %d\n",
      (unsigned long long)seed, (unsigned long long)refines, (unsigned long long)coarsens,
      (unsigned long long)refused, (unsigned long long)t.live_cells(), t.stats().max_depth);
}

// Two roots per axis and 512-cell blocks: random workloads reach many blocks and deep trees
// within a short test.
OctreeConfig small_blocks_config() {
  OctreeConfig cfg;
  cfg.roots_per_axis = 2;
  cfg.block_cells = 512;
  cfg.max_cells = 1u << 22;
  return cfg;
}

TEST(OctreeProperty, RandomSequencesMatchReferenceSmallBlocks) {
  const OctreeConfig cfg = small_blocks_config();
  const std::uint64_t ops = ops_from_env(10000);
  const std::uint64_t seeds = ops > 100000 ? 1 : 2;  // the soak runs one long sequence
  for (std::uint64_t seed = 1; seed <= seeds; ++seed) {
    SCOPED_TRACE(seed);
    run_property(cfg, seed, ops, ops > 100000 ? 25000 : 500, 60000);
    if (HasFatalFailure()) return;
  }
}

TEST(OctreeProperty, RandomSequencesMatchReferenceDefaultGeometry) {
  OctreeConfig cfg;  // 4^3 roots, 20 km, depth 24, 4096-cell blocks
  cfg.max_cells = 1u << 22;
  const std::uint64_t ops = ops_from_env(10000);
  run_property(cfg, 7, ops, ops > 100000 ? 25000 : 500, 60000);
}

TEST(OctreeProperty, ShallowTreeHitsMaxDepth) {
  OctreeConfig cfg;
  cfg.roots_per_axis = 2;
  cfg.max_depth = 4;
  cfg.block_cells = 512;
  cfg.max_cells = 1u << 20;
  const std::uint64_t ops = ops_from_env(3000) / 3;
  run_property(cfg, 11, ops, ops > 100000 ? 25000 : 300, 20000);
}

// Mask completeness: a replica holding the links from the last time the masks were cleared,
// recomputing only the masked groups, ends up with exactly the links recompute_all_links() gives.
TEST(OctreeProperty, MaskedLinkRecomputeEqualsFullRecompute) {
  const OctreeConfig cfg = small_blocks_config();
  auto created = Octree::create(cfg);
  ASSERT_TRUE(created.ok());
  Octree& t = **created;
  RandomWorkload w(99, cfg.edge_m);
  const std::uint64_t rounds = ops_from_env(0) ? 400 : 40;
  std::uint64_t masked_total = 0;
  for (std::uint64_t round = 0; round < rounds; ++round) {
    std::vector<std::uint32_t> replica(t.group_link_pool().begin(), t.group_link_pool().end());
    t.clear_all_neighbour_masks();
    const int burst = 1 + static_cast<int>(w.uni(0, 200));
    for (int i = 0; i < burst; ++i) {
      if (w.uni(0, 1) < 0.05) w.move_focus();
      auto loc = t.locate(w.point(), 99);
      ASSERT_TRUE(loc.ok());
      const CellIndex c = loc->cell;
      if (w.uni(0, 1) < (t.live_cells() > 80000 ? 0.3 : 0.55)) {
        (void)t.refine(c);
      } else if (c >= t.root_count()) {
        (void)t.coarsen(t.parent(c));
      }
    }
    for (BlockId b = 0; b < t.block_count(); ++b)
      for (std::uint64_t word : t.neighbour_mask(b)) masked_total += std::popcount(word);
    replica.resize(t.group_link_pool().size(), kNoCell);
    t.recompute_masked_links_into(replica);
    const std::vector<std::uint32_t> eager(t.group_link_pool().begin(), t.group_link_pool().end());
    t.recompute_masked_links();  // on the tree's own pool; clears the masks
    for (BlockId b = 0; b < t.block_count(); ++b)
      for (std::uint64_t word : t.neighbour_mask(b)) ASSERT_EQ(word, 0u);
    const std::vector<std::uint32_t> own(t.group_link_pool().begin(), t.group_link_pool().end());
    t.recompute_all_links();
    const std::vector<std::uint32_t> full(t.group_link_pool().begin(), t.group_link_pool().end());
    ASSERT_EQ(eager, full) << "eagerly maintained links differ from a full recompute, round "
                           << round;
    ASSERT_EQ(own, full) << "recompute_masked_links changed a correct link, round " << round;
    ASSERT_EQ(replica, full) << "masked recompute missed a group, round " << round;
    if (round % 8 == 0) {
      ASSERT_TRUE(t.check_invariants().ok());
    }
  }
  EXPECT_GT(masked_total, rounds);
}

// The stager's contract: after any sequence of operations, every block whose bytes changed in
// any pool (first_child, colour, group parent, depth_flags, links) has a higher version and is
// on the dirty list; a block's version moves exactly when it is on the dirty list.
TEST(OctreeProperty, EveryChangedBlockIsDirtyWithANewVersion) {
  const OctreeConfig cfg = small_blocks_config();
  auto created = Octree::create(cfg);
  ASSERT_TRUE(created.ok());
  Octree& t = **created;
  RandomWorkload w(1234, cfg.edge_m);
  auto copy32 = [](std::span<const std::uint32_t> s) {
    return std::vector<std::uint32_t>(s.begin(), s.end());
  };
  std::uint64_t changed_blocks = 0;
  for (int round = 0; round < 200; ++round) {
    t.take_dirty_blocks();
    const auto fc = copy32(t.first_child_pool()), col = copy32(t.colour_pool()),
               par = copy32(t.group_parent_pool()), lnk = copy32(t.group_link_pool());
    const std::vector<std::uint8_t> dep(t.group_depth_flags_pool().begin(),
                                        t.group_depth_flags_pool().end());
    std::vector<std::uint64_t> versions;
    for (BlockId b = 0; b < t.block_count(); ++b) versions.push_back(t.block_state(b).version);
    const int burst = 1 + static_cast<int>(w.uni(0, 100));
    for (int i = 0; i < burst; ++i) {
      if (w.uni(0, 1) < 0.05) w.move_focus();
      auto loc = t.locate(w.point(), 99);
      ASSERT_TRUE(loc.ok());
      const double r = w.uni(0, 1);
      if (r < (t.live_cells() > 50000 ? 0.3 : 0.5)) {
        (void)t.refine(loc->cell);
      } else if (r < 0.9 && loc->cell >= t.root_count()) {
        (void)t.coarsen(t.parent(loc->cell));
      } else {
        t.set_colour(loc->cell, static_cast<std::uint32_t>(w.rng()));
      }
    }
    const auto dirty = t.dirty_blocks();
    const std::set<BlockId> dirty_set(dirty.begin(), dirty.end());
    ASSERT_EQ(dirty_set.size(), dirty.size()) << "a block listed twice";
    const std::uint64_t cells_per_block = cfg.block_cells, groups_per_block = cfg.block_cells / 8;
    for (BlockId b = 0; b < t.block_count(); ++b) {
      bool changed = false;
      for (std::uint64_t i = b * cells_per_block; i < (b + 1) * cells_per_block && !changed; ++i) {
        const std::uint32_t old_fc = i < fc.size() ? fc[i] : 0,
                            old_col = i < col.size() ? col[i] : 0;
        if (i < t.first_child_pool().size())
          changed = t.first_child_pool()[i] != old_fc || t.colour_pool()[i] != old_col;
      }
      for (std::uint64_t g = b * groups_per_block; g < (b + 1) * groups_per_block && !changed;
           ++g) {
        if (g >= t.group_parent_pool().size()) break;
        const bool is_new = g >= par.size();
        changed =
            is_new || t.group_parent_pool()[g] != par[g] || t.group_depth_flags_pool()[g] != dep[g];
        for (int f = 0; f < 6 && !changed; ++f)
          changed = t.group_link_pool()[g * 6 + f] != lnk[g * 6 + f];
      }
      const std::uint64_t old_version = b < versions.size() ? versions[b] : 0;
      if (changed) {
        ++changed_blocks;
        EXPECT_GT(t.block_state(b).version, old_version) << "block " << b << " round " << round;
        EXPECT_TRUE(dirty_set.count(b)) << "block " << b << " round " << round;
      }
      // A block may change and change back (refine then coarsen) within a burst: its version
      // still moves, but only together with the dirty flag.
      EXPECT_EQ(t.block_state(b).version != old_version, dirty_set.count(b) == 1)
          << "block " << b << " round " << round;
      EXPECT_EQ(t.block_state(b).dirty, dirty_set.count(b) == 1);
    }
    ASSERT_FALSE(HasFailure());
  }
  EXPECT_GT(changed_blocks, 60u);
}

}  // namespace
}  // namespace deepcanvas::server_core
