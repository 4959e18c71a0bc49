// pool_layout.h: THE layout of the client's GPU replica of the octree pools. One file, valid as
// both C++20 and GLSL 4.50 (included by shaders through GL_GOOGLE_include_directive), so the two
// sides cannot drift apart. tests/client_gpu pins it twice: static_asserts on the C++ side and a
// shader that writes the GLSL side's view of every struct and constant into a buffer, compared at
// run time.
//
// ============================================================================================
// The pools (same fields as the server's octree, see server_core/octree.hpp; a "group" is the
// eight children of one parent, cells 8g .. 8g+7, g = I >> 3)
//
//   pool          Vulkan image                 texel = one   texture width  bytes/cell  written by
//   ------------  ---------------------------  ------------  -------------  ----------  ----------
//   first_child   R32_UINT    2D               cell          W              4           upload
//   colour        R32_UINT    2D               cell          W              4           upload
//   group_parent  R32_UINT    2D               group         W/8            4/8         upload
//   group_depth   R8_UINT     2D               group         W/8            1/8         upload
//   group_links   R32_UINT    2D array, 6 lay  group (x6)    W/8            24/8        G3 pass
//                                                                           ----------
//                                                        GPU memory per cell: 11.625 B (as server)
//
// group_depth is kept as ONE BYTE per group (R8_UINT), bit-identical to the server's depth_flags
// pool, so an upload is a plain copy of the server's bytes with no repacking.
// group_links is computed on the GPU (never uploaded); layer f holds face f's link.
//
// Bits of one texel:
//
//   first_child   |31 ................................................ 0|  child 0's cell index,
//                                                                          kNoCell for a leaf
//   colour        |31    A    24|23    B    16|15    G     8|7     R    0|  RGBA8, A = density
//   group_parent  |31 ................................................ 0|  parent cell (kNoCell
//                                                                          for a root group)
//   group_depth                            |7 F|6 5 zero|4 ... 0 depth|  F = free group
//   group_links   |31 ................................................ 0|  layer f = face f
//                 (-x +x -y +y -z +z): the group parent's same-depth face neighbour, or the
//                 coarser leaf there; kNoCell at the canvas boundary and for root groups.
//
// A cell index (at most 2^28 cells = 16384 x 16384 texels):
//
//   |31 .. 28|27 ............................................ 3|2 1 0|
//   |  zero  |                group g (I >> 3)                  |z y x|  slot in the parent
//
// ============================================================================================
// Texels. W = 1 << width_log2, a power of two, 64 .. 16384 (kMinWidthLog2 .. kMaxWidthLog2).
//   per-cell pools:   cell I  -> (x, y) = (I & (W - 1),          I >> width_log2)
//   per-group pools:  group g -> (x, y) = (g & (W/8 - 1),        g >> (width_log2 - 3))
// so a cell and its group sit in the SAME ROW y (the group's x is the cell's x >> 3), and every
// texture has the same height H = ceil(cells / W). Growing the canvas appends rows to every
// texture alike.
//
// Blocks. B = 1 << block_log2 cells (a power of two, >= 64). Block b is cells [b*B, (b+1)*B):
//   B >= W: a band of B/W full rows, y in [b*B/W, (b+1)*B/W)         (the normal case)
//   B <  W: a segment of one row, W/B blocks per row
// Either way one rectangle per texture (the same rows in all five), so uploading a block is one
// buffer-to-image copy region per pool (the links' 6 layers in one region).
//
//   (illustration only: W = 8, B = 16, a block is 2 rows)   group texture (W/8 = 1 wide):
//          x = 0  1  2  3  4  5  6  7
//     y=0      0  1  2  3  4  5  6  7   | block 0              g0
//     y=1      8  9 10 11 12 13 14 15   |                      g1
//     y=2     16 17 ...             23  | block 1              g2
//     y=3     24 ...                31  |                      g3
//
// ============================================================================================
// Structs shared by C++ and GLSL: only 32-bit scalars (uint, float) and fixed arrays of them,
// padded explicitly to a multiple of 16 bytes. Under std430 (storage buffers and push
// constants; Vulkan GLSL's default for push_constant blocks) their layout equals the C++
// layout. NEVER put them in a std140 uniform block: std140 rounds array strides up to 16.
// ============================================================================================
#ifndef DEEPCANVAS_POOL_LAYOUT_H
#define DEEPCANVAS_POOL_LAYOUT_H

#ifdef __cplusplus
#include <cstdint>
namespace deepcanvas::gpu_layout {
using uint = std::uint32_t;
#define DC_CONST inline constexpr
#define DC_FN inline constexpr
#else
#define DC_CONST const
#define DC_FN
#endif

// ---- constants ------------------------------------------------------------------------------
DC_CONST uint kLayoutVersion = 1u;  // bump on any change below (the handshake may check it)
DC_CONST uint kNoCell = 0xFFFFFFFFu;
DC_CONST uint kDepthMask = 0x1Fu;      // group_depth bits 0-4
DC_CONST uint kGroupFreeFlag = 0x80u;  // group_depth bit 7
DC_CONST uint kMaxDepth = 24u;
DC_CONST uint kMinWidthLog2 = 6u;   // W >= 64 so W/8 >= 8
DC_CONST uint kMaxWidthLog2 = 14u;  // W <= 16384 (Vulkan's guaranteed maxImageDimension2D
                                    // is 4096; 16384 is what desktop drivers give)
DC_CONST uint kMinBlockLog2 = 6u;
DC_CONST uint kMaxCellsLog2 = 28u;  // 16384 x 16384 texels
DC_CONST uint kFaceCount = 6u;      // also the layer count of group_links
DC_CONST uint kCellsPerGroupLog2 = 3u;

// Pool ids: binding order used by the compute passes and the upload code.
DC_CONST uint kPoolFirstChild = 0u;
DC_CONST uint kPoolColour = 1u;
DC_CONST uint kPoolGroupParent = 2u;
DC_CONST uint kPoolGroupDepth = 3u;
DC_CONST uint kPoolGroupLinks = 4u;
DC_CONST uint kPoolCount = 5u;

// ---- shared structs (std430) ----------------------------------------------------------------

// Geometry of the replica: push constant / storage buffer header of every pass. 32 bytes.
struct DcPoolInfo {
  uint width_log2;      //  0  W = 1 << width_log2 (per-cell textures)
  uint block_log2;      //  4  B = 1 << block_log2 cells per block
  uint cell_count;      //  8  high-water mark: cells [0, cell_count) have valid texels
  uint root_count;      // 12  roots_per_axis^3, the first root_count cells
  uint roots_per_axis;  // 16  root (x, y, z) = x + N * (y + N * z)
  uint max_depth;       // 20  deepest level the canvas allows (<= kMaxDepth)
  float canvas_edge_m;  // 24  a float copy for shaders; positions are cell-local on the GPU
  uint reserved0;       // 28  explicit padding to 32 bytes
};

// A range of elements (cells or groups) for one dispatch. 16 bytes.
struct DcDispatchRange {
  uint first;      // 0  first element
  uint count;      // 4  elements to process
  uint reserved0;  // 8
  uint reserved1;  // 12
};

// ---- texel addressing -----------------------------------------------------------------------
DC_FN uint dc_width(uint width_log2) {
  return 1u << width_log2;
}
DC_FN uint dc_group_width(uint width_log2) {
  return 1u << (width_log2 - kCellsPerGroupLog2);
}
DC_FN uint dc_cell_texel_x(uint cell, uint width_log2) {
  return cell & ((1u << width_log2) - 1u);
}
DC_FN uint dc_cell_texel_y(uint cell, uint width_log2) {
  return cell >> width_log2;
}
DC_FN uint dc_group_texel_x(uint group, uint width_log2) {
  return group & (dc_group_width(width_log2) - 1u);
}
DC_FN uint dc_group_texel_y(uint group, uint width_log2) {
  return group >> (width_log2 - kCellsPerGroupLog2);
}
// Rows needed for `cells` cells (every pool texture has this height).
DC_FN uint dc_texture_height(uint cells, uint width_log2) {
  return (cells + (1u << width_log2) - 1u) >> width_log2;
}

// A block's rectangle in the per-cell textures (per-group textures: same y and h, x >> 3, w >> 3).
DC_FN uint dc_block_x0(uint block, uint block_log2, uint width_log2) {
  return block_log2 >= width_log2 ? 0u : ((block << block_log2) & ((1u << width_log2) - 1u));
}
DC_FN uint dc_block_y0(uint block, uint block_log2, uint width_log2) {
  return (block << block_log2) >> width_log2;
}
DC_FN uint dc_block_w(uint block_log2, uint width_log2) {
  return block_log2 >= width_log2 ? (1u << width_log2) : (1u << block_log2);
}
DC_FN uint dc_block_h(uint block_log2, uint width_log2) {
  return block_log2 >= width_log2 ? (1u << (block_log2 - width_log2)) : 1u;
}

// ---- cells, groups, depth flags, colour -----------------------------------------------------
DC_FN uint dc_group_of(uint cell) {
  return cell >> kCellsPerGroupLog2;
}
DC_FN uint dc_slot_of(uint cell) {
  return cell & 7u;
}
DC_FN uint dc_block_of(uint cell, uint block_log2) {
  return cell >> block_log2;
}
DC_FN uint dc_depth_of(uint depth_flags) {
  return depth_flags & kDepthMask;
}
DC_FN bool dc_group_is_free(uint depth_flags) {
  return (depth_flags & kGroupFreeFlag) != 0u;
}
DC_FN uint dc_colour_channel(uint rgba, uint channel) {
  return (rgba >> (8u * channel)) & 0xFFu;
}
DC_FN uint dc_pack_rgba8(uint r, uint g, uint b, uint a) {
  return (r & 0xFFu) | ((g & 0xFFu) << 8u) | ((b & 0xFFu) << 16u) | ((a & 0xFFu) << 24u);
}

// ---- faces and neighbours -------------------------------------------------------------------
// face = 2 * axis + (positive ? 1 : 0): -x +x -y +y -z +z.
DC_FN uint dc_face_axis(uint face) {
  return face >> 1u;
}
DC_FN bool dc_face_positive(uint face) {
  return (face & 1u) != 0u;
}

// Inside the parent: a face is inner when the cell's slot bit on the face's axis points away
// from it; the neighbour is then the sibling with that bit flipped (sibling arithmetic).
DC_FN bool dc_face_is_inner(uint cell, uint face) {
  return ((cell >> dc_face_axis(face)) & 1u) != (face & 1u);
}
DC_FN uint dc_sibling_across(uint cell, uint face) {
  return cell ^ (1u << dc_face_axis(face));
}

// Across an outer face, through the group's link (the parent's neighbour `link`, whose
// first_child is `link_first_child`): the coarser leaf, or the mirrored child (same depth).
DC_FN uint dc_resolve_link(uint cell, uint face, uint link, uint link_first_child) {
  if (link == kNoCell) return kNoCell;
  if (link_first_child == kNoCell) return link;
  return link_first_child + ((cell & 7u) ^ (1u << dc_face_axis(face)));
}

// Roots are a roots_per_axis^3 array: neighbours by index arithmetic; kNoCell at the boundary.
DC_FN uint dc_root_neighbour(uint root, uint face, uint roots_per_axis) {
  uint axis = dc_face_axis(face);
  uint stride = axis == 0u ? 1u : (axis == 1u ? roots_per_axis : roots_per_axis * roots_per_axis);
  uint c = (root / stride) % roots_per_axis;
  if (dc_face_positive(face)) return c + 1u < roots_per_axis ? root + stride : kNoCell;
  return c > 0u ? root - stride : kNoCell;
}

#ifdef __cplusplus
// The C++ side checks its own sizes here; tests/client_gpu pins every offset against GLSL.
static_assert(sizeof(DcPoolInfo) == 32 && alignof(DcPoolInfo) == 4);
static_assert(sizeof(DcDispatchRange) == 16 && alignof(DcDispatchRange) == 4);
}  // namespace deepcanvas::gpu_layout
#endif

#undef DC_CONST
#undef DC_FN

#endif  // DEEPCANVAS_POOL_LAYOUT_H
