#include "deepcanvas/client_gpu/memory.hpp"

#include <utility>

#include "deepcanvas/client_gpu/errors.hpp"

namespace deepcanvas::client_gpu {

namespace {

// Resources are shared CONCURRENT between the compute and transfer families when they differ,
// so uploads need no queue-family ownership transfers.
template <class CreateInfo>
void set_sharing(const Context& ctx, CreateInfo& ci) {
  const auto& fams = ctx.queue_families();
  if (fams.size() > 1) {
    ci.sharingMode = VK_SHARING_MODE_CONCURRENT;
    ci.queueFamilyIndexCount = static_cast<std::uint32_t>(fams.size());
    ci.pQueueFamilyIndices = fams.data();
  } else {
    ci.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  }
}

VkFormatFeatureFlags features_for(VkImageUsageFlags usage) {
  VkFormatFeatureFlags f = 0;
  if (usage & VK_IMAGE_USAGE_SAMPLED_BIT) f |= VK_FORMAT_FEATURE_SAMPLED_IMAGE_BIT;
  if (usage & VK_IMAGE_USAGE_STORAGE_BIT) f |= VK_FORMAT_FEATURE_STORAGE_IMAGE_BIT;
  if (usage & VK_IMAGE_USAGE_TRANSFER_DST_BIT) f |= VK_FORMAT_FEATURE_TRANSFER_DST_BIT;
  if (usage & VK_IMAGE_USAGE_TRANSFER_SRC_BIT) f |= VK_FORMAT_FEATURE_TRANSFER_SRC_BIT;
  if (usage & VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT) f |= VK_FORMAT_FEATURE_COLOR_ATTACHMENT_BIT;
  return f;
}

// The memory type for `req`: one with `required` (and `preferred` where there is one); for
// device-local memory any type as a last resort, since some drivers expose no DEVICE_LOCAL type
// for a usage and any memory works, slower.
Result<std::uint32_t> pick_memory_type(const Context& ctx, const VkMemoryRequirements& req,
                                       VkMemoryPropertyFlags required,
                                       VkMemoryPropertyFlags preferred) {
  auto type = ctx.find_memory_type(req.memoryTypeBits, required, preferred);
  if (!type && required == VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT) {
    type = ctx.find_memory_type(req.memoryTypeBits, 0, 0);
  }
  return type;
}

// Allocates req.size bytes of memory type `type` into `memory`, which stays null on failure.
Result<void> allocate_memory(const Context& ctx, const VkMemoryRequirements& req,
                             std::uint32_t type, VkDeviceMemory& memory, const char* what) {
  VkMemoryAllocateInfo ai{};
  ai.sType = VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO;
  ai.allocationSize = req.size;
  ai.memoryTypeIndex = type;
  if (VkResult r = vkAllocateMemory(ctx.device(), &ai, nullptr, &memory); r != VK_SUCCESS) {
    memory = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::out_of_memory,
                          "vkAllocateMemory(" + std::to_string(req.size) + " bytes) " + what);
  }
  return {};
}

// The range of a mapped allocation of `alloc_size` bytes covering [offset, offset + size),
// widened to whole nonCoherentAtomSize atoms as flushes and invalidations of non-coherent
// memory require (VK_WHOLE_SIZE where it reaches the end).
VkMappedMemoryRange atom_aligned_range(const Context& ctx, VkDeviceMemory memory,
                                       VkDeviceSize alloc_size, VkDeviceSize offset,
                                       VkDeviceSize size) {
  VkMappedMemoryRange range{};
  range.sType = VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE;
  range.memory = memory;
  const VkDeviceSize atom = ctx.limits().nonCoherentAtomSize;
  range.offset = offset / atom * atom;
  range.size = VK_WHOLE_SIZE;
  if (size != VK_WHOLE_SIZE) {
    const VkDeviceSize end = (offset + size + atom - 1) / atom * atom;
    if (end < alloc_size) range.size = end - range.offset;
  }
  return range;
}

}  // namespace

std::uint32_t format_texel_bytes(VkFormat format) noexcept {
  switch (format) {
    case VK_FORMAT_R8_UINT:
    case VK_FORMAT_R8_UNORM:
      return 1;
    case VK_FORMAT_R16_UINT:
      return 2;
    case VK_FORMAT_R32_UINT:
    case VK_FORMAT_R32_SFLOAT:
    case VK_FORMAT_R8G8B8A8_UNORM:
    case VK_FORMAT_R8G8B8A8_UINT:
      return 4;
    case VK_FORMAT_R32G32_UINT:
      return 8;
    case VK_FORMAT_R32G32B32A32_UINT:
    case VK_FORMAT_R32G32B32A32_SFLOAT:
      return 16;
    default:
      return 0;
  }
}

// ---- Buffer ----------------------------------------------------------------------------------

Buffer::~Buffer() {
  destroy();
}
Buffer::Buffer(Buffer&& other) noexcept {
  *this = std::move(other);
}
Buffer& Buffer::operator=(Buffer&& other) noexcept {
  if (this != &other) {
    destroy();
    ctx_ = std::exchange(other.ctx_, nullptr);
    buffer_ = std::exchange(other.buffer_, VK_NULL_HANDLE);
    memory_ = std::exchange(other.memory_, VK_NULL_HANDLE);
    size_ = std::exchange(other.size_, 0);
    alloc_size_ = std::exchange(other.alloc_size_, 0);
    mapped_ = std::exchange(other.mapped_, nullptr);
    coherent_ = other.coherent_;
  }
  return *this;
}

void Buffer::destroy() noexcept {
  if (ctx_ == nullptr) return;
  VkDevice dev = ctx_->device();
  if (mapped_ != nullptr) vkUnmapMemory(dev, memory_);
  if (buffer_ != VK_NULL_HANDLE) vkDestroyBuffer(dev, buffer_, nullptr);
  if (memory_ != VK_NULL_HANDLE) vkFreeMemory(dev, memory_, nullptr);
  buffer_ = VK_NULL_HANDLE;
  memory_ = VK_NULL_HANDLE;
  mapped_ = nullptr;
  ctx_ = nullptr;
}

Result<Buffer> Buffer::create(const Context& ctx, VkDeviceSize size, VkBufferUsageFlags usage,
                              MemoryUse use) {
  if (size == 0) return gpu_error(GpuErrc::bad_argument, "buffer size 0");
  Buffer b;
  b.ctx_ = &ctx;
  b.size_ = size;
  VkBufferCreateInfo ci{};
  ci.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
  ci.size = size;
  ci.usage = usage;
  set_sharing(ctx, ci);
  if (VkResult r = vkCreateBuffer(ctx.device(), &ci, nullptr, &b.buffer_); r != VK_SUCCESS) {
    b.buffer_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::out_of_memory,
                          "vkCreateBuffer(" + std::to_string(size) + " bytes) failed");
  }
  VkMemoryRequirements req{};
  vkGetBufferMemoryRequirements(ctx.device(), b.buffer_, &req);

  VkMemoryPropertyFlags required = 0, preferred = 0;
  switch (use) {
    case MemoryUse::device_local:
      required = VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT;
      break;
    case MemoryUse::upload:
      required = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT;
      preferred = VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
      break;
    case MemoryUse::readback:
      required = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT;
      preferred = VK_MEMORY_PROPERTY_HOST_CACHED_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
      break;
  }
  auto type = pick_memory_type(ctx, req, required, preferred);
  if (!type) return std::move(type).error();
  b.alloc_size_ = req.size;
  if (auto ok = allocate_memory(ctx, req, *type, b.memory_, "failed"); !ok)
    return std::move(ok).error();
  if (VkResult r = vkBindBufferMemory(ctx.device(), b.buffer_, b.memory_, 0); r != VK_SUCCESS) {
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkBindBufferMemory failed");
  }
  const VkMemoryPropertyFlags flags = ctx.memory_properties().memoryTypes[*type].propertyFlags;
  b.coherent_ = (flags & VK_MEMORY_PROPERTY_HOST_COHERENT_BIT) != 0;
  if (use != MemoryUse::device_local) {
    if (VkResult r = vkMapMemory(ctx.device(), b.memory_, 0, VK_WHOLE_SIZE, 0, &b.mapped_);
        r != VK_SUCCESS) {
      b.mapped_ = nullptr;
      return gpu_error_from(r, GpuErrc::out_of_memory, "vkMapMemory failed");
    }
  }
  return b;
}

Result<void> Buffer::flush(VkDeviceSize offset, VkDeviceSize size) const {
  if (coherent_ || mapped_ == nullptr) return {};
  const VkMappedMemoryRange range = atom_aligned_range(*ctx_, memory_, alloc_size_, offset, size);
  if (VkResult r = vkFlushMappedMemoryRanges(ctx_->device(), 1, &range); r != VK_SUCCESS) {
    return gpu_error_from(r, GpuErrc::submit_failed, "vkFlushMappedMemoryRanges failed");
  }
  return {};
}

Result<void> Buffer::invalidate(VkDeviceSize offset, VkDeviceSize size) const {
  if (coherent_ || mapped_ == nullptr) return {};
  const VkMappedMemoryRange range = atom_aligned_range(*ctx_, memory_, alloc_size_, offset, size);
  if (VkResult r = vkInvalidateMappedMemoryRanges(ctx_->device(), 1, &range); r != VK_SUCCESS) {
    return gpu_error_from(r, GpuErrc::submit_failed, "vkInvalidateMappedMemoryRanges failed");
  }
  return {};
}

// ---- Image -----------------------------------------------------------------------------------

Image::~Image() {
  destroy();
}
Image::Image(Image&& other) noexcept {
  *this = std::move(other);
}
Image& Image::operator=(Image&& other) noexcept {
  if (this != &other) {
    destroy();
    ctx_ = std::exchange(other.ctx_, nullptr);
    image_ = std::exchange(other.image_, VK_NULL_HANDLE);
    view_ = std::exchange(other.view_, VK_NULL_HANDLE);
    memory_ = std::exchange(other.memory_, VK_NULL_HANDLE);
    desc_ = other.desc_;
  }
  return *this;
}

void Image::destroy() noexcept {
  if (ctx_ == nullptr) return;
  VkDevice dev = ctx_->device();
  if (view_ != VK_NULL_HANDLE) vkDestroyImageView(dev, view_, nullptr);
  if (image_ != VK_NULL_HANDLE) vkDestroyImage(dev, image_, nullptr);
  if (memory_ != VK_NULL_HANDLE) vkFreeMemory(dev, memory_, nullptr);
  view_ = VK_NULL_HANDLE;
  image_ = VK_NULL_HANDLE;
  memory_ = VK_NULL_HANDLE;
  ctx_ = nullptr;
}

Result<Image> Image::create(const Context& ctx, const ImageDesc& desc) {
  const auto& lim = ctx.limits();
  if (desc.width == 0 || desc.height == 0 || desc.layers == 0 ||
      desc.width > lim.maxImageDimension2D || desc.height > lim.maxImageDimension2D ||
      desc.layers > lim.maxImageArrayLayers) {
    return gpu_error(GpuErrc::bad_argument,
                     "image " + std::to_string(desc.width) + "x" + std::to_string(desc.height) +
                         "x" + std::to_string(desc.layers) + " is outside the device limits (" +
                         std::to_string(lim.maxImageDimension2D) + " per side, " +
                         std::to_string(lim.maxImageArrayLayers) + " layers)");
  }
  VkFormatProperties fp{};
  vkGetPhysicalDeviceFormatProperties(ctx.physical_device(), desc.format, &fp);
  const VkFormatFeatureFlags need = features_for(desc.usage);
  if ((fp.optimalTilingFeatures & need) != need) {
    return gpu_error(GpuErrc::bad_argument, "format " + std::to_string(desc.format) +
                                                " lacks features for usage " +
                                                std::to_string(desc.usage) + " on this device");
  }
  Image img;
  img.ctx_ = &ctx;
  img.desc_ = desc;
  VkImageCreateInfo ci{};
  ci.sType = VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO;
  ci.imageType = VK_IMAGE_TYPE_2D;
  ci.format = desc.format;
  ci.extent = {desc.width, desc.height, 1};
  ci.mipLevels = 1;
  ci.arrayLayers = desc.layers;
  ci.samples = VK_SAMPLE_COUNT_1_BIT;
  ci.tiling = VK_IMAGE_TILING_OPTIMAL;
  ci.usage = desc.usage;
  ci.initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
  set_sharing(ctx, ci);
  if (VkResult r = vkCreateImage(ctx.device(), &ci, nullptr, &img.image_); r != VK_SUCCESS) {
    img.image_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateImage failed");
  }
  VkMemoryRequirements req{};
  vkGetImageMemoryRequirements(ctx.device(), img.image_, &req);
  auto type = pick_memory_type(ctx, req, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT, 0);
  if (!type) return std::move(type).error();
  if (auto ok = allocate_memory(ctx, req, *type, img.memory_, "for an image"); !ok) {
    return std::move(ok).error();
  }
  if (VkResult r = vkBindImageMemory(ctx.device(), img.image_, img.memory_, 0); r != VK_SUCCESS) {
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkBindImageMemory failed");
  }
  VkImageViewCreateInfo vi{};
  vi.sType = VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO;
  vi.image = img.image_;
  vi.viewType =
      (desc.layers > 1 || desc.array) ? VK_IMAGE_VIEW_TYPE_2D_ARRAY : VK_IMAGE_VIEW_TYPE_2D;
  vi.format = desc.format;
  vi.subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, desc.layers};
  if (VkResult r = vkCreateImageView(ctx.device(), &vi, nullptr, &img.view_); r != VK_SUCCESS) {
    img.view_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateImageView failed");
  }
  return img;
}

// ---- Sampler ---------------------------------------------------------------------------------

Sampler::~Sampler() {
  if (ctx_ != nullptr && sampler_ != VK_NULL_HANDLE)
    vkDestroySampler(ctx_->device(), sampler_, nullptr);
}
Sampler::Sampler(Sampler&& other) noexcept
    : ctx_(std::exchange(other.ctx_, nullptr)),
      sampler_(std::exchange(other.sampler_, VK_NULL_HANDLE)) {}
Sampler& Sampler::operator=(Sampler&& other) noexcept {
  if (this != &other) {
    if (ctx_ != nullptr && sampler_ != VK_NULL_HANDLE)
      vkDestroySampler(ctx_->device(), sampler_, nullptr);
    ctx_ = std::exchange(other.ctx_, nullptr);
    sampler_ = std::exchange(other.sampler_, VK_NULL_HANDLE);
  }
  return *this;
}

Result<Sampler> Sampler::create_nearest(const Context& ctx) {
  VkSamplerCreateInfo ci{};
  ci.sType = VK_STRUCTURE_TYPE_SAMPLER_CREATE_INFO;
  ci.magFilter = VK_FILTER_NEAREST;
  ci.minFilter = VK_FILTER_NEAREST;
  ci.mipmapMode = VK_SAMPLER_MIPMAP_MODE_NEAREST;
  ci.addressModeU = ci.addressModeV = ci.addressModeW = VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE;
  ci.maxLod = 0.0f;
  Sampler s;
  s.ctx_ = &ctx;
  if (VkResult r = vkCreateSampler(ctx.device(), &ci, nullptr, &s.sampler_); r != VK_SUCCESS) {
    s.sampler_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateSampler failed");
  }
  return s;
}

// ---- command helpers ---------------------------------------------------------------------------

void image_barrier(VkCommandBuffer cb, const Image& image, VkImageLayout from, VkImageLayout to,
                   VkPipelineStageFlags src_stage, VkAccessFlags src_access,
                   VkPipelineStageFlags dst_stage, VkAccessFlags dst_access) {
  VkImageMemoryBarrier b{};
  b.sType = VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER;
  b.srcAccessMask = src_access;
  b.dstAccessMask = dst_access;
  b.oldLayout = from;
  b.newLayout = to;
  b.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.image = image.handle();
  b.subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, image.desc().layers};
  vkCmdPipelineBarrier(cb, src_stage, dst_stage, 0, 0, nullptr, 0, nullptr, 1, &b);
}

void buffer_barrier(VkCommandBuffer cb, const Buffer& buffer, VkPipelineStageFlags src_stage,
                    VkAccessFlags src_access, VkPipelineStageFlags dst_stage,
                    VkAccessFlags dst_access) {
  VkBufferMemoryBarrier b{};
  b.sType = VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER;
  b.srcAccessMask = src_access;
  b.dstAccessMask = dst_access;
  b.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.buffer = buffer.handle();
  b.offset = 0;
  b.size = VK_WHOLE_SIZE;
  vkCmdPipelineBarrier(cb, src_stage, dst_stage, 0, 0, nullptr, 1, &b, 0, nullptr);
}

void copy_buffer_to_image(VkCommandBuffer cb, const Buffer& src, VkDeviceSize offset,
                          const Image& dst, std::uint32_t x, std::uint32_t y, std::uint32_t w,
                          std::uint32_t h, std::uint32_t first_layer, std::uint32_t layer_count) {
  VkBufferImageCopy region{};
  region.bufferOffset = offset;
  region.bufferRowLength = 0;  // tightly packed
  region.bufferImageHeight = 0;
  region.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, first_layer, layer_count};
  region.imageOffset = {static_cast<std::int32_t>(x), static_cast<std::int32_t>(y), 0};
  region.imageExtent = {w, h, 1};
  vkCmdCopyBufferToImage(cb, src.handle(), dst.handle(), VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1,
                         &region);
}

void copy_image_to_buffer(VkCommandBuffer cb, const Image& src, std::uint32_t x, std::uint32_t y,
                          std::uint32_t w, std::uint32_t h, const Buffer& dst, VkDeviceSize offset,
                          std::uint32_t first_layer, std::uint32_t layer_count) {
  VkBufferImageCopy region{};
  region.bufferOffset = offset;
  region.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, first_layer, layer_count};
  region.imageOffset = {static_cast<std::int32_t>(x), static_cast<std::int32_t>(y), 0};
  region.imageExtent = {w, h, 1};
  vkCmdCopyImageToBuffer(cb, src.handle(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, dst.handle(), 1,
                         &region);
}

void copy_buffer(VkCommandBuffer cb, const Buffer& src, VkDeviceSize src_offset, const Buffer& dst,
                 VkDeviceSize dst_offset, VkDeviceSize size) {
  VkBufferCopy region{src_offset, dst_offset, size};
  vkCmdCopyBuffer(cb, src.handle(), dst.handle(), 1, &region);
}

}  // namespace deepcanvas::client_gpu
