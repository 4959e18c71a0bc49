#include "deepcanvas/client_gpu/raycaster.hpp"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <span>

#include "deepcanvas/client_gpu/errors.hpp"
#include "deepcanvas/shaders/raycast.spv.h"
#include "raycast_layout.h"

namespace deepcanvas::client_gpu {
namespace {

namespace L = gpu_layout;

// A subgroup's loop budget on a CPU device (raycast.comp "Loop limiter"): lavapipe ends all
// loops of a subgroup after 65535 iterations; the estimate is an upper bound and the subgroup
// stops once it plus twice its costliest item passes this, so a small margin is enough.
constexpr std::uint32_t kCpuLoopBudget = 65000;

struct RaycastPush {
  L::DcPoolInfo pool;
  L::DcRaycastDispatch dispatch;
};

void to3(float (&dst)[3], const client_core::DVec3& v) {
  dst[0] = static_cast<float>(v.x);
  dst[1] = static_cast<float>(v.y);
  dst[2] = static_cast<float>(v.z);
}

}  // namespace

GpuRaycaster::~GpuRaycaster() = default;

Result<std::unique_ptr<GpuRaycaster>> GpuRaycaster::create(GpuReplica& replica) {
  const Context& ctx = replica.context();
  std::unique_ptr<GpuRaycaster> r(new GpuRaycaster(replica));
  static constexpr const char* kNames[kPipelines] = {"raycast items (G3)", "raycast retry (G3)",
                                                     "raycast items (descent)",
                                                     "raycast retry (descent)"};
  for (std::uint32_t i = 0; i < kPipelines; ++i) {
    // Specialization: constant 0 the stepping (1 = descent), constant 1 the pass.
    const std::uint32_t pass = i % 2 == 0 ? L::kRaycastItems : L::kRaycastRetry;
    auto pipe = ComputePipeline::create(ctx, {.name = kNames[i],
                                              .spirv = deepcanvas_spv_raycast,
                                              .bindings = {{0, VK_DESCRIPTOR_TYPE_STORAGE_IMAGE},
                                                           {1, VK_DESCRIPTOR_TYPE_STORAGE_IMAGE},
                                                           {2, VK_DESCRIPTOR_TYPE_STORAGE_IMAGE},
                                                           {3, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER},
                                                           {4, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER},
                                                           {5, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER}},
                                              .push_constant_bytes = sizeof(RaycastPush),
                                              .specialization = {i / 2, pass}});
    if (!pipe) return std::move(pipe).error();
    r->pipes_[i] = std::move(*pipe);
  }
  auto pool = DescriptorPool::create(ctx, r->pipes_[0], kPipelines);
  if (!pool) return std::move(pool).error();
  r->pool_ = std::move(*pool);
  for (int i = 0; i < kPipelines; ++i) {
    auto set = r->pool_.allocate(r->pipes_[i]);
    if (!set) return std::move(set).error();
    r->set_[i] = *set;
  }
  auto params = Buffer::create(ctx, sizeof(L::DcRayParamsBuffer),
                               VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, MemoryUse::upload);
  if (!params) return std::move(params).error();
  r->params_ = std::move(*params);
  // See "Scheduling" in raycaster.hpp.
  r->cpu_device_ = ctx.info().type == VK_PHYSICAL_DEVICE_TYPE_CPU;
  r->subgroups_per_workgroup_ =
      std::max(1u, L::kRaycastLocalSizeX * L::kRaycastLocalSizeY / ctx.info().subgroup_size);
  r->set_loop_budget(0);
  if (ctx.timestamps_supported(ctx.compute_queue())) {
    auto ts = TimestampQueries::create(ctx, ctx.compute_queue(), 2);
    if (ts) r->timestamps_ = std::make_unique<TimestampQueries>(std::move(*ts));
  }
  return r;
}

void GpuRaycaster::set_loop_budget(std::uint32_t n) noexcept {
  loop_budget_ = n != 0 ? n : (cpu_device_ ? kCpuLoopBudget : ~0u);
}

Result<void> GpuRaycaster::refresh_descriptors() {
  if (generation_seen_ == replica_->generation()) return {};
  for (int i = 0; i < kPipelines; ++i) {
    DescriptorWriter()
        .storage_image(0, replica_->first_child_image())
        .storage_image(1, replica_->colour_image())
        .storage_image(2, replica_->links_image())
        .buffer(3, params_)
        .buffer(4, output_)
        .buffer(5, work_)
        .update(replica_->context(), set_[i]);
  }
  generation_seen_ = replica_->generation();
  return {};
}

Result<void> GpuRaycaster::set_frame(const client_core::Camera& camera,
                                     const client_core::RayOrigin& origin,
                                     const client_core::RenderOptions& options) {
  if (!(options.termination_transmittance >= 0.0 && options.termination_transmittance < 1.0) ||
      options.max_steps_per_ray == 0 ||
      (options.content_bounds && !client_core::valid_content_bounds(*options.content_bounds)) ||
      !client_core::valid_content_boxes(options.content_boxes)) {
    return gpu_error(GpuErrc::bad_argument,
                     "raycaster: bad termination, max steps, content bounds or content boxes");
  }
  const Context& ctx = replica_->context();
  if (camera.width() != width_ || camera.height() != height_ ||
      output_.handle() == VK_NULL_HANDLE) {
    const VkDeviceSize bytes = VkDeviceSize{camera.width()} * camera.height() * 4;
    auto out = Buffer::create(ctx, bytes,
                              VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_TRANSFER_SRC_BIT,
                              MemoryUse::device_local);
    if (!out) return std::move(out).error();
    auto rb = Buffer::create(ctx, bytes, VK_BUFFER_USAGE_TRANSFER_DST_BIT, MemoryUse::readback);
    if (!rb) return std::move(rb).error();
    // Rows per dispatch: as many 8-row strips as keep its items within
    // kRaycastMaxItemsPerDispatch; one work region per dispatch of the tallest band.
    const std::uint32_t tiles_x = group_count(camera.width(), L::kRaycastLocalSizeX);
    const std::uint32_t strips =
        std::max(1u, L::kRaycastMaxItemsPerDispatch * L::kRaycastTilesPerItem / tiles_x);
    const std::uint32_t rows_per_dispatch = strips * L::kRaycastLocalSizeY;
    const std::uint32_t regions = (camera.height() + rows_per_dispatch - 1) / rows_per_dispatch;
    // The work regions stay on the device: every subgroup's item counter updates and marks go
    // there, and on a discrete GPU each would otherwise cross the bus. Only each region's retry
    // count is copied back.
    auto work =
        Buffer::create(ctx, VkDeviceSize{regions} * L::kRaycastWorkWords * 4,
                       VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT |
                           VK_BUFFER_USAGE_TRANSFER_DST_BIT | VK_BUFFER_USAGE_TRANSFER_SRC_BIT,
                       MemoryUse::device_local);
    if (!work) return std::move(work).error();
    auto retry_counts = Buffer::create(ctx, VkDeviceSize{regions} * 4,
                                       VK_BUFFER_USAGE_TRANSFER_DST_BIT, MemoryUse::readback);
    if (!retry_counts) return std::move(retry_counts).error();
    output_ = std::move(*out);
    readback_ = std::move(*rb);
    work_ = std::move(*work);
    retry_counts_ = std::move(*retry_counts);
    rows_per_dispatch_ = rows_per_dispatch;
    width_ = camera.width();
    height_ = camera.height();
    generation_seen_ = ~std::uint64_t{0};  // the output buffer changed
  }
  static_assert(client_core::kMaxContentBoxes == L::kRaycastCullBoxes);
  L::DcRayParamsBuffer buffer{};
  L::DcRayParams& p = buffer.p;
  if (origin.inside) {
    for (int a = 0; a < 3; ++a) {
      p.origin_local[a] = static_cast<float>(origin.location.local[a]);
      p.origin_coord[a] = origin.location.coord[a];
    }
    p.origin_cell = origin.location.cell;
    p.origin_depth = static_cast<std::uint32_t>(origin.location.depth);
    p.inside = 1;
  } else {
    to3(p.canvas_pos, origin.position_m * (1.0 / replica_->pool_info().canvas_edge_m));
    // The float canvas edge loses nothing that matters here (a camera outside the canvas).
    p.inside = 0;
  }
  to3(p.forward, camera.forward());
  to3(p.right, camera.right());
  to3(p.up, camera.up());
  p.tan_half_h = static_cast<float>(camera.tan_half_h());
  p.tan_half_v = static_cast<float>(camera.tan_half_v());
  p.width = camera.width();
  p.height = camera.height();
  for (int c = 0; c < 3; ++c) p.background[c] = static_cast<float>(options.background[c]);
  p.termination = static_cast<float>(options.termination_transmittance);
  p.max_steps = options.max_steps_per_ray;
  p.skip_empty = options.skip_empty_subtrees && replica_->filtered_interiors() ? 1u : 0u;
  std::span<const client_core::DAabb> boxes;
  if (options.content_boxes) {
    boxes = options.content_boxes->boxes();
  } else if (options.content_bounds) {
    boxes = {&*options.content_bounds, 1};
  }
  if (options.content_empty || (options.content_boxes && boxes.empty())) {
    p.cull = 2;  // nothing painted, or nothing painted in view: every ray is background
  } else if (!boxes.empty()) {
    for (std::size_t b = 0; b < boxes.size(); ++b) {
      const client_core::DAabb rel = client_core::cull_box_relative_to(boxes[b], origin.position_m);
      if (b == 0) {
        to3(p.cull_lo, rel.min);
        to3(p.cull_hi, rel.max);
      } else {
        to3(buffer.more_boxes[b - 1].lo, rel.min);
        to3(buffer.more_boxes[b - 1].hi, rel.max);
      }
    }
    p.cull = 1;
    p.cull_count = static_cast<std::uint32_t>(boxes.size());
  }
  std::memcpy(params_.mapped(), &buffer, sizeof(buffer));
  if (auto v = params_.flush(); !v) return v;
  pipe_index_ = options.stepping == client_core::Stepping::descent ? 2 : 0;
  return refresh_descriptors();
}

Result<void> GpuRaycaster::render_rows(std::uint32_t row0, std::uint32_t rows,
                                       FrameTiming* timing) {
  const Band band{this, row0, rows};
  return render_bands({&band, 1}, timing);
}

Result<void> GpuRaycaster::render_together(std::span<GpuRaycaster* const> views,
                                           FrameTiming* timing) {
  std::vector<Band> bands;
  for (GpuRaycaster* v : views) bands.push_back({v, 0, v->height_});
  return render_bands(bands, timing);
}

// Each band's passes are recorded side by side: all header resets, one barrier, then per
// dispatch index the items passes of every band, one barrier, their retry passes. A barrier
// waits for all earlier compute work, so recording band after band would serialise them; side
// by side, a GPU runs the bands' passes at once and the frame pays one submit and one wait.
Result<void> GpuRaycaster::render_bands(std::span<const Band> in, FrameTiming* timing) {
  struct Recorded {
    GpuRaycaster* rc;
    std::uint32_t row0, rows, dispatches, tiles_x;
  };
  std::vector<Recorded> bands;
  std::uint32_t most_dispatches = 0;
  for (const Band& b : in) {
    GpuRaycaster& rc = *b.raycaster;
    if (rc.output_.handle() == VK_NULL_HANDLE) {
      return gpu_error(GpuErrc::bad_argument, "raycaster: render before set_frame");
    }
    if (&rc.replica_->context() != &in.front().raycaster->replica_->context())
      return gpu_error(GpuErrc::bad_argument, "raycaster: views of different devices");
    if (auto v = rc.refresh_descriptors(); !v) return v;
    const std::uint32_t rows = std::min(b.rows, rc.height_ > b.row0 ? rc.height_ - b.row0 : 0u);
    if (rows == 0) continue;
    const std::uint32_t dispatches = (rows + rc.rows_per_dispatch_ - 1) / rc.rows_per_dispatch_;
    bands.push_back({&rc, b.row0, rows, dispatches, group_count(rc.width_, L::kRaycastLocalSizeX)});
    most_dispatches = std::max(most_dispatches, dispatches);
  }
  if (bands.empty()) return {};
  TimestampQueries* timestamps = bands.front().rc->timestamps_.get();
  const Context& ctx = bands.front().rc->replica_->context();
  const auto t0 = std::chrono::steady_clock::now();
  auto done = ctx.submit_once(ctx.compute_queue(), [&](VkCommandBuffer cb) {
    if (timestamps) {
      timestamps->reset(cb);
      timestamps->write(cb, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0);
    }
    // The work regions are written anew once the previous submission's passes are done.
    for (const Recorded& b : bands)
      buffer_barrier(cb, b.rc->work_, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                     VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT,
                     VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT);
    // Every region's header: no item taken, no item given up (retry groups 0, 1, 1).
    const std::uint32_t header[4] = {0, 0, 1, 1};
    for (const Recorded& b : bands)
      for (std::uint32_t i = 0; i < b.dispatches; ++i)
        vkCmdUpdateBuffer(cb, b.rc->work_.handle(), VkDeviceSize{i} * L::kRaycastWorkWords * 4,
                          sizeof header, header);
    for (const Recorded& b : bands)
      buffer_barrier(cb, b.rc->work_, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                     VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                     VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT);
    const auto push_of = [](const Recorded& b, std::uint32_t i) {
      const std::uint32_t first = b.row0 + i * b.rc->rows_per_dispatch_;
      const std::uint32_t count = std::min(b.rc->rows_per_dispatch_, b.row0 + b.rows - first);
      RaycastPush push{b.rc->replica_->pool_info(), {}};
      push.dispatch = {first, count, i * L::kRaycastWorkWords, b.rc->loop_budget_, 0, 0, 0, 0};
      return std::pair{push, count};
    };
    for (std::uint32_t i = 0; i < most_dispatches; ++i) {
      for (const Recorded& b : bands) {
        if (i >= b.dispatches) continue;
        const auto [push, count] = push_of(b, i);
        const std::uint32_t items =
            group_count(std::uint64_t{b.tiles_x} * group_count(count, L::kRaycastLocalSizeY),
                        L::kRaycastTilesPerItem);
        const ComputePipeline& items_pipe = b.rc->pipes_[b.rc->pipe_index_];
        items_pipe.bind(cb, b.rc->set_[b.rc->pipe_index_]);
        items_pipe.push(cb, push);
        // One subgroup per item, so every item is taken (raycast.comp "Scheduling"); the
        // subgroups that run first take the most items, the last ones often none.
        vkCmdDispatch(cb, group_count(items, b.rc->subgroups_per_workgroup_), 1, 1);
      }
      // The retry pass reads the items given up and its workgroup count, and writes over the
      // pixels of those items the items pass wrote.
      for (const Recorded& b : bands) {
        if (i >= b.dispatches) continue;
        buffer_barrier(cb, b.rc->work_, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_ACCESS_SHADER_WRITE_BIT,
                       VK_PIPELINE_STAGE_DRAW_INDIRECT_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_ACCESS_INDIRECT_COMMAND_READ_BIT | VK_ACCESS_SHADER_READ_BIT);
        buffer_barrier(cb, b.rc->output_, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_ACCESS_SHADER_WRITE_BIT, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_ACCESS_SHADER_WRITE_BIT);
      }
      for (const Recorded& b : bands) {
        if (i >= b.dispatches) continue;
        const auto [push, count] = push_of(b, i);
        const ComputePipeline& retry_pipe = b.rc->pipes_[b.rc->pipe_index_ + 1];
        retry_pipe.bind(cb, b.rc->set_[b.rc->pipe_index_ + 1]);
        retry_pipe.push(cb, push);
        vkCmdDispatchIndirect(
            cb, b.rc->work_.handle(),
            (VkDeviceSize{i} * L::kRaycastWorkWords + L::kRaycastWorkRetryGroups) * 4);
      }
    }
    // Each region's retry count is copied back for the host.
    for (const Recorded& b : bands)
      buffer_barrier(cb, b.rc->work_, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                     VK_ACCESS_SHADER_WRITE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT,
                     VK_ACCESS_TRANSFER_READ_BIT);
    for (const Recorded& b : bands) {
      for (std::uint32_t i = 0; i < b.dispatches; ++i)
        copy_buffer(cb, b.rc->work_,
                    (VkDeviceSize{i} * L::kRaycastWorkWords + L::kRaycastWorkRetryGroups) * 4,
                    b.rc->retry_counts_, VkDeviceSize{i} * 4, 4);
      buffer_barrier(cb, b.rc->retry_counts_, VK_PIPELINE_STAGE_TRANSFER_BIT,
                     VK_ACCESS_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_HOST_BIT,
                     VK_ACCESS_HOST_READ_BIT);
    }
    if (timestamps) timestamps->write(cb, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, 1);
  });
  if (!done) return done;
  std::uint32_t retried = 0;
  for (const Recorded& b : bands) {
    if (auto v = b.rc->retry_counts_.invalidate(); !v) return v;
    std::uint32_t mine = 0;
    for (std::uint32_t i = 0; i < b.dispatches; ++i) {
      std::uint32_t groups = 0;
      std::memcpy(&groups, static_cast<const std::byte*>(b.rc->retry_counts_.mapped()) + i * 4, 4);
      mine += groups / L::kRaycastTilesPerItem;
    }
    b.rc->retried_items_ += mine;
    retried += mine;
  }
  if (timing) {
    timing->retried_items = retried;
    timing->wall_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    timing->gpu_ms = -1;
    if (timestamps) {
      auto ticks = timestamps->ticks();
      if (ticks) timing->gpu_ms = timestamps->elapsed_ns(*ticks, 0, 1) * 1e-6;
    }
  }
  return {};
}

Result<void> GpuRaycaster::render(std::uint32_t bands, FrameTiming* timing) {
  bands = std::clamp(bands, 1u, std::max(1u, height_));
  const std::uint32_t per = (height_ + bands - 1) / bands;
  FrameTiming total{0, 0};
  for (std::uint32_t r = 0; r < height_; r += per) {
    FrameTiming t;
    if (auto v = render_rows(r, per, &t); !v) return v;
    total.wall_ms += t.wall_ms;
    total.retried_items += t.retried_items;
    total.gpu_ms = (t.gpu_ms < 0 || total.gpu_ms < 0) ? -1 : total.gpu_ms + t.gpu_ms;
  }
  if (timing) *timing = total;
  return {};
}

Result<std::vector<std::uint32_t>> GpuRaycaster::read_pixels() const {
  if (output_.handle() == VK_NULL_HANDLE) {
    return gpu_error(GpuErrc::bad_argument, "raycaster: nothing rendered");
  }
  auto done =
      replica_->context().submit_once(replica_->context().compute_queue(), [&](VkCommandBuffer cb) {
        buffer_barrier(cb, output_, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_ACCESS_SHADER_WRITE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT,
                       VK_ACCESS_TRANSFER_READ_BIT);
        copy_buffer(cb, output_, 0, readback_, 0, output_.size());
      });
  if (!done) return std::move(done).error();
  if (auto v = readback_.invalidate(); !v) return std::move(v).error();
  std::vector<std::uint32_t> out(std::size_t{width_} * height_);
  std::memcpy(out.data(), readback_.mapped(), out.size() * 4);
  return out;
}

Result<std::vector<std::uint8_t>> GpuRaycaster::render_rgba8(
    const client_core::Camera& camera, const client_core::RayOrigin& origin,
    const client_core::RenderOptions& options) {
  if (auto v = set_frame(camera, origin, options); !v) return std::move(v).error();
  if (auto v = render(); !v) return std::move(v).error();
  auto px = read_pixels();
  if (!px) return std::move(px).error();
  std::vector<std::uint8_t> out(px->size() * 4);
  std::memcpy(out.data(), px->data(), out.size());  // little-endian: r is the low byte
  return out;
}

}  // namespace deepcanvas::client_gpu
