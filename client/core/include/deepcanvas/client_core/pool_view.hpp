// PoolView: a non-owning, read-only view of an octree's pools plus the canvas geometry, the one
// input of the renderers. The server's Octree (first_child_pool() ...) and the client's CPU
// replica expose the same spans, so both can be rendered and compared with the same code (a
// view of a server Octree, for code linking both: bridge/.../pool_view_of_octree.hpp).
//
// Layout: the pools of shaders/include/pool_layout.h, the one definition (constants, bit fields,
// group / sibling / neighbour arithmetic); the constants below are that header's.
//
// Ownership and threading: the view borrows the spans; the owner keeps them alive and unchanged
// while any reader uses the view. Reading from several threads at once is fine.
//
// Untrusted input: a replica's pools arrive over the network, so nothing here assumes they are
// consistent. validate() checks only sizes and geometry (O(1)); code walking the pools
// (face_neighbour, the renderers) bounds-checks every index it follows.
#pragma once

#include <cstdint>
#include <span>

#include "deepcanvas/base/result.hpp"
#include "pool_layout.h"

namespace deepcanvas::client_core {

struct PoolView {
  static constexpr std::uint32_t kNoCell = pool_layout::kNoCell;
  static constexpr std::uint8_t kDepthMask = pool_layout::kDepthMask;  // depth_flags bytes
  static constexpr std::uint8_t kFreeFlag = pool_layout::kGroupFreeFlag;
  static constexpr int kMaxDepth = static_cast<int>(pool_layout::kMaxDepth);

  std::span<const std::uint32_t> first_child;       // one per cell
  std::span<const std::uint32_t> colour;            // one per cell, RGBA8
  std::span<const std::uint32_t> group_parent;      // one per group
  std::span<const std::uint8_t> group_depth_flags;  // one per group
  std::span<const std::uint32_t> group_links;       // six per group (dc_link_index)
  std::uint32_t roots_per_axis = 4;
  double edge_m = 20000.0;  // canvas edge; the canvas is [-edge/2, edge/2]^3 metres
  // Every interior cell's colour is protocol::density::filter_rgba of its children, which is 0
  // exactly for an empty subtree: the renderers then step over an empty subtree as one cell
  // (RenderOptions::skip_empty_subtrees). True for what a server sends (it refreshes interior
  // values before it stages an epoch) and for a server Octree whose interior values are current
  // (bridge::pool_view_of); false where interior values may be stale. A false true costs only
  // pixels (paint under a stale 0 is not drawn), never memory safety.
  bool filtered_interiors = false;

  std::uint32_t root_count() const noexcept { return pool_layout::dc_root_count(roots_per_axis); }
  std::uint64_t cell_count() const noexcept { return first_child.size(); }
  double root_edge_m() const noexcept { return edge_m / roots_per_axis; }
  // Cell edge in metres at `depth` (roots are depth 0).
  double cell_edge_m(int depth) const noexcept;

  // Sizes agree (colour = first_child, groups = cells / 8, links = 6 * groups, all roots
  // present), roots_per_axis even in pool_layout's 2..64, edge finite and positive.
  // invalid_argument if not.
  Result<void> validate() const;

  bool in_range(std::uint32_t c) const noexcept { return c < first_child.size(); }
  // Unchecked: `c` must be in range.
  bool is_leaf(std::uint32_t c) const noexcept { return first_child[c] == kNoCell; }
  int depth(std::uint32_t c) const noexcept {
    return c < root_count() ? 0
                            : static_cast<int>(pool_layout::dc_depth_of(
                                  group_depth_flags[pool_layout::dc_group_of(c)]));
  }
  std::uint32_t link(std::uint32_t group, int face) const noexcept {
    return group_links[pool_layout::dc_link_index(group, static_cast<pool_layout::uint>(face))];
  }

  // Face neighbour (face = 2 * axis + positive) of a cell, same semantics as
  // Octree::face_neighbour: the same-depth cell across the face, or the coarser leaf there;
  // kNoCell at the canvas boundary or when the pools name an index out of range. O(1):
  // sibling arithmetic, root-array arithmetic, or the group's link (+ one first_child step).
  std::uint32_t face_neighbour(std::uint32_t c, int face) const noexcept;
};

}  // namespace deepcanvas::client_core
