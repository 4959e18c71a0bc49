// StudioWindow: GLFW window, Vulkan swapchain and the Dear ImGui overlay (see window.hpp).
#include "deepcanvas/window/window.hpp"

#define GLFW_INCLUDE_VULKAN
#include <GLFW/glfw3.h>
#include <imgui.h>
#include <imgui_impl_glfw.h>
#include <imgui_impl_vulkan.h>

#include <algorithm>
#include <array>

#include "deepcanvas/client_gpu/errors.hpp"

namespace deepcanvas::window {
namespace {

using client_gpu::gpu_error;
using client_gpu::gpu_error_from;
using client_gpu::GpuErrc;

std::string glfw_error_text() {
  const char* text = nullptr;
  const int code = glfwGetError(&text);
  if (code == GLFW_NO_ERROR) return "no details";
  return text != nullptr ? text : "error " + std::to_string(code);
}

// GLFW is started once per process and ended with the last window.
int g_windows = 0;

}  // namespace

Result<std::unique_ptr<StudioWindow>> StudioWindow::create(const WindowOptions& options) {
  if (g_windows == 0 && glfwInit() != GLFW_TRUE) {
    return make_error(Errc::unsupported,
                      "cannot open a window: " + glfw_error_text() +
                          " (is DISPLAY set? Under no display, run it in Xvfb: xvfb-run)");
  }
  ++g_windows;
  std::unique_ptr<StudioWindow> w(new StudioWindow());
  if (glfwVulkanSupported() != GLFW_TRUE) {
    return make_error(Errc::unsupported, "GLFW finds no Vulkan loader: " + glfw_error_text());
  }
  glfwWindowHint(GLFW_CLIENT_API, GLFW_NO_API);
  w->window_ = glfwCreateWindow(static_cast<int>(options.width), static_cast<int>(options.height),
                                options.title.c_str(), nullptr, nullptr);
  if (w->window_ == nullptr)
    return make_error(Errc::unsupported, "cannot create the window: " + glfw_error_text());
  // Before ImGui installs its callbacks, which then call this one too.
  glfwSetWindowUserPointer(w->window_, w.get());
  glfwSetKeyCallback(w->window_, [](GLFWwindow* window, int key, int, int action, int mods) {
    if (action == GLFW_RELEASE || key == GLFW_KEY_UNKNOWN) return;
    auto* self = static_cast<StudioWindow*>(glfwGetWindowUserPointer(window));
    if (self->keys_.size() < 256) self->keys_.push_back({key, mods, action == GLFW_REPEAT});
  });
  glfwSetCursorPosCallback(w->window_, [](GLFWwindow* window, double x, double y) {
    auto* self = static_cast<StudioWindow*>(glfwGetWindowUserPointer(window));
    if (self->moves_.size() < 4096) self->moves_.emplace_back(x, y);
  });
  glfwGetWindowPos(w->window_, &w->windowed_x_, &w->windowed_y_);
  w->windowed_w_ = static_cast<int>(options.width);
  w->windowed_h_ = static_cast<int>(options.height);

  std::uint32_t count = 0;
  const char** names = glfwGetRequiredInstanceExtensions(&count);
  std::vector<std::string> extensions(names, names + count);
  GLFWwindow* raw = w->window_;
  auto ctx = client_gpu::ContextBuilder()
                 .app_name("deepcanvas studio")
                 .device(options.device)
                 .validation(options.validation)
                 .present_to(std::move(extensions),
                             [raw](VkInstance instance) -> Result<VkSurfaceKHR> {
                               VkSurfaceKHR surface = VK_NULL_HANDLE;
                               const VkResult r =
                                   glfwCreateWindowSurface(instance, raw, nullptr, &surface);
                               if (r != VK_SUCCESS)
                                   return gpu_error_from(r, GpuErrc::unsupported,
                                                         "cannot make a Vulkan surface for the "
                                                         "window");
                               return surface;
                             })
                 .build();
  if (!ctx) return std::move(ctx).error();
  w->ctx_ = std::move(*ctx);
  w->vsync_ = options.vsync;
  const VkDevice dev = w->ctx_->device();

  VkCommandPoolCreateInfo pci{};
  pci.sType = VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO;
  pci.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  pci.queueFamilyIndex = w->ctx_->compute_queue().family();
  if (VkResult r = vkCreateCommandPool(dev, &pci, nullptr, &w->pool_); r != VK_SUCCESS)
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateCommandPool");
  VkCommandBufferAllocateInfo ai{};
  ai.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO;
  ai.commandPool = w->pool_;
  ai.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  ai.commandBufferCount = 1;
  if (VkResult r = vkAllocateCommandBuffers(dev, &ai, &w->cb_); r != VK_SUCCESS)
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkAllocateCommandBuffers");
  VkFenceCreateInfo fci{};
  fci.sType = VK_STRUCTURE_TYPE_FENCE_CREATE_INFO;
  if (VkResult r = vkCreateFence(dev, &fci, nullptr, &w->fence_); r != VK_SUCCESS)
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateFence");
  VkSemaphoreCreateInfo sci{};
  sci.sType = VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO;
  if (VkResult r = vkCreateSemaphore(dev, &sci, nullptr, &w->acquired_); r != VK_SUCCESS)
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateSemaphore");

  if (auto s = w->create_swapchain(); !s) return std::move(s).error();
  if (auto s = w->init_imgui(); !s) return std::move(s).error();
  if (options.fullscreen) w->toggle_fullscreen();
  return w;
}

StudioWindow::~StudioWindow() {
  if (ctx_) {
    (void)ctx_->wait_idle();
    const VkDevice dev = ctx_->device();
    if (imgui_ready_) {
      ImGui_ImplVulkan_Shutdown();
      ImGui_ImplGlfw_Shutdown();
      ImGui::DestroyContext();
    }
    if (imgui_pool_ != VK_NULL_HANDLE) vkDestroyDescriptorPool(dev, imgui_pool_, nullptr);
    destroy_swapchain();
    if (render_pass_ != VK_NULL_HANDLE) vkDestroyRenderPass(dev, render_pass_, nullptr);
    staging_ = client_gpu::Image();
    if (acquired_ != VK_NULL_HANDLE) vkDestroySemaphore(dev, acquired_, nullptr);
    if (fence_ != VK_NULL_HANDLE) vkDestroyFence(dev, fence_, nullptr);
    if (pool_ != VK_NULL_HANDLE) vkDestroyCommandPool(dev, pool_, nullptr);
    ctx_.reset();  // the surface goes with the context, before the window
  }
  if (window_ != nullptr) glfwDestroyWindow(window_);
  if (--g_windows == 0) glfwTerminate();
}

void StudioWindow::poll() {
  glfwPollEvents();
}

std::vector<KeyPress> StudioWindow::take_key_presses() {
  std::vector<KeyPress> out;
  out.swap(keys_);
  return out;
}

std::vector<std::pair<double, double>> StudioWindow::take_pointer_moves() {
  std::vector<std::pair<double, double>> out;
  out.swap(moves_);
  return out;
}

bool StudioWindow::should_close() const {
  return glfwWindowShouldClose(window_) == GLFW_TRUE;
}

void StudioWindow::request_close() {
  glfwSetWindowShouldClose(window_, GLFW_TRUE);
}

std::pair<std::uint32_t, std::uint32_t> StudioWindow::framebuffer_size() const {
  int w = 0, h = 0;
  glfwGetFramebufferSize(window_, &w, &h);
  return {static_cast<std::uint32_t>(std::max(w, 0)), static_cast<std::uint32_t>(std::max(h, 0))};
}

void StudioWindow::set_vsync(bool on) {
  if (on == vsync_) return;
  vsync_ = on;
  swapchain_dirty_ = true;
}

void StudioWindow::toggle_fullscreen() {
  if (!fullscreen_) {
    GLFWmonitor* monitor = glfwGetPrimaryMonitor();
    const GLFWvidmode* mode = monitor != nullptr ? glfwGetVideoMode(monitor) : nullptr;
    if (mode == nullptr) return;  // no monitor to fill (nothing changes)
    glfwGetWindowPos(window_, &windowed_x_, &windowed_y_);
    glfwGetWindowSize(window_, &windowed_w_, &windowed_h_);
    glfwSetWindowMonitor(window_, monitor, 0, 0, mode->width, mode->height, mode->refreshRate);
    fullscreen_ = true;
  } else {
    glfwSetWindowMonitor(window_, nullptr, windowed_x_, windowed_y_, windowed_w_, windowed_h_, 0);
    fullscreen_ = false;
  }
  swapchain_dirty_ = true;
}

const char* StudioWindow::present_mode_name() const noexcept {
  switch (present_mode_) {
    case VK_PRESENT_MODE_MAILBOX_KHR:
      return "mailbox";
    case VK_PRESENT_MODE_IMMEDIATE_KHR:
      return "immediate";
    default:
      return "fifo";
  }
}

// ---- swapchain -------------------------------------------------------------------------------

Result<void> StudioWindow::create_swapchain() {
  const VkPhysicalDevice phys = ctx_->physical_device();
  const VkSurfaceKHR surface = ctx_->surface();
  const VkDevice dev = ctx_->device();
  VkSurfaceCapabilitiesKHR caps{};
  if (VkResult r = vkGetPhysicalDeviceSurfaceCapabilitiesKHR(phys, surface, &caps);
      r != VK_SUCCESS)
    return gpu_error_from(r, GpuErrc::unsupported, "surface capabilities");
  const auto [fw, fh] = framebuffer_size();
  extent_ = caps.currentExtent;
  if (extent_.width == 0xFFFFFFFFu) {
    extent_.width = std::clamp(fw, caps.minImageExtent.width, caps.maxImageExtent.width);
    extent_.height = std::clamp(fh, caps.minImageExtent.height, caps.maxImageExtent.height);
  }
  if (extent_.width == 0 || extent_.height == 0) return {};  // minimised: later
  if ((caps.supportedUsageFlags & VK_IMAGE_USAGE_TRANSFER_DST_BIT) == 0)
    return gpu_error(GpuErrc::unsupported, "the window's swapchain images cannot be copied to");

  std::uint32_t n = 0;
  vkGetPhysicalDeviceSurfaceFormatsKHR(phys, surface, &n, nullptr);
  std::vector<VkSurfaceFormatKHR> formats(n);
  vkGetPhysicalDeviceSurfaceFormatsKHR(phys, surface, &n, formats.data());
  if (formats.empty()) return gpu_error(GpuErrc::unsupported, "the surface has no formats");
  // UNORM: the ray caster's bytes are what the PNGs hold and what the screen should show; an
  // sRGB format would encode them a second time.
  VkSurfaceFormatKHR chosen = formats[0];
  for (const auto& f : formats)
    if (f.format == VK_FORMAT_B8G8R8A8_UNORM || f.format == VK_FORMAT_R8G8B8A8_UNORM) {
      chosen = f;
      break;
    }
  n = 0;
  vkGetPhysicalDeviceSurfacePresentModesKHR(phys, surface, &n, nullptr);
  std::vector<VkPresentModeKHR> modes(n);
  vkGetPhysicalDeviceSurfacePresentModesKHR(phys, surface, &n, modes.data());
  const auto has = [&](VkPresentModeKHR m) {
    return std::find(modes.begin(), modes.end(), m) != modes.end();
  };
  present_mode_ = VK_PRESENT_MODE_FIFO_KHR;
  if (!vsync_) {
    if (has(VK_PRESENT_MODE_MAILBOX_KHR))
      present_mode_ = VK_PRESENT_MODE_MAILBOX_KHR;
    else if (has(VK_PRESENT_MODE_IMMEDIATE_KHR))
      present_mode_ = VK_PRESENT_MODE_IMMEDIATE_KHR;
  }
  std::uint32_t image_count = std::max(2u, caps.minImageCount + 1);
  if (caps.maxImageCount > 0) image_count = std::min(image_count, caps.maxImageCount);

  const VkSwapchainKHR old = swapchain_;
  VkSwapchainCreateInfoKHR ci{};
  ci.sType = VK_STRUCTURE_TYPE_SWAPCHAIN_CREATE_INFO_KHR;
  ci.surface = surface;
  ci.minImageCount = image_count;
  ci.imageFormat = chosen.format;
  ci.imageColorSpace = chosen.colorSpace;
  ci.imageExtent = extent_;
  ci.imageArrayLayers = 1;
  ci.imageUsage = VK_IMAGE_USAGE_TRANSFER_DST_BIT | VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT;
  ci.imageSharingMode = VK_SHARING_MODE_EXCLUSIVE;
  ci.preTransform = caps.currentTransform;
  ci.compositeAlpha = (caps.supportedCompositeAlpha & VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR) != 0
                          ? VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR
                          : static_cast<VkCompositeAlphaFlagBitsKHR>(
                                caps.supportedCompositeAlpha & (~caps.supportedCompositeAlpha + 1));
  ci.presentMode = present_mode_;
  ci.clipped = VK_TRUE;
  ci.oldSwapchain = old;
  VkSwapchainKHR made = VK_NULL_HANDLE;
  if (VkResult r = vkCreateSwapchainKHR(dev, &ci, nullptr, &made); r != VK_SUCCESS)
    return gpu_error_from(r, GpuErrc::unsupported, "vkCreateSwapchainKHR");
  destroy_swapchain();
  swapchain_ = made;

  if (format_ != chosen.format && render_pass_ != VK_NULL_HANDLE) {
    vkDestroyRenderPass(dev, render_pass_, nullptr);
    render_pass_ = VK_NULL_HANDLE;
  }
  format_ = chosen.format;
  if (render_pass_ == VK_NULL_HANDLE) {
    // The overlay's pass: loads what the blit wrote, draws ImGui, leaves it for presenting.
    VkAttachmentDescription att{};
    att.format = format_;
    att.samples = VK_SAMPLE_COUNT_1_BIT;
    att.loadOp = VK_ATTACHMENT_LOAD_OP_LOAD;
    att.storeOp = VK_ATTACHMENT_STORE_OP_STORE;
    att.stencilLoadOp = VK_ATTACHMENT_LOAD_OP_DONT_CARE;
    att.stencilStoreOp = VK_ATTACHMENT_STORE_OP_DONT_CARE;
    att.initialLayout = VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL;
    att.finalLayout = VK_IMAGE_LAYOUT_PRESENT_SRC_KHR;
    VkAttachmentReference ref{0, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL};
    VkSubpassDescription sub{};
    sub.pipelineBindPoint = VK_PIPELINE_BIND_POINT_GRAPHICS;
    sub.colorAttachmentCount = 1;
    sub.pColorAttachments = &ref;
    VkSubpassDependency dep{};
    dep.srcSubpass = VK_SUBPASS_EXTERNAL;
    dep.dstSubpass = 0;
    dep.srcStageMask = VK_PIPELINE_STAGE_TRANSFER_BIT;
    dep.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
    dep.dstStageMask = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT;
    dep.dstAccessMask =
        VK_ACCESS_COLOR_ATTACHMENT_READ_BIT | VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
    VkRenderPassCreateInfo rci{};
    rci.sType = VK_STRUCTURE_TYPE_RENDER_PASS_CREATE_INFO;
    rci.attachmentCount = 1;
    rci.pAttachments = &att;
    rci.subpassCount = 1;
    rci.pSubpasses = &sub;
    rci.dependencyCount = 1;
    rci.pDependencies = &dep;
    if (VkResult r = vkCreateRenderPass(dev, &rci, nullptr, &render_pass_); r != VK_SUCCESS)
      return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateRenderPass");
  }

  n = 0;
  vkGetSwapchainImagesKHR(dev, swapchain_, &n, nullptr);
  images_.resize(n);
  vkGetSwapchainImagesKHR(dev, swapchain_, &n, images_.data());
  for (VkImage image : images_) {
    VkImageViewCreateInfo vci{};
    vci.sType = VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO;
    vci.image = image;
    vci.viewType = VK_IMAGE_VIEW_TYPE_2D;
    vci.format = format_;
    vci.subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
    VkImageView view = VK_NULL_HANDLE;
    if (VkResult r = vkCreateImageView(dev, &vci, nullptr, &view); r != VK_SUCCESS)
      return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateImageView");
    views_.push_back(view);
    VkFramebufferCreateInfo fbi{};
    fbi.sType = VK_STRUCTURE_TYPE_FRAMEBUFFER_CREATE_INFO;
    fbi.renderPass = render_pass_;
    fbi.attachmentCount = 1;
    fbi.pAttachments = &view;
    fbi.width = extent_.width;
    fbi.height = extent_.height;
    fbi.layers = 1;
    VkFramebuffer fb = VK_NULL_HANDLE;
    if (VkResult r = vkCreateFramebuffer(dev, &fbi, nullptr, &fb); r != VK_SUCCESS)
      return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateFramebuffer");
    framebuffers_.push_back(fb);
    VkSemaphoreCreateInfo sci{};
    sci.sType = VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO;
    VkSemaphore s = VK_NULL_HANDLE;
    if (VkResult r = vkCreateSemaphore(dev, &sci, nullptr, &s); r != VK_SUCCESS)
      return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateSemaphore");
    render_done_.push_back(s);
  }
  if (imgui_ready_) ImGui_ImplVulkan_SetMinImageCount(image_count);
  swapchain_dirty_ = false;
  return {};
}

// Destroys what belongs to the current swapchain (the device must be idle or the swapchain
// retired); the swapchain handle itself unless a new one was made from it already.
void StudioWindow::destroy_swapchain() noexcept {
  const VkDevice dev = ctx_->device();
  for (VkFramebuffer fb : framebuffers_) vkDestroyFramebuffer(dev, fb, nullptr);
  for (VkImageView v : views_) vkDestroyImageView(dev, v, nullptr);
  for (VkSemaphore s : render_done_) vkDestroySemaphore(dev, s, nullptr);
  framebuffers_.clear();
  views_.clear();
  render_done_.clear();
  images_.clear();
  if (swapchain_ != VK_NULL_HANDLE) vkDestroySwapchainKHR(dev, swapchain_, nullptr);
  swapchain_ = VK_NULL_HANDLE;
}

// ---- ImGui -----------------------------------------------------------------------------------

Result<void> StudioWindow::init_imgui() {
  const VkDevice dev = ctx_->device();
  // ImGui needs one combined image sampler (its font); a few more for safety.
  const VkDescriptorPoolSize size{VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, 8};
  VkDescriptorPoolCreateInfo dpi{};
  dpi.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO;
  dpi.flags = VK_DESCRIPTOR_POOL_CREATE_FREE_DESCRIPTOR_SET_BIT;
  dpi.maxSets = 8;
  dpi.poolSizeCount = 1;
  dpi.pPoolSizes = &size;
  if (VkResult r = vkCreateDescriptorPool(dev, &dpi, nullptr, &imgui_pool_); r != VK_SUCCESS)
    return gpu_error_from(r, GpuErrc::out_of_memory, "vkCreateDescriptorPool (overlay)");
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGui::GetIO().IniFilename = nullptr;  // no imgui.ini written into the working directory
  ImGui::StyleColorsDark();
  ImGui_ImplGlfw_InitForVulkan(window_, true);
  ImGui_ImplVulkan_InitInfo info{};
  info.Instance = ctx_->instance();
  info.PhysicalDevice = ctx_->physical_device();
  info.Device = dev;
  info.QueueFamily = ctx_->compute_queue().family();
  info.Queue = ctx_->compute_queue().handle();
  info.DescriptorPool = imgui_pool_;
  info.MinImageCount = 2;
  info.ImageCount = static_cast<std::uint32_t>(std::max<std::size_t>(images_.size(), 2));
  info.MSAASamples = VK_SAMPLE_COUNT_1_BIT;
  if (!ImGui_ImplVulkan_Init(&info, render_pass_))
    return gpu_error(GpuErrc::unsupported, "the overlay (Dear ImGui) could not start");
  imgui_ready_ = true;
  auto fonts = ctx_->submit_once(ctx_->compute_queue(), [](VkCommandBuffer cb) {
    ImGui_ImplVulkan_CreateFontsTexture(cb);
  });
  if (!fonts) return fonts;
  ImGui_ImplVulkan_DestroyFontUploadObjects();
  return {};
}

void StudioWindow::begin_ui() {
  ImGui_ImplVulkan_NewFrame();
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
}

// ---- frames ----------------------------------------------------------------------------------

Result<void> StudioWindow::ensure_staging(std::uint32_t width, std::uint32_t height) {
  if (staging_.handle() != VK_NULL_HANDLE && staging_.desc().width == width &&
      staging_.desc().height == height)
    return {};
  client_gpu::ImageDesc desc;
  desc.format = VK_FORMAT_R8G8B8A8_UNORM;
  desc.width = width;
  desc.height = height;
  desc.usage = VK_IMAGE_USAGE_TRANSFER_DST_BIT | VK_IMAGE_USAGE_TRANSFER_SRC_BIT;
  auto img = client_gpu::Image::create(*ctx_, desc);
  if (!img) return std::move(img).error();
  staging_ = std::move(*img);
  return {};
}

Result<void> StudioWindow::wait_frame_done() {
  if (!fence_pending_) return {};
  const VkResult r = vkWaitForFences(ctx_->device(), 1, &fence_, VK_TRUE,
                                     static_cast<std::uint64_t>(ctx_->fence_timeout().count()));
  if (r != VK_SUCCESS) return gpu_error_from(r, GpuErrc::timeout, "waiting for the last frame");
  fence_pending_ = false;
  return vkResetFences(ctx_->device(), 1, &fence_) == VK_SUCCESS
             ? Result<void>{}
             : Result<void>{gpu_error(GpuErrc::device_lost, "vkResetFences")};
}

void StudioWindow::record_frame(VkCommandBuffer cb, const client_gpu::Buffer& pixels,
                                std::uint32_t width, std::uint32_t height,
                                std::uint32_t image_index) {
  using client_gpu::image_barrier;
  // The ray caster's compute writes -> this copy (earlier submissions on the same queue).
  client_gpu::buffer_barrier(cb, pixels, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                             VK_ACCESS_SHADER_WRITE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT,
                             VK_ACCESS_TRANSFER_READ_BIT);
  image_barrier(cb, staging_, VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0, VK_PIPELINE_STAGE_TRANSFER_BIT,
                VK_ACCESS_TRANSFER_WRITE_BIT);
  client_gpu::copy_buffer_to_image(cb, pixels, 0, staging_, 0, 0, width, height);
  image_barrier(cb, staging_, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, VK_PIPELINE_STAGE_TRANSFER_BIT,
                VK_ACCESS_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT,
                VK_ACCESS_TRANSFER_READ_BIT);
  const VkImage target = images_[image_index];
  VkImageMemoryBarrier b{};
  b.sType = VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER;
  b.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.image = target;
  b.subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
  b.oldLayout = VK_IMAGE_LAYOUT_UNDEFINED;
  b.newLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
  b.dstAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
  vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 0,
                       nullptr, 0, nullptr, 1, &b);
  VkImageBlit blit{};
  blit.srcSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  blit.srcOffsets[1] = {static_cast<int32_t>(width), static_cast<int32_t>(height), 1};
  blit.dstSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  blit.dstOffsets[1] = {static_cast<int32_t>(extent_.width), static_cast<int32_t>(extent_.height),
                        1};
  vkCmdBlitImage(cb, staging_.handle(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, target,
                 VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &blit, VK_FILTER_LINEAR);
  b.oldLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
  b.newLayout = VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL;
  b.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
  b.dstAccessMask = VK_ACCESS_COLOR_ATTACHMENT_READ_BIT | VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
  vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT,
                       VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT, 0, 0, nullptr, 0, nullptr, 1,
                       &b);
  VkRenderPassBeginInfo rbi{};
  rbi.sType = VK_STRUCTURE_TYPE_RENDER_PASS_BEGIN_INFO;
  rbi.renderPass = render_pass_;
  rbi.framebuffer = framebuffers_[image_index];
  rbi.renderArea.extent = extent_;
  vkCmdBeginRenderPass(cb, &rbi, VK_SUBPASS_CONTENTS_INLINE);
  ImGui_ImplVulkan_RenderDrawData(ImGui::GetDrawData(), cb);
  vkCmdEndRenderPass(cb);
}

Result<void> StudioWindow::present(const client_gpu::Buffer& pixels, std::uint32_t width,
                                   std::uint32_t height) {
  ImGui::Render();
  if (auto w = wait_frame_done(); !w) return w;
  const auto [fw, fh] = framebuffer_size();
  if (fw == 0 || fh == 0) return {};  // minimised
  if (swapchain_dirty_ || swapchain_ == VK_NULL_HANDLE || fw != extent_.width ||
      fh != extent_.height) {
    if (auto w = ctx_->wait_idle(); !w) return w;
    if (auto s = create_swapchain(); !s) return s;
    if (swapchain_ == VK_NULL_HANDLE) return {};
  }
  if (pixels.handle() == VK_NULL_HANDLE || width == 0 || height == 0 ||
      pixels.size() < VkDeviceSize{width} * height * 4)
    return gpu_error(GpuErrc::bad_argument, "present: no pixels of that size");
  if (auto s = ensure_staging(width, height); !s) return s;

  std::uint32_t index = 0;
  VkResult r = vkAcquireNextImageKHR(ctx_->device(), swapchain_, UINT64_MAX, acquired_,
                                     VK_NULL_HANDLE, &index);
  if (r == VK_ERROR_OUT_OF_DATE_KHR) {
    swapchain_dirty_ = true;
    return {};
  }
  if (r != VK_SUCCESS && r != VK_SUBOPTIMAL_KHR)
    return gpu_error_from(r, GpuErrc::device_lost, "vkAcquireNextImageKHR");

  vkResetCommandBuffer(cb_, 0);
  VkCommandBufferBeginInfo bi{};
  bi.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO;
  bi.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  vkBeginCommandBuffer(cb_, &bi);
  record_frame(cb_, pixels, width, height, index);
  vkEndCommandBuffer(cb_);
  const VkPipelineStageFlags wait_stage = VK_PIPELINE_STAGE_TRANSFER_BIT;
  VkSubmitInfo si{};
  si.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
  si.waitSemaphoreCount = 1;
  si.pWaitSemaphores = &acquired_;
  si.pWaitDstStageMask = &wait_stage;
  si.commandBufferCount = 1;
  si.pCommandBuffers = &cb_;
  si.signalSemaphoreCount = 1;
  si.pSignalSemaphores = &render_done_[index];
  if (auto s = ctx_->compute_queue().submit(si, fence_); !s) return s;
  fence_pending_ = true;
  VkPresentInfoKHR pi{};
  pi.sType = VK_STRUCTURE_TYPE_PRESENT_INFO_KHR;
  pi.waitSemaphoreCount = 1;
  pi.pWaitSemaphores = &render_done_[index];
  pi.swapchainCount = 1;
  pi.pSwapchains = &swapchain_;
  pi.pImageIndices = &index;
  r = ctx_->compute_queue().present(pi);
  if (r == VK_ERROR_OUT_OF_DATE_KHR || r == VK_SUBOPTIMAL_KHR) {
    swapchain_dirty_ = true;
    return {};
  }
  if (r != VK_SUCCESS) return gpu_error_from(r, GpuErrc::device_lost, "vkQueuePresentKHR");
  return {};
}

}  // namespace deepcanvas::window
