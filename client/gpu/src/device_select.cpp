#include "deepcanvas/client_gpu/device_select.hpp"

#include <algorithm>
#include <cctype>
#include <cstdlib>

#include "deepcanvas/client_gpu/errors.hpp"

namespace deepcanvas::client_gpu {

namespace {

int type_rank(VkPhysicalDeviceType type) {
  switch (type) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU:
      return 4;
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU:
      return 3;
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU:
      return 2;
    case VK_PHYSICAL_DEVICE_TYPE_CPU:
      return 1;
    default:
      return 0;
  }
}

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

bool all_digits(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

std::string list_devices(const std::vector<DeviceInfo>& devices) {
  std::string out;
  for (const auto& d : devices) {
    if (!out.empty()) out += ", ";
    out += std::to_string(d.index) + ": '" + d.name + "'";
  }
  return out;
}

}  // namespace

std::string_view device_type_name(VkPhysicalDeviceType type) noexcept {
  switch (type) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU:
      return "discrete GPU";
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU:
      return "integrated GPU";
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU:
      return "virtual GPU";
    case VK_PHYSICAL_DEVICE_TYPE_CPU:
      return "CPU";
    default:
      return "other";
  }
}

std::string format_api_version(std::uint32_t version) {
  return std::to_string(VK_API_VERSION_MAJOR(version)) + "." +
         std::to_string(VK_API_VERSION_MINOR(version)) + "." +
         std::to_string(VK_API_VERSION_PATCH(version));
}

std::string format_queue_flags(VkQueueFlags flags) {
  std::string out;
  auto add = [&](VkQueueFlags bit, const char* name) {
    if ((flags & bit) == 0) return;
    if (!out.empty()) out += '|';
    out += name;
  };
  add(VK_QUEUE_GRAPHICS_BIT, "GRAPHICS");
  add(VK_QUEUE_COMPUTE_BIT, "COMPUTE");
  add(VK_QUEUE_TRANSFER_BIT, "TRANSFER");
  add(VK_QUEUE_SPARSE_BINDING_BIT, "SPARSE");
  add(VK_QUEUE_PROTECTED_BIT, "PROTECTED");
  return out.empty() ? std::string("none") : out;
}

bool has_compute_subgroup_ops(const DeviceInfo& device) {
  const VkSubgroupFeatureFlags ops = VK_SUBGROUP_FEATURE_BASIC_BIT |
                                     VK_SUBGROUP_FEATURE_BALLOT_BIT |
                                     VK_SUBGROUP_FEATURE_ARITHMETIC_BIT;
  return (device.subgroup_stages & VK_SHADER_STAGE_COMPUTE_BIT) != 0 &&
         (device.subgroup_operations & ops) == ops;
}

std::string unusable_reason(const DeviceInfo& device) {
  if (device.api_version < kMinApiVersion) {
    return "Vulkan " + format_api_version(device.api_version) + " < 1.1";
  }
  const bool compute =
      std::any_of(device.queue_families.begin(), device.queue_families.end(),
                  [](const QueueFamilyInfo& q) { return (q.flags & VK_QUEUE_COMPUTE_BIT) != 0; });
  if (!compute) return "no compute queue";
  if (!has_compute_subgroup_ops(device))
    return "no subgroup ballot and arithmetic in compute shaders";
  if (device.subgroup_size == 0 || device.subgroup_size > 64 || 64 % device.subgroup_size != 0) {
    return "subgroup size " + std::to_string(device.subgroup_size) + " does not divide 64";
  }
  return {};
}

Result<DeviceChoice> select_device(const std::vector<DeviceInfo>& devices,
                                   std::string_view override_spec) {
  if (devices.empty()) {
    return gpu_error(GpuErrc::no_device, "the Vulkan loader reports no physical device");
  }
  if (!override_spec.empty()) {
    const DeviceInfo* match = nullptr;
    if (all_digits(override_spec)) {
      const unsigned long want = std::strtoul(std::string(override_spec).c_str(), nullptr, 10);
      for (const auto& d : devices) {
        if (d.index == want) match = &d;
      }
    } else {
      const std::string needle = lower(override_spec);
      for (const auto& d : devices) {
        if (lower(d.name).find(needle) != std::string::npos) {
          match = &d;
          break;
        }
      }
    }
    if (match == nullptr) {
      return gpu_error(GpuErrc::device_not_found,
                       "no Vulkan device matches '" + std::string(override_spec) +
                           "' (an index or a name substring); devices: " + list_devices(devices));
    }
    if (std::string why = unusable_reason(*match); !why.empty()) {
      return gpu_error(GpuErrc::no_suitable_device,
                       "device " + std::to_string(match->index) + " '" + match->name +
                           "' was requested but cannot be used: " + why);
    }
    return DeviceChoice{match->index,
                        "requested explicitly as '" + std::string(override_spec) + "'"};
  }

  const DeviceInfo* best = nullptr;
  int usable = 0;
  for (const auto& d : devices) {
    if (!unusable_reason(d).empty()) continue;
    ++usable;
    if (best == nullptr) {
      best = &d;
      continue;
    }
    const int r = type_rank(d.type), rb = type_rank(best->type);
    if (r > rb || (r == rb && d.device_local_bytes > best->device_local_bytes)) best = &d;
  }
  if (best == nullptr) {
    std::string why;
    for (const auto& d : devices) {
      if (!why.empty()) why += "; ";
      why += "'" + d.name + "': " + unusable_reason(d);
    }
    return gpu_error(
        GpuErrc::no_suitable_device,
        "no Vulkan device has Vulkan 1.1, a compute queue and subgroup ballot and arithmetic (" +
            why + ")");
  }
  std::string reason;
  const std::string type(device_type_name(best->type));
  if (usable == 1) {
    reason = "the only usable device (" + type + ")";
  } else {
    reason = "best type among " + std::to_string(usable) + " usable devices (" + type +
             "; preference: discrete GPU > integrated GPU > virtual GPU > CPU)";
  }
  if (best->type == VK_PHYSICAL_DEVICE_TYPE_CPU) {
    reason += "; a software rasterizer (lavapipe): correct but slow";
  }
  return DeviceChoice{best->index, reason};
}

std::string device_override_from(std::string_view cli) {
  if (!cli.empty()) return std::string(cli);
  const char* env = std::getenv(kDeviceEnvVar);
  return env != nullptr ? std::string(env) : std::string();
}

}  // namespace deepcanvas::client_gpu
