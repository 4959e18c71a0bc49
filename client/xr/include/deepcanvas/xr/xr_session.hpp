// XrHeadset: the headset client's OpenXR session with a Vulkan graphics binding
// (XR_KHR_vulkan_enable2). It makes the XR instance and system, the client's Vulkan context
// through the runtime (client_gpu::VulkanCreationHooks: the runtime creates the instance and
// device and picks the GPU it drives), the session, a LOCAL reference space, one swapchain per
// view (the runtime's recommended size; an 8-bit RGBA format, sRGB where offered) and the
// controller actions (aim pose, trigger value, grip) of the Khronos simple controller profile.
//
// A frame, for the caller's loop (xr_command.cpp), top to bottom:
//   poll()        events: READY begins the session, STOPPING ends it, EXITING / LOSS_PENDING
//                 end the loop (false);
//   begin_frame() xrWaitFrame (the runtime paces the loop), xrBeginFrame, xrLocateViews at the
//                 predicted display time (both eyes' poses and fields of view), xrSyncActions
//                 and the controllers' states;
//   render each eye into a device buffer (the ray caster's output), then
//   end_frame()   copies each eye's buffer into its swapchain image and submits a projection
//                 layer of both views (no layer when the frame should not be rendered).
//
// Errors: every XrResult that fails becomes Errc::io_error naming the call and the runtime's
// string for it; no OpenXR runtime installed or active is Errc::unsupported with a message that
// says so. Threading: one thread. Destruction ends the session and destroys everything in order
// (swapchains, spaces, session, then the Vulkan context, then the XR instance).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_core/stereo.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/memory.hpp"

namespace deepcanvas::xr {

// One eye as the runtime locates it: its pose in the reference space (room metres, OpenXR's
// axes: +y up, looking down -z) and its field of view (radians, left and down negative).
struct EyeView {
  client_core::DVec3 position;
  client_core::Quat orientation;
  double angle_left = 0, angle_right = 0, angle_up = 0, angle_down = 0;
  std::uint32_t width = 0, height = 0;  // the swapchain's size
};

struct ControllerState {
  bool active = false;  // the runtime tracks this hand
  client_core::DVec3 tip;  // the aim pose's position, room metres
  double trigger = 0;      // 0..1
  bool grip = false;
};

struct XrFrame {
  bool should_render = false;
  bool views_valid = false;  // both eyes' orientation and position located
  std::int64_t display_time = 0;  // XrTime (ns)
  double display_period_ms = 0;   // the runtime's frame interval
  std::array<EyeView, 2> eyes;
  std::array<ControllerState, 2> hands;  // left, right
};

class XrHeadset {
 public:
  // The runtime picks the GPU (there is no --device: the headset is wired to one).
  static Result<std::unique_ptr<XrHeadset>> create(const std::string& app_name);
  ~XrHeadset();
  XrHeadset(const XrHeadset&) = delete;
  XrHeadset& operator=(const XrHeadset&) = delete;

  client_gpu::Context& context() noexcept;
  const std::string& runtime_name() const noexcept;
  const std::string& system_name() const noexcept;

  // Events; false once the session has ended (the loop should stop).
  Result<bool> poll();
  bool running() const noexcept;  // begun and not ended
  Result<XrFrame> begin_frame();
  // `eyes[i]` holds sizes[i] = {w, h} RGBA8 words (the ray caster's output; at most the eye's
  // swapchain size: dynamic resolution renders fewer pixels, and the layer shows that
  // sub-rectangle of the swapchain image) when the frame is rendered; ignored otherwise.
  Result<void> end_frame(const XrFrame& frame, std::array<const client_gpu::Buffer*, 2> eyes,
                         std::array<std::array<std::uint32_t, 2>, 2> sizes);
  // Asks the runtime to end the session (STOPPING follows; keep polling).
  Result<void> request_exit();

  struct Impl;

 private:
  XrHeadset() = default;
  std::unique_ptr<Impl> impl_;
};

// A symmetric field of view that covers an eye's asymmetric one (the ray casters' cameras are
// symmetric): the vertical angle 2 x max(|up|, |down|) in degrees. The image then shows a little
// more than the runtime's frustum (the price: a slightly smaller scale near the edges).
double covering_vfov_deg(const EyeView& eye) noexcept;

}  // namespace deepcanvas::xr
