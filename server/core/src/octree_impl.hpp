// Private state of Octree and the small inline helpers shared by octree*.cpp.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "deepcanvas/base/reserved_array.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::server_core {

inline constexpr GroupIndex kNoGroup = 0xFFFFFFFFu;
inline constexpr BlockId kNoBlock = 0xFFFFFFFFu;
// Fixed-point resolution used by locate(): depth-24 cell units, whatever the configured depth.
inline constexpr int kFixedBits = kMaxSupportedDepth;
inline constexpr int kFaces = static_cast<int>(pool_layout::kFaceCount);

struct Octree::Impl {
  OctreeConfig cfg;
  std::uint32_t n = 4;             // roots per axis
  std::uint32_t root_count = 64;   // n^3, a multiple of 8
  std::uint32_t root_groups = 8;   // root_count / 8
  std::uint32_t block_shift = 12;  // log2(block_cells)
  std::uint32_t gblock_shift = 9;  // log2(groups per block)
  std::uint32_t groups_per_block = 512;
  std::uint32_t mask_words_per_block = 8;
  std::uint32_t avail_threshold = 128;  // free groups that make a block worth opening
  std::uint64_t group_capacity = 0;
  std::uint32_t block_capacity = 0;
  double half_edge = 10000.0;
  double fixed_scale = 0.0;  // fixed-point units per metre

  // Persistent pools (what a replica holds, links aside).
  base::ReservedArray<std::uint32_t> first_child;
  base::ReservedArray<std::uint32_t> colour;
  base::ReservedArray<std::uint32_t> gparent;
  base::ReservedArray<std::uint8_t> gdepth;
  base::ReservedArray<std::uint32_t> links;  // kFaces per group (pool_layout::dc_link_index)
  // Bookkeeping.
  base::ReservedArray<std::uint64_t> mask;  // one bit per group
  base::ReservedArray<BlockState> blocks;
  base::ReservedArray<std::uint32_t> free_head;   // per block: first free group or kNoGroup+1
  base::ReservedArray<std::uint32_t> free_count;  // per block
  base::ReservedArray<std::uint8_t> block_flags;  // kInAvail

  static constexpr std::uint8_t kInAvail = 1;

  std::vector<BlockId> dirty_list;
  std::vector<BlockId> avail;  // blocks with >= avail_threshold free groups (lazy)
  std::vector<CellIndex> refine_stack;
  // refresh_filtered()'s work lists, one per depth (kept to reuse their memory).
  std::array<std::vector<CellIndex>, kMaxSupportedDepth + 1> filter_queue;
  // Interior cells whose filtered value may be stale since the last refresh_filtered(): the
  // parent of every cell whose colour changed or that became a leaf, every cell given children,
  // every interior cell written (duplicates allowed). refilter_all: every interior cell of a
  // dirty block and the parent of every group in one instead (a restored tree, whose saved
  // values are not trusted, or a list grown too long).
  std::vector<CellIndex> stale_filtered;
  bool refilter_all = false;
  // Interior cells a zeros_exact refresh left with an older nonzero value (duplicates allowed,
  // deduplicated as the list doubles): the next exact refresh recomputes them.
  std::vector<CellIndex> lagging_filtered;
  std::size_t lagging_unique = 0;  // lagging_filtered's size when it was last deduplicated
  std::uint64_t hw_groups = 0;  // groups ever touched (bump pointer)
  BlockId open_block = kNoBlock;
  std::uint64_t live_groups = 0;  // non-root, allocated groups
  std::uint64_t free_groups = 0;
  std::array<std::uint64_t, kMaxSupportedDepth + 1> groups_at_depth{};

  // ---- small helpers ----
  // free_head stores group+1 so that zero-filled (never-touched) blocks read as "empty list".
  GroupIndex head(BlockId b) const noexcept { return free_head[b] - 1u; }
  void set_head(BlockId b, GroupIndex g) noexcept { free_head[b] = g + 1u; }

  std::uint64_t hw_cells() const noexcept { return hw_groups * pool_layout::kCellsPerGroup; }
  int depth(CellIndex c) const noexcept {
    return static_cast<int>(pool_layout::dc_depth_of(gdepth[pool_layout::dc_group_of(c)]));
  }
  bool is_free_group(GroupIndex g) const noexcept {
    return pool_layout::dc_group_is_free(gdepth[g]);
  }
  // The links of group g: kFaces words at links[dc_link_index(g, 0)].
  std::uint32_t* links_of(GroupIndex g) noexcept {
    return &links[pool_layout::dc_link_index(g, 0)];
  }
  const std::uint32_t* links_of(GroupIndex g) const noexcept {
    return &links[pool_layout::dc_link_index(g, 0)];
  }

  void mark_dirty(BlockId b) noexcept {
    BlockState& s = blocks[b];
    ++s.version;
    if (!s.dirty) {
      s.dirty = true;
      dirty_list.push_back(b);
    }
  }
  // A tree painted for long without refresh_filtered() (a replay) would grow the list without
  // bound: past this many entries it falls back to refilter_all, which covers every entry (each
  // write also marked the written cell's block dirty).
  static constexpr std::size_t kMaxStaleFiltered = std::size_t{1} << 20;
  void filter_stale(CellIndex c) {
    if (refilter_all || (!stale_filtered.empty() && stale_filtered.back() == c)) return;
    if (stale_filtered.size() >= kMaxStaleFiltered) {
      refilter_all = true;
      stale_filtered.clear();
      return;
    }
    stale_filtered.push_back(c);
  }
  // Cell c's colour or leafness changed: its parent's filtered value may be stale.
  void parent_filter_stale(CellIndex c) {
    const GroupIndex g = pool_layout::dc_group_of(c);
    if (g >= root_groups) filter_stale(gparent[g]);
  }
  void set_mask(GroupIndex g) noexcept { mask[g >> 6] |= std::uint64_t{1} << (g & 63); }

  // Same-depth face neighbour of cell p across `face` (or the coarser leaf there; kNoCell at the
  // canvas boundary), the arithmetic of pool_layout.h, given a links pool `l` holding correct
  // links for p's group. Under 2:1 balance an internal cell's same-depth neighbours exist; if
  // the tree is unbalanced there, the coarser leaf is returned (the checker reports it).
  CellIndex same_depth_neighbour(CellIndex p, int face, const std::uint32_t* l) const noexcept {
    namespace pl = pool_layout;
    if (p < root_count) return pl::dc_root_neighbour(p, face, n);
    if (pl::dc_face_is_inner(p, face)) return pl::dc_sibling_across(p, face);
    const CellIndex q = l[pl::dc_link_index(pl::dc_group_of(p), face)];
    if (q == kNoCell) return kNoCell;
    return pl::dc_resolve_link(p, face, q, first_child[q]);
  }

  // Face neighbour through the tree's own links.
  CellIndex face_neighbour(CellIndex c, int face) const noexcept {
    return same_depth_neighbour(c, face, links.data());
  }

  // The six links of group g (pool_layout.h: its parent's face neighbours), read from `src`.
  void compute_group_links(GroupIndex g, const std::uint32_t* src,
                           std::uint32_t* out) const noexcept {
    if (g < root_groups || is_free_group(g)) {
      for (int f = 0; f < kFaces; ++f) out[f] = kNoCell;
      return;
    }
    const CellIndex p = gparent[g];
    for (int f = 0; f < kFaces; ++f) out[f] = same_depth_neighbour(p, f, src);
  }

  // Interior cells' filtered values (octree_links.cpp): recomputes, deepest first, the cells of
  // stale_filtered that are still interior (or refilter_all's), and the parents of those that
  // changed, up to the roots (their blocks become dirty too).
  void refresh_filtered(bool zeros_exact = false);
  void filter_lags(CellIndex c);

  // Allocation (octree.cpp).
  GroupIndex take_from_block(BlockId b) noexcept;
  GroupIndex alloc_group(CellIndex parent) noexcept;
  void free_group(GroupIndex g) noexcept;
  bool split(CellIndex c) noexcept;  // false: out of memory
  bool can_coarsen(CellIndex c) const noexcept;
};

}  // namespace deepcanvas::server_core
