#include "deepcanvas/client_gpu/context.hpp"

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <filesystem>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/client_gpu/errors.hpp"
#include "driver_leak_scope.hpp"

namespace deepcanvas::client_gpu {

namespace {

constexpr const char* kValidationLayer = "VK_LAYER_KHRONOS_validation";
constexpr const char* kLavapipeManifest = "/usr/share/vulkan/icd.d/lvp_icd.x86_64.json";

bool env_flag(const char* name) {
  const char* v = std::getenv(name);
  return v != nullptr && (std::strcmp(v, "1") == 0 || std::strcmp(v, "true") == 0 ||
                          std::strcmp(v, "on") == 0 || std::strcmp(v, "yes") == 0);
}

bool has_layer(const char* name) {
  std::uint32_t count = 0;
  if (vkEnumerateInstanceLayerProperties(&count, nullptr) != VK_SUCCESS) return false;
  std::vector<VkLayerProperties> layers(count);
  if (vkEnumerateInstanceLayerProperties(&count, layers.data()) != VK_SUCCESS) return false;
  return std::any_of(layers.begin(), layers.end(), [&](const VkLayerProperties& l) {
    return std::strcmp(l.layerName, name) == 0;
  });
}

bool has_instance_extension(const char* name) {
  std::uint32_t count = 0;
  if (vkEnumerateInstanceExtensionProperties(nullptr, &count, nullptr) != VK_SUCCESS) return false;
  std::vector<VkExtensionProperties> exts(count);
  if (vkEnumerateInstanceExtensionProperties(nullptr, &count, exts.data()) != VK_SUCCESS) {
    return false;
  }
  return std::any_of(exts.begin(), exts.end(), [&](const VkExtensionProperties& e) {
    return std::strcmp(e.extensionName, name) == 0;
  });
}

VKAPI_ATTR VkBool32 VKAPI_CALL debug_callback(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                              VkDebugUtilsMessageTypeFlagsEXT /*types*/,
                                              const VkDebugUtilsMessengerCallbackDataEXT* data,
                                              void* user) {
  if ((severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT) != 0) {
    static_cast<std::atomic<std::uint64_t>*>(user)->fetch_add(1, std::memory_order_relaxed);
  }
  // Validation is a debugging aid the user asked for with DEEPCANVAS_VK_VALIDATION=1: every
  // message is logged (the logger's rate limit keeps a message repeated per frame in bounds).
  // The messenger asks for warnings and errors only.
  const base::LogLevel level = (severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT) != 0
                                   ? base::LogLevel::error
                                   : base::LogLevel::warn;
  base::log_event(
      level, "vulkan_validation",
      {{"message", data != nullptr && data->pMessage != nullptr ? data->pMessage : ""}});
  return VK_FALSE;
}

}  // namespace

std::string no_device_hint() {
  std::string hint =
      "No Vulkan driver (ICD) is visible to the loader. For a machine without a GPU install "
      "mesa-vulkan-drivers (lavapipe, a CPU implementation), or point the loader at a driver "
      "manifest: VK_ICD_FILENAMES=";
  hint += kLavapipeManifest;
  hint += " (VK_DRIVER_FILES on loaders >= 1.3.207).";
  std::error_code ec;
  hint += std::filesystem::exists(kLavapipeManifest, ec)
              ? " That manifest exists on this machine."
              : " That manifest is NOT present on this machine.";
  for (const char* var : {"VK_ICD_FILENAMES", "VK_DRIVER_FILES"}) {
    if (const char* v = std::getenv(var); v != nullptr) {
      hint += std::string(" ") + var + " is set to '" + v + "'.";
    }
  }
  return hint;
}

// ---- Instance ----------------------------------------------------------------------------

Instance::~Instance() {
  destroy();
}

Instance::Instance(Instance&& other) noexcept {
  *this = std::move(other);
}

Instance& Instance::operator=(Instance&& other) noexcept {
  if (this != &other) {
    destroy();
    instance_ = std::exchange(other.instance_, VK_NULL_HANDLE);
    messenger_ = std::exchange(other.messenger_, VK_NULL_HANDLE);
    validation_errors_ = std::move(other.validation_errors_);
    physical_ = std::move(other.physical_);
    api_version_ = other.api_version_;
    loader_version_ = other.loader_version_;
    validation_ = other.validation_;
    validation_note_ = std::move(other.validation_note_);
  }
  return *this;
}

void Instance::destroy() noexcept {
  if (instance_ == VK_NULL_HANDLE) return;
  if (messenger_ != VK_NULL_HANDLE) {
    auto destroy_fn = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
    if (destroy_fn != nullptr) destroy_fn(instance_, messenger_, nullptr);
    messenger_ = VK_NULL_HANDLE;
  }
  vkDestroyInstance(instance_, nullptr);
  instance_ = VK_NULL_HANDLE;
}

std::uint64_t Instance::validation_errors() const noexcept {
  return validation_errors_ ? validation_errors_->load(std::memory_order_relaxed) : 0;
}

VkPhysicalDevice Instance::physical_device(std::uint32_t index) const noexcept {
  return index < physical_.size() ? physical_[index] : VK_NULL_HANDLE;
}

Result<std::vector<DeviceInfo>> Instance::devices() const {
  if (physical_.empty()) return gpu_error(GpuErrc::no_device, no_device_hint());
  std::vector<DeviceInfo> out;
  for (std::uint32_t i = 0; i < physical_.size(); ++i) {
    VkPhysicalDevice pd = physical_[i];
    DeviceInfo d;
    d.index = i;
    VkPhysicalDeviceProperties props{};
    vkGetPhysicalDeviceProperties(pd, &props);
    if (props.apiVersion >= VK_API_VERSION_1_1) {
      // One query for the subgroup properties (Vulkan 1.1) and, from 1.2, the driver's name.
      VkPhysicalDeviceSubgroupProperties subgroup{};
      subgroup.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES;
      VkPhysicalDeviceDriverProperties driver{};
      driver.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES;
      const bool has_driver =
          props.apiVersion >= VK_API_VERSION_1_2 && api_version_ >= VK_API_VERSION_1_2;
      if (has_driver) subgroup.pNext = &driver;
      VkPhysicalDeviceProperties2 props2{};
      props2.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2;
      props2.pNext = &subgroup;
      vkGetPhysicalDeviceProperties2(pd, &props2);
      d.subgroup_size = subgroup.subgroupSize;
      d.subgroup_stages = subgroup.supportedStages;
      d.subgroup_operations = subgroup.supportedOperations;
      if (has_driver) {
        d.driver_name = driver.driverName;
        d.driver_info = driver.driverInfo;
      }
    }
    d.name = props.deviceName;
    d.type = props.deviceType;
    d.vendor_id = props.vendorID;
    d.device_id = props.deviceID;
    d.api_version = props.apiVersion;
    d.driver_version = props.driverVersion;
    d.max_image_dimension_2d = props.limits.maxImageDimension2D;
    d.max_image_array_layers = props.limits.maxImageArrayLayers;
    d.max_storage_buffer_range = props.limits.maxStorageBufferRange;
    d.max_push_constants_size = props.limits.maxPushConstantsSize;
    d.max_compute_workgroup_invocations = props.limits.maxComputeWorkGroupInvocations;
    d.timestamp_period_ns = props.limits.timestampPeriod;
    d.timestamp_compute_and_graphics = props.limits.timestampComputeAndGraphics == VK_TRUE;

    VkPhysicalDeviceMemoryProperties mem{};
    vkGetPhysicalDeviceMemoryProperties(pd, &mem);
    for (std::uint32_t h = 0; h < mem.memoryHeapCount; ++h) {
      if ((mem.memoryHeaps[h].flags & VK_MEMORY_HEAP_DEVICE_LOCAL_BIT) != 0) {
        d.device_local_bytes =
            std::max<std::uint64_t>(d.device_local_bytes, mem.memoryHeaps[h].size);
      }
    }
    std::uint32_t qcount = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(pd, &qcount, nullptr);
    std::vector<VkQueueFamilyProperties> qprops(qcount);
    vkGetPhysicalDeviceQueueFamilyProperties(pd, &qcount, qprops.data());
    for (std::uint32_t q = 0; q < qcount; ++q) {
      d.queue_families.push_back(
          {q, qprops[q].queueFlags, qprops[q].queueCount, qprops[q].timestampValidBits});
    }
    out.push_back(std::move(d));
  }
  return out;
}

Result<Instance> InstanceBuilder::build() const {
  std::uint32_t loader_version = VK_API_VERSION_1_0;
  if (vkEnumerateInstanceVersion(&loader_version) != VK_SUCCESS)
    loader_version = VK_API_VERSION_1_0;
  if (loader_version < VK_API_VERSION_1_1) {
    return gpu_error(GpuErrc::instance_failed,
                     "the Vulkan loader supports only " + format_api_version(loader_version) +
                         "; deepcanvas needs 1.1 or newer (update libvulkan1)");
  }
  Instance inst;
  inst.loader_version_ = loader_version;
  inst.api_version_ = std::min<std::uint32_t>(loader_version, VK_API_VERSION_1_3);

  const bool want_validation = validation_set_ ? validation_ : env_flag(kValidationEnvVar);
  std::vector<const char*> layers;
  std::vector<const char*> extensions;
  if (want_validation) {
    if (!has_layer(kValidationLayer)) {
      inst.validation_note_ = std::string("validation requested but ") + kValidationLayer +
                              " is not installed (Debian: vulkan-validationlayers); running "
                              "without it";
    } else {
      layers.push_back(kValidationLayer);
      inst.validation_ = true;
      if (has_instance_extension(VK_EXT_DEBUG_UTILS_EXTENSION_NAME)) {
        extensions.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
      }
    }
  }
  for (const std::string& e : extensions_) {
    if (!has_instance_extension(e.c_str()))
      return gpu_error(GpuErrc::unsupported,
                       "the Vulkan instance lacks " + e + ", needed to show a window");
    extensions.push_back(e.c_str());
  }
  VkInstanceCreateFlags flags = 0;
  // Lets the loader list portability (non-conformant) drivers such as MoltenVK too.
  if (has_instance_extension(VK_KHR_PORTABILITY_ENUMERATION_EXTENSION_NAME)) {
    extensions.push_back(VK_KHR_PORTABILITY_ENUMERATION_EXTENSION_NAME);
    flags |= VK_INSTANCE_CREATE_ENUMERATE_PORTABILITY_BIT_KHR;
  }

  VkApplicationInfo app{};
  app.sType = VK_STRUCTURE_TYPE_APPLICATION_INFO;
  app.pApplicationName = app_name_.c_str();
  app.applicationVersion = VK_MAKE_API_VERSION(0, 0, 1, 0);
  app.pEngineName = "deepcanvas";
  app.engineVersion = VK_MAKE_API_VERSION(0, 0, 1, 0);
  app.apiVersion = inst.api_version_;

  VkInstanceCreateInfo ci{};
  ci.sType = VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO;
  ci.flags = flags;
  ci.pApplicationInfo = &app;
  ci.enabledLayerCount = static_cast<std::uint32_t>(layers.size());
  ci.ppEnabledLayerNames = layers.data();
  ci.enabledExtensionCount = static_cast<std::uint32_t>(extensions.size());
  ci.ppEnabledExtensionNames = extensions.data();

  if (create_instance_) {
    auto made = create_instance_(ci);
    if (!made) return std::move(made).error();
    inst.instance_ = *made;
  }
  const VkResult r =
      create_instance_ ? VK_SUCCESS : vkCreateInstance(&ci, nullptr, &inst.instance_);
  if (r == VK_ERROR_INCOMPATIBLE_DRIVER) {
    inst.instance_ = VK_NULL_HANDLE;
    return gpu_error(GpuErrc::no_driver, no_device_hint(), r);
  }
  if (r != VK_SUCCESS) {
    inst.instance_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::instance_failed, "vkCreateInstance failed");
  }
  detail::keep_drivers_mapped_for_leak_reports();

  if (inst.validation_ &&
      std::find(extensions.begin(), extensions.end(),
                std::string_view(VK_EXT_DEBUG_UTILS_EXTENSION_NAME)) != extensions.end()) {
    inst.validation_errors_ = std::make_unique<std::atomic<std::uint64_t>>(0);
    auto create_fn = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(inst.instance_, "vkCreateDebugUtilsMessengerEXT"));
    if (create_fn != nullptr) {
      VkDebugUtilsMessengerCreateInfoEXT mi{};
      mi.sType = VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT;
      mi.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT |
                           VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
      mi.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT |
                       VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                       VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
      mi.pfnUserCallback = debug_callback;
      mi.pUserData = inst.validation_errors_.get();
      if (create_fn(inst.instance_, &mi, nullptr, &inst.messenger_) != VK_SUCCESS) {
        inst.messenger_ = VK_NULL_HANDLE;
      }
    }
  }

  std::uint32_t count = 0;
  VkResult er = vkEnumeratePhysicalDevices(inst.instance_, &count, nullptr);
  if (er == VK_SUCCESS && count > 0) {
    inst.physical_.resize(count);
    er = vkEnumeratePhysicalDevices(inst.instance_, &count, inst.physical_.data());
    inst.physical_.resize(count);
  }
  if (er != VK_SUCCESS && er != VK_INCOMPLETE) {
    return gpu_error_from(er, GpuErrc::instance_failed, "vkEnumeratePhysicalDevices failed");
  }
  return inst;
}

// ---- Queue -----------------------------------------------------------------------------------

Result<void> Queue::submit(const VkSubmitInfo& info, VkFence fence) const {
  VkResult r;
  {
    std::lock_guard lock(*mutex_);
    r = vkQueueSubmit(queue_, 1, &info, fence);
  }
  if (r != VK_SUCCESS) return gpu_error_from(r, GpuErrc::submit_failed, "vkQueueSubmit failed");
  return {};
}

VkResult Queue::present(const VkPresentInfoKHR& info) const {
  std::lock_guard lock(*mutex_);
  return vkQueuePresentKHR(queue_, &info);
}

// ---- Context -------------------------------------------------------------------------------

Context::~Context() {
  if (device_ != VK_NULL_HANDLE) {
    vkDeviceWaitIdle(device_);
    vkDestroyDevice(device_, nullptr);
  }
  if (surface_ != VK_NULL_HANDLE) vkDestroySurfaceKHR(instance_.handle(), surface_, nullptr);
}

Result<std::uint32_t> Context::find_memory_type(std::uint32_t type_bits,
                                                VkMemoryPropertyFlags required,
                                                VkMemoryPropertyFlags preferred) const {
  int fallback = -1;
  for (std::uint32_t i = 0; i < memory_.memoryTypeCount; ++i) {
    if ((type_bits & (1u << i)) == 0) continue;
    const VkMemoryPropertyFlags f = memory_.memoryTypes[i].propertyFlags;
    if ((f & required) != required) continue;
    if ((f & preferred) == preferred) return i;
    if (fallback < 0) fallback = static_cast<int>(i);
  }
  if (fallback >= 0) return static_cast<std::uint32_t>(fallback);
  return gpu_error(GpuErrc::out_of_memory, "no memory type with the required properties (flags " +
                                               std::to_string(required) + ", allowed types mask " +
                                               std::to_string(type_bits) + ")");
}

Result<void> Context::submit_once(const Queue& queue,
                                  const std::function<void(VkCommandBuffer)>& record) const {
  VkCommandPoolCreateInfo pci{};
  pci.sType = VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO;
  pci.flags = VK_COMMAND_POOL_CREATE_TRANSIENT_BIT;
  pci.queueFamilyIndex = queue.family();
  VkCommandPool pool = VK_NULL_HANDLE;
  if (VkResult r = vkCreateCommandPool(device_, &pci, nullptr, &pool); r != VK_SUCCESS) {
    return gpu_error_from(r, GpuErrc::submit_failed, "vkCreateCommandPool failed");
  }
  VkFence fence = VK_NULL_HANDLE;
  bool in_flight = false;
  auto cleanup = [&] {
    // After a timeout the GPU may still use the command buffer: leak rather than free it.
    if (in_flight) return;
    if (fence != VK_NULL_HANDLE) vkDestroyFence(device_, fence, nullptr);
    vkDestroyCommandPool(device_, pool, nullptr);
  };

  VkCommandBufferAllocateInfo ai{};
  ai.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO;
  ai.commandPool = pool;
  ai.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  ai.commandBufferCount = 1;
  VkCommandBuffer cb = VK_NULL_HANDLE;
  if (VkResult r = vkAllocateCommandBuffers(device_, &ai, &cb); r != VK_SUCCESS) {
    cleanup();
    return gpu_error_from(r, GpuErrc::submit_failed, "vkAllocateCommandBuffers failed");
  }
  VkCommandBufferBeginInfo bi{};
  bi.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO;
  bi.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  if (VkResult r = vkBeginCommandBuffer(cb, &bi); r != VK_SUCCESS) {
    cleanup();
    return gpu_error_from(r, GpuErrc::submit_failed, "vkBeginCommandBuffer failed");
  }
  record(cb);
  if (VkResult r = vkEndCommandBuffer(cb); r != VK_SUCCESS) {
    cleanup();
    return gpu_error_from(r, GpuErrc::submit_failed, "vkEndCommandBuffer failed");
  }
  VkFenceCreateInfo fci{};
  fci.sType = VK_STRUCTURE_TYPE_FENCE_CREATE_INFO;
  if (VkResult r = vkCreateFence(device_, &fci, nullptr, &fence); r != VK_SUCCESS) {
    fence = VK_NULL_HANDLE;
    cleanup();
    return gpu_error_from(r, GpuErrc::submit_failed, "vkCreateFence failed");
  }
  VkSubmitInfo si{};
  si.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
  si.commandBufferCount = 1;
  si.pCommandBuffers = &cb;
  if (auto s = queue.submit(si, fence); !s) {
    cleanup();
    return s;
  }
  in_flight = true;
  const VkResult w = vkWaitForFences(device_, 1, &fence, VK_TRUE,
                                     static_cast<std::uint64_t>(fence_timeout_.count()));
  if (w == VK_TIMEOUT) {
    return gpu_error(GpuErrc::timeout, "a submission did not finish within " +
                                           std::to_string(fence_timeout_.count() / 1000000) +
                                           " ms");
  }
  in_flight = w != VK_SUCCESS && w != VK_ERROR_DEVICE_LOST;
  cleanup();
  if (w != VK_SUCCESS) return gpu_error_from(w, GpuErrc::submit_failed, "vkWaitForFences failed");
  return {};
}

bool Context::timestamps_supported(const Queue& queue) const noexcept {
  return queue.timestamp_valid_bits() > 0 && limits_.timestampPeriod > 0.0f;
}

Result<void> Context::wait_idle() const {
  if (VkResult r = vkDeviceWaitIdle(device_); r != VK_SUCCESS) {
    return gpu_error_from(r, GpuErrc::submit_failed, "vkDeviceWaitIdle failed");
  }
  return {};
}

Result<std::unique_ptr<Context>> ContextBuilder::build() const {
  auto inst = instance_.build();
  if (!inst) return std::move(inst).error();
  auto devices = inst->devices();
  if (!devices) return std::move(devices).error();
  Result<DeviceChoice> choice = make_error(Errc::internal, "no device chosen");
  if (hooks_.physical_device) {
    // The device the runtime drives, if it is usable at all.
    auto wanted = hooks_.physical_device(inst->handle());
    if (!wanted) return std::move(wanted).error();
    for (std::uint32_t i = 0; i < devices->size(); ++i) {
      if (inst->physical_device(i) != *wanted) continue;
      const std::string why = unusable_reason((*devices)[i]);
      if (!why.empty())
        return gpu_error(GpuErrc::no_suitable_device,
                         "the device the runtime drives, '" + (*devices)[i].name + "', " + why);
      choice = DeviceChoice{i, "the device the runtime drives"};
    }
    if (!choice)
      return gpu_error(GpuErrc::no_suitable_device,
                       "the runtime named a device the Vulkan instance does not list");
  } else {
    choice = select_device(*devices, device_override_from(device_));
    if (!choice) return std::move(choice).error();
  }

  std::unique_ptr<Context> ctx(new Context());
  ctx->instance_ = std::move(*inst);
  ctx->fence_timeout_ = fence_timeout_;
  if (make_surface_) {
    auto surface = make_surface_(ctx->instance_.handle());
    if (!surface) return std::move(surface).error();
    ctx->surface_ = *surface;
  }
  ctx->choice_ = *choice;
  ctx->info_ = (*devices)[choice->index];
  ctx->physical_ = ctx->instance_.physical_device(choice->index);
  VkPhysicalDeviceProperties props{};
  vkGetPhysicalDeviceProperties(ctx->physical_, &props);
  ctx->limits_ = props.limits;
  vkGetPhysicalDeviceMemoryProperties(ctx->physical_, &ctx->memory_);

  // Queue families: the first with compute for passes; a transfer-only family (a DMA engine)
  // for uploads if there is one, else a second queue of the compute family, else share.
  const auto& fams = ctx->info_.queue_families;
  std::uint32_t compute_family = UINT32_MAX, transfer_family = UINT32_MAX;
  const auto can_present = [&](std::uint32_t family) {
    if (ctx->surface_ == VK_NULL_HANDLE) return true;
    VkBool32 ok = VK_FALSE;
    return vkGetPhysicalDeviceSurfaceSupportKHR(ctx->physical_, family, ctx->surface_, &ok) ==
               VK_SUCCESS &&
           ok == VK_TRUE;
  };
  const VkQueueFlags wanted =
      VK_QUEUE_COMPUTE_BIT | (ctx->surface_ != VK_NULL_HANDLE ? VK_QUEUE_GRAPHICS_BIT : 0);
  for (const auto& q : fams) {
    if ((q.flags & wanted) == wanted && compute_family == UINT32_MAX && can_present(q.index))
      compute_family = q.index;
    if ((q.flags & VK_QUEUE_TRANSFER_BIT) != 0 &&
        (q.flags & (VK_QUEUE_GRAPHICS_BIT | VK_QUEUE_COMPUTE_BIT)) == 0 &&
        transfer_family == UINT32_MAX) {
      transfer_family = q.index;
    }
  }
  if (compute_family == UINT32_MAX) {
    return gpu_error(GpuErrc::no_suitable_device,
                     "device '" + ctx->info_.name +
                         (ctx->surface_ != VK_NULL_HANDLE
                              ? "' has no queue with graphics and compute that can present to "
                                "the window"
                              : "' has no compute queue"));
  }
  const bool separate_family = transfer_family != UINT32_MAX;
  const bool second_queue = !separate_family && fams[compute_family].count >= 2;

  const float priorities[2] = {1.0f, 0.5f};
  std::vector<VkDeviceQueueCreateInfo> qcis;
  VkDeviceQueueCreateInfo qci{};
  qci.sType = VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO;
  qci.queueFamilyIndex = compute_family;
  qci.queueCount = second_queue ? 2 : 1;
  qci.pQueuePriorities = priorities;
  qcis.push_back(qci);
  if (separate_family) {
    qci.queueFamilyIndex = transfer_family;
    qci.queueCount = 1;
    qci.pQueuePriorities = &priorities[1];
    qcis.push_back(qci);
  }

  VkPhysicalDeviceFeatures supported{};
  vkGetPhysicalDeviceFeatures(ctx->physical_, &supported);
  VkPhysicalDeviceFeatures enabled{};
  // R8_UINT storage images (group_depth, pool_layout.h) need the extended formats.
  enabled.shaderStorageImageExtendedFormats = supported.shaderStorageImageExtendedFormats;
  enabled.shaderInt64 = supported.shaderInt64;

  VkDeviceCreateInfo dci{};
  dci.sType = VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO;
  dci.queueCreateInfoCount = static_cast<std::uint32_t>(qcis.size());
  dci.pQueueCreateInfos = qcis.data();
  dci.pEnabledFeatures = &enabled;
  const char* swapchain_ext = VK_KHR_SWAPCHAIN_EXTENSION_NAME;
  if (ctx->surface_ != VK_NULL_HANDLE) {
    dci.enabledExtensionCount = 1;
    dci.ppEnabledExtensionNames = &swapchain_ext;
  }
  if (hooks_.create_device) {
    auto made = hooks_.create_device(ctx->physical_, dci);
    if (!made) return std::move(made).error();
    ctx->device_ = *made;
  } else if (VkResult r = vkCreateDevice(ctx->physical_, &dci, nullptr, &ctx->device_);
             r != VK_SUCCESS) {
    ctx->device_ = VK_NULL_HANDLE;
    return gpu_error_from(r, GpuErrc::device_failed,
                          "vkCreateDevice failed on '" + ctx->info_.name + "'");
  }

  ctx->compute_.family_ = compute_family;
  ctx->compute_.timestamp_bits_ = fams[compute_family].timestamp_valid_bits;
  ctx->compute_.mutex_ = std::make_shared<std::mutex>();
  vkGetDeviceQueue(ctx->device_, compute_family, 0, &ctx->compute_.queue_);
  ctx->families_.push_back(compute_family);
  if (separate_family) {
    ctx->transfer_.family_ = transfer_family;
    ctx->transfer_.timestamp_bits_ = fams[transfer_family].timestamp_valid_bits;
    ctx->transfer_.mutex_ = std::make_shared<std::mutex>();
    vkGetDeviceQueue(ctx->device_, transfer_family, 0, &ctx->transfer_.queue_);
    ctx->families_.push_back(transfer_family);
  } else if (second_queue) {
    ctx->transfer_.family_ = compute_family;
    ctx->transfer_.timestamp_bits_ = ctx->compute_.timestamp_bits_;
    ctx->transfer_.mutex_ = std::make_shared<std::mutex>();
    vkGetDeviceQueue(ctx->device_, compute_family, 1, &ctx->transfer_.queue_);
  } else {
    ctx->transfer_ = ctx->compute_;  // same VkQueue, same mutex
  }
  return ctx;
}

}  // namespace deepcanvas::client_gpu
