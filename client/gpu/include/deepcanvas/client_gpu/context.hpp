// The Vulkan context of the client: instance, chosen physical device, logical device, queues.
// Headless (no surface, no window-system extensions) unless ContextBuilder::present_to() asks
// for a window surface (the studio window). Set up builder-style:
//
//   auto ctx = ContextBuilder().app_name("deepcanvas-client").device(cli_device).build();
//   if (!ctx) { print ctx.error().message; }   // named errors, see errors.hpp
//
// Device choice: device_select.hpp (override by --device / DEEPCANVAS_VK_DEVICE, else discrete >
// integrated > virtual > CPU). Validation layers: off unless DEEPCANVAS_VK_VALIDATION=1 (or
// .validation(true)); when the Khronos layer is not installed the context is still built and
// validation_note() says so; validation is never required.
//
// Threading: a Context may be used from several threads. Queue::submit() serialises on the
// queue's mutex (Vulkan requires external synchronisation of a VkQueue); everything else is
// immutable after build(). Objects made from a Context (buffers, pipelines) must be destroyed
// before it; the Context must outlive them (they keep a raw pointer to it).
#pragma once

#include <vulkan/vulkan.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "deepcanvas/client_gpu/device_select.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_gpu {

inline constexpr const char* kValidationEnvVar = "DEEPCANVAS_VK_VALIDATION";

// Owns a VkInstance. Move-only.
class Instance {
 public:
  Instance() = default;
  ~Instance();
  Instance(Instance&& other) noexcept;
  Instance& operator=(Instance&& other) noexcept;
  Instance(const Instance&) = delete;
  Instance& operator=(const Instance&) = delete;

  VkInstance handle() const noexcept { return instance_; }
  // The Vulkan version this instance was created for (min(loader, 1.3)).
  std::uint32_t api_version() const noexcept { return api_version_; }
  // What the loader itself reports (vkEnumerateInstanceVersion).
  std::uint32_t loader_version() const noexcept { return loader_version_; }
  bool validation_enabled() const noexcept { return validation_; }
  // Empty, or why validation was requested but is off (layer missing).
  const std::string& validation_note() const noexcept { return validation_note_; }
  // Validation messages of severity error seen so far (0 when validation is off).
  std::uint64_t validation_errors() const noexcept;

  // Every physical device with its properties, in enumeration order. Error no_device when the
  // loader reports none (the message says how to point the loader at lavapipe).
  Result<std::vector<DeviceInfo>> devices() const;
  VkPhysicalDevice physical_device(std::uint32_t index) const noexcept;

 private:
  friend class InstanceBuilder;
  struct Messenger;
  void destroy() noexcept;

  VkInstance instance_ = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
  std::unique_ptr<std::atomic<std::uint64_t>> validation_errors_;
  std::vector<VkPhysicalDevice> physical_;
  std::uint32_t api_version_ = 0;
  std::uint32_t loader_version_ = 0;
  bool validation_ = false;
  std::string validation_note_;
};

// A context made through another API that creates the Vulkan instance and device itself: an
// OpenXR runtime (XR_KHR_vulkan_enable2: xrCreateVulkanInstanceKHR, xrGetVulkanGraphicsDevice2KHR,
// xrCreateVulkanDeviceKHR add what the runtime needs and pick the device it drives). Each hook
// gets the create info the builder made and returns the handle, or an error that build()
// returns. The Context owns what the hooks made (destroyed with vkDestroyDevice /
// vkDestroyInstance, as OpenXR specifies).
struct VulkanCreationHooks {
  std::function<Result<VkInstance>(const VkInstanceCreateInfo&)> create_instance;
  std::function<Result<VkPhysicalDevice>(VkInstance)> physical_device;
  std::function<Result<VkDevice>(VkPhysicalDevice, const VkDeviceCreateInfo&)> create_device;
};

class InstanceBuilder {
 public:
  InstanceBuilder& app_name(std::string name) {
    app_name_ = std::move(name);
    return *this;
  }
  // Requests VK_LAYER_KHRONOS_validation (used only if installed). Default: the env var.
  InstanceBuilder& validation(bool on) {
    validation_ = on;
    validation_set_ = true;
    return *this;
  }
  // Errors: no_driver (no ICD; the message names VK_ICD_FILENAMES / VK_DRIVER_FILES and the
  // lavapipe manifest), instance_failed.
  Result<Instance> build() const;

 private:
  std::string app_name_ = "deepcanvas";
  bool validation_ = false;
  bool validation_set_ = false;
  std::vector<std::string> extensions_;  // required (present_to); missing ones fail build()
  std::function<Result<VkInstance>(const VkInstanceCreateInfo&)> create_instance_;  // hooks
  friend class ContextBuilder;
};

// A device queue. submit() is thread-safe; the handle may be shared by two Queue roles (compute
// and transfer) when the device has only one queue, in which case they share the mutex too.
class Queue {
 public:
  VkQueue handle() const noexcept { return queue_; }
  std::uint32_t family() const noexcept { return family_; }
  std::uint32_t timestamp_valid_bits() const noexcept { return timestamp_bits_; }
  Result<void> submit(const VkSubmitInfo& info, VkFence fence) const;
  // vkQueuePresentKHR under the queue's mutex (contexts made with present_to() only). The
  // VkResult is returned as is: VK_SUBOPTIMAL_KHR / VK_ERROR_OUT_OF_DATE_KHR ask the caller to
  // recreate its swapchain, they are not failures.
  VkResult present(const VkPresentInfoKHR& info) const;

 private:
  friend class ContextBuilder;
  VkQueue queue_ = VK_NULL_HANDLE;
  std::uint32_t family_ = 0;
  std::uint32_t timestamp_bits_ = 0;
  std::shared_ptr<std::mutex> mutex_;
};

class Context {
 public:
  ~Context();
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  VkInstance instance() const noexcept { return instance_.handle(); }
  const Instance& instance_object() const noexcept { return instance_; }
  VkPhysicalDevice physical_device() const noexcept { return physical_; }
  VkDevice device() const noexcept { return device_; }
  const DeviceInfo& info() const noexcept { return info_; }
  const DeviceChoice& choice() const noexcept { return choice_; }
  const VkPhysicalDeviceLimits& limits() const noexcept { return limits_; }
  const VkPhysicalDeviceMemoryProperties& memory_properties() const noexcept { return memory_; }

  // The queue for compute passes, and the one for uploads (a dedicated transfer family or a
  // second queue when the device has one, else the same queue).
  const Queue& compute_queue() const noexcept { return compute_; }
  const Queue& transfer_queue() const noexcept { return transfer_; }
  // The distinct queue families in use: resources are created VK_SHARING_MODE_CONCURRENT over
  // them when there are two, so no ownership transfers are needed.
  const std::vector<std::uint32_t>& queue_families() const noexcept { return families_; }

  // The index of a memory type allowed by `type_bits` with all `required` flags, preferring one
  // that also has `preferred`. Error out_of_memory when none fits.
  Result<std::uint32_t> find_memory_type(std::uint32_t type_bits, VkMemoryPropertyFlags required,
                                         VkMemoryPropertyFlags preferred) const;

  // Records a command buffer with `record`, submits it to `queue` and waits for its fence (up to
  // fence_timeout()). Blocking; thread-safe. Errors: submit_failed, timeout, device_lost.
  Result<void> submit_once(const Queue& queue,
                           const std::function<void(VkCommandBuffer)>& record) const;
  std::chrono::nanoseconds fence_timeout() const noexcept { return fence_timeout_; }

  // True when `queue` can write timestamps (timestampValidBits > 0 and a nonzero period).
  bool timestamps_supported(const Queue& queue) const noexcept;

  Result<void> wait_idle() const;

  // The window surface made by ContextBuilder::present_to(), VK_NULL_HANDLE when headless. The
  // compute queue can present to it and has graphics too (for overlays drawn in render passes).
  VkSurfaceKHR surface() const noexcept { return surface_; }

 private:
  friend class ContextBuilder;
  Context() = default;

  Instance instance_;
  VkSurfaceKHR surface_ = VK_NULL_HANDLE;  // destroyed before the instance
  VkPhysicalDevice physical_ = VK_NULL_HANDLE;
  VkDevice device_ = VK_NULL_HANDLE;
  DeviceInfo info_;
  DeviceChoice choice_;
  VkPhysicalDeviceLimits limits_{};
  VkPhysicalDeviceMemoryProperties memory_{};
  Queue compute_;
  Queue transfer_;
  std::vector<std::uint32_t> families_;
  std::chrono::nanoseconds fence_timeout_{std::chrono::seconds(120)};
};

class ContextBuilder {
 public:
  ContextBuilder& app_name(std::string name) {
    instance_.app_name(std::move(name));
    return *this;
  }
  // An index or name substring; empty = DEEPCANVAS_VK_DEVICE, else automatic.
  ContextBuilder& device(std::string override_spec) {
    device_ = std::move(override_spec);
    return *this;
  }
  ContextBuilder& validation(bool on) {
    instance_.validation(on);
    return *this;
  }
  ContextBuilder& fence_timeout(std::chrono::nanoseconds timeout) {
    fence_timeout_ = timeout;
    return *this;
  }
  // Presentation to a window: the instance gets `instance_extensions` (a window system's, e.g.
  // glfwGetRequiredInstanceExtensions()), `make_surface` makes the surface on that instance (the
  // Context then owns it), the device gets VK_KHR_swapchain, and the compute queue's family must
  // have graphics and compute and be able to present to the surface. Errors: the extensions or
  // the surface missing (unsupported), a device that cannot present (no_suitable_device).
  using SurfaceFactory = std::function<Result<VkSurfaceKHR>(VkInstance)>;
  ContextBuilder& present_to(std::vector<std::string> instance_extensions,
                             SurfaceFactory make_surface) {
    instance_.extensions_ = std::move(instance_extensions);
    make_surface_ = std::move(make_surface);
    return *this;
  }
  // The instance, the physical device and the device made by `hooks` (an OpenXR runtime's)
  // instead of vkCreateInstance, select_device() and vkCreateDevice. The device must still be
  // usable (device_select.hpp): no_suitable_device names why when it is not.
  ContextBuilder& created_by(VulkanCreationHooks hooks) {
    instance_.create_instance_ = hooks.create_instance;
    hooks_ = std::move(hooks);
    return *this;
  }
  // Errors: those of InstanceBuilder::build() and select_device(), device_failed.
  Result<std::unique_ptr<Context>> build() const;

 private:
  InstanceBuilder instance_;
  VulkanCreationHooks hooks_;
  SurfaceFactory make_surface_;
  std::string device_;
  std::chrono::nanoseconds fence_timeout_{std::chrono::seconds(120)};
};

// Text for "no device" situations: how to make the loader see lavapipe.
std::string no_device_hint();

}  // namespace deepcanvas::client_gpu
