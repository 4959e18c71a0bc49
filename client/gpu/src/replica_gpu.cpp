#include "deepcanvas/client_gpu/replica_gpu.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <string>

#include "deepcanvas/client_gpu/errors.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/shaders/links.spv.h"

namespace deepcanvas::client_gpu {

GpuReplicaConfig replica_config_for(const protocol::Welcome& welcome) {
  GpuReplicaConfig cfg;
  cfg.width_log2 = static_cast<std::uint32_t>(std::countr_zero(welcome.texture_width));
  cfg.block_log2 = static_cast<std::uint32_t>(std::countr_zero(welcome.block_cells));
  cfg.roots_per_axis = welcome.geometry.roots_per_axis;
  cfg.edge_m = welcome.geometry.edge_m;
  cfg.max_depth = welcome.geometry.max_depth;
  return cfg;
}

namespace {

namespace L = gpu_layout;

// The layout each pool image rests in between passes (index = pool id): GENERAL for the images
// also used as storage images (first_child, colour: imageLoad in the ray caster; links: written
// by the G3 pass), SHADER_READ_ONLY_OPTIMAL for the sampled-only ones.
VkImageLayout resting_layout(int pool) {
  return pool == 0 || pool == 1 || pool == 4 ? VK_IMAGE_LAYOUT_GENERAL
                                             : VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL;
}
using client_core::PoolView;

constexpr std::uint32_t kLinksLocalSize = 64;
// Rows of the links texture one copy from GpuReplica::no_links_ covers.
constexpr std::uint32_t kNoLinkRows = 64;

struct LinksPush {
  L::DcPoolInfo pool;
  L::DcDispatchRange range;
};

VkDeviceSize align16(VkDeviceSize v) {
  return (v + 15) & ~VkDeviceSize{15};
}

void global_barrier(VkCommandBuffer cb, VkPipelineStageFlags src, VkAccessFlags src_access,
                    VkPipelineStageFlags dst, VkAccessFlags dst_access) {
  VkMemoryBarrier mb{};
  mb.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
  mb.srcAccessMask = src_access;
  mb.dstAccessMask = dst_access;
  vkCmdPipelineBarrier(cb, src, dst, 0, 1, &mb, 0, nullptr, 0, nullptr);
}

void clear_image(VkCommandBuffer cb, const Image& img, std::uint32_t value) {
  VkClearColorValue v{};
  v.uint32[0] = value;
  VkImageSubresourceRange range{VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, img.desc().layers};
  vkCmdClearColorImage(cb, img.handle(), VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, &v, 1, &range);
}

}  // namespace

// An incremental growth under way (see begin_growth()).
struct GpuReplica::Growth {
  Image fresh[5];
  std::uint32_t old_height = 0, new_height = 0;
  std::uint32_t next_row = 0;  // rows [0, next_row) of `fresh` are copied (or left unwritten)
  // Rows below next_row written to the current textures after they were copied.
  std::vector<std::uint8_t> dirty;  // per row below old_height
  std::vector<std::uint32_t> dirty_rows;
};

GpuReplica::GpuReplica(const Context& ctx, const GpuReplicaConfig& cfg) : ctx_(&ctx), cfg_(cfg) {}
GpuReplica::~GpuReplica() = default;

Result<std::unique_ptr<GpuReplica>> GpuReplica::create(const Context& ctx,
                                                       const GpuReplicaConfig& cfg) {
  if (cfg.width_log2 < L::kMinWidthLog2 || cfg.width_log2 > L::kMaxWidthLog2 ||
      (1u << cfg.width_log2) > ctx.limits().maxImageDimension2D) {
    return gpu_error(GpuErrc::bad_argument,
                     "replica: texture width 2^" + std::to_string(cfg.width_log2) +
                         " outside 2^6..2^14 or above the device's maxImageDimension2D");
  }
  if (cfg.block_log2 < L::kMinBlockLog2 || cfg.block_log2 > L::kMaxCellsLog2) {
    return gpu_error(GpuErrc::bad_argument, "replica: block size out of range");
  }
  if (cfg.roots_per_axis < 2 || cfg.roots_per_axis > 64 || cfg.roots_per_axis % 2 != 0 ||
      !(cfg.edge_m > 0) || cfg.max_depth > L::kMaxDepth) {
    return gpu_error(GpuErrc::bad_argument, "replica: bad canvas geometry");
  }
  std::unique_ptr<GpuReplica> r(new GpuReplica(ctx, cfg));
  auto sampler = Sampler::create_nearest(ctx);
  if (!sampler) return std::move(sampler).error();
  r->sampler_ = std::move(*sampler);

  auto pipe =
      ComputePipeline::create(ctx, {.name = "links",
                                    .spirv = deepcanvas_spv_links,
                                    .bindings = {{0, VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER},
                                                 {1, VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER},
                                                 {2, VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER},
                                                 {3, VK_DESCRIPTOR_TYPE_STORAGE_IMAGE},
                                                 {4, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER}},
                                    .push_constant_bytes = sizeof(LinksPush)});
  if (!pipe) return std::move(pipe).error();
  r->links_pipe_ = std::move(*pipe);
  auto pool = DescriptorPool::create(ctx, r->links_pipe_, 1);
  if (!pool) return std::move(pool).error();
  r->links_pool_ = std::move(*pool);
  auto set = r->links_pool_.allocate(r->links_pipe_);
  if (!set) return std::move(set).error();
  r->links_set_ = *set;
  if (ctx.timestamps_supported(ctx.compute_queue())) {
    auto ts = TimestampQueries::create(ctx, ctx.compute_queue(), 2);
    if (ts) r->timestamps_ = std::make_unique<TimestampQueries>(std::move(*ts));
  }
  {
    const VkDeviceSize words = VkDeviceSize{kNoLinkRows} * ((1u << cfg.width_log2) / 8) * L::kFaceCount;
    auto b = Buffer::create(ctx, words * 4, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, MemoryUse::upload);
    if (!b) return std::move(b).error();
    std::fill_n(static_cast<std::uint32_t*>(b->mapped()), words, L::kNoCell);
    if (auto v = b->flush(0, words * 4); !v) return std::move(v).error();
    r->no_links_ = std::move(*b);
  }
  const std::uint64_t root_cells =
      std::uint64_t{cfg.roots_per_axis} * cfg.roots_per_axis * cfg.roots_per_axis;
  if (auto v = r->reserve(std::max<std::uint64_t>(cfg.initial_capacity_cells, root_cells)); !v) {
    return std::move(v).error();
  }
  return r;
}

Result<void> GpuReplica::make_images(std::uint32_t height, Image (&out)[5]) const {
  const std::uint32_t w = 1u << cfg_.width_log2;
  const VkImageUsageFlags pool_usage = VK_IMAGE_USAGE_SAMPLED_BIT |
                                       VK_IMAGE_USAGE_TRANSFER_DST_BIT |
                                       VK_IMAGE_USAGE_TRANSFER_SRC_BIT;
  // first_child and colour are also storage images: the ray caster reads them with imageLoad,
  // measurably cheaper than texelFetch on lavapipe (see raycast.comp's header).
  const ImageDesc descs[5] = {
      {VK_FORMAT_R32_UINT, w, height, 1, false, pool_usage | VK_IMAGE_USAGE_STORAGE_BIT},
      {VK_FORMAT_R32_UINT, w, height, 1, false, pool_usage | VK_IMAGE_USAGE_STORAGE_BIT},
      {VK_FORMAT_R32_UINT, w / 8, height, 1, false, pool_usage},
      {VK_FORMAT_R8_UINT, w / 8, height, 1, false, pool_usage},
      {VK_FORMAT_R32_UINT, w / 8, height, L::kFaceCount, true,
       VK_IMAGE_USAGE_STORAGE_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT |
           VK_IMAGE_USAGE_TRANSFER_SRC_BIT},
  };
  for (int i = 0; i < 5; ++i) {
    auto img = Image::create(*ctx_, descs[i]);
    if (!img) return std::move(img).error();
    out[i] = std::move(*img);
  }
  return {};
}

// The height the textures grow to for `cells` (0: they fit already); `error` when impossible.
std::uint32_t GpuReplica::new_height_for(std::uint64_t cells, Result<void>& error) const {
  const std::uint32_t w_log2 = cfg_.width_log2;
  if (cells > (std::uint64_t{1} << L::kMaxCellsLog2)) {
    error = gpu_error(GpuErrc::bad_argument, "replica: more than 2^28 cells");
    return 0;
  }
  const std::uint64_t rows_needed = L::dc_texture_height(
      static_cast<std::uint32_t>(std::min<std::uint64_t>(cells, 0xFFFFFFFFu)), w_log2);
  if (rows_needed <= height_) return 0;
  const std::uint64_t max_rows = std::min<std::uint64_t>(
      ctx_->limits().maxImageDimension2D, (std::uint64_t{1} << L::kMaxCellsLog2) >> w_log2);
  if (rows_needed > max_rows) {
    error = gpu_error(GpuErrc::bad_argument,
                      "replica: " + std::to_string(cells) +
                          " cells need more texture rows than the device allows; use a wider "
                          "texture");
    return 0;
  }
  const std::uint64_t ahead_rows = std::min<std::uint64_t>(
      2ull * height_, std::uint64_t{height_} + (max_growth_cells() >> w_log2));
  return static_cast<std::uint32_t>(
      std::min<std::uint64_t>(max_rows, std::max<std::uint64_t>(rows_needed, ahead_rows)));
}

std::uint64_t GpuReplica::max_growth_cells() const noexcept {
  const std::uint64_t w = std::uint64_t{1} << cfg_.width_log2;
  return std::max<std::uint64_t>(1, (cfg_.max_growth_cells + w - 1) / w) * w;
}

Result<void> GpuReplica::reserve(std::uint64_t cells) {
  Result<void> error;
  std::uint32_t new_height = new_height_for(cells, error);
  if (!error) return error;
  if (new_height == 0) return {};
  if (growth_) {
    // The current textures are too small: finish the growth under way at once.
    auto done = growth_step(~0u);
    if (!done) return std::move(done).error();
    new_height = new_height_for(cells, error);
    if (!error) return error;
    if (new_height == 0) return {};
  }
  Image fresh[5];
  if (auto v = make_images(new_height, fresh); !v) return v;
  Image* old[5] = {&first_child_, &colour_, &group_parent_, &group_depth_, &links_};
  const std::uint32_t old_height = height_;
  // Only the first textures are cleared; the rows a growth adds are written when first used
  // (see the header).
  const std::uint32_t fill[5] = {L::kNoCell, 0u, L::kNoCell, L::kGroupFreeFlag, L::kNoCell};
  auto done = ctx_->submit_once(ctx_->compute_queue(), [&](VkCommandBuffer cb) {
    for (int i = 0; i < 5; ++i) {
      image_barrier(cb, fresh[i], VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                    VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0, VK_PIPELINE_STAGE_TRANSFER_BIT,
                    VK_ACCESS_TRANSFER_WRITE_BIT);
      if (old_height == 0) clear_image(cb, fresh[i], fill[i]);
      if (old_height > 0) {
        const VkImageLayout old_layout = resting_layout(i);
        image_barrier(cb, *old[i], old_layout, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                      VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
                      VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_READ_BIT);
        image_barrier(cb, fresh[i], VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                      VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, VK_PIPELINE_STAGE_TRANSFER_BIT,
                      VK_ACCESS_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT,
                      VK_ACCESS_TRANSFER_WRITE_BIT);
        VkImageCopy region{};
        region.srcSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, fresh[i].desc().layers};
        region.dstSubresource = region.srcSubresource;
        region.extent = {fresh[i].desc().width, old_height, 1};
        vkCmdCopyImage(cb, old[i]->handle(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                       fresh[i].handle(), VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &region);
      }
      const VkImageLayout final_layout = resting_layout(i);
      image_barrier(cb, fresh[i], VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, final_layout,
                    VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                    VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                    VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT);
    }
  });
  if (!done) return done;
  for (int i = 0; i < 5; ++i) *old[i] = std::move(fresh[i]);
  height_ = new_height;
  row_state_.resize(new_height, old_height == 0 ? kRowLinksSet | kRowUploaded : 0);
  ++generation_;
  return write_descriptors();
}

Result<void> GpuReplica::begin_growth(std::uint64_t cells) {
  if (growth_) return {};
  Result<void> error;
  const std::uint32_t new_height = new_height_for(cells, error);
  if (!error) return error;
  if (new_height == 0) return {};
  auto g = std::make_unique<Growth>();
  if (auto v = make_images(new_height, g->fresh); !v) return v;
  g->old_height = height_;
  g->new_height = new_height;
  g->dirty.assign(height_, 0);
  auto done = ctx_->submit_once(ctx_->compute_queue(), [&](VkCommandBuffer cb) {
    for (auto& img : g->fresh) {
      image_barrier(cb, img, VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                    VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0, VK_PIPELINE_STAGE_TRANSFER_BIT,
                    VK_ACCESS_TRANSFER_WRITE_BIT);
    }
  });
  if (!done) return done;
  growth_ = std::move(g);
  return {};
}

std::uint32_t GpuReplica::growth_rows_left() const noexcept {
  return growth_ ? growth_->new_height - growth_->next_row : 0;
}

void GpuReplica::note_rows_written(std::uint32_t row0, std::uint32_t rows) {
  if (!growth_) return;
  Growth& g = *growth_;
  const std::uint32_t end = std::min(row0 + rows, g.next_row);
  for (std::uint32_t r = row0; r < end; ++r) {
    if (!g.dirty[r]) {
      g.dirty[r] = 1;
      g.dirty_rows.push_back(r);
    }
  }
}

Result<bool> GpuReplica::growth_step(std::uint32_t max_rows) {
  if (!growth_) return true;
  Growth& g = *growth_;
  const std::uint32_t a = g.next_row;
  std::uint32_t b = static_cast<std::uint32_t>(
      std::min<std::uint64_t>(g.new_height, std::uint64_t{a} + max_rows));
  // Rows past the old height are left unwritten: nothing to copy there, so the step that
  // reaches them is the last.
  if (b >= g.old_height) b = g.new_height;
  const bool last = b == g.new_height;
  // Runs of rows to copy again (written after they were copied), on the last step.
  std::vector<RowRun> again;
  if (last) {
    std::sort(g.dirty_rows.begin(), g.dirty_rows.end());
    for (std::size_t i = 0; i < g.dirty_rows.size();) {
      std::size_t j = i + 1;
      while (j < g.dirty_rows.size() && g.dirty_rows[j] == g.dirty_rows[j - 1] + 1) ++j;
      again.push_back({g.dirty_rows[i], static_cast<std::uint32_t>(j - i)});
      i = j;
    }
  }
  Image* old[5] = {&first_child_, &colour_, &group_parent_, &group_depth_, &links_};
  const std::uint32_t copy_end = std::min(b, g.old_height);
  const bool read_old = a < copy_end || !again.empty();
  auto done = ctx_->submit_once(ctx_->compute_queue(), [&](VkCommandBuffer cb) {
    for (int i = 0; i < 5; ++i) {
      Image& fresh = g.fresh[i];
      const std::uint32_t layers = fresh.desc().layers;
      if (read_old) {
        image_barrier(cb, *old[i], resting_layout(i), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                      VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
                      VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_READ_BIT);
        auto copy_rows = [&](std::uint32_t row0, std::uint32_t rows) {
          VkImageCopy region{};
          region.srcSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, layers};
          region.dstSubresource = region.srcSubresource;
          region.srcOffset = {0, static_cast<std::int32_t>(row0), 0};
          region.dstOffset = region.srcOffset;
          region.extent = {fresh.desc().width, rows, 1};
          vkCmdCopyImage(cb, old[i]->handle(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, fresh.handle(),
                         VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &region);
        };
        if (a < copy_end) copy_rows(a, copy_end - a);
        for (const RowRun& r : again) copy_rows(r.row0, r.rows);
        image_barrier(cb, *old[i], VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, resting_layout(i),
                      VK_PIPELINE_STAGE_TRANSFER_BIT, 0, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                      VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT);
      }
      if (last) {
        image_barrier(cb, fresh, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, resting_layout(i),
                      VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                      VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                      VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT);
      }
    }
  });
  if (!done) return std::move(done).error();
  g.next_row = b;
  if (!last) return false;
  for (int i = 0; i < 5; ++i) *old[i] = std::move(g.fresh[i]);
  height_ = g.new_height;
  row_state_.resize(height_, 0);  // the rows past the old height: unwritten
  growth_.reset();
  ++generation_;
  if (auto v = write_descriptors(); !v) return std::move(v).error();
  return true;
}

std::vector<GpuReplica::RowRun> GpuReplica::rows_without_links(
    std::span<const RowRun> runs) const {
  std::vector<RowRun> out;
  for (const RowRun& r : runs) {
    for (std::uint32_t k = 0; k < r.rows; ++k) {
      const std::uint32_t row = r.row0 + k;
      if (row_state_[row] & kRowLinksSet) continue;
      if (!out.empty() && out.back().row0 + out.back().rows == row) {
        ++out.back().rows;
      } else {
        out.push_back({row, 1});
      }
    }
  }
  return out;
}

void GpuReplica::record_no_links(VkCommandBuffer cb, std::span<const RowRun> runs) {
  if (runs.empty()) return;
  image_barrier(cb, links_, resting_layout(4), VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, VK_PIPELINE_STAGE_TRANSFER_BIT,
                VK_ACCESS_TRANSFER_WRITE_BIT);
  for (const RowRun& r : runs) {
    for (std::uint32_t row = r.row0; row < r.row0 + r.rows; row += kNoLinkRows) {
      copy_buffer_to_image(cb, no_links_, 0, links_, 0, row, links_.desc().width,
                           std::min(kNoLinkRows, r.row0 + r.rows - row), 0, L::kFaceCount);
    }
    for (std::uint32_t k = 0; k < r.rows; ++k) row_state_[r.row0 + k] |= kRowLinksSet;
    note_rows_written(r.row0, r.rows);
  }
  image_barrier(cb, links_, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, resting_layout(4),
                VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT);
}

Result<void> GpuReplica::write_descriptors() {
  DescriptorWriter()
      .sampled_image(0, first_child_, sampler_, VK_IMAGE_LAYOUT_GENERAL)
      .sampled_image(1, group_parent_, sampler_)
      .sampled_image(2, group_depth_, sampler_)
      .storage_image(3, links_)
      .update(*ctx_, links_set_);
  return {};
}

Result<void> GpuReplica::ensure_staging(VkDeviceSize bytes) {
  if (staging_.handle() != VK_NULL_HANDLE && staging_.size() >= bytes) return {};
  const VkDeviceSize size = std::max<VkDeviceSize>(bytes, staging_.size() * 2);
  auto b = Buffer::create(*ctx_, size, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, MemoryUse::upload);
  if (!b) return std::move(b).error();
  staging_ = std::move(*b);
  return {};
}

gpu_layout::DcPoolInfo GpuReplica::pool_info() const noexcept {
  L::DcPoolInfo info{};
  info.width_log2 = cfg_.width_log2;
  info.block_log2 = cfg_.block_log2;
  info.cell_count = static_cast<std::uint32_t>(cell_count_);
  info.root_count = cfg_.roots_per_axis * cfg_.roots_per_axis * cfg_.roots_per_axis;
  info.roots_per_axis = cfg_.roots_per_axis;
  info.max_depth = cfg_.max_depth;
  info.canvas_edge_m = static_cast<float>(cfg_.edge_m);
  return info;
}

Result<void> GpuReplica::upload_cells(const PoolView& pools, std::uint64_t first,
                                      std::uint64_t count) {
  if (auto v = pools.validate(); !v) return v;
  if (pools.roots_per_axis != cfg_.roots_per_axis) {
    return gpu_error(GpuErrc::bad_argument, "replica: pools of a different canvas geometry");
  }
  if (auto v = reserve(pools.cell_count()); !v) return v;
  cell_count_ = pools.cell_count();
  const std::uint64_t end = std::min(first + count, pools.cell_count());
  if (first >= end) return {};
  const std::uint32_t row0 = static_cast<std::uint32_t>(first >> cfg_.width_log2);
  const std::uint32_t row1 = static_cast<std::uint32_t>((end - 1) >> cfg_.width_log2) + 1;
  return upload_rows(pools, row0, row1 - row0);
}

Result<void> GpuReplica::upload_blocks(const PoolView& pools,
                                       std::span<const std::uint32_t> blocks) {
  if (auto v = pools.validate(); !v) return v;
  // Rows touched.
  std::vector<std::uint32_t> rows;
  const std::uint32_t w_log2 = cfg_.width_log2;
  for (std::uint32_t b : blocks) {
    const std::uint64_t c0 = std::uint64_t{b} << cfg_.block_log2;
    if (c0 >= pools.cell_count()) continue;
    const std::uint64_t c1 =
        std::min(c0 + (std::uint64_t{1} << cfg_.block_log2), pools.cell_count());
    for (std::uint64_t r = c0 >> w_log2; r <= (c1 - 1) >> w_log2; ++r) {
      rows.push_back(static_cast<std::uint32_t>(r));
    }
  }
  return upload_row_list(pools, rows);
}

Result<void> GpuReplica::upload_row_list(const PoolView& pools,
                                         std::span<const std::uint32_t> row_list) {
  if (auto v = pools.validate(); !v) return v;
  if (pools.roots_per_axis != cfg_.roots_per_axis) {
    return gpu_error(GpuErrc::bad_argument, "replica: pools of a different canvas geometry");
  }
  if (auto v = reserve(pools.cell_count()); !v) return v;
  cell_count_ = pools.cell_count();
  std::vector<std::uint32_t> rows(row_list.begin(), row_list.end());
  std::sort(rows.begin(), rows.end());
  rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
  while (!rows.empty() && rows.back() >= height_) rows.pop_back();
  // Coalesced into runs, all copied in one submission.
  return upload_runs(pools, runs_of(rows));
}

Result<void> GpuReplica::upload_rows(const PoolView& pools, std::uint32_t row0,
                                     std::uint32_t rows) {
  const RowRun run{row0, rows};
  return upload_runs(pools, std::span<const RowRun>(&run, 1));
}

std::vector<GpuReplica::RowRun> GpuReplica::runs_of(std::span<const std::uint32_t> rows) {
  std::vector<RowRun> runs;
  for (std::size_t i = 0; i < rows.size();) {
    std::size_t j = i + 1;
    while (j < rows.size() && rows[j] == rows[j - 1] + 1) ++j;
    runs.push_back({rows[i], static_cast<std::uint32_t>(j - i)});
    i = j;
  }
  return runs;
}

std::vector<GpuReplica::StagedPiece> GpuReplica::staging_layout(std::span<const RowRun> runs,
                                                                VkDeviceSize& total) const {
  const std::uint32_t w = 1u << cfg_.width_log2;
  std::vector<StagedPiece> pieces;
  pieces.reserve(runs.size());
  total = 0;
  for (const RowRun& r : runs) {
    const std::uint64_t cells = std::uint64_t{r.rows} * w;
    StagedPiece p{r, {}};
    p.off[0] = total;
    p.off[1] = align16(p.off[0] + cells * 4);
    p.off[2] = align16(p.off[1] + cells * 4);
    p.off[3] = align16(p.off[2] + cells / 8 * 4);
    total = align16(p.off[3] + cells / 8);
    pieces.push_back(p);
  }
  return pieces;
}

Result<void> GpuReplica::upload_runs(const PoolView& pools, std::span<const RowRun> runs) {
  filtered_interiors_ = pools.filtered_interiors;
  if (runs.empty()) return {};
  const std::uint32_t w = 1u << cfg_.width_log2;
  VkDeviceSize total = 0;
  const std::vector<StagedPiece> pieces = staging_layout(runs, total);
  if (auto v = ensure_staging(total); !v) return v;
  ++staging_use_;
  auto* base = static_cast<std::uint8_t*>(staging_.mapped());
  const std::uint64_t have = pools.cell_count();
  // Rows past the high-water mark: the values of never-used cells (leaf, empty, free group).
  auto fill32 = [&](VkDeviceSize off, std::span<const std::uint32_t> src, std::uint64_t first,
                    std::uint64_t n, std::uint32_t filler) {
    auto* dst = reinterpret_cast<std::uint32_t*>(base + off);
    const std::uint64_t avail =
        first < src.size() ? std::min<std::uint64_t>(n, src.size() - first) : 0;
    if (avail) std::memcpy(dst, src.data() + first, avail * 4);
    std::fill(dst + avail, dst + n, filler);
  };
  for (const StagedPiece& p : pieces) {
    const std::uint64_t cells = std::uint64_t{p.run.rows} * w;
    const std::uint64_t groups = cells / 8;
    const std::uint64_t c0 = std::uint64_t{p.run.row0} * w;
    fill32(p.off[0], pools.first_child, c0, cells, L::kNoCell);
    fill32(p.off[1], pools.colour, c0, cells, 0u);
    fill32(p.off[2], pools.group_parent, c0 / 8, groups, L::kNoCell);
    auto* dst = base + p.off[3];
    const std::uint64_t g0 = c0 / 8;
    const std::uint64_t src_n = have / 8;
    const std::uint64_t avail = g0 < src_n ? std::min<std::uint64_t>(groups, src_n - g0) : 0;
    if (avail) std::memcpy(dst, pools.group_depth_flags.data() + g0, avail);
    std::fill(dst + avail, dst + groups, static_cast<std::uint8_t>(L::kGroupFreeFlag));
  }
  if (auto v = staging_.flush(0, total); !v) return v;
  return copy_staged(pieces);
}

Result<GpuReplica::StagedRows> GpuReplica::stage_rows(std::span<const RowSource> rows) {
  const std::uint32_t w = 1u << cfg_.width_log2;
  StagedRows staged;
  staged.rows.reserve(rows.size());
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const RowSource& r = rows[i];
    if (i > 0 && r.row <= rows[i - 1].row)
      return gpu_error(GpuErrc::bad_argument, "stage_rows: rows not sorted and unique");
    if (r.first_child.size() != w || r.colour.size() != w || r.group_parent.size() != w / 8 ||
        r.depth_flags.size() != w / 8)
      return gpu_error(GpuErrc::bad_argument, "stage_rows: a row of another texture width");
    staged.rows.push_back(r.row);
  }
  VkDeviceSize total = 0;
  const std::vector<StagedPiece> pieces = staging_layout(runs_of(staged.rows), total);
  if (auto v = ensure_staging(total); !v) return std::move(v).error();
  staged.staging_use = ++staging_use_;
  auto* base = static_cast<std::uint8_t*>(staging_.mapped());
  std::size_t k = 0;  // rows[k]: the next row to copy
  for (const StagedPiece& p : pieces) {
    for (std::uint32_t i = 0; i < p.run.rows; ++i, ++k) {
      const RowSource& r = rows[k];
      std::memcpy(base + p.off[0] + std::uint64_t{i} * w * 4, r.first_child.data(), w * 4);
      std::memcpy(base + p.off[1] + std::uint64_t{i} * w * 4, r.colour.data(), w * 4);
      std::memcpy(base + p.off[2] + std::uint64_t{i} * w / 2, r.group_parent.data(), w / 2);
      std::memcpy(base + p.off[3] + std::uint64_t{i} * w / 8, r.depth_flags.data(), w / 8);
    }
  }
  if (total > 0) {
    if (auto v = staging_.flush(0, total); !v) return std::move(v).error();
  }
  return staged;
}

Result<void> GpuReplica::upload_staged(const PoolView& pools, const StagedRows& staged) {
  if (staged.staging_use != staging_use_) {
    return gpu_error(GpuErrc::bad_argument,
                     "upload_staged: the staging buffer was filled again since stage_rows");
  }
  if (auto v = pools.validate(); !v) return v;
  if (pools.roots_per_axis != cfg_.roots_per_axis) {
    return gpu_error(GpuErrc::bad_argument, "replica: pools of a different canvas geometry");
  }
  if (auto v = reserve(pools.cell_count()); !v) return v;
  cell_count_ = pools.cell_count();
  filtered_interiors_ = pools.filtered_interiors;
  // The same runs and layout stage_rows used; runs past the texture are left out (clipped).
  VkDeviceSize total = 0;
  std::vector<StagedPiece> pieces = staging_layout(runs_of(staged.rows), total);
  std::erase_if(pieces, [&](const StagedPiece& p) { return p.run.row0 >= height_; });
  for (StagedPiece& p : pieces) p.run.rows = std::min(p.run.rows, height_ - p.run.row0);
  ++staging_use_;  // staged rows are copied once
  return copy_staged(pieces);
}

Result<void> GpuReplica::copy_staged(std::span<const StagedPiece> pieces) {
  if (pieces.empty()) return {};
  for (const StagedPiece& p : pieces) note_rows_written(p.run.row0, p.run.rows);
  std::vector<RowRun> runs;
  runs.reserve(pieces.size());
  for (const StagedPiece& p : pieces) runs.push_back(p.run);
  const std::vector<RowRun> first = rows_without_links(runs);
  for (const RowRun& r : runs)
    for (std::uint32_t k = 0; k < r.rows; ++k) row_state_[r.row0 + k] |= kRowUploaded;
  const Image* imgs[4] = {&first_child_, &colour_, &group_parent_, &group_depth_};
  return ctx_->submit_once(ctx_->compute_queue(), [&](VkCommandBuffer cb) {
    record_no_links(cb, first);
    for (int i = 0; i < 4; ++i) {
      image_barrier(cb, *imgs[i], resting_layout(i), VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                    VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, VK_PIPELINE_STAGE_TRANSFER_BIT,
                    VK_ACCESS_TRANSFER_WRITE_BIT);
      for (const StagedPiece& p : pieces) {
        copy_buffer_to_image(cb, staging_, p.off[i], *imgs[i], 0, p.run.row0, imgs[i]->desc().width,
                             p.run.rows);
      }
      image_barrier(cb, *imgs[i], VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, resting_layout(i),
                    VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                    VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_READ_BIT);
    }
  });
}

Result<void> GpuReplica::compute_links(const PoolView& pools, std::span<const std::uint32_t> groups,
                                       LinksTiming* timing) {
  const std::uint64_t hw_groups = cell_count_ / 8;
  if (pools.cell_count() != cell_count_) {
    return gpu_error(GpuErrc::bad_argument, "compute_links: pools differ from the uploaded ones");
  }
  // Bucket by depth (free and root groups first: they only write kNoCell).
  std::array<std::uint32_t, L::kMaxDepth + 2> start{};
  const std::uint32_t root_groups = pools.root_count() / 8;
  auto bucket_of = [&](std::uint32_t g) -> std::uint32_t {
    const std::uint8_t df = pools.group_depth_flags[g];
    if (g < root_groups || (df & L::kGroupFreeFlag)) return 0;
    return std::min<std::uint32_t>(df & L::kDepthMask, L::kMaxDepth);
  };
  std::uint32_t n = 0;
  for (std::uint32_t g : groups) {
    if (g >= hw_groups) continue;
    ++start[bucket_of(g) + 1];
    ++n;
  }
  if (timing) *timing = {-1, n, 0};
  if (n == 0) return {};
  for (std::size_t d = 1; d < start.size(); ++d) start[d] += start[d - 1];
  const VkDeviceSize bytes = VkDeviceSize{n} * 4;
  if (group_list_.handle() == VK_NULL_HANDLE || group_list_.size() < bytes) {
    auto b = Buffer::create(*ctx_, std::max<VkDeviceSize>(bytes, group_list_.size() * 2),
                            VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, MemoryUse::upload);
    if (!b) return std::move(b).error();
    group_list_ = std::move(*b);
    DescriptorWriter().buffer(4, group_list_).update(*ctx_, links_set_);
  }
  auto* list = static_cast<std::uint32_t*>(group_list_.mapped());
  std::array<std::uint32_t, L::kMaxDepth + 2> fill = start;
  const std::uint32_t group_row_log2 = cfg_.width_log2 - 3;  // W/8 groups per texture row
  std::vector<std::uint32_t> group_rows;
  for (std::uint32_t g : groups) {
    if (g >= hw_groups) continue;
    list[fill[bucket_of(g)]++] = g;
    note_rows_written(g >> group_row_log2, 1);
    if (!(row_state_[g >> group_row_log2] & kRowLinksSet)) group_rows.push_back(g >> group_row_log2);
  }
  if (auto v = group_list_.flush(0, bytes); !v) return v;
  // Rows whose links were never set: "no link" first (the links of their other groups).
  std::ranges::sort(group_rows);
  group_rows.erase(std::unique(group_rows.begin(), group_rows.end()), group_rows.end());
  const std::vector<RowRun> first = runs_of(group_rows);
  const L::DcPoolInfo info = pool_info();
  std::uint32_t dispatches = 0;
  auto done = ctx_->submit_once(ctx_->compute_queue(), [&](VkCommandBuffer cb) {
    record_no_links(cb, first);
    if (timestamps_) {
      timestamps_->reset(cb);
      timestamps_->write(cb, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0);
    }
    links_pipe_.bind(cb, links_set_);
    for (std::uint32_t d = 0; d <= L::kMaxDepth; ++d) {
      const std::uint32_t count = start[d + 1] - start[d];
      if (count == 0) continue;
      if (dispatches > 0) {
        global_barrier(cb, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
                       VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT);
      }
      const LinksPush push{info, {start[d], count, 0, 0}};
      links_pipe_.push(cb, push);
      vkCmdDispatch(cb, group_count(count, kLinksLocalSize), 1, 1);
      ++dispatches;
    }
    global_barrier(cb, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
                   VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT,
                   VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_TRANSFER_READ_BIT);
    if (timestamps_) timestamps_->write(cb, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, 1);
  });
  if (!done) return done;
  if (timing) {
    timing->dispatches = dispatches;
    if (timestamps_) {
      auto ticks = timestamps_->ticks();
      if (ticks) timing->gpu_ms = timestamps_->elapsed_ns(*ticks, 0, 1) * 1e-6;
    }
  }
  return {};
}

Result<void> GpuReplica::compute_links_masked(const PoolView& pools,
                                              std::span<const std::uint64_t> mask,
                                              LinksTiming* timing) {
  std::vector<std::uint32_t> groups;
  for (std::size_t w = 0; w < mask.size(); ++w) {
    std::uint64_t bits = mask[w];
    while (bits) {
      groups.push_back(static_cast<std::uint32_t>(w * 64 + std::countr_zero(bits)));
      bits &= bits - 1;
    }
  }
  return compute_links(pools, groups, timing);
}

Result<void> GpuReplica::compute_all_links(const PoolView& pools, LinksTiming* timing) {
  std::vector<std::uint32_t> groups(cell_count_ / 8);
  for (std::uint32_t g = 0; g < groups.size(); ++g) groups[g] = g;
  return compute_links(pools, groups, timing);
}

Result<std::vector<std::uint32_t>> GpuReplica::read_links() const {
  const std::uint32_t gw = (1u << cfg_.width_log2) / 8;
  const std::uint64_t layer_groups = std::uint64_t{gw} * height_;
  auto rb = Buffer::create(*ctx_, layer_groups * 4 * L::kFaceCount,
                           VK_BUFFER_USAGE_TRANSFER_DST_BIT, MemoryUse::readback);
  if (!rb) return std::move(rb).error();
  auto done = ctx_->submit_once(ctx_->compute_queue(), [&](VkCommandBuffer cb) {
    image_barrier(cb, links_, VK_IMAGE_LAYOUT_GENERAL, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                  VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
                  VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_READ_BIT);
    copy_image_to_buffer(cb, links_, 0, 0, gw, height_, *rb, 0, 0, L::kFaceCount);
    image_barrier(cb, links_, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, VK_IMAGE_LAYOUT_GENERAL,
                  VK_PIPELINE_STAGE_TRANSFER_BIT, 0, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                  VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT);
  });
  if (!done) return std::move(done).error();
  if (auto v = rb->invalidate(); !v) return std::move(v).error();
  const auto* src = static_cast<const std::uint32_t*>(rb->mapped());
  const std::uint64_t groups = cell_count_ / 8;
  std::vector<std::uint32_t> out(groups * L::kFaceCount);
  // Texel (x, y) of a group texture is group y * gw + x, so layer f is group-linear.
  for (std::uint64_t g = 0; g < groups; ++g) {
    for (std::uint32_t f = 0; f < L::kFaceCount; ++f) out[g * 6 + f] = src[f * layer_groups + g];
  }
  return out;
}

Result<GpuReplica::UploadedPools> GpuReplica::read_uploaded() const {
  const std::uint64_t texels = std::uint64_t{1} << cfg_.width_log2;
  const Image* imgs[4] = {&first_child_, &colour_, &group_parent_, &group_depth_};
  const std::uint32_t bytes[4] = {4, 4, 4, 1};
  const std::uint64_t per_row[4] = {texels, texels, texels / 8, texels / 8};
  VkDeviceSize off[5] = {0};
  for (int i = 0; i < 4; ++i) off[i + 1] = align16(off[i] + per_row[i] * height_ * bytes[i]);
  auto rb = Buffer::create(*ctx_, std::max<VkDeviceSize>(off[4], 16),
                           VK_BUFFER_USAGE_TRANSFER_DST_BIT, MemoryUse::readback);
  if (!rb) return std::move(rb).error();
  if (height_ > 0) {
    auto done = ctx_->submit_once(ctx_->compute_queue(), [&](VkCommandBuffer cb) {
      for (int i = 0; i < 4; ++i) {
        image_barrier(cb, *imgs[i], resting_layout(i), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                      VK_PIPELINE_STAGE_TRANSFER_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                      VK_ACCESS_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT,
                      VK_ACCESS_TRANSFER_READ_BIT);
        copy_image_to_buffer(cb, *imgs[i], 0, 0, static_cast<std::uint32_t>(per_row[i]), height_,
                             *rb, off[i]);
        image_barrier(cb, *imgs[i], VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, resting_layout(i),
                      VK_PIPELINE_STAGE_TRANSFER_BIT, 0, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                      VK_ACCESS_SHADER_READ_BIT);
      }
    });
    if (!done) return std::move(done).error();
  }
  if (auto v = rb->invalidate(); !v) return std::move(v).error();
  const auto* base = static_cast<const std::uint8_t*>(rb->mapped());
  UploadedPools out;
  auto words = [&](int i, std::uint64_t n) {
    std::vector<std::uint32_t> v(n);
    if (n) std::memcpy(v.data(), base + off[i], n * 4);
    return v;
  };
  out.first_child = words(0, cell_count_);
  out.colour = words(1, cell_count_);
  out.group_parent = words(2, cell_count_ / 8);
  out.group_depth_flags.assign(base + off[3], base + off[3] + cell_count_ / 8);
  return out;
}

}  // namespace deepcanvas::client_gpu
