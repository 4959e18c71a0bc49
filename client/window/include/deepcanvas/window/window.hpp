// StudioWindow: a GLFW window that shows the ray caster's frames through a Vulkan swapchain,
// with a Dear ImGui overlay drawn over them.
//
// One frame, from the caller's frame loop (studio_command.cpp):
//
//   window->poll();                        // GLFW events -> ImGui's input state
//   window->begin_ui();                    // ImGui::NewFrame(): panels may be built now
//   ... render the 3D view into a buffer (RenderLoop::render_frame) ...
//   window->present(pixels, w, h);         // ImGui::Render() + copy, scale, overlay, present
//
// present() records one command buffer: a barrier from the ray caster's compute writes, the
// RGBA8 buffer copied into an image of its size, that image blitted (scaled, linear filter,
// RGBA -> the swapchain's format) onto the swapchain image, then the ImGui draw data in a render
// pass that loads the blitted pixels. One frame is in flight: present() first waits for the
// previous frame's submission, so after present() returns the caller may write the buffer again
// only once wait_idle_frame() says the copy is done (render_frame() calls it implicitly through
// the caller: see studio_command.cpp). The swapchain is recreated when the framebuffer size
// changes or the surface says it is out of date; a minimised window (size 0) presents nothing.
//
// The Vulkan context is a client_gpu::Context made with present_to() on this window's surface,
// so the StreamingReplica, the ray caster and the overlay share one device and queue.
//
// vsync: FIFO (always available); without vsync, MAILBOX where the surface has it, else
// IMMEDIATE, else FIFO. Fullscreen: the primary monitor at its current mode, toggled.
//
// Errors: GLFW that cannot start (no display: the message says so) or has no Vulkan, and the
// errors of client_gpu::ContextBuilder. Exceptions are not used.
//
// Threading: everything here runs on the thread that created the window (GLFW requires the
// main thread for its event functions); the Context may be used from other threads as usual.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/memory.hpp"

struct GLFWwindow;

namespace deepcanvas::window {

struct WindowOptions {
  std::string title = "deepcanvas studio";
  std::uint32_t width = 1280, height = 720;
  bool vsync = true;
  bool fullscreen = false;
  std::string device;  // client_gpu device override (index or name part); empty: automatic
  bool validation = false;
};

// A key pressed (or repeating while held) since the last take_key_presses(). The window keeps
// them itself because Dear ImGui 1.86 keeps only each key's current state, so a press and its
// release between two frames (a quick tap, or synthetic input) would never be seen.
struct KeyPress {
  int key = 0;   // GLFW_KEY_*
  int mods = 0;  // GLFW_MOD_*
  bool repeat = false;
};

class StudioWindow {
 public:
  static Result<std::unique_ptr<StudioWindow>> create(const WindowOptions& options);
  ~StudioWindow();
  StudioWindow(const StudioWindow&) = delete;
  StudioWindow& operator=(const StudioWindow&) = delete;

  const client_gpu::Context& context() const noexcept { return *ctx_; }
  GLFWwindow* glfw() const noexcept { return window_; }

  // Processes the window system's events (input reaches ImGui's IO, key presses the list
  // below).
  void poll();
  std::vector<KeyPress> take_key_presses();
  // Every pointer position reported since the last call (window coordinates), in order: a
  // stroke follows the pointer's whole path, not one position per frame.
  std::vector<std::pair<double, double>> take_pointer_moves();
  bool should_close() const;
  void request_close();
  // The framebuffer's size in pixels now (0 x 0 while minimised).
  std::pair<std::uint32_t, std::uint32_t> framebuffer_size() const;

  // Starts the ImGui frame (ImGui::NewFrame); build panels after it, then present().
  void begin_ui();
  // Shows `pixels` (RGBA8 words, width x height, written by compute shaders on the context's
  // compute queue) scaled to the window, with the ImGui frame over it, and presents. Waits for
  // the previous frame's submission first. A minimised window or an out-of-date swapchain skips
  // the frame (recreated for the next one): not an error.
  Result<void> present(const client_gpu::Buffer& pixels, std::uint32_t width,
                       std::uint32_t height);
  // Waits until the last present()'s copy of the pixels is done (the caller may then write the
  // buffer again).
  Result<void> wait_frame_done();

  void set_vsync(bool on);
  bool vsync() const noexcept { return vsync_; }
  void toggle_fullscreen();
  bool fullscreen() const noexcept { return fullscreen_; }
  // The present mode in use, for the status line ("fifo", "mailbox", "immediate").
  const char* present_mode_name() const noexcept;

 private:
  StudioWindow() = default;
  Result<void> init_imgui();
  Result<void> create_swapchain();
  void destroy_swapchain() noexcept;
  Result<void> ensure_staging(std::uint32_t width, std::uint32_t height);
  void record_frame(VkCommandBuffer cb, const client_gpu::Buffer& pixels, std::uint32_t width,
                    std::uint32_t height, std::uint32_t image_index);

  GLFWwindow* window_ = nullptr;
  std::unique_ptr<client_gpu::Context> ctx_;
  bool vsync_ = true, fullscreen_ = false, swapchain_dirty_ = false;
  int windowed_x_ = 0, windowed_y_ = 0, windowed_w_ = 0, windowed_h_ = 0;

  // The swapchain and what is made per image.
  VkSwapchainKHR swapchain_ = VK_NULL_HANDLE;
  VkFormat format_ = VK_FORMAT_UNDEFINED;
  VkPresentModeKHR present_mode_ = VK_PRESENT_MODE_FIFO_KHR;
  VkExtent2D extent_{};
  std::vector<VkImage> images_;
  std::vector<VkImageView> views_;
  std::vector<VkFramebuffer> framebuffers_;
  std::vector<VkSemaphore> render_done_;  // per image: the present waits for it
  VkRenderPass render_pass_ = VK_NULL_HANDLE;  // the overlay's: loads the blitted pixels

  // The one frame in flight.
  VkCommandPool pool_ = VK_NULL_HANDLE;
  VkCommandBuffer cb_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;
  bool fence_pending_ = false;
  VkSemaphore acquired_ = VK_NULL_HANDLE;
  client_gpu::Image staging_;  // the ray caster's pixels as an image (blit source)

  std::vector<KeyPress> keys_;
  std::vector<std::pair<double, double>> moves_;
  VkDescriptorPool imgui_pool_ = VK_NULL_HANDLE;
  bool imgui_ready_ = false;
};

}  // namespace deepcanvas::window
