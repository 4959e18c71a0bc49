// The GPU replica of the octree pools: the five textures of shaders/include/pool_layout.h
// (first_child, colour, group_parent, group_depth uploaded from the CPU replica's bytes;
// group_links computed here by links.comp, never uploaded).
//
// Uploads: upload_cells()/upload_blocks() copy whole texture rows from a PoolView (the CPU
// replica, or a server Octree in tests and benchmarks) through a persistent host-visible
// staging buffer, in one submission. Growth: reserve() re-creates the textures taller and
// copies the old rows on the GPU (one submission; indices never change); generation() then
// increases, so passes holding descriptors re-write them.
//
// Rows a growth adds are not written until used. Only the textures the replica starts with
// hold the never-used values (leaf, empty, free group, no link) everywhere; a row a growth adds
// holds unspecified values in the four uploaded textures until a first upload writes it whole,
// and its links are set to "no link" when it is first uploaded or its groups' links first
// computed. Why: a viewer joining a canvas of 128M cells grows its textures to the canvas's
// index range before its first picture, and writing never-used values over 1.5 GB of them took
// 0.2 s to seconds (the pages of a VM's fresh memory first touched), all before the first
// picture. Nothing reads such a row: a frame follows first_child and links from the roots only
// into rows that hold a consistent epoch's cells (the epoch rule), and links.comp likewise.
//
// G3: compute_links() recomputes the links of the listed groups (the groups the neighbour
// computation mask marks), sorted by depth on the CPU and dispatched one depth per dispatch
// with a barrier between, so a group always reads its parent group's final links. The result is
// bit-identical to the server's Octree::recompute_masked_links_into (tested).
//
// Threading: one thread at a time (submissions go through Context::submit_once, which waits),
// except stage_rows(), which touches only the staging buffer: renders from the textures on other
// threads may run alongside it (not another call of this class).
// The Context must outlive the replica. The PoolView passed to a call must stay unchanged for
// the duration of that call only.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_core/pool_view.hpp"
#include "deepcanvas/client_gpu/compute.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/memory.hpp"
#include "pool_layout.h"

namespace deepcanvas::protocol {
struct Welcome;
}  // namespace deepcanvas::protocol

namespace deepcanvas::client_gpu {

struct GpuReplicaConfig {
  std::uint32_t width_log2 = 12;  // texture width W = 4096 cells (kMinWidthLog2..kMaxWidthLog2)
  std::uint32_t block_log2 = 12;  // cells per block (the server's block size)
  std::uint32_t roots_per_axis = 4;
  double edge_m = 20000.0;
  std::uint32_t max_depth = 24;
  // Rounded up to whole rows. 2^20 cells is 12 MB of textures: a painting's first strokes
  // (often 100k+ cells each) then fit without growing at once; later growth is incremental.
  std::uint64_t initial_capacity_cells = 1u << 20;
  // A growth doubles the textures' height but adds at most this many cells (rounded up to whole
  // rows). Why: past that, doubling holds a large canvas twice over for room it seldom uses: a
  // viewer joining 128M cells grew its textures to 256M cells (3 GB of textures where 1.5 GB
  // hold the canvas, plus the old ones while the growth ran). 2^24 cells are about 190 MB of
  // textures, and copying them in steps costs a few seconds of gaps at most on a CPU device.
  std::uint64_t max_growth_cells = 1u << 24;
};

// The replica matching the canvas a server announced on join (pool texture width, block size,
// geometry). The welcome comes validated by the protocol decoder (powers of two in range).
GpuReplicaConfig replica_config_for(const protocol::Welcome& welcome);

// GPU time of the last compute_links() call, when the queue has timestamps.
struct LinksTiming {
  double gpu_ms = -1;  // -1: no timestamps on this device
  std::uint32_t groups = 0;
  std::uint32_t dispatches = 0;
};

class GpuReplica {
 public:
  // Errors: bad_argument (widths, block size, geometry), those of image/pipeline creation.
  static Result<std::unique_ptr<GpuReplica>> create(const Context& ctx, const GpuReplicaConfig&);
  ~GpuReplica();
  GpuReplica(const GpuReplica&) = delete;
  GpuReplica& operator=(const GpuReplica&) = delete;

  // Makes the textures hold at least `cells` cells (rows), growing by doubling, by at most
  // max_growth_cells beyond what `cells` needs (GpuReplicaConfig). Error
  // bad_argument above 2^28 cells. Completes an incremental growth under way when the current
  // textures are too small.
  Result<void> reserve(std::uint64_t cells);

  // Incremental growth, so that no single call stalls the render loop for a whole copy (the
  // StreamingReplica's upload thread runs the steps between frames). begin_growth() makes the
  // taller textures (the current ones stay in use, nothing is copied yet); each growth_step()
  // copies up to `max_rows` further rows into them (rows past the current height are left
  // unwritten: see the header); the step that copies the last row first copies again every row that
  // uploads or compute_links() wrote after it had been copied, then switches to the new
  // textures (generation() increases). Uploads and links go to the current textures throughout.
  // begin_growth: no-op when `cells` fit or a growth is under way; errors as reserve().
  Result<void> begin_growth(std::uint64_t cells);
  bool growing() const noexcept { return growth_ != nullptr; }
  // true once switched (then growing() is false).
  Result<bool> growth_step(std::uint32_t max_rows);
  std::uint32_t growth_rows_left() const noexcept;
  // Copies cells [first, first + count) of the four uploaded pools (whole rows around them) and
  // sets the high-water mark to pools.cell_count(). Reserves as needed.
  Result<void> upload_cells(const client_core::PoolView& pools, std::uint64_t first,
                            std::uint64_t count);
  Result<void> upload_all(const client_core::PoolView& pools) {
    return upload_cells(pools, 0, pools.cell_count());
  }
  Result<void> upload_blocks(const client_core::PoolView& pools,
                             std::span<const std::uint32_t> blocks);
  // Copies the listed texture rows (any order, duplicates allowed; rows past the texture are
  // ignored) in one submission, coalesced into runs. Reserves as needed.
  Result<void> upload_row_list(const client_core::PoolView& pools,
                               std::span<const std::uint32_t> rows);

  // Two-step upload, so the CPU copy into the staging buffer runs outside whatever lock keeps
  // renders off the textures: stage_rows() fills the staging buffer from `rows` (sorted by
  // row, unique; each row's W cells and W/8 groups, never-used values past the high-water mark)
  // and touches nothing else, so other threads may render from the replica meanwhile; then
  // upload_staged() copies the staged rows into the textures (rows past the texture ignored) and
  // sets the high-water mark to pools.cell_count() (`pools`: the CPU copy those rows are now
  // part of). Any other upload in between overwrites the staging buffer: upload_staged() then
  // fails with bad_argument and changes nothing. Errors of stage_rows: bad_argument (unsorted
  // rows, rows of another width), those of buffer creation.
  struct RowSource {
    std::uint32_t row = 0;
    std::span<const std::uint32_t> first_child, colour;  // W each
    std::span<const std::uint32_t> group_parent;         // W/8
    std::span<const std::uint8_t> depth_flags;           // W/8
  };
  struct StagedRows {
    std::uint64_t staging_use = 0;  // which filling of the staging buffer this is
    std::vector<std::uint32_t> rows;
  };
  Result<StagedRows> stage_rows(std::span<const RowSource> rows);
  Result<void> upload_staged(const client_core::PoolView& pools, const StagedRows& staged);

  // Recomputes the links of `groups` (any order, duplicates allowed). `pools` is the CPU copy
  // of the uploaded bytes (used only to sort by depth).
  Result<void> compute_links(const client_core::PoolView& pools,
                             std::span<const std::uint32_t> groups, LinksTiming* timing = nullptr);
  // The groups whose bit is set in `mask` (bit g of word g / 64), then compute_links().
  Result<void> compute_links_masked(const client_core::PoolView& pools,
                                    std::span<const std::uint64_t> mask,
                                    LinksTiming* timing = nullptr);
  // Every group below the high-water mark.
  Result<void> compute_all_links(const client_core::PoolView& pools, LinksTiming* timing = nullptr);

  // The links texture read back as 6 words per group, group-major (the server's pool order),
  // for groups below the high-water mark (unspecified for a row a growth added and nothing has
  // uploaded or linked since).
  Result<std::vector<std::uint32_t>> read_links() const;
  // Whether texture row `row` holds written values: in the textures the replica started with,
  // or uploaded since a growth added it (its links: "no link" until computed).
  bool row_written(std::uint32_t row) const noexcept {
    return row < row_state_.size() && (row_state_[row] & kRowUploaded) != 0;
  }

  // The four uploaded textures read back, for cells (groups) below the high-water mark, in the
  // pools' order: what a check compares with the CPU copy they were uploaded from (rows a growth
  // added and no upload wrote since hold unspecified values: compare where row_written()).
  struct UploadedPools {
    std::vector<std::uint32_t> first_child, colour, group_parent;
    std::vector<std::uint8_t> group_depth_flags;
  };
  Result<UploadedPools> read_uploaded() const;

  const Context& context() const noexcept { return *ctx_; }
  gpu_layout::DcPoolInfo pool_info() const noexcept;
  std::uint64_t cell_count() const noexcept { return cell_count_; }
  // The last upload's PoolView::filtered_interiors: the ray caster steps over empty subtrees
  // whole only then (RenderOptions::skip_empty_subtrees).
  bool filtered_interiors() const noexcept { return filtered_interiors_; }
  std::uint64_t capacity_cells() const noexcept {
    return std::uint64_t{height_} << cfg_.width_log2;
  }
  // GpuReplicaConfig::max_growth_cells, rounded up to whole rows.
  std::uint64_t max_growth_cells() const noexcept;
  std::uint64_t generation() const noexcept { return generation_; }
  std::uint32_t width_log2() const noexcept { return cfg_.width_log2; }
  const GpuReplicaConfig& config() const noexcept { return cfg_; }
  const Image& first_child_image() const noexcept { return first_child_; }
  const Image& colour_image() const noexcept { return colour_; }
  const Image& group_parent_image() const noexcept { return group_parent_; }
  const Image& group_depth_image() const noexcept { return group_depth_; }
  const Image& links_image() const noexcept { return links_; }
  const Sampler& sampler() const noexcept { return sampler_; }

 private:
  explicit GpuReplica(const Context& ctx, const GpuReplicaConfig& cfg);
  Result<void> make_images(std::uint32_t height, Image (&out)[5]) const;
  Result<void> ensure_staging(VkDeviceSize bytes);
  Result<void> write_descriptors();
  struct RowRun {
    std::uint32_t row0, rows;
  };
  // `rows` (sorted, unique) as runs of consecutive rows.
  static std::vector<RowRun> runs_of(std::span<const std::uint32_t> rows);
  Result<void> upload_rows(const client_core::PoolView& pools, std::uint32_t row0,
                           std::uint32_t rows);
  Result<void> upload_runs(const client_core::PoolView& pools, std::span<const RowRun> runs);
  // The staging buffer's layout for `runs`: per run, the four pools' rows back to back, in
  // 16-byte aligned pieces.
  struct StagedPiece {
    RowRun run;
    VkDeviceSize off[4];
  };
  std::vector<StagedPiece> staging_layout(std::span<const RowRun> runs, VkDeviceSize& total) const;
  // Records the copies of `pieces` (already in the staging buffer) and waits for them.
  Result<void> copy_staged(std::span<const StagedPiece> pieces);
  // Rows the current textures' writes touched while a growth is under way (copied again).
  void note_rows_written(std::uint32_t row0, std::uint32_t rows);
  std::uint32_t new_height_for(std::uint64_t cells, Result<void>& error) const;

  // The runs of `runs`' rows whose links were never set (a growth added them since).
  std::vector<RowRun> rows_without_links(std::span<const RowRun> runs) const;
  // Records, into `cb`, "no link" over every face of `runs`' rows in the links texture (from
  // and back to its resting layout), marks their links set, and notes them written for a growth
  // under way.
  void record_no_links(VkCommandBuffer cb, std::span<const RowRun> runs);

  struct Growth;
  std::unique_ptr<Growth> growth_;
  Buffer no_links_;  // "no link" in every face of kNoLinkRows rows of the links texture
  // Per texture row, as tall as the textures (see the header): kRowLinksSet once its links
  // hold "no link" or computed links, kRowUploaded once its four pools were uploaded.
  static constexpr std::uint8_t kRowLinksSet = 1, kRowUploaded = 2;
  std::vector<std::uint8_t> row_state_;

  const Context* ctx_;
  GpuReplicaConfig cfg_;
  std::uint32_t height_ = 0;
  std::uint64_t cell_count_ = 0;
  bool filtered_interiors_ = false;
  std::uint64_t generation_ = 0;
  Image first_child_, colour_, group_parent_, group_depth_, links_;
  Sampler sampler_;
  Buffer staging_;
  std::uint64_t staging_use_ = 0;  // counts the fillings of staging_ (StagedRows)
  Buffer group_list_;
  ComputePipeline links_pipe_;
  DescriptorPool links_pool_;
  VkDescriptorSet links_set_ = VK_NULL_HANDLE;
  std::unique_ptr<TimestampQueries> timestamps_;
};

}  // namespace deepcanvas::client_gpu
