// Named errors of the Vulkan layer. Every client_gpu function returns deepcanvas::Result; the
// Error's message starts with "vulkan.<name>: " (the GpuErrc below) so callers and logs can tell
// a missing driver from a lost device without parsing Vulkan codes, and gpu_errc_of() recovers
// the name from an Error. Thread-safe: pure functions.
#pragma once

#include <vulkan/vulkan.h>

#include <optional>
#include <string>
#include <string_view>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_gpu {

enum class GpuErrc : int {
  no_driver,           // the loader found no ICD (no Vulkan driver installed or visible)
  instance_failed,     // vkCreateInstance failed for another reason
  no_device,           // the loader found drivers but no physical device
  no_suitable_device,  // devices exist but none has a compute queue and Vulkan >= 1.1
  device_not_found,    // --device / DEEPCANVAS_VK_DEVICE matched no device
  device_failed,       // vkCreateDevice failed
  out_of_memory,       // host or device memory exhausted, or no memory type fits
  bad_argument,        // a size, format or dimension outside the device's limits
  shader_failed,       // shader module or pipeline creation failed (bad SPIR-V, limits)
  submit_failed,       // queue submission or command recording failed
  timeout,             // a fence did not signal within the wait limit
  device_lost,         // VK_ERROR_DEVICE_LOST: the device is gone, the context is unusable
  unsupported,         // a feature this code needs is missing (e.g. timestamps)
  wrong_result,        // the device computed a wrong result (driver bug or broken hardware)
};
inline constexpr int kGpuErrcCount = 14;

std::string_view gpu_errc_name(GpuErrc code) noexcept;
// The Vulkan-Hpp name of a result (vk::to_string: "ErrorOutOfDeviceMemory", "Timeout", ...);
// "invalid ( <hex> )" for codes the installed headers do not name.
std::string vk_result_name(VkResult result);

// Builds the Error: message "vulkan.<name>: <message>[ (<VkResult>)]", Errc mapped from the name.
Error gpu_error(GpuErrc code, std::string message, VkResult vk = VK_SUCCESS);
// Maps a failed VkResult to the closest GpuErrc (out of memory, device lost, ...), `fallback`
// otherwise.
Error gpu_error_from(VkResult vk, GpuErrc fallback, std::string message);
// The GpuErrc named at the start of an Error built by gpu_error(), or nullopt.
std::optional<GpuErrc> gpu_errc_of(const Error& error);

}  // namespace deepcanvas::client_gpu
