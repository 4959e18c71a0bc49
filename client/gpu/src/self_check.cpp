#include "deepcanvas/client_gpu/self_check.hpp"

#include <cstring>

#include "deepcanvas/client_gpu/compute.hpp"
#include "deepcanvas/client_gpu/errors.hpp"
#include "deepcanvas/client_gpu/memory.hpp"
#include "deepcanvas/shaders/self_check.spv.h"
#include "pool_layout.h"

namespace deepcanvas::client_gpu {

namespace {

namespace L = gpu_layout;

struct Push {
  L::DcPoolInfo pool;
  L::DcDispatchRange range;
};

constexpr std::uint32_t kWidthLog2 = 10;

}  // namespace

std::uint32_t self_check_hash(std::uint32_t x) noexcept {
  const std::uint32_t state = x * 747796405u + 2891336453u;
  const std::uint32_t word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
  return (word >> 22u) ^ word;
}

Result<SelfCheckReport> self_check(const Context& ctx, std::uint32_t invocations) {
  if (invocations == 0 || invocations > (1u << 24)) {
    return gpu_error(GpuErrc::bad_argument, "self-check invocations must be 1..2^24");
  }
  auto pipe = ComputePipeline::create(ctx, {.name = "self_check",
                                            .spirv = deepcanvas_spv_self_check,
                                            .bindings = {{0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER}},
                                            .push_constant_bytes = sizeof(Push)});
  if (!pipe) return std::move(pipe).error();
  auto pool = DescriptorPool::create(ctx, *pipe, 1);
  if (!pool) return std::move(pool).error();
  auto set = pool->allocate(*pipe);
  if (!set) return std::move(set).error();
  const VkDeviceSize bytes = invocations * 2ull * sizeof(std::uint32_t);
  auto out = Buffer::create(ctx, bytes, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, MemoryUse::readback);
  if (!out) return std::move(out).error();
  std::memset(out->mapped(), 0, bytes);
  if (auto f = out->flush(); !f) return std::move(f).error();
  DescriptorWriter().buffer(0, *out).update(ctx, *set);

  std::optional<TimestampQueries> ts;
  if (ctx.timestamps_supported(ctx.compute_queue())) {
    auto t = TimestampQueries::create(ctx, ctx.compute_queue(), 2);
    if (t) ts = std::move(*t);
  }
  Push push{};
  push.pool = {kWidthLog2, 12, invocations, 64, 4, L::kMaxDepth, 20000.0f, 0};
  push.range = {7, invocations, 0, 0};  // a nonzero first, so the range really arrives
  auto run = ctx.submit_once(ctx.compute_queue(), [&](VkCommandBuffer cb) {
    if (ts) {
      ts->reset(cb);
      ts->write(cb, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0);
    }
    pipe->bind(cb, *set);
    pipe->push(cb, push);
    vkCmdDispatch(cb, group_count(invocations, 64), 1, 1);
    if (ts) ts->write(cb, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, 1);
    VkMemoryBarrier mb{};
    mb.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
    mb.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT;
    mb.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0, 1,
                         &mb, 0, nullptr, 0, nullptr);
  });
  if (!run) return std::move(run).error();
  if (auto inv = out->invalidate(); !inv) return std::move(inv).error();

  const auto v = out->mapped_span<const std::uint32_t>();
  for (std::uint32_t k = 0; k < invocations; ++k) {
    const std::uint32_t i = push.range.first + k;
    const std::uint32_t texel =
        L::dc_cell_texel_x(i, kWidthLog2) | (L::dc_cell_texel_y(i, kWidthLog2) << 16);
    if (v[2 * k] != self_check_hash(i) || v[2 * k + 1] != texel) {
      return gpu_error(GpuErrc::wrong_result,
                       "self-check on '" + ctx.info().name + "': invocation " + std::to_string(k) +
                           " wrote " + std::to_string(v[2 * k]) + "/" +
                           std::to_string(v[2 * k + 1]) + ", expected " +
                           std::to_string(self_check_hash(i)) + "/" + std::to_string(texel));
    }
  }
  SelfCheckReport report;
  report.invocations = invocations;
  if (ts) {
    if (auto ticks = ts->ticks(); ticks) report.dispatch_ns = ts->elapsed_ns(*ticks, 0, 1);
  }
  return report;
}

}  // namespace deepcanvas::client_gpu
