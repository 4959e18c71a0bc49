// PoolView: a non-owning, read-only view of an octree's pools plus the canvas geometry, the one
// input of the renderers. The server's Octree (first_child_pool() ...) and the client's CPU
// replica expose the same spans, so both can be rendered and compared with the same code.
//
// Layout (see server_core/octree.hpp, the design): per cell first_child (kNoCell for a leaf) and
// colour (RGBA8, r in the low byte, alpha = density); per group (the eight children of one
// parent, cells 8g .. 8g+7; a cell's slot in its parent is I & 7, bit 0 = x, 1 = y, 2 = z)
// parent, depth_flags (bits 0-4 depth, bit 7 free) and six links (the group parent's face
// neighbours at the parent's depth, order -x +x -y +y -z +z, kNoCell at the canvas boundary and
// for root groups). Roots are cells 0 .. N^3-1, root (x, y, z) = x + N * (y + N * z).
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

#include "deepcanvas/protocol/result.hpp"

namespace deepcanvas::client_core {

struct PoolView {
  static constexpr std::uint32_t kNoCell = 0xFFFFFFFFu;
  static constexpr std::uint8_t kDepthMask = 0x1F;
  static constexpr std::uint8_t kFreeFlag = 0x80;
  static constexpr int kMaxDepth = 24;

  std::span<const std::uint32_t> first_child;       // one per cell
  std::span<const std::uint32_t> colour;            // one per cell, RGBA8
  std::span<const std::uint32_t> group_parent;      // one per group
  std::span<const std::uint8_t> group_depth_flags;  // one per group
  std::span<const std::uint32_t> group_links;       // six per group
  std::uint32_t roots_per_axis = 4;
  double edge_m = 20000.0;  // canvas edge; the canvas is [-edge/2, edge/2]^3 metres

  std::uint32_t root_count() const noexcept {
    return roots_per_axis * roots_per_axis * roots_per_axis;
  }
  std::uint64_t cell_count() const noexcept { return first_child.size(); }
  double root_edge_m() const noexcept { return edge_m / roots_per_axis; }
  // Cell edge in metres at `depth` (roots are depth 0).
  double cell_edge_m(int depth) const noexcept;

  // Sizes agree (colour = first_child, groups = cells / 8, links = 6 * groups, all roots
  // present), roots_per_axis even in 2..64, edge finite and positive. invalid_argument if not.
  Result<void> validate() const;

  bool in_range(std::uint32_t c) const noexcept { return c < first_child.size(); }
  // Unchecked: `c` must be in range.
  bool is_leaf(std::uint32_t c) const noexcept { return first_child[c] == kNoCell; }
  int depth(std::uint32_t c) const noexcept {
    return c < root_count() ? 0 : group_depth_flags[c >> 3] & kDepthMask;
  }
  std::uint32_t link(std::uint32_t group, int face) const noexcept {
    return group_links[std::size_t{group} * 6 + static_cast<std::size_t>(face)];
  }

  // Face neighbour (face = 2 * axis + positive) of a cell, same semantics as
  // Octree::face_neighbour: the same-depth cell across the face, or the coarser leaf there;
  // kNoCell at the canvas boundary or when the pools name an index out of range. O(1):
  // sibling arithmetic, root-array arithmetic, or the group's link (+ one first_child step).
  std::uint32_t face_neighbour(std::uint32_t c, int face) const noexcept;
};

}  // namespace deepcanvas::client_core
