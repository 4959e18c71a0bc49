// Compute pipelines from embedded SPIR-V, their descriptor sets, and timestamp queries.
//
//   #include "deepcanvas/shaders/my_pass.spv.h"   // generated: const uint32_t
//   deepcanvas_spv_my_pass[] auto pipe = ComputePipeline::create(ctx, {.name = "my_pass", .spirv =
//   deepcanvas_spv_my_pass,
//       .bindings = {{0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER}}, .push_constant_bytes = 16});
//   auto pool = DescriptorPool::create(ctx, *pipe, 1);
//   auto set = pool->allocate(*pipe);
//   DescriptorWriter().buffer(0, out).update(ctx, *set);
//   ctx.submit_once(ctx.compute_queue(), [&](VkCommandBuffer cb) {
//     pipe->bind(cb, *set); pipe->push(cb, params); vkCmdDispatch(cb, n, 1, 1); });
//
// One descriptor set (set = 0) per pipeline; the shader's bindings must match `bindings`.
// Ownership and threading as memory.hpp: the Context outlives these, one thread at a time each.
#pragma once

#include <vulkan/vulkan.h>

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/memory.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_gpu {

struct BindingDesc {
  std::uint32_t binding = 0;
  VkDescriptorType type = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
  std::uint32_t count = 1;
};

struct ComputePipelineDesc {
  std::string name{};                      // for error messages
  std::span<const std::uint32_t> spirv{};  // SPIR-V words (the generated array)
  std::vector<BindingDesc> bindings{};     // set 0
  std::uint32_t push_constant_bytes = 0;   // multiple of 4, <= maxPushConstantsSize
  // Specialization constants: constant_id i gets specialization[i] (uint32 each).
  std::vector<std::uint32_t> specialization{};
};

class ComputePipeline {
 public:
  ComputePipeline() = default;
  ~ComputePipeline();
  ComputePipeline(ComputePipeline&& other) noexcept;
  ComputePipeline& operator=(ComputePipeline&& other) noexcept;
  ComputePipeline(const ComputePipeline&) = delete;
  ComputePipeline& operator=(const ComputePipeline&) = delete;

  // Errors: shader_failed (empty or non-SPIR-V words, module or pipeline creation failed),
  // bad_argument (push constants over the device limit or not a multiple of 4).
  static Result<ComputePipeline> create(const Context& ctx, const ComputePipelineDesc& desc);

  VkPipeline handle() const noexcept { return pipeline_; }
  VkPipelineLayout layout() const noexcept { return layout_; }
  VkDescriptorSetLayout set_layout() const noexcept { return set_layout_; }
  const std::vector<BindingDesc>& bindings() const noexcept { return bindings_; }
  std::uint32_t push_constant_bytes() const noexcept { return push_bytes_; }

  void bind(VkCommandBuffer cb, VkDescriptorSet set) const;
  // `bytes` must equal push_constant_bytes() (checked by assert; a mismatch is a bug).
  void push(VkCommandBuffer cb, const void* data, std::uint32_t bytes) const;
  template <class T>
  void push(VkCommandBuffer cb, const T& value) const {
    push(cb, &value, static_cast<std::uint32_t>(sizeof(T)));
  }

 private:
  void destroy() noexcept;
  const Context* ctx_ = nullptr;
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout layout_ = VK_NULL_HANDLE;
  VkPipeline pipeline_ = VK_NULL_HANDLE;
  std::vector<BindingDesc> bindings_;
  std::uint32_t push_bytes_ = 0;
};

// Workgroups needed to cover `items` with `local_size` invocations each.
constexpr std::uint32_t group_count(std::uint64_t items, std::uint32_t local_size) noexcept {
  return static_cast<std::uint32_t>((items + local_size - 1) / local_size);
}

// A descriptor pool sized for `sets` sets of one pipeline's layout. Sets live as long as the pool.
class DescriptorPool {
 public:
  DescriptorPool() = default;
  ~DescriptorPool();
  DescriptorPool(DescriptorPool&& other) noexcept;
  DescriptorPool& operator=(DescriptorPool&& other) noexcept;
  DescriptorPool(const DescriptorPool&) = delete;
  DescriptorPool& operator=(const DescriptorPool&) = delete;

  static Result<DescriptorPool> create(const Context& ctx, const ComputePipeline& pipeline,
                                       std::uint32_t sets);
  // Error out_of_memory when the pool's sets are used up.
  Result<VkDescriptorSet> allocate(const ComputePipeline& pipeline);

 private:
  const Context* ctx_ = nullptr;
  VkDescriptorPool pool_ = VK_NULL_HANDLE;
};

// Collects descriptor writes, then applies them in one vkUpdateDescriptorSets.
class DescriptorWriter {
 public:
  DescriptorWriter& buffer(std::uint32_t binding, const Buffer& buffer, VkDeviceSize offset = 0,
                           VkDeviceSize range = VK_WHOLE_SIZE,
                           VkDescriptorType type = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER);
  // A storage image in VK_IMAGE_LAYOUT_GENERAL.
  DescriptorWriter& storage_image(std::uint32_t binding, const Image& image);
  // A sampled image (texelFetch) with a sampler, in `layout` (GENERAL for an image that is
  // also bound as a storage image elsewhere).
  DescriptorWriter& sampled_image(std::uint32_t binding, const Image& image, const Sampler& sampler,
                                  VkImageLayout layout = VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL);
  void update(const Context& ctx, VkDescriptorSet set);

 private:
  struct Entry {
    std::uint32_t binding;
    VkDescriptorType type;
    VkDescriptorBufferInfo buffer;
    VkDescriptorImageInfo image;
  };
  std::vector<Entry> entries_;
};

// A timestamp query pool. write() records the GPU clock after `stage`; results() converts tick
// differences to nanoseconds with the device's timestampPeriod. Only for benchmarks and
// diagnostics: timings never decide a test.
class TimestampQueries {
 public:
  TimestampQueries() = default;
  ~TimestampQueries();
  TimestampQueries(TimestampQueries&& other) noexcept;
  TimestampQueries& operator=(TimestampQueries&& other) noexcept;
  TimestampQueries(const TimestampQueries&) = delete;
  TimestampQueries& operator=(const TimestampQueries&) = delete;

  // Error unsupported when `queue` has no timestamp bits.
  static Result<TimestampQueries> create(const Context& ctx, const Queue& queue,
                                         std::uint32_t count);
  std::uint32_t count() const noexcept { return count_; }
  void reset(VkCommandBuffer cb) const;  // record before the first write of a submission
  void write(VkCommandBuffer cb, VkPipelineStageFlagBits stage, std::uint32_t index) const;
  // Raw ticks (masked to the valid bits), after the submission completed.
  Result<std::vector<std::uint64_t>> ticks() const;
  // Nanoseconds between queries `from` and `to`.
  double elapsed_ns(const std::vector<std::uint64_t>& ticks, std::uint32_t from,
                    std::uint32_t to) const;

 private:
  const Context* ctx_ = nullptr;
  VkQueryPool pool_ = VK_NULL_HANDLE;
  std::uint32_t count_ = 0;
  std::uint64_t mask_ = 0;
  double period_ns_ = 0.0;
};

}  // namespace deepcanvas::client_gpu
