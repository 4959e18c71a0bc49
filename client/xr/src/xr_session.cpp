// The OpenXR session of the headset client (xr_session.hpp).
#include "deepcanvas/xr/xr_session.hpp"

#include <vulkan/vulkan.h>
#define XR_USE_GRAPHICS_API_VULKAN
#include <openxr/openxr.h>
#include <openxr/openxr_platform.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

namespace deepcanvas::xr {

namespace {

constexpr XrViewConfigurationType kViewConfig = XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO;

}  // namespace

struct XrHeadset::Impl {
  XrInstance instance = XR_NULL_HANDLE;
  XrSystemId system = XR_NULL_SYSTEM_ID;
  std::unique_ptr<client_gpu::Context> ctx;
  XrSession session = XR_NULL_HANDLE;
  XrSpace space = XR_NULL_HANDLE;
  XrSessionState state = XR_SESSION_STATE_UNKNOWN;
  bool running = false, ended = false;
  std::string runtime, system_name;
  struct Swapchain {
    XrSwapchain handle = XR_NULL_HANDLE;
    std::uint32_t width = 0, height = 0;
    std::vector<XrSwapchainImageVulkan2KHR> images;
  };
  std::array<Swapchain, 2> swapchains;
  // Actions: aim pose, trigger value and grip of each hand.
  XrActionSet action_set = XR_NULL_HANDLE;
  XrAction aim = XR_NULL_HANDLE, trigger = XR_NULL_HANDLE, grip = XR_NULL_HANDLE;
  std::array<XrPath, 2> hand_paths{};
  std::array<XrSpace, 2> aim_spaces{};

  // The runtime's words for a failed call.
  Error fail(XrResult r, const std::string& call) const {
    char s[XR_MAX_RESULT_STRING_SIZE] = "";
    if (instance == XR_NULL_HANDLE || xrResultToString(instance, r, s) != XR_SUCCESS)
      std::snprintf(s, sizeof s, "XrResult %d", static_cast<int>(r));
    return make_error(Errc::io_error, "OpenXR: " + call + " failed: " + s);
  }
  template <class F>
  Result<void> proc(const char* name, F& out) const {
    PFN_xrVoidFunction f = nullptr;
    if (XrResult r = xrGetInstanceProcAddr(instance, name, &f); XR_FAILED(r)) return fail(r, name);
    out = reinterpret_cast<F>(f);
    return {};
  }
  Result<void> make_instance(const std::string& app_name);
  Result<void> make_vulkan();
  Result<void> make_session();
  Result<void> make_actions();
  ~Impl();
};

#define DC_XR(call, what)                          \
  do {                                             \
    if (XrResult r_ = (call); XR_FAILED(r_)) return fail(r_, what); \
  } while (0)

Result<void> XrHeadset::Impl::make_instance(const std::string& app_name) {
  std::uint32_t n = 0;
  XrResult r = xrEnumerateInstanceExtensionProperties(nullptr, 0, &n, nullptr);
  if (XR_FAILED(r))
    return make_error(Errc::unsupported,
                      "no OpenXR runtime is installed or active (the loader found none: install "
                      "your headset's runtime, e.g. Monado or SteamVR, or set XR_RUNTIME_JSON)");
  std::vector<XrExtensionProperties> exts(n, {XR_TYPE_EXTENSION_PROPERTIES, nullptr, {}, 0});
  xrEnumerateInstanceExtensionProperties(nullptr, n, &n, exts.data());
  const bool has_vk2 = std::any_of(exts.begin(), exts.end(), [](const XrExtensionProperties& e) {
    return std::strcmp(e.extensionName, XR_KHR_VULKAN_ENABLE2_EXTENSION_NAME) == 0;
  });
  if (!has_vk2)
    return make_error(Errc::unsupported, std::string("the OpenXR runtime lacks ") +
                                             XR_KHR_VULKAN_ENABLE2_EXTENSION_NAME +
                                             " (Vulkan rendering)");
  const char* enabled[] = {XR_KHR_VULKAN_ENABLE2_EXTENSION_NAME};
  XrInstanceCreateInfo ci{XR_TYPE_INSTANCE_CREATE_INFO};
  std::snprintf(ci.applicationInfo.applicationName, XR_MAX_APPLICATION_NAME_SIZE, "%s",
                app_name.c_str());
  std::snprintf(ci.applicationInfo.engineName, XR_MAX_ENGINE_NAME_SIZE, "deepcanvas");
  ci.applicationInfo.apiVersion = XR_MAKE_VERSION(1, 0, 0);
  ci.enabledExtensionCount = 1;
  ci.enabledExtensionNames = enabled;
  r = xrCreateInstance(&ci, &instance);
  if (r == XR_ERROR_RUNTIME_UNAVAILABLE || r == XR_ERROR_RUNTIME_FAILURE)
    return make_error(Errc::unsupported,
                      "no OpenXR runtime is installed or active (xrCreateInstance: runtime "
                      "unavailable; install your headset's runtime or set XR_RUNTIME_JSON)");
  DC_XR(r, "xrCreateInstance");
  XrInstanceProperties ip{XR_TYPE_INSTANCE_PROPERTIES};
  DC_XR(xrGetInstanceProperties(instance, &ip), "xrGetInstanceProperties");
  runtime = ip.runtimeName;
  XrSystemGetInfo sgi{XR_TYPE_SYSTEM_GET_INFO};
  sgi.formFactor = XR_FORM_FACTOR_HEAD_MOUNTED_DISPLAY;
  r = xrGetSystem(instance, &sgi, &system);
  if (r == XR_ERROR_FORM_FACTOR_UNAVAILABLE)
    return make_error(Errc::unsupported, "the OpenXR runtime '" + runtime +
                                             "' has no headset connected (form factor unavailable)");
  DC_XR(r, "xrGetSystem");
  XrSystemProperties sp{XR_TYPE_SYSTEM_PROPERTIES};
  DC_XR(xrGetSystemProperties(instance, system, &sp), "xrGetSystemProperties");
  system_name = sp.systemName;
  return {};
}

// The Vulkan context through the runtime (XR_KHR_vulkan_enable2).
Result<void> XrHeadset::Impl::make_vulkan() {
  PFN_xrGetVulkanGraphicsRequirements2KHR requirements = nullptr;
  PFN_xrCreateVulkanInstanceKHR create_instance = nullptr;
  PFN_xrGetVulkanGraphicsDevice2KHR graphics_device = nullptr;
  PFN_xrCreateVulkanDeviceKHR create_device = nullptr;
  if (auto r = proc("xrGetVulkanGraphicsRequirements2KHR", requirements); !r) return r;
  if (auto r = proc("xrCreateVulkanInstanceKHR", create_instance); !r) return r;
  if (auto r = proc("xrGetVulkanGraphicsDevice2KHR", graphics_device); !r) return r;
  if (auto r = proc("xrCreateVulkanDeviceKHR", create_device); !r) return r;
  // Required before a session is made; the device's Vulkan version is checked by the runtime.
  XrGraphicsRequirementsVulkan2KHR req{XR_TYPE_GRAPHICS_REQUIREMENTS_VULKAN2_KHR};
  DC_XR(requirements(instance, system, &req), "xrGetVulkanGraphicsRequirements2KHR");
  client_gpu::VulkanCreationHooks hooks;
  hooks.create_instance = [&, fn = create_instance](const VkInstanceCreateInfo& vci) -> Result<VkInstance> {
    XrVulkanInstanceCreateInfoKHR xci{XR_TYPE_VULKAN_INSTANCE_CREATE_INFO_KHR};
    xci.systemId = system;
    xci.pfnGetInstanceProcAddr = vkGetInstanceProcAddr;
    xci.vulkanCreateInfo = &vci;
    VkInstance out = VK_NULL_HANDLE;
    VkResult vr = VK_SUCCESS;
    if (XrResult r = fn(instance, &xci, &out, &vr); XR_FAILED(r)) return fail(r, "xrCreateVulkanInstanceKHR");
    if (vr != VK_SUCCESS)
      return make_error(Errc::io_error, "OpenXR: vkCreateInstance through the runtime failed: VkResult " +
                                            std::to_string(static_cast<int>(vr)));
    return out;
  };
  hooks.physical_device = [&, fn = graphics_device](VkInstance vk) -> Result<VkPhysicalDevice> {
    XrVulkanGraphicsDeviceGetInfoKHR gi{XR_TYPE_VULKAN_GRAPHICS_DEVICE_GET_INFO_KHR};
    gi.systemId = system;
    gi.vulkanInstance = vk;
    VkPhysicalDevice out = VK_NULL_HANDLE;
    if (XrResult r = fn(instance, &gi, &out); XR_FAILED(r)) return fail(r, "xrGetVulkanGraphicsDevice2KHR");
    return out;
  };
  hooks.create_device = [&, fn = create_device](VkPhysicalDevice pd, const VkDeviceCreateInfo& dci) -> Result<VkDevice> {
    XrVulkanDeviceCreateInfoKHR xci{XR_TYPE_VULKAN_DEVICE_CREATE_INFO_KHR};
    xci.systemId = system;
    xci.pfnGetInstanceProcAddr = vkGetInstanceProcAddr;
    xci.vulkanPhysicalDevice = pd;
    xci.vulkanCreateInfo = &dci;
    VkDevice out = VK_NULL_HANDLE;
    VkResult vr = VK_SUCCESS;
    if (XrResult r = fn(instance, &xci, &out, &vr); XR_FAILED(r)) return fail(r, "xrCreateVulkanDeviceKHR");
    if (vr != VK_SUCCESS)
      return make_error(Errc::io_error, "OpenXR: vkCreateDevice through the runtime failed: VkResult " +
                                            std::to_string(static_cast<int>(vr)));
    return out;
  };
  auto ctx_r = client_gpu::ContextBuilder().app_name("deepcanvas-client xr").created_by(hooks).build();
  if (!ctx_r) return std::move(ctx_r).error();
  ctx = std::move(*ctx_r);
  return {};
}

Result<void> XrHeadset::Impl::make_session() {
  XrGraphicsBindingVulkan2KHR gb{XR_TYPE_GRAPHICS_BINDING_VULKAN2_KHR};
  gb.instance = ctx->instance();
  gb.physicalDevice = ctx->physical_device();
  gb.device = ctx->device();
  gb.queueFamilyIndex = ctx->compute_queue().family();
  gb.queueIndex = 0;
  XrSessionCreateInfo sci{XR_TYPE_SESSION_CREATE_INFO};
  sci.next = &gb;
  sci.systemId = system;
  DC_XR(xrCreateSession(instance, &sci, &session), "xrCreateSession");
  XrReferenceSpaceCreateInfo rs{XR_TYPE_REFERENCE_SPACE_CREATE_INFO};
  rs.referenceSpaceType = XR_REFERENCE_SPACE_TYPE_LOCAL;
  rs.poseInReferenceSpace.orientation.w = 1;
  DC_XR(xrCreateReferenceSpace(session, &rs, &space), "xrCreateReferenceSpace");
  std::uint32_t nv = 0;
  DC_XR(xrEnumerateViewConfigurationViews(instance, system, kViewConfig, 0, &nv, nullptr),
        "xrEnumerateViewConfigurationViews");
  if (nv != 2)
    return make_error(Errc::unsupported, "the headset has " + std::to_string(nv) + " views, not 2");
  std::vector<XrViewConfigurationView> views(nv, {XR_TYPE_VIEW_CONFIGURATION_VIEW});
  DC_XR(xrEnumerateViewConfigurationViews(instance, system, kViewConfig, nv, &nv, views.data()),
        "xrEnumerateViewConfigurationViews");
  std::uint32_t nf = 0;
  DC_XR(xrEnumerateSwapchainFormats(session, 0, &nf, nullptr), "xrEnumerateSwapchainFormats");
  std::vector<std::int64_t> formats(nf);
  DC_XR(xrEnumerateSwapchainFormats(session, nf, &nf, formats.data()), "xrEnumerateSwapchainFormats");
  // The ray caster writes 8-bit RGBA ready for display (what a PNG of it holds): sRGB where the
  // runtime offers it (it then shows the bytes as they are), else UNORM.
  std::int64_t format = 0;
  for (std::int64_t f : {std::int64_t{VK_FORMAT_R8G8B8A8_SRGB}, std::int64_t{VK_FORMAT_R8G8B8A8_UNORM}})
    if (format == 0 && std::find(formats.begin(), formats.end(), f) != formats.end()) format = f;
  if (format == 0) return make_error(Errc::unsupported, "the runtime offers no 8-bit RGBA swapchain format");
  for (std::uint32_t i = 0; i < 2; ++i) {
    XrSwapchainCreateInfo ci{XR_TYPE_SWAPCHAIN_CREATE_INFO};
    ci.usageFlags = XR_SWAPCHAIN_USAGE_COLOR_ATTACHMENT_BIT | XR_SWAPCHAIN_USAGE_TRANSFER_DST_BIT;
    ci.format = format;
    ci.sampleCount = 1;
    ci.faceCount = 1;
    ci.arraySize = 1;
    ci.mipCount = 1;
    ci.width = views[i].recommendedImageRectWidth;
    ci.height = views[i].recommendedImageRectHeight;
    auto& sc = swapchains[i];
    DC_XR(xrCreateSwapchain(session, &ci, &sc.handle), "xrCreateSwapchain");
    sc.width = ci.width;
    sc.height = ci.height;
    std::uint32_t n = 0;
    DC_XR(xrEnumerateSwapchainImages(sc.handle, 0, &n, nullptr), "xrEnumerateSwapchainImages");
    sc.images.assign(n, {XR_TYPE_SWAPCHAIN_IMAGE_VULKAN2_KHR});
    DC_XR(xrEnumerateSwapchainImages(sc.handle, n, &n,
                                     reinterpret_cast<XrSwapchainImageBaseHeader*>(sc.images.data())),
          "xrEnumerateSwapchainImages");
  }
  return make_actions();
}

// The controllers: aim pose, trigger and grip of both hands, bound for the Khronos simple
// controller (every runtime maps its controllers onto it).
Result<void> XrHeadset::Impl::make_actions() {
  XrActionSetCreateInfo asci{XR_TYPE_ACTION_SET_CREATE_INFO};
  std::snprintf(asci.actionSetName, XR_MAX_ACTION_SET_NAME_SIZE, "painting");
  std::snprintf(asci.localizedActionSetName, XR_MAX_LOCALIZED_ACTION_SET_NAME_SIZE, "Painting");
  DC_XR(xrCreateActionSet(instance, &asci, &action_set), "xrCreateActionSet");
  DC_XR(xrStringToPath(instance, "/user/hand/left", &hand_paths[0]), "xrStringToPath");
  DC_XR(xrStringToPath(instance, "/user/hand/right", &hand_paths[1]), "xrStringToPath");
  auto make = [&](XrAction& a, XrActionType type, const char* name, const char* label) -> Result<void> {
    XrActionCreateInfo ci{XR_TYPE_ACTION_CREATE_INFO};
    ci.actionType = type;
    std::snprintf(ci.actionName, XR_MAX_ACTION_NAME_SIZE, "%s", name);
    std::snprintf(ci.localizedActionName, XR_MAX_LOCALIZED_ACTION_NAME_SIZE, "%s", label);
    ci.countSubactionPaths = 2;
    ci.subactionPaths = hand_paths.data();
    DC_XR(xrCreateAction(action_set, &ci, &a), "xrCreateAction");
    return {};
  };
  if (auto r = make(aim, XR_ACTION_TYPE_POSE_INPUT, "brush_tip", "Brush tip"); !r) return r;
  if (auto r = make(trigger, XR_ACTION_TYPE_FLOAT_INPUT, "paint", "Paint"); !r) return r;
  if (auto r = make(grip, XR_ACTION_TYPE_BOOLEAN_INPUT, "grab", "Grab the world"); !r) return r;
  XrPath profile;
  DC_XR(xrStringToPath(instance, "/interaction_profiles/khr/simple_controller", &profile), "xrStringToPath");
  std::vector<XrActionSuggestedBinding> bindings;
  const char* hands[] = {"left", "right"};
  for (const char* h : hands) {
    const std::string base = std::string("/user/hand/") + h + "/input/";
    XrPath p;
    DC_XR(xrStringToPath(instance, (base + "aim/pose").c_str(), &p), "xrStringToPath");
    bindings.push_back({aim, p});
    DC_XR(xrStringToPath(instance, (base + "select/click").c_str(), &p), "xrStringToPath");
    bindings.push_back({trigger, p});
    DC_XR(xrStringToPath(instance, (base + "menu/click").c_str(), &p), "xrStringToPath");
    bindings.push_back({grip, p});
  }
  XrInteractionProfileSuggestedBinding sb{XR_TYPE_INTERACTION_PROFILE_SUGGESTED_BINDING};
  sb.interactionProfile = profile;
  sb.countSuggestedBindings = static_cast<std::uint32_t>(bindings.size());
  sb.suggestedBindings = bindings.data();
  DC_XR(xrSuggestInteractionProfileBindings(instance, &sb), "xrSuggestInteractionProfileBindings");
  XrSessionActionSetsAttachInfo ai{XR_TYPE_SESSION_ACTION_SETS_ATTACH_INFO};
  ai.countActionSets = 1;
  ai.actionSets = &action_set;
  DC_XR(xrAttachSessionActionSets(session, &ai), "xrAttachSessionActionSets");
  for (int h = 0; h < 2; ++h) {
    XrActionSpaceCreateInfo sci{XR_TYPE_ACTION_SPACE_CREATE_INFO};
    sci.action = aim;
    sci.subactionPath = hand_paths[static_cast<std::size_t>(h)];
    sci.poseInActionSpace.orientation.w = 1;
    DC_XR(xrCreateActionSpace(session, &sci, &aim_spaces[static_cast<std::size_t>(h)]), "xrCreateActionSpace");
  }
  return {};
}

XrHeadset::Impl::~Impl() {
  if (ctx) (void)ctx->wait_idle();
  for (auto& s : aim_spaces)
    if (s != XR_NULL_HANDLE) xrDestroySpace(s);
  if (action_set != XR_NULL_HANDLE) xrDestroyActionSet(action_set);
  for (auto& sc : swapchains)
    if (sc.handle != XR_NULL_HANDLE) xrDestroySwapchain(sc.handle);
  if (space != XR_NULL_HANDLE) xrDestroySpace(space);
  if (session != XR_NULL_HANDLE) {
    if (running) xrEndSession(session);
    xrDestroySession(session);
  }
  ctx.reset();  // the device and instance, before the XR instance that made them
  if (instance != XR_NULL_HANDLE) xrDestroyInstance(instance);
}

Result<std::unique_ptr<XrHeadset>> XrHeadset::create(const std::string& app_name) {
  std::unique_ptr<XrHeadset> h(new XrHeadset());
  h->impl_ = std::make_unique<Impl>();
  if (auto r = h->impl_->make_instance(app_name); !r) return std::move(r).error();
  if (auto r = h->impl_->make_vulkan(); !r) return std::move(r).error();
  if (auto r = h->impl_->make_session(); !r) return std::move(r).error();
  return h;
}

XrHeadset::~XrHeadset() = default;

client_gpu::Context& XrHeadset::context() noexcept { return *impl_->ctx; }
const std::string& XrHeadset::runtime_name() const noexcept { return impl_->runtime; }
const std::string& XrHeadset::system_name() const noexcept { return impl_->system_name; }
bool XrHeadset::running() const noexcept { return impl_->running; }

Result<bool> XrHeadset::poll() {
  Impl& m = *impl_;
  auto fail = [&](XrResult r, const char* what) { return m.fail(r, what); };
  for (;;) {
    XrEventDataBuffer ev{XR_TYPE_EVENT_DATA_BUFFER};
    const XrResult r = xrPollEvent(m.instance, &ev);
    if (r == XR_EVENT_UNAVAILABLE) break;
    DC_XR(r, "xrPollEvent");
    if (ev.type == XR_TYPE_EVENT_DATA_INSTANCE_LOSS_PENDING) {
      m.ended = true;
    } else if (ev.type == XR_TYPE_EVENT_DATA_SESSION_STATE_CHANGED) {
      m.state = reinterpret_cast<const XrEventDataSessionStateChanged&>(ev).state;
      if (m.state == XR_SESSION_STATE_READY) {
        XrSessionBeginInfo bi{XR_TYPE_SESSION_BEGIN_INFO};
        bi.primaryViewConfigurationType = kViewConfig;
        DC_XR(xrBeginSession(m.session, &bi), "xrBeginSession");
        m.running = true;
      } else if (m.state == XR_SESSION_STATE_STOPPING) {
        DC_XR(xrEndSession(m.session), "xrEndSession");
        m.running = false;
        m.ended = true;
      } else if (m.state == XR_SESSION_STATE_EXITING || m.state == XR_SESSION_STATE_LOSS_PENDING) {
        m.running = false;
        m.ended = true;
      }
    }
  }
  return !m.ended;
}

Result<XrFrame> XrHeadset::begin_frame() {
  Impl& m = *impl_;
  auto fail = [&](XrResult r, const char* what) { return m.fail(r, what); };
  XrFrame out;
  XrFrameState fs{XR_TYPE_FRAME_STATE};
  DC_XR(xrWaitFrame(m.session, nullptr, &fs), "xrWaitFrame");
  DC_XR(xrBeginFrame(m.session, nullptr), "xrBeginFrame");
  out.should_render = fs.shouldRender == XR_TRUE;
  out.display_time = fs.predictedDisplayTime;
  out.display_period_ms = static_cast<double>(fs.predictedDisplayPeriod) / 1e6;
  XrViewLocateInfo li{XR_TYPE_VIEW_LOCATE_INFO};
  li.viewConfigurationType = kViewConfig;
  li.displayTime = fs.predictedDisplayTime;
  li.space = m.space;
  XrViewState vs{XR_TYPE_VIEW_STATE};
  std::array<XrView, 2> views{{{XR_TYPE_VIEW}, {XR_TYPE_VIEW}}};
  std::uint32_t n = 0;
  DC_XR(xrLocateViews(m.session, &li, &vs, 2, &n, views.data()), "xrLocateViews");
  const XrViewStateFlags need = XR_VIEW_STATE_ORIENTATION_VALID_BIT | XR_VIEW_STATE_POSITION_VALID_BIT;
  out.views_valid = n == 2 && (vs.viewStateFlags & need) == need;
  for (std::size_t i = 0; i < 2; ++i) {
    const XrPosef& p = views[i].pose;
    auto& e = out.eyes[i];
    e.position = {p.position.x, p.position.y, p.position.z};
    e.orientation = {p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z};
    e.angle_left = views[i].fov.angleLeft;
    e.angle_right = views[i].fov.angleRight;
    e.angle_up = views[i].fov.angleUp;
    e.angle_down = views[i].fov.angleDown;
    e.width = m.swapchains[i].width;
    e.height = m.swapchains[i].height;
  }
  if (m.state == XR_SESSION_STATE_FOCUSED) {
    XrActiveActionSet active{m.action_set, XR_NULL_PATH};
    XrActionsSyncInfo si{XR_TYPE_ACTIONS_SYNC_INFO};
    si.countActiveActionSets = 1;
    si.activeActionSets = &active;
    DC_XR(xrSyncActions(m.session, &si), "xrSyncActions");
    for (std::size_t h = 0; h < 2; ++h) {
      auto& hand = out.hands[h];
      XrSpaceLocation loc{XR_TYPE_SPACE_LOCATION};
      DC_XR(xrLocateSpace(m.aim_spaces[h], m.space, fs.predictedDisplayTime, &loc), "xrLocateSpace");
      hand.active = (loc.locationFlags & XR_SPACE_LOCATION_POSITION_VALID_BIT) != 0;
      hand.tip = {loc.pose.position.x, loc.pose.position.y, loc.pose.position.z};
      XrActionStateGetInfo gi{XR_TYPE_ACTION_STATE_GET_INFO};
      gi.subactionPath = m.hand_paths[h];
      gi.action = m.trigger;
      XrActionStateFloat tf{XR_TYPE_ACTION_STATE_FLOAT};
      DC_XR(xrGetActionStateFloat(m.session, &gi, &tf), "xrGetActionStateFloat");
      hand.trigger = tf.isActive ? std::clamp<double>(tf.currentState, 0, 1) : 0;
      gi.action = m.grip;
      XrActionStateBoolean gb{XR_TYPE_ACTION_STATE_BOOLEAN};
      DC_XR(xrGetActionStateBoolean(m.session, &gi, &gb), "xrGetActionStateBoolean");
      hand.grip = gb.isActive && gb.currentState;
    }
  }
  return out;
}

Result<void> XrHeadset::end_frame(const XrFrame& frame, std::array<const client_gpu::Buffer*, 2> eyes,
                                  std::array<std::array<std::uint32_t, 2>, 2> sizes) {
  Impl& m = *impl_;
  auto fail = [&](XrResult r, const char* what) { return m.fail(r, what); };
  const bool render = frame.should_render && frame.views_valid && eyes[0] && eyes[1];
  std::array<XrCompositionLayerProjectionView, 2> pv{
      {{XR_TYPE_COMPOSITION_LAYER_PROJECTION_VIEW}, {XR_TYPE_COMPOSITION_LAYER_PROJECTION_VIEW}}};
  if (render) {
    for (std::size_t i = 0; i < 2; ++i) {
      auto& sc = m.swapchains[i];
      const std::uint32_t w = std::clamp<std::uint32_t>(sizes[i][0], 1, sc.width);
      const std::uint32_t h = std::clamp<std::uint32_t>(sizes[i][1], 1, sc.height);
      if (eyes[i]->size() < VkDeviceSize{w} * h * 4)
        return make_error(Errc::invalid_argument, "OpenXR: an eye's image is smaller than its size");
      std::uint32_t index = 0;
      XrSwapchainImageAcquireInfo acq{XR_TYPE_SWAPCHAIN_IMAGE_ACQUIRE_INFO};
      DC_XR(xrAcquireSwapchainImage(sc.handle, &acq, &index), "xrAcquireSwapchainImage");
      XrSwapchainImageWaitInfo wi{XR_TYPE_SWAPCHAIN_IMAGE_WAIT_INFO};
      wi.timeout = XR_INFINITE_DURATION;
      DC_XR(xrWaitSwapchainImage(sc.handle, &wi), "xrWaitSwapchainImage");
      const VkImage image = sc.images[index].image;
      const VkBuffer src = eyes[i]->handle();
      auto copied = m.ctx->submit_once(m.ctx->compute_queue(), [&](VkCommandBuffer cmd) {
        VkImageMemoryBarrier b{VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER};
        b.srcAccessMask = VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
        b.dstAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
        b.oldLayout = VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL;
        b.newLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
        b.srcQueueFamilyIndex = b.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
        b.image = image;
        b.subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
        vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                             VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 0, nullptr, 0, nullptr, 1, &b);
        VkBufferImageCopy region{};
        region.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
        region.imageExtent = {w, h, 1};
        vkCmdCopyBufferToImage(cmd, src, image, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &region);
        b.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
        b.dstAccessMask = VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
        b.oldLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
        b.newLayout = VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL;
        vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT, 0,
                             0, nullptr, 0, nullptr, 1, &b);
      });
      XrSwapchainImageReleaseInfo rel{XR_TYPE_SWAPCHAIN_IMAGE_RELEASE_INFO};
      DC_XR(xrReleaseSwapchainImage(sc.handle, &rel), "xrReleaseSwapchainImage");
      if (!copied) return copied;
      const auto& e = frame.eyes[i];
      pv[i].pose.position = {static_cast<float>(e.position.x), static_cast<float>(e.position.y),
                             static_cast<float>(e.position.z)};
      pv[i].pose.orientation = {static_cast<float>(e.orientation.x), static_cast<float>(e.orientation.y),
                                static_cast<float>(e.orientation.z), static_cast<float>(e.orientation.w)};
      // The field of view the image was rendered with (symmetric, covering the eye's).
      const double half_v = covering_vfov_deg(e) * 3.14159265358979323846 / 360.0;
      const double half_h = std::atan(std::tan(half_v) * w / h);
      pv[i].fov = {static_cast<float>(-half_h), static_cast<float>(half_h), static_cast<float>(half_v),
                   static_cast<float>(-half_v)};
      pv[i].subImage.swapchain = sc.handle;
      pv[i].subImage.imageRect = {{0, 0}, {static_cast<std::int32_t>(w), static_cast<std::int32_t>(h)}};
    }
  }
  XrCompositionLayerProjection layer{XR_TYPE_COMPOSITION_LAYER_PROJECTION};
  layer.space = m.space;
  layer.viewCount = 2;
  layer.views = pv.data();
  const XrCompositionLayerBaseHeader* layers[] = {reinterpret_cast<const XrCompositionLayerBaseHeader*>(&layer)};
  XrFrameEndInfo fe{XR_TYPE_FRAME_END_INFO};
  fe.displayTime = frame.display_time;
  fe.environmentBlendMode = XR_ENVIRONMENT_BLEND_MODE_OPAQUE;
  fe.layerCount = render ? 1 : 0;
  fe.layers = layers;
  DC_XR(xrEndFrame(m.session, &fe), "xrEndFrame");
  return {};
}

Result<void> XrHeadset::request_exit() {
  Impl& m = *impl_;
  if (!m.running) return {};
  if (XrResult r = xrRequestExitSession(m.session); XR_FAILED(r)) return m.fail(r, "xrRequestExitSession");
  return {};
}

double covering_vfov_deg(const EyeView& e) noexcept {
  const double half = std::max(std::abs(e.angle_up), std::abs(e.angle_down));
  const double deg = 2 * half * 180.0 / 3.14159265358979323846;
  return std::clamp(deg, 1.0, 170.0);
}

}  // namespace deepcanvas::xr
