// The dynamic deep octree: the server's authoritative canvas structure.
//
// Layout: the pools of shaders/include/pool_layout.h (namespace pool_layout), the one definition
// shared with the wire and the client replicas: structure of arrays indexed by a 32-bit cell
// index; per cell first_child and colour, per group (the eight children of one parent, cells
// 8g .. 8g+7) parent, depth_flags and the six links of the group's parent, 11.625 bytes per cell
// with the links. The constants below (kNoCell, kDepthMask, ...) are that header's, and so is the
// neighbour arithmetic (root array, siblings, links). The paper's GPU layout is about 16 bytes
// per cell without its G3 links (12 more per cell).
//
// Positions: the canvas is the cube [-edge/2, edge/2]^3 metres. Cells are addressed exactly by
// integer coordinates (depth d, x, y, z in units of the depth-d cell edge from the canvas minimum
// corner; at most roots_per_axis * 2^24 <= 2^32 per axis). Points in metres are doubles: with a
// 20 km canvas a double resolves 20000 * 2^-53 m ~ 2e-12 m, nine orders of magnitude below the
// finest cell (0.3 mm), so locating a point is exact up to points within ~1e-12 m of a face.
//
// Memory: each pool is a virtual-memory reservation of its capacity (MAP_NORESERVE); pages are
// committed on first touch, so pools grow without moving and indices (and pointers) stay valid.
//
// Allocation (groups of 8, never single cells): each block keeps its own linked free list
// (through the group parent pool) and a count. A new group for parent P is taken, in order,
// from P's block, from the current "open" block, from a block with at least a quarter of its
// groups free (which then becomes the open block), by bumping the high-water mark, and as a last
// resort from any block with a free group. So the groups one stroke creates land in few blocks,
// and freed memory is reused. Freed cells are cleaned (first_child kNoCell, colour 0, links
// kNoCell, depth_flags = kGroupFreeFlag) so that pools are a pure function of the operations.
//
// Links are kept up to date eagerly: refine() fills the new group's six links in O(1) from the
// parent's group links, coarsen() resets the freed group's links to kNoCell, and both also set
// the group's neighbour-mask bit so that a replica (the GPU), which computes links itself,
// knows exactly which groups to recompute.
//
// Blocks: every change to a block's bytes (first_child, colour, group parent, depth_flags, links
// of the groups in it) increments its version and, the first time since take_dirty_blocks(),
// appends it to the dirty list. Block size: 4096 cells by default, chosen by measurement
// (deepcanvas-bench octree, block_size_choice: strokes of 16 stamps on a canvas with a
// painting-like history, blocks dirtied and bytes copied per stamp and per stroke for 1024,
// 4096 and 16384 cells). Smaller blocks copy somewhat fewer bytes but dirty several times more
// blocks (frames, headers, upload regions); larger ones copy markedly more per stamp for little
// further saving in block count.
//
// Interior cells carry a filtered value: the colour of an internal cell is
// protocol::density::filter_rgba of its eight children, so a client that lacks a subtree
// (a progressive join, PROTOCOL.md 4.4) shows that cell in its place. It is brought up to date
// lazily, by take_dirty_blocks(), which first recomputes (deepest first) the interior cells of
// the dirty blocks and the parents of their groups, and the parents of whatever changed, up to
// the roots; their blocks join the dirty list. So what is taken (staged, sent) by an exact take
// is a pure function of the leaves; between two calls an interior value may be stale, and
// nothing but a client's stand-in for a missing subtree and the renderers' empty-subtree test
// read it (painting, merging, picking and canvas_hash() read leaves only).
//
// A take may leave nonzero values lagging (InteriorRefresh::zeros_exact): an interior cell
// whose value changes from one nonzero value to another keeps the old one until an exact take,
// so its block is not dirtied; a value that becomes 0 or stops being 0 is written at once. So
// "0 exactly when the subtree is empty", which the renderers and content boxes rely on, holds
// after every take, and a stroke's epochs do not resend the interior cells above it at every
// step (about a fifth of a streamed stroke's bytes on demo.apa).
//
// Hashes: pool_hash() covers the high-water mark and the first_child, colour, group parent and
// depth_flags pools up to it; links are excluded (they are derived data that replicas compute).
//
// Untrusted input: refine(), coarsen(), set_colour(), locate() and find() check their arguments
// and fail without changing anything. The plain accessors (first_child, colour, parent, depth,
// face_neighbour, g3, coord, ...) are unchecked for speed: pass live cell indices only.
//
// Threading: an Octree is not thread-safe. One thread (the canvas's stroke thread) mutates it;
// others may read block bytes only while that thread is excluded by the owner's lock.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "pool_layout.h"

namespace deepcanvas::server_core {

using CellIndex = std::uint32_t;
using GroupIndex = std::uint32_t;
using BlockId = std::uint32_t;

using pool_layout::kDepthMask;
using pool_layout::kGroupFreeFlag;
using pool_layout::kNoCell;
inline constexpr int kMaxSupportedDepth = static_cast<int>(pool_layout::kMaxDepth);

// Face numbering: face = 2 * axis + (positive ? 1 : 0).
enum Face : int { kNegX = 0, kPosX = 1, kNegY = 2, kPosY = 3, kNegZ = 4, kPosZ = 5 };

struct OctreeConfig {
  std::uint32_t roots_per_axis = 4;  // even, 2..64 (pool_layout::kMin/kMaxRootsPerAxis)
  double edge_m = 20000.0;           // canvas edge in metres
  int max_depth = 24;                // deepest level (roots are depth 0), 1..24
  std::uint32_t block_cells = 4096;  // cells per block, a power of two, >= 512 (whole mask words)
  // Capacity, <= 2^28 (pool_layout::kMaxCellsLog2, the GPU texture limit).
  std::uint64_t max_cells = std::uint64_t{1} << pool_layout::kMaxCellsLog2;
};

// Exact integer address of a cell: coordinates in units of the depth's cell edge, measured
// from the canvas minimum corner.
struct CellCoord {
  int depth = 0;
  std::uint32_t x = 0, y = 0, z = 0;
  friend bool operator==(const CellCoord&, const CellCoord&) = default;
};

// Child i (0..7: bit 0 x, bit 1 y, bit 2 z, the order of a group's cells) of the cell at k.
inline CellCoord child_coord(const CellCoord& k, std::uint32_t i) noexcept {
  return CellCoord{k.depth + 1, 2 * k.x + (i & 1), 2 * k.y + ((i >> 1) & 1), 2 * k.z + (i >> 2)};
}
// The parent of the cell at k (depth > 0).
inline CellCoord parent_coord(const CellCoord& k) noexcept {
  return CellCoord{k.depth - 1, k.x >> 1, k.y >> 1, k.z >> 1};
}

struct Vec3d {
  double x = 0, y = 0, z = 0;
};

struct Aabb {
  Vec3d min, max;
};

struct LocateResult {
  CellIndex cell = kNoCell;
  CellCoord coord;
};

struct OctreeStats {
  std::uint64_t live_cells = 0;  // roots + allocated children
  std::uint64_t leaves = 0;
  int max_depth = 0;                   // deepest live cell
  std::uint64_t high_water_cells = 0;  // pool length actually touched
  std::uint64_t pool_bytes = 0;        // bytes of persistent pools up to the high-water mark
};

// A block's bookkeeping. `version` increases every time the block changes; `dirty` says it has
// changed since the last take_dirty_blocks().
struct BlockState {
  std::uint64_t version = 0;
  bool dirty = false;
};

class Octree {
 public:
  // Fails (Errc::invalid_argument) on an inconsistent config, (Errc::out_of_memory) when the
  // reservation cannot be made.
  static Result<std::unique_ptr<Octree>> create(const OctreeConfig& config);
  ~Octree();
  Octree(const Octree&) = delete;
  Octree& operator=(const Octree&) = delete;

  const OctreeConfig& config() const noexcept;
  std::uint32_t root_count() const noexcept;
  double cell_edge_m(int depth) const noexcept;

  // ---- pools (read access; index < high_water_cells()) ----
  CellIndex first_child(CellIndex c) const noexcept { return first_child_ptr_[c]; }
  std::uint32_t colour(CellIndex c) const noexcept { return colour_ptr_[c]; }
  CellIndex parent(CellIndex c) const noexcept;  // kNoCell for roots
  int depth(CellIndex c) const noexcept;
  bool is_leaf(CellIndex c) const noexcept { return first_child(c) == kNoCell; }
  bool is_live(CellIndex c) const noexcept;  // allocated (not in a free group)
  CellIndex group_link(GroupIndex g, int face) const noexcept;
  std::uint64_t high_water_cells() const noexcept;
  std::uint64_t live_cells() const noexcept;  // roots + allocated children
  // Bytes of memory the tree has committed: every pool up to the high-water mark (rounded up to
  // pages) plus block bookkeeping. What allocated_bytes_per_live_cell is measured from.
  std::uint64_t allocated_bytes() const noexcept;

  // Raw pool views for staging, hashing and the wire (length high_water_cells() or groups).
  std::span<const std::uint32_t> first_child_pool() const noexcept;
  std::span<const std::uint32_t> colour_pool() const noexcept;
  std::span<const std::uint32_t> group_parent_pool() const noexcept;
  std::span<const std::uint8_t> group_depth_flags_pool() const noexcept;
  std::span<const std::uint32_t> group_link_pool() const noexcept;  // 6 per group

  // ---- mutation ----
  // Sets a cell's colour and marks its block dirty (nothing happens when the colour is already
  // `rgba` or `c` is beyond the high-water mark).
  void set_colour(CellIndex c, std::uint32_t rgba) noexcept;

  // Refines leaf `c`: its eight children inherit its colour. First refines any coarser
  // neighbour leaves so that 2:1 balance holds afterwards (recursively). Errors: not a live
  // leaf (invalid_argument), at max depth (refused), capacity reached (out_of_memory; the tree
  // is left balanced and valid, possibly with some neighbours already refined).
  // `created` (if given) receives the number of cells created, balance refinements included.
  Result<void> refine(CellIndex c, std::uint64_t* created = nullptr);

  // True when `c` is internal, all its children are leaves and coarsening keeps 2:1 balance.
  bool can_coarsen(CellIndex c) const noexcept;
  // Removes `c`'s children; `c` gets their average colour (per channel, rounded to nearest:
  // (sum + 4) / 8). Refused (Errc::refused) when can_coarsen(c) is false for a live cell;
  // invalid_argument when `c` is not a live cell. A refused call changes nothing.
  Result<void> coarsen(CellIndex c);

  // ---- navigation ----
  // The leaf containing `p` (metres), or the cell at `max_depth` on the way down if the leaf is
  // deeper. invalid_argument for NaN/inf or points outside the canvas.
  Result<LocateResult> locate(const Vec3d& p, int max_depth) const;
  // The cell with exactly this address if it exists, else the deepest existing ancestor.
  LocateResult find(const CellCoord& coord) const noexcept;
  // O(depth): walks up the parents.
  CellCoord coord(CellIndex c) const noexcept;
  Aabb bounds_m(const CellCoord& coord) const noexcept;

  // Face neighbour in O(1): the same-depth cell across `face`, or the coarser leaf there;
  // kNoCell at the canvas boundary.
  CellIndex face_neighbour(CellIndex c, int face) const noexcept;
  // G3: the three links across the parent's faces, axis 0..2 (the outer face on that axis):
  // the same-depth neighbour there or the coarser leaf; kNoCell at the canvas boundary and for
  // roots (which have no parent; use face_neighbour(), i.e. root-array arithmetic).
  CellIndex g3(CellIndex c, int axis) const noexcept;

  // ---- blocks and neighbour masks ----
  BlockId block_of(CellIndex c) const noexcept { return c / config_block_cells_; }
  std::uint32_t block_count() const noexcept;  // blocks up to the high-water mark
  const BlockState& block_state(BlockId b) const noexcept;
  // Blocks dirtied since the last call, in first-dirtied order (the blocks the filtered
  // interior values changed in last); clears their dirty flags. Refreshes the interior values
  // first (see "Interior cells" above): all of them, or with zeros_exact only those whose
  // zero-ness changes, the others waiting for the next exact take.
  enum class InteriorRefresh { exact, zeros_exact };
  std::vector<BlockId> take_dirty_blocks(InteriorRefresh refresh = InteriorRefresh::exact);
  // Some interior value lags its children's (a zeros_exact take left it): the next exact take
  // or refresh_interior_colours() writes it.
  bool interior_colours_lag() const noexcept;
  // Brings the interior cells' filtered values up to date without taking the dirty list (for
  // hashing the pools between two takes: pool_hash() is then what the next take will send).
  void refresh_interior_colours();
  // No interior value is stale, but for the lagging nonzero ones (interior_colours_lag()):
  // every interior cell is 0 exactly when its children are all 0, and holds filter_rgba of them
  // unless it lags (true right after take_dirty_blocks() or refresh_interior_colours(), until the
  // next write), so a renderer may read an interior 0 as an empty subtree (client_core::PoolView).
  bool interior_colours_current() const noexcept;
  std::span<const BlockId> dirty_blocks() const noexcept;
  // Neighbour computation mask of a block: one bit per group (block_cells / 8 bits, as 64-bit
  // words); set for groups whose links must be recomputed (created or freed groups).
  std::span<const std::uint64_t> neighbour_mask(BlockId b) const noexcept;
  void clear_neighbour_mask(BlockId b) noexcept;
  // Recomputes links for masked groups only (in depth order, so parents come first) and clears
  // the masks. recompute_all_links() is the reference: every group, ignoring masks.
  void recompute_masked_links();
  void recompute_all_links();
  // What a replica does: recomputes, in `links` (6 per group, at least 6 * high-water groups,
  // e.g. a copy of group_link_pool() taken when the masks were last cleared), the masked groups
  // only, in depth order, from this tree's first_child / parent / depth pools. Masks are kept.
  void recompute_masked_links_into(std::span<std::uint32_t> links) const;
  // Clears every block's neighbour mask.
  void clear_all_neighbour_masks() noexcept;

  // ---- extra field pools (painting temporaries) ----
  // A pool of `bytes_per_cell`-byte elements (1, 2, 4 or 8) covering every cell index, zero
  // filled. Released when the handle is destroyed; memory is committed only where touched.
  class FieldPool;
  Result<std::unique_ptr<FieldPool>> add_field_pool(std::string name, std::size_t bytes_per_cell);

  // ---- checkpoints (octree_snapshot.cpp) ----
  // A block's persistent state, the unit of a checkpoint. Layout (little-endian, C =
  // block_cells, G = C / 8 groups), kBlockSnapshotVersion 1:
  //   u32 magic "DCBK", u32 layout version, u32 C, u32 free_count, u64 version,
  //   u32 free_head (first free group + 1, 0 = none), u8 flags, 3 x u8 zero,
  //   C x u32 first_child, C x u32 colour, G x u32 group parent, G x u8 depth_flags
  // (32 + 8.625 C bytes). Links are not saved: restore() recomputes them.
  std::vector<std::uint8_t> save_block(BlockId b) const;
  // The allocator's state: high-water mark, open block, group counts and the blocks with free
  // room, in order (so that a restored tree allocates exactly as the saved one would have).
  //   u32 magic "DCAL", u32 layout version, u64 hw_groups, u32 open_block, u32 block_count,
  //   u64 live_groups, u64 free_groups, 25 x u64 groups_at_depth, u32 n, n x u32 avail blocks
  std::vector<std::uint8_t> save_allocator() const;
  // The tree saved by save_allocator() and save_block() of each block below the allocator's
  // block_count (`block(b)` returns those bytes; an empty span is an error), with the same
  // pools, versions and allocator state, so its pool_hash() and canvas_hash() equal the saved
  // tree's. Every block is marked dirty with full neighbour masks (a fresh replica's view).
  // Untrusted input: malformed names the block and the field on any size, magic, version,
  // index or structure check that fails (each parent/child link is checked to stay inside the
  // high-water mark and point back); nothing is partially built.
  static Result<std::unique_ptr<Octree>> restore(
      const OctreeConfig& config, std::span<const std::uint8_t> allocator,
      const std::function<std::span<const std::uint8_t>(BlockId)>& block);

  // ---- checks and hashes ----
  // Parent/child consistency, free-list integrity, no reachable freed cell, 2:1 balance, links
  // equal to a brute-force neighbour search. Returns the first violation found.
  Result<void> check_invariants() const;
  OctreeStats stats() const;
  // Hash of the pool bytes (positions included): equal iff replicas are byte-identical.
  std::uint64_t pool_hash() const;
  // Hash of the canvas content (structure, depths, colours) in canonical traversal order,
  // independent of where cells sit in the pools.
  std::uint64_t canvas_hash() const;

 private:
  struct Impl;
  explicit Octree(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
  std::uint32_t config_block_cells_ = 4096;
  // Raw views of two hot pools (they never move), so that reads inline.
  const std::uint32_t* first_child_ptr_ = nullptr;
  const std::uint32_t* colour_ptr_ = nullptr;
};

class Octree::FieldPool {
 public:
  virtual ~FieldPool() = default;
  virtual const std::string& name() const noexcept = 0;
  virtual std::size_t bytes_per_cell() const noexcept = 0;
  virtual void* data() noexcept = 0;  // element i at data() + i * bytes_per_cell()
  template <class T>
  T* as() noexcept {
    return static_cast<T*>(data());
  }
  // Returns touched pages to the OS and zeroes the pool (cheap reuse between strokes).
  virtual void clear() noexcept = 0;
};

}  // namespace deepcanvas::server_core
