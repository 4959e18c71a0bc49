// Replica: a client's CPU copy of one canvas's pools, built from block frames.
//
// The pools have the layout of shaders/include/pool_layout.h: per cell first_child and colour,
// per group parent and depth_flags, which arrive in block frames, plus the six links per group,
// which never cross the wire: the replica recomputes them for the groups the frames' neighbour
// masks mark, in depth order (parents' groups first), with that header's neighbour arithmetic,
// so the links equal the server's group_link_pool().
//
// Epochs: frames are staged with stage() and become visible together with commit(), which is
// what a client does at epoch_end (no reader ever sees a half-applied epoch). pool_hash() is
// protocol::pool_hash over the high-water mark (the end of the furthest range received).
//
// Delta frames (PROTOCOL.md 4.7): stage() resolves a delta at once against the block as this
// replica holds it (the newest staged frame of the block, else the committed pools) and stages
// the full frame it stands for; a delta whose base version the replica does not hold, or whose
// result fails its checksum, is rejected with an error and nothing is staged. The replica keeps
// each block's version and range (from the frames applied) for this.
//
// Untrusted input: stage() checks every frame against the geometry (range inside its block,
// at most kMaxCells); link computation bounds-checks every index it follows, so garbage pools
// give garbage links, never out-of-bounds reads.
//
// Threading: not thread-safe; the owner (Client) serialises access.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <unordered_map>
#include <utility>
#include <vector>

#include "deepcanvas/client_core/pool_array.hpp"
#include "deepcanvas/client_core/pool_view.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_core {

struct ReplicaGeometry {
  std::uint32_t roots_per_axis = 4;
  double edge_m = 20000.0;
  std::uint32_t block_cells = 4096;
};

class Replica {
 public:
  static constexpr std::uint64_t kMaxCells = std::uint64_t{1} << pool_layout::kMaxCellsLog2;

  explicit Replica(const ReplicaGeometry& geometry);

  // Queues a decoded frame for the next commit. invalid_argument for a range outside its block
  // or past kMaxCells, or a delta frame whose base version this replica does not hold; malformed
  // for a delta whose result fails payload_crc. Nothing is queued on error.
  Result<void> stage(protocol::BlockFrame frame);
  // Applies every staged frame in order (later frames of the same block overwrite the fields
  // they carry; neighbour masks are OR-ed), then recomputes the links of the masked groups.
  // Returns the number of frames applied.
  std::size_t commit();
  std::size_t staged_frames() const noexcept { return staged_.size(); }

  // Progressive join (PROTOCOL.md 4.4): applies the frames staged so far of a snapshot that is
  // still arriving (its epoch_end has not come) and hides what they cannot show yet: a cell
  // whose children lie in a block this replica holds no version of reads as a leaf
  // (first_child kNoCell), so a renderer shows the cell's filtered value in place of the
  // subtree and never a cell whose data has not arrived. A later commit_partial() or commit()
  // un-hides the cells whose children's block has come; commit() un-hides all of them, so the
  // replica equals the server's pools byte for byte again. Both recompute the links of every
  // group received while cells are or were hidden (hiding a cell changes the links of groups anywhere
  // near it). Returns the number of frames applied: 0, applying nothing, until the block
  // holding the roots (block 0) has come. Only for a replica that holds nothing but this
  // snapshot: the blocks of an earlier epoch would mix with the snapshot's.
  std::size_t commit_partial();
  // Cells are hidden (since a commit_partial(), until a commit()).
  bool partial() const noexcept { return partial_; }
  // The cells whose first_child the last commit or commit_partial() hid or un-hid, ascending:
  // their bytes changed beside the frames' ranges (a GPU copy must take them too).
  std::span<const std::uint32_t> changed_cells() const noexcept { return changed_cells_; }
  // The groups of every block received, ascending (the groups whose links a commit of a part,
  // or of the whole after parts, recomputed).
  std::vector<std::uint32_t> received_groups() const;
  // Drops staged frames (e.g. after a broken connection).
  void discard_staged() noexcept { staged_.clear(); }

  std::uint64_t high_water_cells() const noexcept { return hw_groups_ * 8; }
  std::uint64_t pool_hash() const noexcept;
  // Hash of the links pool up to the high-water mark (compare with the server's links).
  std::uint64_t links_hash() const noexcept;
  // A view of the pools (valid until the next commit).
  PoolView view() const noexcept;
  const ReplicaGeometry& geometry() const noexcept { return geometry_; }
  std::uint64_t links_recomputed() const noexcept { return links_recomputed_; }
  // The version of block `block` as committed (the last frame with pools applied), if any.
  std::optional<std::uint64_t> block_version(std::uint32_t block) const noexcept;

  std::span<const std::uint32_t> group_links() const noexcept {
    return {links_.data(), hw_groups_ * pool_layout::kFaceCount};
  }

 private:
  void grow(std::uint64_t groups);
  // Applies the staged frames (commit()'s first half); the blocks they carried pools for.
  std::vector<std::uint32_t> apply_staged();
  // Masked groups' links, in depth order (every group with `all`).
  void recompute_links(bool all);
  bool holds_block(std::uint64_t block) const noexcept {
    return block < held_.size() && held_[block].valid;
  }
  Result<void> resolve_delta(protocol::BlockFrame& frame) const;
  std::uint32_t same_depth_neighbour(std::uint32_t p, pool_layout::uint face) const noexcept;
  void compute_group_links(std::uint32_t g) noexcept;

  ReplicaGeometry geometry_;
  std::uint32_t root_count_ = 64;
  std::uint64_t hw_groups_ = 0;
  // Reserved for kMaxCells and grown without copying or writing (PoolArray): a large canvas's
  // first part shows without waiting for its whole index range to be written. The links of a
  // chunk of 2^kLinkChunkLog2 groups are set to kNoCell when a frame first carries pools there
  // or a group's links there are first computed (set_links_of); before that they read zero,
  // and nothing reads them (a group no frame carried is no group's parent or neighbour).
  PoolArray<std::uint32_t> first_child_, colour_, group_parent_, links_;
  PoolArray<std::uint8_t> depth_flags_;
  PoolArray<std::uint64_t> mask_;  // one bit per group, pending recomputation
  static constexpr unsigned kLinkChunkLog2 = 9;
  std::vector<std::uint8_t> links_set_;  // per chunk of groups
  // Sets the links of groups [g0, g0 + groups)'s chunks not set yet to kNoCell.
  void set_links_of(std::uint64_t g0, std::uint64_t groups) noexcept;
  std::vector<protocol::BlockFrame> staged_;
  // Per block id: the version and range of the last frame carrying pools that was committed.
  struct BlockHeld {
    bool valid = false;
    std::uint64_t version = 0;
    std::uint32_t first_cell = 0, cell_count = 0;
  };
  std::vector<BlockHeld> held_;
  std::uint64_t links_recomputed_ = 0;
  // Progressive join: hidden cells and their real first_child, by the block it lies in.
  bool partial_ = false;
  std::unordered_map<std::uint32_t, std::vector<std::pair<std::uint32_t, std::uint32_t>>> hidden_;
  std::vector<std::uint32_t> changed_cells_;
};

}  // namespace deepcanvas::client_core
