// client_gpu on a real Vulkan device (label gpu): context and device choice, the GLSL side of
// pool_layout.h pinned against the C++ side, buffers, pipelines, timestamps.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstring>
#include <random>
#include <vector>

#include "deepcanvas/client_gpu/compute.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/errors.hpp"
#include "deepcanvas/client_gpu/memory.hpp"
#include "deepcanvas/client_gpu/self_check.hpp"
#include "deepcanvas/shaders/layout_probe.spv.h"
#include "deepcanvas/shaders/pool_addressing.spv.h"
#include "gpu_test_support.hpp"
#include "pool_layout.h"

namespace deepcanvas::client_gpu {
namespace {

namespace L = pool_layout;

// The push-constant block of the test shaders, as C++ sees it.
struct GpuPush {
  L::DcPoolInfo pool;
  L::DcDispatchRange range;
};
static_assert(sizeof(GpuPush) == 48);

// Words pool_addressing.comp writes per index (its kWords).
constexpr std::uint32_t kAddressingWords = 26;

constexpr VkBufferUsageFlags kStorage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT |
                                        VK_BUFFER_USAGE_TRANSFER_SRC_BIT |
                                        VK_BUFFER_USAGE_TRANSFER_DST_BIT;

void shader_to_host(VkCommandBuffer cb) {
  VkMemoryBarrier b{};
  b.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
  b.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  b.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
  vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT,
                       VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &b, 0, nullptr, 0, nullptr);
}

// With DEEPCANVAS_VK_VALIDATION=1 and the Khronos layer installed, any validation error seen
// during the run fails it.
class ValidationErrorsFailTheRun : public ::testing::Environment {
 public:
  void TearDown() override {
    auto& shared = testing::shared_context();
    if (shared.ctx && shared.ctx->instance_object().validation_enabled()) {
      EXPECT_EQ(shared.ctx->instance_object().validation_errors(), 0u)
          << "the validation layer reported errors (see stderr)";
    }
  }
};
[[maybe_unused]] const auto* const kValidationEnv =
    ::testing::AddGlobalTestEnvironment(new ValidationErrorsFailTheRun);

TEST(GpuContext, BuildsOnTheSelectedDevice) {
  Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  std::printf("device: [%u] %s (%s, Vulkan %s); %s\n", ctx->info().index, ctx->info().name.c_str(),
              std::string(device_type_name(ctx->info().type)).c_str(),
              format_api_version(ctx->info().api_version).c_str(), ctx->choice().reason.c_str());
  EXPECT_TRUE(unusable_reason(ctx->info()).empty());
  EXPECT_FALSE(ctx->choice().reason.empty());
  EXPECT_NE(ctx->device(), VK_NULL_HANDLE);
  EXPECT_NE(ctx->compute_queue().handle(), VK_NULL_HANDLE);
  EXPECT_NE(ctx->transfer_queue().handle(), VK_NULL_HANDLE);
  EXPECT_FALSE(ctx->queue_families().empty());
  // The pools need the widest textures the layout allows wherever the device has them.
  EXPECT_GE(ctx->limits().maxImageDimension2D, 4096u);
  EXPECT_GE(ctx->limits().maxPushConstantsSize, sizeof(GpuPush));
}

TEST(GpuContext, SelfCheckVerifiesEveryWord) {
  Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto report = self_check(*ctx, 100003);  // not a multiple of the workgroup size
  ASSERT_TRUE(report) << report.error().message;
  EXPECT_EQ(report->invocations, 100003u);
  auto bad = self_check(*ctx, 0);
  ASSERT_FALSE(bad);
  EXPECT_EQ(gpu_errc_of(bad.error()), GpuErrc::bad_argument);
}

TEST(GpuContext, ExplicitDeviceChoiceByIndexAndNameAndMismatch) {
  Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto by_index = ContextBuilder().device(std::to_string(ctx->info().index)).build();
  ASSERT_TRUE(by_index) << by_index.error().message;
  EXPECT_EQ((*by_index)->info().index, ctx->info().index);
  EXPECT_NE((*by_index)->choice().reason.find("requested"), std::string::npos);

  const std::string name = ctx->info().name;
  auto by_name =
      ContextBuilder().device(name.substr(0, std::min<std::size_t>(name.size(), 5))).build();
  ASSERT_TRUE(by_name) << by_name.error().message;
  EXPECT_EQ((*by_name)->info().name.substr(0, 5), name.substr(0, 5));

  auto none = ContextBuilder().device("no-such-device-name-xyz").build();
  ASSERT_FALSE(none);
  EXPECT_EQ(gpu_errc_of(none.error()), GpuErrc::device_not_found) << none.error().message;
  EXPECT_NE(none.error().message.find(name), std::string::npos)
      << "the error lists the devices: " << none.error().message;
}

// The real pin between the two languages: GLSL writes structs, C++ reads them and vice versa,
// push constants echo, and every constant crosses over.
TEST(GpuLayout, GlslStructsAndConstantsMatchCpp) {
  Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  struct Written {
    L::DcPoolInfo info[2];
    L::DcDispatchRange range[2];
  };
  struct Given {
    L::DcPoolInfo info;
    L::DcDispatchRange range;
  };
  static_assert(offsetof(Written, range) == 64 && sizeof(Written) == 96);

  auto written = Buffer::create(*ctx, sizeof(Written), kStorage, MemoryUse::readback);
  auto given = Buffer::create(*ctx, sizeof(Given), kStorage, MemoryUse::upload);
  auto probes = Buffer::create(*ctx, 64 * sizeof(std::uint32_t), kStorage, MemoryUse::readback);
  ASSERT_TRUE(written && given && probes);
  std::memset(written->mapped(), 0xCD, sizeof(Written));
  std::memset(probes->mapped(), 0xCD, 64 * sizeof(std::uint32_t));
  Given g{};
  g.info = {0x101, 0x102, 0x103, 0x104, 0x105, 0x106, 20000.25f, 0x108};
  g.range = {0x201, 0x202, 0x203, 0x204};
  std::memcpy(given->mapped(), &g, sizeof g);
  ASSERT_TRUE(given->flush() && written->flush() && probes->flush());
  GpuPush push{};
  push.pool = {14, 12, 0x12345678, 64, 4, 24, -7.75f, 0x9ABCDEF0};
  push.range = {0x11111111, 0x22222222, 0x33333333, 0x44444444};

  auto pipe = ComputePipeline::create(*ctx, {.name = "layout_probe",
                                             .spirv = deepcanvas_spv_layout_probe,
                                             .bindings = {{0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER},
                                                          {1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER},
                                                          {2, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER}},
                                             .push_constant_bytes = sizeof(GpuPush)});
  ASSERT_TRUE(pipe) << pipe.error().message;
  auto pool = DescriptorPool::create(*ctx, *pipe, 1);
  ASSERT_TRUE(pool);
  auto set = pool->allocate(*pipe);
  ASSERT_TRUE(set);
  DescriptorWriter().buffer(0, *written).buffer(1, *given).buffer(2, *probes).update(*ctx, *set);
  auto run = ctx->submit_once(ctx->compute_queue(), [&](VkCommandBuffer cb) {
    pipe->bind(cb, *set);
    pipe->push(cb, push);
    vkCmdDispatch(cb, 1, 1, 1);
    shader_to_host(cb);
  });
  ASSERT_TRUE(run) << run.error().message;
  ASSERT_TRUE(written->invalidate() && probes->invalidate());

  // GLSL -> C++: each field must hold its own sentinel at the C++ offset.
  Written w;
  std::memcpy(&w, written->mapped(), sizeof w);
  auto sentinel = [](std::uint32_t field, std::uint32_t e) {
    return 0xA5000000u | (e << 16) | field;
  };
  for (std::uint32_t e = 0; e < 2; ++e) {
    SCOPED_TRACE("element " + std::to_string(e));
    EXPECT_EQ(w.info[e].width_log2, sentinel(0, e));
    EXPECT_EQ(w.info[e].block_log2, sentinel(1, e));
    EXPECT_EQ(w.info[e].cell_count, sentinel(2, e));
    EXPECT_EQ(w.info[e].root_count, sentinel(3, e));
    EXPECT_EQ(w.info[e].roots_per_axis, sentinel(4, e));
    EXPECT_EQ(w.info[e].max_depth, sentinel(5, e));
    EXPECT_EQ(w.info[e].canvas_edge_m, 1000.5f + static_cast<float>(e));
    EXPECT_EQ(w.info[e].reserved0, sentinel(7, e));
    EXPECT_EQ(w.range[e].first, sentinel(10, e));
    EXPECT_EQ(w.range[e].count, sentinel(11, e));
    EXPECT_EQ(w.range[e].reserved0, sentinel(12, e));
    EXPECT_EQ(w.range[e].reserved1, sentinel(13, e));
  }

  // C++ -> GLSL: push constants and the storage buffer, echoed in declaration order.
  const auto v = probes->mapped_span<const std::uint32_t>();
  auto bits = [](float f) {
    std::uint32_t u;
    std::memcpy(&u, &f, 4);
    return u;
  };
  const std::vector<std::uint32_t> expect_push = {push.pool.width_log2,
                                                  push.pool.block_log2,
                                                  push.pool.cell_count,
                                                  push.pool.root_count,
                                                  push.pool.roots_per_axis,
                                                  push.pool.max_depth,
                                                  bits(push.pool.canvas_edge_m),
                                                  push.pool.reserved0,
                                                  push.range.first,
                                                  push.range.count,
                                                  push.range.reserved0,
                                                  push.range.reserved1};
  const std::vector<std::uint32_t> expect_given = {
      g.info.width_log2,     g.info.block_log2, g.info.cell_count,          g.info.root_count,
      g.info.roots_per_axis, g.info.max_depth,  bits(g.info.canvas_edge_m), g.info.reserved0,
      g.range.first,         g.range.count,     g.range.reserved0,          g.range.reserved1};
  for (std::size_t i = 0; i < 12; ++i) {
    EXPECT_EQ(v[i], expect_push[i]) << "push-constant field " << i;
    EXPECT_EQ(v[12 + i], expect_given[i]) << "storage-buffer field " << i;
  }
  const std::vector<std::uint32_t> constants = {
      L::kLayoutVersion, L::kNoCell,          L::kDepthMask,         L::kGroupFreeFlag,
      L::kMaxDepth,      L::kMinWidthLog2,    L::kMaxWidthLog2,      L::kMinBlockLog2,
      L::kMaxCellsLog2,  L::kFaceCount,       L::kCellsPerGroupLog2, L::kPoolFirstChild,
      L::kPoolColour,    L::kPoolGroupParent, L::kPoolGroupDepth,    L::kPoolGroupLinks,
      L::kPoolCount,     L::kMinRootsPerAxis, L::kMaxRootsPerAxis,   L::kCellsPerGroup};
  for (std::size_t i = 0; i < constants.size(); ++i) {
    EXPECT_EQ(v[24 + i], constants[i]) << "constant #" << i;
  }
  const std::size_t end = 24 + constants.size();
  EXPECT_EQ(v[end], 0xE0D0E0D0u) << "GLSL wrote a different number of constants";
  EXPECT_EQ(v[end + 1], end + 1);
}

// The addressing functions compiled by glslang and by the C++ compiler agree word for word.
TEST(GpuLayout, AddressingFunctionsMatchCpu) {
  Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  constexpr std::uint32_t kWords = kAddressingWords;
  auto pipe = ComputePipeline::create(*ctx, {.name = "pool_addressing",
                                             .spirv = deepcanvas_spv_pool_addressing,
                                             .bindings = {{0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER}},
                                             .push_constant_bytes = sizeof(GpuPush)});
  ASSERT_TRUE(pipe) << pipe.error().message;
  auto pool = DescriptorPool::create(*ctx, *pipe, 1);
  ASSERT_TRUE(pool);
  auto set = pool->allocate(*pipe);
  ASSERT_TRUE(set);
  constexpr std::uint32_t kCount = 1u << 15;
  auto out = Buffer::create(*ctx, kCount * kWords * 4ull, kStorage, MemoryUse::readback);
  ASSERT_TRUE(out);
  DescriptorWriter().buffer(0, *out).update(*ctx, *set);

  struct Case {
    std::uint32_t width_log2, block_log2, first, roots_per_axis;
  };
  const Case cases[] = {{6, 12, 0, 4},
                        {14, 12, 0, 2},
                        {10, 6, (1u << 20) + 3, 8},
                        {14, 16, (1u << 28) - kCount, 64},
                        {9, 9, 123457, 4}};
  for (const Case& c : cases) {
    SCOPED_TRACE("W=2^" + std::to_string(c.width_log2) + " B=2^" + std::to_string(c.block_log2) +
                 " first=" + std::to_string(c.first));
    GpuPush push{};
    push.pool = {c.width_log2,
                 c.block_log2,
                 0,
                 c.roots_per_axis * c.roots_per_axis * c.roots_per_axis,
                 c.roots_per_axis,
                 24,
                 20000.0f,
                 0};
    push.range = {c.first, kCount, 0, 0};
    std::memset(out->mapped(), 0xEE, kCount * kWords * 4ull);
    ASSERT_TRUE(out->flush());
    auto run = ctx->submit_once(ctx->compute_queue(), [&](VkCommandBuffer cb) {
      pipe->bind(cb, *set);
      pipe->push(cb, push);
      vkCmdDispatch(cb, group_count(kCount, 64), 1, 1);
      shader_to_host(cb);
    });
    ASSERT_TRUE(run) << run.error().message;
    ASSERT_TRUE(out->invalidate());
    const auto v = out->mapped_span<const std::uint32_t>();
    const std::uint32_t w = c.width_log2, b = c.block_log2, n = c.roots_per_axis;
    std::uint64_t mismatches = 0;
    for (std::uint32_t k = 0; k < kCount; ++k) {
      const std::uint32_t i = c.first + k;
      std::uint32_t inner = 0;
      for (std::uint32_t f = 0; f < L::kFaceCount; ++f)
        inner |= L::dc_face_is_inner(i, f) ? 1u << f : 0;
      const std::uint32_t expect[kWords] = {
          L::dc_cell_texel_x(i, w),
          L::dc_cell_texel_y(i, w),
          L::dc_group_texel_x(L::dc_group_of(i), w),
          L::dc_group_texel_y(L::dc_group_of(i), w),
          L::dc_block_of(i, b),
          L::dc_block_x0(L::dc_block_of(i, b), b, w),
          L::dc_block_y0(L::dc_block_of(i, b), b, w),
          L::dc_block_w(b, w) | (L::dc_block_h(b, w) << 16),
          inner,
          L::dc_sibling_across(i, i % 6u),
          L::dc_resolve_link(i, i % 6u, (i & 1u) != 0u ? i * 3u : L::kNoCell,
                             (i & 2u) != 0u ? i * 5u : L::kNoCell),
          L::dc_root_neighbour(i % push.pool.root_count, i % 6u, c.roots_per_axis),
          L::dc_depth_of(i) | (L::dc_group_is_free(i) ? 0x100u : 0u),
          L::dc_pack_rgba8(i, i >> 3, i >> 7, i >> 11),
          L::dc_colour_channel(i * 2654435761u, i & 3u),
          L::dc_texture_height(i, w),
          L::dc_face(i % 3u, (i & 8u) != 0u),
          L::dc_outer_face(i, i % 3u),
          L::dc_mirror_child(i, i % 6u, i * 8u),
          L::dc_link_index(L::dc_group_of(i), i % 6u),
          L::dc_group_first_cell(L::dc_group_of(i)),
          L::dc_slot(i, i >> 1, i >> 2),
          L::dc_root_index(i % n, (i / n) % n, (i / (n * n)) % n, n),
          L::dc_root_count(n) + L::dc_slot_of(i),
          L::dc_face_axis(i % 6u) | (L::dc_face_positive(i % 6u) ? 0x100u : 0u) |
              (L::dc_group_width(w) << 12),
          L::dc_width(w) ^ L::dc_group_of(i)};
      for (std::uint32_t j = 0; j < kWords; ++j) {
        if (v[k * kWords + j] != expect[j] && mismatches++ < 10) {
          ADD_FAILURE() << "index " << i << " word " << j << ": GPU " << v[k * kWords + j]
                        << ", C++ " << expect[j];
        }
      }
      // And the semantics, independently of the shared code: the texel is row-major and the
      // cell's group sits in the same row.
      ASSERT_EQ(static_cast<std::uint64_t>(v[k * kWords + 1]) << w | v[k * kWords + 0], i);
      ASSERT_EQ(v[k * kWords + 3], v[k * kWords + 1]);
      ASSERT_EQ(v[k * kWords + 2], v[k * kWords + 0] >> 3);
    }
    EXPECT_EQ(mismatches, 0u);
  }
}

TEST(GpuBuffers, StagingToDeviceLocalAndBack) {
  Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  constexpr std::size_t kWords = 3u << 18;  // 3 MiB
  auto up = Buffer::create(*ctx, kWords * 4, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, MemoryUse::upload);
  auto dev = Buffer::create(*ctx, kWords * 4, kStorage, MemoryUse::device_local);
  auto down =
      Buffer::create(*ctx, kWords * 4, VK_BUFFER_USAGE_TRANSFER_DST_BIT, MemoryUse::readback);
  ASSERT_TRUE(up && dev && down);
  ASSERT_NE(up->mapped(), nullptr);
  ASSERT_NE(down->mapped(), nullptr);
  EXPECT_EQ(dev->mapped(), nullptr);
  std::mt19937 rng(7);
  auto src = up->mapped_span<std::uint32_t>();
  ASSERT_EQ(src.size(), kWords);
  for (auto& x : src) x = static_cast<std::uint32_t>(rng());
  ASSERT_TRUE(up->flush());
  auto run = ctx->submit_once(ctx->transfer_queue(), [&](VkCommandBuffer cb) {
    copy_buffer(cb, *up, 0, *dev, 0, kWords * 4);
    buffer_barrier(cb, *dev, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                   VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_READ_BIT);
    // Out of order on purpose: the second half first.
    copy_buffer(cb, *dev, kWords * 2, *down, kWords * 2, kWords * 2);
    copy_buffer(cb, *dev, 0, *down, 0, kWords * 2);
    shader_to_host(cb);
  });
  ASSERT_TRUE(run) << run.error().message;
  ASSERT_TRUE(down->invalidate());
  EXPECT_EQ(std::memcmp(down->mapped(), up->mapped(), kWords * 4), 0);
}

TEST(GpuBuffers, RejectsBadArguments) {
  Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto zero = Buffer::create(*ctx, 0, kStorage, MemoryUse::upload);
  ASSERT_FALSE(zero);
  EXPECT_EQ(gpu_errc_of(zero.error()), GpuErrc::bad_argument);
  auto huge = Image::create(
      *ctx,
      {.format = VK_FORMAT_R32_UINT, .width = ctx->limits().maxImageDimension2D + 1, .height = 1});
  ASSERT_FALSE(huge);
  EXPECT_EQ(gpu_errc_of(huge.error()), GpuErrc::bad_argument);
  const std::uint32_t garbage[8] = {1, 2, 3, 4, 5, 6, 7, 8};
  auto bad = ComputePipeline::create(*ctx, {.name = "garbage", .spirv = garbage});
  ASSERT_FALSE(bad);
  EXPECT_EQ(gpu_errc_of(bad.error()), GpuErrc::shader_failed);
  auto too_many_push = ComputePipeline::create(
      *ctx, {.name = "probe",
             .spirv = deepcanvas_spv_layout_probe,
             .push_constant_bytes = ctx->limits().maxPushConstantsSize + 4});
  ASSERT_FALSE(too_many_push);
  EXPECT_EQ(gpu_errc_of(too_many_push.error()), GpuErrc::bad_argument);
}

TEST(GpuTimestamps, BracketADispatch) {
  Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto ts = TimestampQueries::create(*ctx, ctx->compute_queue(), 2);
  if (!ctx->timestamps_supported(ctx->compute_queue())) {
    ASSERT_FALSE(ts);
    EXPECT_EQ(gpu_errc_of(ts.error()), GpuErrc::unsupported);
    GTEST_SKIP() << "the compute queue has no timestamps on " << ctx->info().name;
  }
  ASSERT_TRUE(ts) << ts.error().message;
  auto pipe = ComputePipeline::create(*ctx, {.name = "pool_addressing",
                                             .spirv = deepcanvas_spv_pool_addressing,
                                             .bindings = {{0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER}},
                                             .push_constant_bytes = sizeof(GpuPush)});
  ASSERT_TRUE(pipe);
  auto pool = DescriptorPool::create(*ctx, *pipe, 1);
  ASSERT_TRUE(pool);
  auto set = pool->allocate(*pipe);
  ASSERT_TRUE(set);
  auto out = Buffer::create(*ctx, 1024 * kAddressingWords * 4, kStorage, MemoryUse::device_local);
  ASSERT_TRUE(out);
  DescriptorWriter().buffer(0, *out).update(*ctx, *set);
  GpuPush push{};
  push.pool = {10, 12, 0, 64, 4, 24, 1.0f, 0};
  push.range = {0, 1024, 0, 0};
  auto run = ctx->submit_once(ctx->compute_queue(), [&](VkCommandBuffer cb) {
    ts->reset(cb);
    ts->write(cb, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0);
    pipe->bind(cb, *set);
    pipe->push(cb, push);
    vkCmdDispatch(cb, group_count(1024, 64), 1, 1);
    ts->write(cb, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, 1);
  });
  ASSERT_TRUE(run) << run.error().message;
  auto ticks = ts->ticks();
  ASSERT_TRUE(ticks) << ticks.error().message;
  // Only that both queries were written and ordered; durations are for benchmarks.
  EXPECT_NE((*ticks)[1], 0u);
  if (ctx->compute_queue().timestamp_valid_bits() == 64) {
    EXPECT_GE((*ticks)[1], (*ticks)[0]);
  }
  std::printf("dispatch of 1024 invocations: %.0f ns (informational)\n",
              ts->elapsed_ns(*ticks, 0, 1));
}

}  // namespace
}  // namespace deepcanvas::client_gpu
