#include "deepcanvas/client_gpu/compute.hpp"

#include <cassert>
#include <map>
#include <utility>

#include "deepcanvas/client_gpu/errors.hpp"

namespace deepcanvas::client_gpu {

namespace {
constexpr std::uint32_t kSpirvMagic = 0x07230203u;
}

// ---- ComputePipeline ---------------------------------------------------------------------------

ComputePipeline::~ComputePipeline() {
  destroy();
}
ComputePipeline::ComputePipeline(ComputePipeline&& other) noexcept {
  *this = std::move(other);
}
ComputePipeline& ComputePipeline::operator=(ComputePipeline&& other) noexcept {
  if (this != &other) {
    destroy();
    ctx_ = std::exchange(other.ctx_, nullptr);
    set_layout_ = std::exchange(other.set_layout_, VK_NULL_HANDLE);
    layout_ = std::exchange(other.layout_, VK_NULL_HANDLE);
    pipeline_ = std::exchange(other.pipeline_, VK_NULL_HANDLE);
    bindings_ = std::move(other.bindings_);
    push_bytes_ = other.push_bytes_;
  }
  return *this;
}

void ComputePipeline::destroy() noexcept {
  if (ctx_ == nullptr) return;
  VkDevice dev = ctx_->device();
  if (pipeline_ != VK_NULL_HANDLE) vkDestroyPipeline(dev, pipeline_, nullptr);
  if (layout_ != VK_NULL_HANDLE) vkDestroyPipelineLayout(dev, layout_, nullptr);
  if (set_layout_ != VK_NULL_HANDLE) vkDestroyDescriptorSetLayout(dev, set_layout_, nullptr);
  pipeline_ = VK_NULL_HANDLE;
  layout_ = VK_NULL_HANDLE;
  set_layout_ = VK_NULL_HANDLE;
  ctx_ = nullptr;
}

Result<ComputePipeline> ComputePipeline::create(const Context& ctx,
                                                const ComputePipelineDesc& desc) {
  if (desc.spirv.size() < 5 || desc.spirv[0] != kSpirvMagic) {
    return gpu_error(GpuErrc::shader_failed,
                     "shader '" + desc.name + "': not SPIR-V (missing magic number or empty)");
  }
  if (desc.push_constant_bytes % 4 != 0 ||
      desc.push_constant_bytes > ctx.limits().maxPushConstantsSize) {
    return gpu_error(GpuErrc::bad_argument,
                     "shader '" + desc.name + "': " + std::to_string(desc.push_constant_bytes) +
                         " push-constant bytes (a multiple of 4, at most " +
                         std::to_string(ctx.limits().maxPushConstantsSize) + ")");
  }
  ComputePipeline p;
  p.ctx_ = &ctx;
  p.bindings_ = desc.bindings;
  p.push_bytes_ = desc.push_constant_bytes;
  VkDevice dev = ctx.device();

  std::vector<VkDescriptorSetLayoutBinding> lb;
  for (const auto& b : desc.bindings) {
    VkDescriptorSetLayoutBinding x{};
    x.binding = b.binding;
    x.descriptorType = b.type;
    x.descriptorCount = b.count;
    x.stageFlags = VK_SHADER_STAGE_COMPUTE_BIT;
    lb.push_back(x);
  }
  VkDescriptorSetLayoutCreateInfo sli{};
  sli.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO;
  sli.bindingCount = static_cast<std::uint32_t>(lb.size());
  sli.pBindings = lb.data();
  if (VkResult r = vkCreateDescriptorSetLayout(dev, &sli, nullptr, &p.set_layout_);
      r != VK_SUCCESS) {
    p.set_layout_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::shader_failed,
                          "shader '" + desc.name + "': vkCreateDescriptorSetLayout failed");
  }
  VkPushConstantRange pcr{VK_SHADER_STAGE_COMPUTE_BIT, 0, desc.push_constant_bytes};
  VkPipelineLayoutCreateInfo pli{};
  pli.sType = VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO;
  pli.setLayoutCount = 1;
  pli.pSetLayouts = &p.set_layout_;
  pli.pushConstantRangeCount = desc.push_constant_bytes > 0 ? 1 : 0;
  pli.pPushConstantRanges = &pcr;
  if (VkResult r = vkCreatePipelineLayout(dev, &pli, nullptr, &p.layout_); r != VK_SUCCESS) {
    p.layout_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::shader_failed,
                          "shader '" + desc.name + "': vkCreatePipelineLayout failed");
  }

  VkShaderModuleCreateInfo smi{};
  smi.sType = VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO;
  smi.codeSize = desc.spirv.size_bytes();
  smi.pCode = desc.spirv.data();
  VkShaderModule module = VK_NULL_HANDLE;
  if (VkResult r = vkCreateShaderModule(dev, &smi, nullptr, &module); r != VK_SUCCESS) {
    return gpu_error_from(r, GpuErrc::shader_failed,
                          "shader '" + desc.name + "': vkCreateShaderModule failed");
  }
  std::vector<VkSpecializationMapEntry> entries;
  for (std::uint32_t i = 0; i < desc.specialization.size(); ++i) {
    entries.push_back(
        {i, static_cast<std::uint32_t>(i * sizeof(std::uint32_t)), sizeof(std::uint32_t)});
  }
  VkSpecializationInfo spec{};
  spec.mapEntryCount = static_cast<std::uint32_t>(entries.size());
  spec.pMapEntries = entries.data();
  spec.dataSize = desc.specialization.size() * sizeof(std::uint32_t);
  spec.pData = desc.specialization.data();

  VkComputePipelineCreateInfo ci{};
  ci.sType = VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO;
  ci.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
  ci.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  ci.stage.module = module;
  ci.stage.pName = "main";
  ci.stage.pSpecializationInfo = entries.empty() ? nullptr : &spec;
  ci.layout = p.layout_;
  const VkResult r = vkCreateComputePipelines(dev, VK_NULL_HANDLE, 1, &ci, nullptr, &p.pipeline_);
  // The module is only needed while the pipeline is created.
  vkDestroyShaderModule(dev, module, nullptr);
  if (r != VK_SUCCESS) {
    p.pipeline_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::shader_failed,
                          "shader '" + desc.name + "': vkCreateComputePipelines failed");
  }
  return p;
}

void ComputePipeline::bind(VkCommandBuffer cb, VkDescriptorSet set) const {
  vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline_);
  vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, layout_, 0, 1, &set, 0, nullptr);
}

void ComputePipeline::push(VkCommandBuffer cb, const void* data, std::uint32_t bytes) const {
  assert(bytes == push_bytes_);
  vkCmdPushConstants(cb, layout_, VK_SHADER_STAGE_COMPUTE_BIT, 0, bytes, data);
}

// ---- DescriptorPool ----------------------------------------------------------------------------

DescriptorPool::~DescriptorPool() {
  if (ctx_ != nullptr && pool_ != VK_NULL_HANDLE)
    vkDestroyDescriptorPool(ctx_->device(), pool_, nullptr);
}
DescriptorPool::DescriptorPool(DescriptorPool&& other) noexcept
    : ctx_(std::exchange(other.ctx_, nullptr)), pool_(std::exchange(other.pool_, VK_NULL_HANDLE)) {}
DescriptorPool& DescriptorPool::operator=(DescriptorPool&& other) noexcept {
  if (this != &other) {
    if (ctx_ != nullptr && pool_ != VK_NULL_HANDLE)
      vkDestroyDescriptorPool(ctx_->device(), pool_, nullptr);
    ctx_ = std::exchange(other.ctx_, nullptr);
    pool_ = std::exchange(other.pool_, VK_NULL_HANDLE);
  }
  return *this;
}

Result<DescriptorPool> DescriptorPool::create(const Context& ctx, const ComputePipeline& pipeline,
                                              std::uint32_t sets) {
  if (sets == 0) return gpu_error(GpuErrc::bad_argument, "descriptor pool of 0 sets");
  std::map<VkDescriptorType, std::uint32_t> counts;
  for (const auto& b : pipeline.bindings()) counts[b.type] += b.count * sets;
  std::vector<VkDescriptorPoolSize> sizes;
  for (const auto& [type, n] : counts) sizes.push_back({type, n});
  VkDescriptorPoolCreateInfo ci{};
  ci.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO;
  ci.maxSets = sets;
  ci.poolSizeCount = static_cast<std::uint32_t>(sizes.size());
  ci.pPoolSizes = sizes.data();
  DescriptorPool p;
  p.ctx_ = &ctx;
  if (VkResult r = vkCreateDescriptorPool(ctx.device(), &ci, nullptr, &p.pool_); r != VK_SUCCESS) {
    p.pool_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateDescriptorPool failed");
  }
  return p;
}

Result<VkDescriptorSet> DescriptorPool::allocate(const ComputePipeline& pipeline) {
  VkDescriptorSetLayout layout = pipeline.set_layout();
  VkDescriptorSetAllocateInfo ai{};
  ai.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO;
  ai.descriptorPool = pool_;
  ai.descriptorSetCount = 1;
  ai.pSetLayouts = &layout;
  VkDescriptorSet set = VK_NULL_HANDLE;
  if (VkResult r = vkAllocateDescriptorSets(ctx_->device(), &ai, &set); r != VK_SUCCESS) {
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkAllocateDescriptorSets failed");
  }
  return set;
}

// ---- DescriptorWriter --------------------------------------------------------------------------

DescriptorWriter& DescriptorWriter::buffer(std::uint32_t binding, const Buffer& buffer,
                                           VkDeviceSize offset, VkDeviceSize range,
                                           VkDescriptorType type) {
  entries_.push_back({binding, type, {buffer.handle(), offset, range}, {}});
  return *this;
}

DescriptorWriter& DescriptorWriter::storage_image(std::uint32_t binding, const Image& image) {
  entries_.push_back({binding,
                      VK_DESCRIPTOR_TYPE_STORAGE_IMAGE,
                      {},
                      {VK_NULL_HANDLE, image.view(), VK_IMAGE_LAYOUT_GENERAL}});
  return *this;
}

DescriptorWriter& DescriptorWriter::sampled_image(std::uint32_t binding, const Image& image,
                                                  const Sampler& sampler, VkImageLayout layout) {
  entries_.push_back({binding,
                      VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER,
                      {},
                      {sampler.handle(), image.view(), layout}});
  return *this;
}

void DescriptorWriter::update(const Context& ctx, VkDescriptorSet set) {
  std::vector<VkWriteDescriptorSet> writes;
  writes.reserve(entries_.size());
  for (const auto& e : entries_) {
    VkWriteDescriptorSet w{};
    w.sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
    w.dstSet = set;
    w.dstBinding = e.binding;
    w.descriptorCount = 1;
    w.descriptorType = e.type;
    const bool is_buffer =
        e.type == VK_DESCRIPTOR_TYPE_STORAGE_BUFFER || e.type == VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER;
    if (is_buffer) {
      w.pBufferInfo = &e.buffer;
    } else {
      w.pImageInfo = &e.image;
    }
    writes.push_back(w);
  }
  vkUpdateDescriptorSets(ctx.device(), static_cast<std::uint32_t>(writes.size()), writes.data(), 0,
                         nullptr);
}

// ---- TimestampQueries --------------------------------------------------------------------------

TimestampQueries::~TimestampQueries() {
  if (ctx_ != nullptr && pool_ != VK_NULL_HANDLE)
    vkDestroyQueryPool(ctx_->device(), pool_, nullptr);
}
TimestampQueries::TimestampQueries(TimestampQueries&& other) noexcept {
  *this = std::move(other);
}
TimestampQueries& TimestampQueries::operator=(TimestampQueries&& other) noexcept {
  if (this != &other) {
    if (ctx_ != nullptr && pool_ != VK_NULL_HANDLE)
      vkDestroyQueryPool(ctx_->device(), pool_, nullptr);
    ctx_ = std::exchange(other.ctx_, nullptr);
    pool_ = std::exchange(other.pool_, VK_NULL_HANDLE);
    count_ = other.count_;
    mask_ = other.mask_;
    period_ns_ = other.period_ns_;
  }
  return *this;
}

Result<TimestampQueries> TimestampQueries::create(const Context& ctx, const Queue& queue,
                                                  std::uint32_t count) {
  if (!ctx.timestamps_supported(queue)) {
    return gpu_error(GpuErrc::unsupported, "queue family " + std::to_string(queue.family()) +
                                               " of '" + ctx.info().name +
                                               "' cannot write timestamps");
  }
  if (count == 0) return gpu_error(GpuErrc::bad_argument, "0 timestamp queries");
  VkQueryPoolCreateInfo ci{};
  ci.sType = VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO;
  ci.queryType = VK_QUERY_TYPE_TIMESTAMP;
  ci.queryCount = count;
  TimestampQueries t;
  t.ctx_ = &ctx;
  t.count_ = count;
  const std::uint32_t bits = queue.timestamp_valid_bits();
  t.mask_ = bits >= 64 ? ~0ull : ((1ull << bits) - 1);
  t.period_ns_ = ctx.limits().timestampPeriod;
  if (VkResult r = vkCreateQueryPool(ctx.device(), &ci, nullptr, &t.pool_); r != VK_SUCCESS) {
    t.pool_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateQueryPool failed");
  }
  return t;
}

void TimestampQueries::reset(VkCommandBuffer cb) const {
  vkCmdResetQueryPool(cb, pool_, 0, count_);
}

void TimestampQueries::write(VkCommandBuffer cb, VkPipelineStageFlagBits stage,
                             std::uint32_t index) const {
  vkCmdWriteTimestamp(cb, stage, pool_, index);
}

Result<std::vector<std::uint64_t>> TimestampQueries::ticks() const {
  std::vector<std::uint64_t> out(count_);
  const VkResult r =
      vkGetQueryPoolResults(ctx_->device(), pool_, 0, count_, out.size() * sizeof(std::uint64_t),
                            out.data(), sizeof(std::uint64_t), VK_QUERY_RESULT_64_BIT);
  if (r != VK_SUCCESS) {
    return gpu_error_from(r, GpuErrc::submit_failed,
                          "vkGetQueryPoolResults failed (were all queries written?)");
  }
  for (auto& t : out) t &= mask_;
  return out;
}

double TimestampQueries::elapsed_ns(const std::vector<std::uint64_t>& ticks, std::uint32_t from,
                                    std::uint32_t to) const {
  // Masked counters may wrap once between two queries of one submission.
  const std::uint64_t dt = (ticks[to] - ticks[from]) & mask_;
  return static_cast<double>(dt) * period_ns_;
}

}  // namespace deepcanvas::client_gpu
