// GPU memory objects: buffers, images, samplers (RAII, move-only), and the barrier and copy
// helpers the passes use. One VkDeviceMemory per object: the replica has a handful of large
// pool textures and staging rings, far below maxMemoryAllocationCount, so no sub-allocator.
//
// Why our own wrappers and not vk::raii (Vulkan-Hpp): in the Debian 12 headers (1.3.239) every
// vk::raii constructor throws vk::SystemError and there are no non-throwing factories, while
// buffers, images and pipelines are created at run time where a failure (out of device memory,
// device lost) must come back as a Result. Wrapping vk::raii in try/catch would also pull
// vulkan.hpp into every file that includes this header, several seconds of compile each.
//
// Ownership: every object keeps a pointer to its Context, which must outlive it.
// Threading: an object may be used from one thread at a time; mapped memory of a host-visible
// buffer may be written by one thread while the GPU reads other ranges of it.
#pragma once

#include <vulkan/vulkan.h>

#include <cstddef>
#include <cstdint>
#include <span>

#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_gpu {

enum class MemoryUse {
  device_local,  // GPU-only (DEVICE_LOCAL); not mapped
  upload,        // staging for uploads: HOST_VISIBLE (coherent preferred), persistently mapped
  readback,      // results read by the CPU: HOST_VISIBLE, HOST_CACHED preferred, mapped
};

class Buffer {
 public:
  Buffer() = default;
  ~Buffer();
  Buffer(Buffer&& other) noexcept;
  Buffer& operator=(Buffer&& other) noexcept;
  Buffer(const Buffer&) = delete;
  Buffer& operator=(const Buffer&) = delete;

  // Errors: bad_argument (size 0), out_of_memory.
  static Result<Buffer> create(const Context& ctx, VkDeviceSize size, VkBufferUsageFlags usage,
                               MemoryUse use);

  VkBuffer handle() const noexcept { return buffer_; }
  VkDeviceSize size() const noexcept { return size_; }
  // The persistent mapping (upload / readback buffers), nullptr for device_local.
  void* mapped() const noexcept { return mapped_; }
  bool coherent() const noexcept { return coherent_; }
  template <class T>
  std::span<T> mapped_span() const noexcept {
    return {static_cast<T*>(mapped_), mapped_ ? static_cast<std::size_t>(size_ / sizeof(T)) : 0};
  }
  // Make CPU writes visible to the GPU / GPU writes visible to the CPU (no-ops when coherent).
  Result<void> flush(VkDeviceSize offset = 0, VkDeviceSize size = VK_WHOLE_SIZE) const;
  Result<void> invalidate(VkDeviceSize offset = 0, VkDeviceSize size = VK_WHOLE_SIZE) const;

 private:
  void destroy() noexcept;
  const Context* ctx_ = nullptr;
  VkBuffer buffer_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  VkDeviceSize size_ = 0;
  VkDeviceSize alloc_size_ = 0;
  void* mapped_ = nullptr;
  bool coherent_ = true;
};

struct ImageDesc {
  VkFormat format = VK_FORMAT_R32_UINT;
  std::uint32_t width = 1;
  std::uint32_t height = 1;
  std::uint32_t layers = 1;  // > 1: a 2D array (view type 2D_ARRAY); also 2D_ARRAY when
  bool array = false;        // `array` is set with one layer, so shaders can bind it alike
  VkImageUsageFlags usage = VK_IMAGE_USAGE_SAMPLED_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT;
};

// A device-local 2D (array) colour image with one mip level and a view over all layers.
// Created in VK_IMAGE_LAYOUT_UNDEFINED; the caller transitions it (image_barrier()).
class Image {
 public:
  Image() = default;
  ~Image();
  Image(Image&& other) noexcept;
  Image& operator=(Image&& other) noexcept;
  Image(const Image&) = delete;
  Image& operator=(const Image&) = delete;

  // Errors: bad_argument (zero or over-limit extent, format lacking the usage's features),
  // out_of_memory.
  static Result<Image> create(const Context& ctx, const ImageDesc& desc);

  VkImage handle() const noexcept { return image_; }
  VkImageView view() const noexcept { return view_; }
  const ImageDesc& desc() const noexcept { return desc_; }

 private:
  void destroy() noexcept;
  const Context* ctx_ = nullptr;
  VkImage image_ = VK_NULL_HANDLE;
  VkImageView view_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  ImageDesc desc_;
};

// A nearest-filter, clamp-to-edge sampler: what texelFetch on the integer pool textures needs.
class Sampler {
 public:
  Sampler() = default;
  ~Sampler();
  Sampler(Sampler&& other) noexcept;
  Sampler& operator=(Sampler&& other) noexcept;
  Sampler(const Sampler&) = delete;
  Sampler& operator=(const Sampler&) = delete;
  static Result<Sampler> create_nearest(const Context& ctx);
  VkSampler handle() const noexcept { return sampler_; }

 private:
  const Context* ctx_ = nullptr;
  VkSampler sampler_ = VK_NULL_HANDLE;
};

// ---- command helpers (record into `cb`) ----
void image_barrier(VkCommandBuffer cb, const Image& image, VkImageLayout from, VkImageLayout to,
                   VkPipelineStageFlags src_stage, VkAccessFlags src_access,
                   VkPipelineStageFlags dst_stage, VkAccessFlags dst_access);
void buffer_barrier(VkCommandBuffer cb, const Buffer& buffer, VkPipelineStageFlags src_stage,
                    VkAccessFlags src_access, VkPipelineStageFlags dst_stage,
                    VkAccessFlags dst_access);
// Copies a tightly packed rectangle of texels (layers consecutive) from `src` at `offset`.
void copy_buffer_to_image(VkCommandBuffer cb, const Buffer& src, VkDeviceSize offset,
                          const Image& dst, std::uint32_t x, std::uint32_t y, std::uint32_t w,
                          std::uint32_t h, std::uint32_t first_layer = 0,
                          std::uint32_t layer_count = 1);
void copy_image_to_buffer(VkCommandBuffer cb, const Image& src, std::uint32_t x, std::uint32_t y,
                          std::uint32_t w, std::uint32_t h, const Buffer& dst, VkDeviceSize offset,
                          std::uint32_t first_layer = 0, std::uint32_t layer_count = 1);
void copy_buffer(VkCommandBuffer cb, const Buffer& src, VkDeviceSize src_offset, const Buffer& dst,
                 VkDeviceSize dst_offset, VkDeviceSize size);

// Bytes per texel of the integer/colour formats the replica uses (0 for others).
std::uint32_t format_texel_bytes(VkFormat format) noexcept;

}  // namespace deepcanvas::client_gpu
