#include "deepcanvas/client_gpu/errors.hpp"

// vulkan.hpp costs a few seconds per translation unit: only this file includes it, for the
// generated result names, so the other client_gpu sources keep the C header.
#include <vulkan/vulkan.hpp>
#include <vulkan/vulkan_to_string.hpp>

#include <array>

namespace deepcanvas::client_gpu {

namespace {

constexpr std::array<GpuErrc, kGpuErrcCount> kAllErrc = {
    GpuErrc::no_driver,          GpuErrc::instance_failed,  GpuErrc::no_device,
    GpuErrc::no_suitable_device, GpuErrc::device_not_found, GpuErrc::device_failed,
    GpuErrc::out_of_memory,      GpuErrc::bad_argument,     GpuErrc::shader_failed,
    GpuErrc::submit_failed,      GpuErrc::timeout,          GpuErrc::device_lost,
    GpuErrc::unsupported,        GpuErrc::wrong_result};

constexpr std::string_view kPrefix = "vulkan.";

Errc to_errc(GpuErrc code) {
  switch (code) {
    case GpuErrc::no_driver:
    case GpuErrc::no_device:
    case GpuErrc::no_suitable_device:
    case GpuErrc::unsupported:
      return Errc::unsupported;
    case GpuErrc::device_not_found:
      return Errc::not_found;
    case GpuErrc::out_of_memory:
      return Errc::out_of_memory;
    case GpuErrc::bad_argument:
      return Errc::invalid_argument;
    case GpuErrc::timeout:
      return Errc::limit_exceeded;
    case GpuErrc::instance_failed:
    case GpuErrc::device_failed:
    case GpuErrc::shader_failed:
    case GpuErrc::submit_failed:
    case GpuErrc::device_lost:
    case GpuErrc::wrong_result:
      return Errc::internal;
  }
  return Errc::internal;
}

}  // namespace

std::string_view gpu_errc_name(GpuErrc code) noexcept {
  switch (code) {
    case GpuErrc::no_driver:
      return "no_driver";
    case GpuErrc::instance_failed:
      return "instance_failed";
    case GpuErrc::no_device:
      return "no_device";
    case GpuErrc::no_suitable_device:
      return "no_suitable_device";
    case GpuErrc::device_not_found:
      return "device_not_found";
    case GpuErrc::device_failed:
      return "device_failed";
    case GpuErrc::out_of_memory:
      return "out_of_memory";
    case GpuErrc::bad_argument:
      return "bad_argument";
    case GpuErrc::shader_failed:
      return "shader_failed";
    case GpuErrc::submit_failed:
      return "submit_failed";
    case GpuErrc::timeout:
      return "timeout";
    case GpuErrc::device_lost:
      return "device_lost";
    case GpuErrc::unsupported:
      return "unsupported";
    case GpuErrc::wrong_result:
      return "wrong_result";
  }
  return "unknown";
}

std::string vk_result_name(VkResult result) {
  return vk::to_string(static_cast<vk::Result>(result));
}

Error gpu_error(GpuErrc code, std::string message, VkResult vk) {
  std::string text(kPrefix);
  text += gpu_errc_name(code);
  text += ": ";
  text += message;
  if (vk != VK_SUCCESS) {
    text += " (";
    text += vk_result_name(vk);
    text += ")";
  }
  return make_error(to_errc(code), std::move(text));
}

Error gpu_error_from(VkResult vk, GpuErrc fallback, std::string message) {
  GpuErrc code = fallback;
  if (vk == VK_ERROR_OUT_OF_HOST_MEMORY || vk == VK_ERROR_OUT_OF_DEVICE_MEMORY ||
      vk == VK_ERROR_OUT_OF_POOL_MEMORY || vk == VK_ERROR_FRAGMENTED_POOL) {
    code = GpuErrc::out_of_memory;
  } else if (vk == VK_ERROR_DEVICE_LOST) {
    code = GpuErrc::device_lost;
  } else if (vk == VK_TIMEOUT) {
    code = GpuErrc::timeout;
  }
  return gpu_error(code, std::move(message), vk);
}

std::optional<GpuErrc> gpu_errc_of(const Error& error) {
  const std::string_view msg = error.message;
  if (msg.substr(0, kPrefix.size()) != kPrefix) return std::nullopt;
  const std::string_view rest = msg.substr(kPrefix.size());
  for (GpuErrc code : kAllErrc) {
    const std::string_view name = gpu_errc_name(code);
    if (rest.size() > name.size() && rest.substr(0, name.size()) == name &&
        rest[name.size()] == ':') {
      return code;
    }
  }
  return std::nullopt;
}

}  // namespace deepcanvas::client_gpu
