// Which Vulkan physical device the client uses, and why. The policy is a pure function over
// DeviceInfo records, so it is unit-tested without a GPU:
//   1. an explicit choice (--device, else env DEEPCANVAS_VK_DEVICE): a decimal index into the
//      enumeration order, or a case-insensitive substring of the device name. A choice that
//      matches nothing, or matches an unusable device, is an error (never silently ignored).
//   2. otherwise the usable device of the best type: discrete GPU > integrated GPU > virtual
//      GPU > CPU (lavapipe/llvmpipe) > other; ties go to the larger device-local heap, then to
//      the lower index.
// Usable = Vulkan 1.1 or newer, at least one queue family with compute, and subgroup basic,
// ballot and arithmetic operations in compute shaders with a subgroup size dividing 64 (the ray
// caster takes its work items per subgroup and sums its loop counts, raycast.comp
// "Scheduling").
// Thread-safe: pure functions.
#pragma once

#include <vulkan/vulkan.h>

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_gpu {

inline constexpr std::uint32_t kMinApiVersion = VK_API_VERSION_1_1;
inline constexpr const char* kDeviceEnvVar = "DEEPCANVAS_VK_DEVICE";

struct QueueFamilyInfo {
  std::uint32_t index = 0;
  VkQueueFlags flags = 0;
  std::uint32_t count = 0;
  std::uint32_t timestamp_valid_bits = 0;
};

struct DeviceInfo {
  std::uint32_t index = 0;  // position in vkEnumeratePhysicalDevices order
  std::string name;
  VkPhysicalDeviceType type = VK_PHYSICAL_DEVICE_TYPE_OTHER;
  std::uint32_t vendor_id = 0;
  std::uint32_t device_id = 0;
  std::uint32_t api_version = 0;
  std::uint32_t driver_version = 0;
  std::string driver_name;  // VkPhysicalDeviceDriverProperties (Vulkan 1.2), else empty
  std::string driver_info;
  std::uint32_t max_image_dimension_2d = 0;
  std::uint32_t max_image_array_layers = 0;
  std::uint32_t max_storage_buffer_range = 0;
  std::uint32_t max_push_constants_size = 0;
  std::uint32_t max_compute_workgroup_invocations = 0;
  float timestamp_period_ns = 0.0f;
  bool timestamp_compute_and_graphics = false;
  std::uint64_t device_local_bytes = 0;  // largest DEVICE_LOCAL heap
  // VkPhysicalDeviceSubgroupProperties (Vulkan 1.1).
  std::uint32_t subgroup_size = 0;
  VkShaderStageFlags subgroup_stages = 0;
  VkSubgroupFeatureFlags subgroup_operations = 0;
  std::vector<QueueFamilyInfo> queue_families;
};

struct DeviceChoice {
  std::uint32_t index = 0;  // DeviceInfo::index of the chosen device
  std::string reason;       // one sentence for `deepcanvas-client devices` and logs
};

std::string_view device_type_name(VkPhysicalDeviceType type) noexcept;
// "1.3.230"
std::string format_api_version(std::uint32_t version);
// "GRAPHICS|COMPUTE|TRANSFER"
std::string format_queue_flags(VkQueueFlags flags);

// Empty string when usable, else why not ("Vulkan 1.0 < 1.1", "no compute queue", "no subgroup
// ballot and arithmetic in compute shaders", "subgroup size 128 does not divide 64").
std::string unusable_reason(const DeviceInfo& device);
// Subgroup basic, ballot and arithmetic operations in compute shaders.
bool has_compute_subgroup_ops(const DeviceInfo& device);

// The policy above. `override_spec` empty = automatic. Errors: GpuErrc::no_device (empty list),
// device_not_found (override matches nothing; the message lists the devices),
// no_suitable_device (nothing usable, or the override names an unusable device).
Result<DeviceChoice> select_device(const std::vector<DeviceInfo>& devices,
                                   std::string_view override_spec);

// The override to use: `cli` when non-empty, else $DEEPCANVAS_VK_DEVICE, else empty.
std::string device_override_from(std::string_view cli);

}  // namespace deepcanvas::client_gpu
