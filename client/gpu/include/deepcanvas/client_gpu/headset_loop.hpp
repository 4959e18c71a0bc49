// HeadsetLoop: the headset's frame loop, headless. Both eyes are rendered from one head pose
// (client_core/stereo.hpp) and one resident epoch of one StreamingReplica (one upload stream),
// each eye by its own ray caster into its own output, at the headset's frame interval.
//
// Before the first slot, with dynamic resolution on, probe frames (one at half scale to pay for
// first use, then one timed at half and one at quarter scale) set the controller's starting
// scale and how much of a frame's time is in its pixels, so the first displayed frame does not
// miss while the controller finds it. Probes need painted cells (an empty canvas costs the same
// at any scale): a loop that starts on an empty canvas probes, without the first-use frame, at
// the start of the first frame that has some, and that frame may miss its slot.
// One frame, top to bottom (run()):
//   1. wait for the frame's slot on the interval grid (t0 + k x interval; a late frame takes the
//      next slot: the slots it missed are dropped frames, as on a headset);
//   2. tell the StreamingReplica a frame starts (uploads wait for the gap after it: an upload
//      never lands in a frame, "Frame gaps" in streaming_replica.hpp);
//   3. under the GPU lock: latch the pose as late as possible (pose_at(now)), make both eye
//      cameras at the controller's render scale, locate each eye on the resident epoch's
//      mirror, render both eyes in one submission (a GPU runs them at once);
//   4. the frame is complete when both renders have finished: motion to photon is latch ->
//      complete (a display adds its scan-out; none here), `missed` when complete is past the
//      slot's end;
//   5. feed the render time to the ResolutionController (dynamic resolution with hysteresis)
//      and tell the replica when the next frame is due.
// The network never touches this thread: frames decode and upload on their own threads.
//
// Threading: one thread calls run(); the StreamingReplica must outlive the loop.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/client_core/stereo.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"

namespace deepcanvas::client_gpu {

struct HeadsetOptions {
  client_core::EyeSetup eyes;  // each eye's size at render scale 1
  double hz = 90;              // the headset's refresh rate, (0, 1000]
  double min_scale = 0.25;     // the lowest render scale the controller may choose
  bool adapt = true;           // false: always at fixed_scale
  double fixed_scale = 1.0;
  bool mono = false;           // the left eye only (the stereo cost comparison)
  // Both eyes' ray casts in one submission, side by side (GpuRaycaster::render_together); false:
  // a submission and a wait per eye (the benchmark's comparison).
  bool one_submission = true;
  client_core::RenderOptions render;  // content_bounds and content_empty ignored: the replica's box is used
  bool content_cull = true;
};

struct HeadsetFrame {
  double start_s = 0;              // since run() began
  double pose_t_s = 0;             // the time the pose was latched for (since run() began)
  double render_ms = 0;            // both eyes' renders (under the lock)
  double gpu_ms = -1;              // of render_ms, the device's timestamps (-1: none)
  double motion_to_photon_ms = 0;  // pose latched -> both eyes complete
  double render_scale = 1;
  // The dynamic resolution's estimate of the share of a frame's time in its pixels when this
  // frame's scale was chosen (ResolutionController::pixel_share; -1 with adapt off).
  double pixel_share = -1;
  std::uint64_t epoch = 0;
  bool missed = false;  // complete after its slot ended (a dropped frame on a headset)
  bool empty = true;    // nothing resident yet: nothing rendered
};

class HeadsetLoop {
 public:
  static Result<std::unique_ptr<HeadsetLoop>> create(StreamingReplica& replica,
                                                     const HeadsetOptions& options);
  ~HeadsetLoop();
  HeadsetLoop(const HeadsetLoop&) = delete;
  HeadsetLoop& operator=(const HeadsetLoop&) = delete;

  // Runs frames until `done(frames so far)` says so (asked after each frame). `pose_at(t)` gives
  // the pose at t seconds since run() began; it is called under the GPU lock, so it must be
  // quick. Frames before the first resident epoch are recorded as empty.
  Result<std::vector<HeadsetFrame>> run(
      const std::function<client_core::ArtistPose(double t_s)>& pose_at,
      const std::function<bool(const std::vector<HeadsetFrame>&)>& done);

  // The last frame: both eyes side by side (mono: the left eye), RGBA8 words, row 0 at the top;
  // `width` and `height` receive its size.
  Result<std::vector<std::uint32_t>> read_side_by_side(std::uint32_t& width, std::uint32_t& height);

  const HeadsetOptions& options() const noexcept { return options_; }

 private:
  HeadsetLoop(StreamingReplica& replica, const HeadsetOptions& options)
      : replica_(&replica), options_(options) {}
  // The scale of the probe frames that calibrate dynamic resolution before the first slot.
  static constexpr double kProbeScale = 0.5;
  // Under the GPU lock (`st`): the probe frames' render times at kProbeScale and half of it,
  // after one untimed at kProbeScale where `warm_up` (that one also on an empty canvas). {0, 0}
  // while no painted cell is resident.
  Result<std::array<double, 2>> probe_render_ms(const ResidentState& st,
                                                const client_core::ArtistPose& pose, int eye_count,
                                                bool warm_up);
  Result<void> render_eyes(const ResidentState& st, const std::array<client_core::Camera, 2>& cams,
                           int eye_count, double* gpu_ms = nullptr);
  StreamingReplica* replica_;
  HeadsetOptions options_;
  std::unique_ptr<GpuRaycaster> eyes_[2];
  std::uint32_t eye_width_ = 0, eye_height_ = 0;  // of the last frame
};

}  // namespace deepcanvas::client_gpu
