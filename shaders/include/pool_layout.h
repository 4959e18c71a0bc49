// pool_layout.h: THE layout of the octree pools. The server's Octree stores them, block frames
// carry their bytes (protocol/PROTOCOL.md 4.4 describes the wire and points here), the client's
// CPU replica holds them and the client's GPU replica keeps them as textures. This one file owns
// the constants, the group / sibling / neighbour arithmetic and the layout version; it is valid
// as C++20 (namespace deepcanvas::pool_layout, every function constexpr) and as GLSL 4.50
// (shaders include it through GL_GOOGLE_include_directive), so no side can drift from another.
//
// Pinned by tests: tests/client_gpu/layout_test.cpp (C++ side: sizes, offsets, constants, the
// functions against brute force), tests/client_gpu/gpu_test.cpp (what the GLSL compiler sees of
// every struct, constant and function, compared word for word) and tests/octree/
// octree_layout_test.cpp (the server's Octree against this header on random trees).
//
// ============================================================================================
// Memory layout: five pools, structure of arrays, all indexed by one 32-bit cell index I.
// Cells are allocated eight at a time: a group g is the eight children of one parent, the cells
// 8g .. 8g+7. R = N^3 roots come first (N = roots per axis, even, so R is a multiple of 8 and the
// roots fill the root groups 0 .. R/8-1); H is the high-water mark (a multiple of 8).
//
//   cell I         0     1   ..   R-1  | R  ..  R+7 | ... | 8g  8g+1 .. 8g+7 | ... | H-1
//                 [--- root groups ---][- group R/8 -]     [---- group g ----]
//   first_child   [u32 ][u32]..[u32]    [u32]..[u32]        [u32][u32]..[u32]         4 B/cell
//   colour        [u32 ][u32]..[u32]    [u32]..[u32]        [u32][u32]..[u32]         4 B/cell
//   group_parent  [ u32 per group  ]    [    u32    ]       [      u32       ]        4 B/group
//   depth_flags   [  u8 per group  ]    [    u8     ]       [      u8        ]        1 B/group
//   links         [6 x u32 per group]   [  6 x u32  ]       [-x +x -y +y -z +z]      24 B/group
//                                                          (links[6g + face], kFaceCount = 6)
//                                   = 8 + 29/8 = 11.625 bytes per cell, neighbour links included
//
// One word of each pool:
//
//   first_child   |31 ................................................ 0|  child 0's cell index
//                                                                          (a multiple of 8);
//                                                                          kNoCell for a leaf
//   colour        |31    A    24|23    B    16|15    G     8|7     R    0|  RGBA8, A = density
//   group_parent  |31 ................................................ 0|  the parent cell;
//                         kNoCell for a root group; for a free group the next free group of its
//                         block (a server-internal link: store it, never interpret it)
//   depth_flags                            |7 F|6 5 zero|4 ... 0 depth|  F = free group (its
//                         cells are in no tree: first_child kNoCell, colour 0, depth_flags 0x80)
//   links         |31 ................................................ 0|  slot f = face f
//                         (-x +x -y +y -z +z): the group PARENT's same-depth face neighbour (or
//                         the coarser leaf there); kNoCell at the canvas boundary, for root
//                         groups and free groups. Derived data: never sent, every replica
//                         recomputes it (the neighbour mask of a block frame says which).
//
// A cell index (at most 2^28 cells, kMaxCellsLog2):
//
//   |31 .. 28|27 ............................................ 3|2 1 0|
//   |  zero  |                group g (I >> 3)                  |z y x|  slot in the parent
//
//   Root (x, y, z), counted from the canvas's minimum corner, is cell x + N * (y + N * z).
//   Child s of a cell P is first_child[P] + s, s = x | y << 1 | z << 2 (the +x, +y, +z halves).
//
// Neighbours (face = 2 * axis + positive). Why links per group: all eight siblings share their
// parent, so the links across the parent's faces are the parent's six face neighbours. Under
// 2:1 face balance every internal cell's six same-depth face neighbours exist, so a stored link
// always names a same-depth cell, and the face neighbour of any cell I is O(1):
//   I a root                       -> root-array arithmetic (dc_root_neighbour)
//   face inside I's parent         -> the sibling I ^ (1 << axis)       (dc_sibling_across)
//   else L = links[6 * (I >> 3) + face]:
//        L == kNoCell -> kNoCell (canvas boundary); L a leaf -> L (the coarser leaf);
//        else first_child[L] + ((I & 7) ^ (1 << axis)) (the mirrored child, dc_resolve_link).
// Because links only name same-depth cells, a refine or coarsen changes stored links only in the
// group it creates or frees, so a replica recomputes exactly the groups the mask marks, in depth
// order (a group reads the links of its parent's group).
//
// Blocks: fixed runs of B = 2^block_log2 consecutive cells (the server's block_cells); the unit
// of staging, the wire and the GPU upload.
//
// ============================================================================================
// On the GPU each pool is a texture:
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
// group_depth is ONE BYTE per group (R8_UINT), bit-identical to depth_flags, so an upload is a
// plain copy of the server's bytes with no repacking. group_links is computed on the GPU
// (links.comp, never uploaded); layer f holds face f's link.
//
// Texels. W = 1 << width_log2, a power of two, 64 .. 16384 (kMinWidthLog2 .. kMaxWidthLog2).
//   per-cell pools:   cell I  -> (x, y) = (I & (W - 1),          I >> width_log2)
//   per-group pools:  group g -> (x, y) = (g & (W/8 - 1),        g >> (width_log2 - 3))
// so a cell and its group sit in the SAME ROW y (the group's x is the cell's x >> 3), and every
// texture has the same height H = ceil(cells / W). Growing the canvas appends rows to every
// texture alike.
//
// A block on the GPU (B >= 64, kMinBlockLog2):
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
//
// Untrusted input: these functions are pure arithmetic and check nothing. Pools that arrive
// over the network may name any index; code that follows an index from the pools bounds-checks
// it first (PoolView, the client Replica, links.comp, raycast.comp).
// ============================================================================================
#ifndef DEEPCANVAS_POOL_LAYOUT_H
#define DEEPCANVAS_POOL_LAYOUT_H

#ifdef __cplusplus
#include <cstdint>
namespace deepcanvas::pool_layout {
using uint = std::uint32_t;
#define DC_CONST inline constexpr
#define DC_FN inline constexpr
#else
#define DC_CONST const
#define DC_FN
#endif

// ---- constants ------------------------------------------------------------------------------
// The layout version: bump on any change to what the pools' bytes mean. protocol::
// kPoolLayoutVersion (the welcome message's pool_layout.version) is this constant.
DC_CONST uint kLayoutVersion = 1u;
DC_CONST uint kNoCell = 0xFFFFFFFFu;   // "no cell": a leaf's first_child, a root's parent ...
DC_CONST uint kDepthMask = 0x1Fu;      // depth_flags bits 0-4
DC_CONST uint kGroupFreeFlag = 0x80u;  // depth_flags bit 7
DC_CONST uint kMaxDepth = 24u;         // deepest level (roots are depth 0)
DC_CONST uint kMinRootsPerAxis = 2u;   // N: even (so the roots fill whole groups), 2 .. 64
DC_CONST uint kMaxRootsPerAxis = 64u;
DC_CONST uint kMinWidthLog2 = 6u;   // W >= 64 so W/8 >= 8
DC_CONST uint kMaxWidthLog2 = 14u;  // W <= 16384 (Vulkan's guaranteed maxImageDimension2D
                                    // is 4096; 16384 is what desktop drivers give)
DC_CONST uint kMinBlockLog2 = 6u;
DC_CONST uint kMaxCellsLog2 = 28u;  // 16384 x 16384 texels
DC_CONST uint kFaceCount = 6u;      // links per group; also the layer count of group_links
DC_CONST uint kCellsPerGroupLog2 = 3u;
DC_CONST uint kCellsPerGroup = 8u;

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

// ---- cells, groups, roots, depth flags, colour ----------------------------------------------
DC_FN uint dc_group_of(uint cell) {
  return cell >> kCellsPerGroupLog2;
}
DC_FN uint dc_slot_of(uint cell) {
  return cell & (kCellsPerGroup - 1u);
}
DC_FN uint dc_group_first_cell(uint group) {
  return group << kCellsPerGroupLog2;
}
// The slot of the child in the +x (bx = 1) / +y / +z halves of its parent.
DC_FN uint dc_slot(uint bx, uint by, uint bz) {
  return (bx & 1u) | ((by & 1u) << 1u) | ((bz & 1u) << 2u);
}
DC_FN uint dc_root_count(uint roots_per_axis) {
  return roots_per_axis * roots_per_axis * roots_per_axis;
}
DC_FN uint dc_root_index(uint x, uint y, uint z, uint roots_per_axis) {
  return x + roots_per_axis * (y + roots_per_axis * z);
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
DC_FN uint dc_face(uint axis, bool positive) {
  return 2u * axis + (positive ? 1u : 0u);
}
DC_FN uint dc_face_axis(uint face) {
  return face >> 1u;
}
DC_FN bool dc_face_positive(uint face) {
  return (face & 1u) != 0u;
}
// Where the link of `group` across `face` sits in a links pool of kFaceCount words per group.
DC_FN uint dc_link_index(uint group, uint face) {
  return group * kFaceCount + face;
}

// Inside the parent: a face is inner when the cell's slot bit on the face's axis points away
// from it; the neighbour is then the sibling with that bit flipped (sibling arithmetic).
DC_FN bool dc_face_is_inner(uint cell, uint face) {
  return ((cell >> dc_face_axis(face)) & 1u) != (face & 1u);
}
DC_FN uint dc_sibling_across(uint cell, uint face) {
  return cell ^ (1u << dc_face_axis(face));
}
// The cell's face on `axis` that lies on its parent's boundary (the one its G3 link crosses).
DC_FN uint dc_outer_face(uint cell, uint axis) {
  return 2u * axis + ((cell >> axis) & 1u);
}

// Across an outer face into an internal same-depth neighbour whose first child is
// `link_first_child`: the child facing `cell` (same slot, the face's axis bit flipped).
DC_FN uint dc_mirror_child(uint cell, uint face, uint link_first_child) {
  return link_first_child + (dc_slot_of(cell) ^ (1u << dc_face_axis(face)));
}
// Across an outer face, through the group's link (the parent's neighbour `link`, whose
// first_child is `link_first_child`): kNoCell at the boundary, the coarser leaf, or the mirrored
// child (same depth). Callers read link_first_child only once link != kNoCell.
DC_FN uint dc_resolve_link(uint cell, uint face, uint link, uint link_first_child) {
  if (link == kNoCell) return kNoCell;
  if (link_first_child == kNoCell) return link;
  return dc_mirror_child(cell, face, link_first_child);
}

// Roots are a roots_per_axis^3 array: neighbours by index arithmetic; kNoCell at the boundary.
DC_FN uint dc_root_neighbour(uint root, uint face, uint roots_per_axis) {
  uint axis = dc_face_axis(face);
  uint stride = axis == 0u ? 1u : (axis == 1u ? roots_per_axis : roots_per_axis * roots_per_axis);
  uint c = (root / stride) % roots_per_axis;
  if (dc_face_positive(face)) return c + 1u < roots_per_axis ? root + stride : kNoCell;
  return c > 0u ? root - stride : kNoCell;
}

// ---- texel addressing (the GPU textures) ----------------------------------------------------
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

#ifdef __cplusplus
// The C++ side checks its own sizes here; tests/client_gpu pins every offset against GLSL.
static_assert(sizeof(DcPoolInfo) == 32 && alignof(DcPoolInfo) == 4);
static_assert(sizeof(DcDispatchRange) == 16 && alignof(DcDispatchRange) == 4);
static_assert(kCellsPerGroup == 1u << kCellsPerGroupLog2);
static_assert(kMaxDepth <= kDepthMask && (kGroupFreeFlag & kDepthMask) == 0u);
static_assert((1ull << kMaxCellsLog2) == (1ull << kMaxWidthLog2) * (1ull << kMaxWidthLog2));
}  // namespace deepcanvas::pool_layout

// The GPU passes' own parameter structs (raycast_layout.h) live in gpu_layout, which sees the
// whole pool layout too (gpu_layout::DcPoolInfo, gpu_layout::kNoCell, ...).
namespace deepcanvas::gpu_layout {
using namespace deepcanvas::pool_layout;
}  // namespace deepcanvas::gpu_layout
#endif

#undef DC_CONST
#undef DC_FN

#endif  // DEEPCANVAS_POOL_LAYOUT_H
