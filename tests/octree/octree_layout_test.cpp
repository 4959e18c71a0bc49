// The server's Octree against shaders/include/pool_layout.h, the one layout module (label unit):
// its constants are the header's, its pools have the header's shape, and on random cells of
// random trees its navigation (depth, parent, coord, face_neighbour, g3, group_link) equals the
// header's arithmetic applied to the raw pools, which in turn equals a brute-force search by
// integer coordinates that knows nothing of groups, slots or links. The client's PoolView (the
// bridge's view of the same tree) answers the same. The GLSL side of the header is pinned in
// tests/client_gpu (layout_test.cpp, gpu_test.cpp).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "deepcanvas/bridge/pool_view_of_octree.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/version.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "pool_layout.h"

namespace deepcanvas::server_core {
namespace {

namespace pl = pool_layout;

// One source for every constant: the server's, the wire's and the client's names are the
// header's values.
static_assert(kNoCell == pl::kNoCell && protocol::kNoCellWire == pl::kNoCell);
static_assert(kDepthMask == pl::kDepthMask && kGroupFreeFlag == pl::kGroupFreeFlag);
static_assert(kMaxSupportedDepth == static_cast<int>(pl::kMaxDepth));
static_assert(client_core::PoolView::kNoCell == pl::kNoCell &&
              client_core::PoolView::kDepthMask == pl::kDepthMask &&
              client_core::PoolView::kFreeFlag == pl::kGroupFreeFlag &&
              client_core::PoolView::kMaxDepth == static_cast<int>(pl::kMaxDepth));
static_assert(protocol::kPoolLayoutVersion == pl::kLayoutVersion);
static_assert(OctreeConfig{}.max_cells == std::uint64_t{1} << pl::kMaxCellsLog2);
static_assert(kNegX == pl::dc_face(0, false) && kPosX == pl::dc_face(0, true) &&
              kNegY == pl::dc_face(1, false) && kPosY == pl::dc_face(1, true) &&
              kNegZ == pl::dc_face(2, false) && kPosZ == pl::dc_face(2, true));

std::unique_ptr<Octree> random_tree(std::uint64_t seed, std::uint32_t roots_per_axis, int ops) {
  OctreeConfig cfg;
  cfg.roots_per_axis = roots_per_axis;
  cfg.block_cells = 512;
  auto created = Octree::create(cfg);
  EXPECT_TRUE(created.ok());
  auto tree = std::move(created).value();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(-0.5, 0.5);
  // Refinements clustered around a few centres (deep cells, coarser neighbours next to finer
  // ones), a few coarsenings (freed and reused groups), colours everywhere.
  std::vector<Vec3d> centres;
  for (int i = 0; i < 3; ++i)
    centres.push_back({unit(rng) * cfg.edge_m, unit(rng) * cfg.edge_m, unit(rng) * cfg.edge_m});
  for (int i = 0; i < ops; ++i) {
    const Vec3d& c = centres[rng() % centres.size()];
    const double s = cfg.edge_m * std::ldexp(1.0, -static_cast<int>(rng() % 12));
    const Vec3d p{c.x + unit(rng) * s, c.y + unit(rng) * s, c.z + unit(rng) * s};
    auto at = tree->locate(p, 1 + static_cast<int>(rng() % 12));
    if (!at.ok()) continue;
    tree->set_colour(at->cell, static_cast<std::uint32_t>(rng()));
    if (rng() % 8 == 0 && at->cell >= tree->root_count()) {
      (void)tree->coarsen(tree->parent(at->cell));
    } else {
      (void)tree->refine(at->cell);
    }
  }
  return tree;
}

// The brute force: the cell across `face` by integer address (find), no pools involved.
CellIndex brute_force_neighbour(const Octree& t, CellIndex c, int face) {
  CellCoord k = t.coord(c);
  const std::uint64_t lim = std::uint64_t{t.config().roots_per_axis} << k.depth;
  std::uint32_t* a = face < 2 ? &k.x : face < 4 ? &k.y : &k.z;
  if (face & 1) {
    if (*a + 1ull >= lim) return kNoCell;
    ++*a;
  } else {
    if (*a == 0) return kNoCell;
    --*a;
  }
  return t.find(k).cell;
}

// The header's rule applied by hand to the raw pools.
CellIndex header_neighbour(const Octree& t, CellIndex c, pl::uint face) {
  const std::uint32_t n = t.config().roots_per_axis;
  if (c < pl::dc_root_count(n)) return pl::dc_root_neighbour(c, face, n);
  if (pl::dc_face_is_inner(c, face)) return pl::dc_sibling_across(c, face);
  const CellIndex link = t.group_link_pool()[pl::dc_link_index(pl::dc_group_of(c), face)];
  if (link == pl::kNoCell) return pl::kNoCell;
  return pl::dc_resolve_link(c, face, link, t.first_child_pool()[link]);
}

std::vector<CellIndex> live_cells(const Octree& t) {
  std::vector<CellIndex> out, stack;
  for (CellIndex r = 0; r < t.root_count(); ++r) stack.push_back(r);
  while (!stack.empty()) {
    const CellIndex c = stack.back();
    stack.pop_back();
    out.push_back(c);
    if (!t.is_leaf(c))
      for (CellIndex s = 0; s < pl::kCellsPerGroup; ++s) stack.push_back(t.first_child(c) + s);
  }
  return out;
}

TEST(OctreeLayout, PoolsHaveTheHeadersShape) {
  for (std::uint32_t n : {2u, 4u, 6u}) {
    auto t = random_tree(n, n, 300);
    ASSERT_TRUE(t->check_invariants().ok());
    const std::uint64_t cells = t->high_water_cells();
    ASSERT_EQ(cells % pl::kCellsPerGroup, 0u);
    const std::uint64_t groups = cells / pl::kCellsPerGroup;
    EXPECT_EQ(t->root_count(), pl::dc_root_count(n));
    EXPECT_EQ(t->first_child_pool().size(), cells);
    EXPECT_EQ(t->colour_pool().size(), cells);
    EXPECT_EQ(t->group_parent_pool().size(), groups);
    EXPECT_EQ(t->group_depth_flags_pool().size(), groups);
    EXPECT_EQ(t->group_link_pool().size(), groups * pl::kFaceCount);
    // Root groups: no parent, depth 0, no links (pool_layout.h).
    for (std::uint32_t g = 0; g < pl::dc_group_of(t->root_count()); ++g) {
      EXPECT_EQ(t->group_parent_pool()[g], pl::kNoCell);
      EXPECT_EQ(t->group_depth_flags_pool()[g], 0u);
      for (pl::uint f = 0; f < pl::kFaceCount; ++f)
        EXPECT_EQ(t->group_link_pool()[pl::dc_link_index(g, f)], pl::kNoCell);
    }
    // Free groups: clean, flagged, linked to nothing.
    for (std::uint32_t g = pl::dc_group_of(t->root_count()); g < groups; ++g) {
      const std::uint32_t flags = t->group_depth_flags_pool()[g];
      if (!pl::dc_group_is_free(flags)) continue;
      EXPECT_EQ(flags, pl::kGroupFreeFlag);
      for (CellIndex s = 0; s < pl::kCellsPerGroup; ++s) {
        EXPECT_EQ(t->first_child_pool()[pl::dc_group_first_cell(g) + s], pl::kNoCell);
        EXPECT_EQ(t->colour_pool()[pl::dc_group_first_cell(g) + s], 0u);
      }
      for (pl::uint f = 0; f < pl::kFaceCount; ++f)
        EXPECT_EQ(t->group_link_pool()[pl::dc_link_index(g, f)], pl::kNoCell);
    }
  }
}

TEST(OctreeLayout, NavigationEqualsTheHeadersArithmeticAndBruteForceOnRandomCells) {
  std::uint64_t checked = 0, through_links = 0, coarser = 0;
  for (std::uint64_t seed = 1; seed <= 6; ++seed) {
    const std::uint32_t n = 2 + 2 * static_cast<std::uint32_t>(seed % 3);
    auto t = random_tree(seed * 7919, n, 400);
    ASSERT_TRUE(t->check_invariants().ok());
    const client_core::PoolView view = bridge::pool_view_of(*t);
    ASSERT_TRUE(view.validate().ok());
    const std::vector<CellIndex> cells = live_cells(*t);
    std::mt19937_64 rng(seed);
    for (int i = 0; i < 3000; ++i) {
      const CellIndex c = cells[rng() % cells.size()];
      SCOPED_TRACE("seed " + std::to_string(seed) + " cell " + std::to_string(c));
      const CellCoord k = t->coord(c);
      if (c < t->root_count()) {
        ASSERT_EQ(k.depth, 0);
        ASSERT_EQ(pl::dc_root_index(k.x, k.y, k.z, n), c);
      } else {
        // Group, slot, parent and depth as the header reads them from the raw pools.
        const pl::uint g = pl::dc_group_of(c);
        ASSERT_EQ(t->parent(c), t->group_parent_pool()[g]);
        ASSERT_EQ(t->depth(c), static_cast<int>(pl::dc_depth_of(t->group_depth_flags_pool()[g])));
        ASSERT_EQ(view.depth(c), t->depth(c));
        ASSERT_EQ(t->first_child(t->parent(c)), pl::dc_group_first_cell(g));
        ASSERT_EQ(pl::dc_slot_of(c), pl::dc_slot(k.x, k.y, k.z)) << "slot bits = coordinate bits";
        for (pl::uint axis = 0; axis < 3; ++axis) {
          const pl::uint outer = pl::dc_outer_face(c, axis);
          ASSERT_FALSE(pl::dc_face_is_inner(c, outer));
          ASSERT_TRUE(pl::dc_face_is_inner(c, outer ^ 1u));
          ASSERT_EQ(t->g3(c, static_cast<int>(axis)), t->face_neighbour(c, static_cast<int>(outer)));
        }
      }
      for (pl::uint f = 0; f < pl::kFaceCount; ++f) {
        const CellIndex want = brute_force_neighbour(*t, c, static_cast<int>(f));
        ASSERT_EQ(header_neighbour(*t, c, f), want) << "face " << f;
        ASSERT_EQ(t->face_neighbour(c, static_cast<int>(f)), want) << "face " << f;
        ASSERT_EQ(view.face_neighbour(c, static_cast<int>(f)), want) << "face " << f;
        if (c >= t->root_count() && !pl::dc_face_is_inner(c, f)) {
          ++through_links;
          if (want != kNoCell && t->depth(want) < t->depth(c)) ++coarser;
        }
        ++checked;
      }
      if (!t->is_leaf(c)) {
        const pl::uint g = pl::dc_group_of(t->first_child(c));
        for (pl::uint f = 0; f < pl::kFaceCount; ++f) {
          // A group's links are its parent's face neighbours.
          ASSERT_EQ(t->group_link(g, static_cast<int>(f)),
                    t->group_link_pool()[pl::dc_link_index(g, f)]);
          ASSERT_EQ(t->group_link(g, static_cast<int>(f)),
                    brute_force_neighbour(*t, c, static_cast<int>(f)));
        }
      }
    }
  }
  // The random trees exercise every branch of the rule.
  EXPECT_GT(checked, 100000u);
  EXPECT_GT(through_links, 10000u);
  EXPECT_GT(coarser, 100u);
}

}  // namespace
}  // namespace deepcanvas::server_core
