// pool_layout.h on the C++ side (label unit, no device): offsets and sizes pinned at compile
// time, constants pinned (the one layout version included), and the shared functions checked
// against brute-force references. The GLSL side is pinned against these in gpu_test.cpp, the
// server's Octree in tests/octree/octree_layout_test.cpp.
#include <gtest/gtest.h>

#include <cstddef>
#include <cstring>
#include <set>
#include <vector>

#include "deepcanvas/protocol/version.hpp"
#include "pool_layout.h"

namespace L = deepcanvas::pool_layout;

// ---- the pin: any change here is a layout change (bump kLayoutVersion) ----
static_assert(sizeof(L::DcPoolInfo) == 32);
static_assert(offsetof(L::DcPoolInfo, width_log2) == 0);
static_assert(offsetof(L::DcPoolInfo, block_log2) == 4);
static_assert(offsetof(L::DcPoolInfo, cell_count) == 8);
static_assert(offsetof(L::DcPoolInfo, root_count) == 12);
static_assert(offsetof(L::DcPoolInfo, roots_per_axis) == 16);
static_assert(offsetof(L::DcPoolInfo, max_depth) == 20);
static_assert(offsetof(L::DcPoolInfo, canvas_edge_m) == 24);
static_assert(offsetof(L::DcPoolInfo, reserved0) == 28);
static_assert(sizeof(L::DcDispatchRange) == 16);
static_assert(offsetof(L::DcDispatchRange, first) == 0);
static_assert(offsetof(L::DcDispatchRange, count) == 4);
static_assert(offsetof(L::DcDispatchRange, reserved0) == 8);
static_assert(offsetof(L::DcDispatchRange, reserved1) == 12);
// std430 puts a struct at its largest member alignment (4 here) and arrays at that stride:
// sizes that are multiples of 16 keep arrays of them identical under std140-like packers too.
static_assert(sizeof(L::DcPoolInfo) % 16 == 0 && sizeof(L::DcDispatchRange) % 16 == 0);
static_assert(sizeof(float) == 4 && sizeof(L::uint) == 4);
static_assert(L::kLayoutVersion == 1);
static_assert(deepcanvas::protocol::kPoolLayoutVersion == L::kLayoutVersion);  // one version
static_assert(L::kNoCell == 0xFFFFFFFFu);
static_assert(L::kDepthMask == 0x1F && L::kGroupFreeFlag == 0x80 && L::kMaxDepth == 24);
static_assert((1u << L::kMaxWidthLog2) == 16384 && (1u << L::kMinWidthLog2) == 64);
static_assert(L::kMaxCellsLog2 == 2 * L::kMaxWidthLog2);  // 16384^2 texels = 2^28 cells
static_assert(L::kPoolCount == 5 && L::kFaceCount == 6);
static_assert(L::kCellsPerGroup == 8 && L::kCellsPerGroupLog2 == 3);
static_assert(L::kMinRootsPerAxis == 2 && L::kMaxRootsPerAxis == 64);
// The GPU replica's passes see the pool layout through gpu_layout.
static_assert(deepcanvas::gpu_layout::kNoCell == L::kNoCell &&
              sizeof(deepcanvas::gpu_layout::DcPoolInfo) == sizeof(L::DcPoolInfo));
// The functions are constexpr in C++, so the layout can be checked at compile time too.
static_assert(L::dc_cell_texel_x(16385, 14) == 1 && L::dc_cell_texel_y(16385, 14) == 1);
static_assert(L::dc_group_texel_x(2049, 14) == 1 && L::dc_group_texel_y(2049, 14) == 1);
static_assert(L::dc_pack_rgba8(1, 2, 3, 4) == 0x04030201u);
static_assert(L::dc_face(2, true) == 5 && L::dc_link_index(10, 3) == 63);
static_assert(L::dc_root_index(1, 2, 3, 4) == 1 + 4 * (2 + 4 * 3) && L::dc_root_count(6) == 216);

TEST(PoolLayout, TexelMappingIsARowMajorBijection) {
  for (std::uint32_t w = L::kMinWidthLog2; w <= L::kMaxWidthLog2; ++w) {
    const std::uint32_t W = 1u << w;
    const std::uint32_t cells = 3 * W + 17;
    std::set<std::pair<std::uint32_t, std::uint32_t>> seen;
    for (std::uint32_t i = 0; i < cells; ++i) {
      const std::uint32_t x = L::dc_cell_texel_x(i, w), y = L::dc_cell_texel_y(i, w);
      ASSERT_LT(x, W);
      ASSERT_EQ(y * W + x, i);
      ASSERT_LT(y, L::dc_texture_height(cells, w));
      ASSERT_TRUE(seen.insert({x, y}).second);
      // The cell's group is in the same row of the W/8-wide group textures.
      const std::uint32_t g = L::dc_group_of(i);
      ASSERT_EQ(L::dc_group_texel_y(g, w), y);
      ASSERT_EQ(L::dc_group_texel_x(g, w), x >> 3);
      ASSERT_LT(L::dc_group_texel_x(g, w), L::dc_group_width(w));
    }
    EXPECT_EQ(L::dc_texture_height(cells, w), 4u);
    EXPECT_EQ(L::dc_texture_height(3 * W, w), 3u);
  }
  // The largest canvas fills a 16384 x 16384 texture exactly.
  const std::uint32_t last = (1u << L::kMaxCellsLog2) - 1;
  EXPECT_EQ(L::dc_cell_texel_x(last, L::kMaxWidthLog2), 16383u);
  EXPECT_EQ(L::dc_cell_texel_y(last, L::kMaxWidthLog2), 16383u);
}

TEST(PoolLayout, EveryBlockIsOneRectangleHoldingExactlyItsCells) {
  for (std::uint32_t w = L::kMinWidthLog2; w <= 12; ++w) {
    for (std::uint32_t b = L::kMinBlockLog2; b <= 14; ++b) {
      const std::uint32_t W = 1u << w, B = 1u << b;
      const std::uint32_t bw = L::dc_block_w(b, w), bh = L::dc_block_h(b, w);
      ASSERT_EQ(bw * bh, B) << "W=" << W << " B=" << B;
      ASSERT_LE(bw, W);
      ASSERT_EQ(bw % 8, 0u) << "group rectangles are the cell rectangle >> 3";
      for (std::uint32_t block = 0; block < 5; ++block) {
        const std::uint32_t x0 = L::dc_block_x0(block, b, w), y0 = L::dc_block_y0(block, b, w);
        ASSERT_LE(x0 + bw, W);
        // Brute force: every texel of the rectangle holds a cell of this block, row-major.
        for (std::uint32_t dy = 0; dy < bh; dy += (bh > 4 ? bh - 1 : 1)) {
          for (std::uint32_t dx = 0; dx < bw; ++dx) {
            const std::uint32_t cell = (y0 + dy) * W + x0 + dx;
            ASSERT_EQ(L::dc_block_of(cell, b), block);
            ASSERT_EQ(cell - block * B, dy * bw + dx) << "staging order is row-major";
          }
        }
      }
    }
  }
}

TEST(PoolLayout, SiblingArithmeticAgreesWithCoordinates) {
  // A cell's slot bits are its coordinates' low bits: x bit 0, y bit 1, z bit 2.
  for (std::uint32_t cell = 64; cell < 64 + 8 * 100; ++cell) {
    const std::uint32_t s = L::dc_slot_of(cell);
    const std::uint32_t c[3] = {s & 1, (s >> 1) & 1, s >> 2};
    for (std::uint32_t face = 0; face < 6; ++face) {
      const std::uint32_t axis = L::dc_face_axis(face);
      const bool pos = L::dc_face_positive(face);
      const bool inner = pos ? c[axis] == 0 : c[axis] == 1;
      ASSERT_EQ(L::dc_face_is_inner(cell, face), inner);
      if (inner) {
        const std::uint32_t n = L::dc_sibling_across(cell, face);
        ASSERT_EQ(L::dc_group_of(n), L::dc_group_of(cell));
        std::uint32_t nc[3] = {L::dc_slot_of(n) & 1, (L::dc_slot_of(n) >> 1) & 1,
                               L::dc_slot_of(n) >> 2};
        for (std::uint32_t a = 0; a < 3; ++a) {
          ASSERT_EQ(nc[a], a == axis ? c[a] + (pos ? 1 : 0) - (pos ? 0 : 1) : c[a]);
        }
      } else {
        // Across an outer face: a coarser leaf stays itself, an internal neighbour resolves to
        // the mirrored child (same slot with the face's axis bit flipped).
        EXPECT_EQ(L::dc_resolve_link(cell, face, 1000, L::kNoCell), 1000u);
        EXPECT_EQ(L::dc_resolve_link(cell, face, L::kNoCell, 5), L::kNoCell);
        const std::uint32_t m = L::dc_resolve_link(cell, face, 1000, 4096);
        ASSERT_EQ(m & ~7u, 4096u);
        ASSERT_EQ(L::dc_slot_of(m), s ^ (1u << axis));
      }
    }
  }
}

TEST(PoolLayout, RootNeighboursMatchTheRootArray) {
  for (std::uint32_t n : {2u, 4u, 6u}) {
    for (std::uint32_t z = 0; z < n; ++z)
      for (std::uint32_t y = 0; y < n; ++y)
        for (std::uint32_t x = 0; x < n; ++x) {
          const std::uint32_t root = x + n * (y + n * z);
          const std::int64_t p[3] = {x, y, z};
          for (std::uint32_t face = 0; face < 6; ++face) {
            std::int64_t q[3] = {p[0], p[1], p[2]};
            q[face >> 1] += (face & 1) ? 1 : -1;
            const bool inside = q[face >> 1] >= 0 && q[face >> 1] < n;
            const std::uint32_t want =
                inside ? static_cast<std::uint32_t>(q[0] + n * (q[1] + n * q[2])) : L::kNoCell;
            ASSERT_EQ(L::dc_root_neighbour(root, face, n), want) << "n=" << n << " root=" << root;
          }
        }
  }
}

TEST(PoolLayout, DepthFlagsAndColourMatchTheServerEncoding) {
  // group_depth is the server's depth_flags byte: bits 0-4 depth, bit 7 free.
  for (std::uint32_t d = 0; d <= L::kMaxDepth; ++d) {
    EXPECT_EQ(L::dc_depth_of(d), d);
    EXPECT_FALSE(L::dc_group_is_free(d));
    EXPECT_EQ(L::dc_depth_of(d | L::kGroupFreeFlag), d);
    EXPECT_TRUE(L::dc_group_is_free(d | L::kGroupFreeFlag));
  }
  const std::uint32_t rgba = L::dc_pack_rgba8(0x12, 0x34, 0x56, 0x78);
  const std::uint8_t bytes[4] = {0x12, 0x34, 0x56, 0x78};  // r in the low byte, little endian
  std::uint32_t mem;
  std::memcpy(&mem, bytes, 4);
  EXPECT_EQ(rgba, mem);
  for (std::uint32_t ch = 0; ch < 4; ++ch) EXPECT_EQ(L::dc_colour_channel(rgba, ch), bytes[ch]);
}

TEST(PoolLayout, GroupsSlotsAndLinkSlotsAreTheIndexBits) {
  // A cell index is the group (bits 3..) and the slot (bits 0-2: x, y, z halves of the parent).
  for (std::uint32_t cell = 0; cell < 8 * 1000; ++cell) {
    const std::uint32_t g = L::dc_group_of(cell), s = L::dc_slot_of(cell);
    ASSERT_EQ(g * 8 + s, cell);
    ASSERT_EQ(L::dc_group_first_cell(g), g * 8);
    ASSERT_EQ(L::dc_slot(s & 1, (s >> 1) & 1, s >> 2), s);
    // dc_slot takes the low bit of each coordinate: the child holding coordinate (x, y, z).
    ASSERT_EQ(L::dc_slot(2 * cell + 1, 4 * cell, 2 * cell + 1), 5u);
  }
  // Links: six words per group, in face order, one group after another.
  std::set<std::uint32_t> seen;
  for (std::uint32_t g = 0; g < 100; ++g)
    for (std::uint32_t f = 0; f < L::kFaceCount; ++f) {
      ASSERT_EQ(L::dc_link_index(g, f), g * 6 + f);
      ASSERT_TRUE(seen.insert(L::dc_link_index(g, f)).second);
    }
  EXPECT_EQ(*seen.rbegin(), 100u * 6 - 1);
}

TEST(PoolLayout, FacesAndOuterFacesFollowTheSlotBits) {
  for (std::uint32_t axis = 0; axis < 3; ++axis) {
    for (bool pos : {false, true}) {
      const std::uint32_t f = L::dc_face(axis, pos);
      ASSERT_LT(f, L::kFaceCount);
      ASSERT_EQ(L::dc_face_axis(f), axis);
      ASSERT_EQ(L::dc_face_positive(f), pos);
    }
  }
  // The outer face on an axis is the one on the parent's boundary: the +side for a cell in the
  // parent's + half (slot bit 1), the -side otherwise; the other face on that axis is inner.
  for (std::uint32_t cell = 64; cell < 64 + 8 * 50; ++cell) {
    for (std::uint32_t axis = 0; axis < 3; ++axis) {
      const bool plus_half = ((L::dc_slot_of(cell) >> axis) & 1u) != 0;
      const std::uint32_t outer = L::dc_outer_face(cell, axis);
      ASSERT_EQ(outer, L::dc_face(axis, plus_half));
      ASSERT_FALSE(L::dc_face_is_inner(cell, outer));
      ASSERT_TRUE(L::dc_face_is_inner(cell, L::dc_face(axis, !plus_half)));
      // Across it, into a finer neighbour: the child mirrored on that axis, in the same group.
      const std::uint32_t m = L::dc_mirror_child(cell, outer, 8000);
      ASSERT_EQ(L::dc_group_of(m), 1000u);
      for (std::uint32_t a = 0; a < 3; ++a) {
        const std::uint32_t bit = (L::dc_slot_of(m) >> a) & 1u, mine = (L::dc_slot_of(cell) >> a) & 1u;
        ASSERT_EQ(bit, a == axis ? 1u - mine : mine);
      }
    }
  }
}

TEST(PoolLayout, RootIndexIsXPlusNTimesYPlusNTimesZ) {
  for (std::uint32_t n = L::kMinRootsPerAxis; n <= L::kMaxRootsPerAxis; n += 2) {
    std::uint32_t expect = 0;
    for (std::uint32_t z = 0; z < n; z += (n > 8 ? n - 1 : 1))
      for (std::uint32_t y = 0; y < n; ++y)
        for (std::uint32_t x = 0; x < n; ++x) {
          expect = x + n * y + n * n * z;
          ASSERT_EQ(L::dc_root_index(x, y, z, n), expect);
        }
    EXPECT_EQ(L::dc_root_count(n), n * n * n);
    EXPECT_EQ(L::dc_root_count(n) % L::kCellsPerGroup, 0u) << "even N: the roots fill whole groups";
  }
}
