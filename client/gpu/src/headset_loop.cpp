// The headset's frame loop (headset_loop.hpp).
#include "deepcanvas/client_gpu/headset_loop.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <thread>

#include "deepcanvas/client_gpu/errors.hpp"

namespace deepcanvas::client_gpu {

namespace {
using Clock = std::chrono::steady_clock;
double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}
}  // namespace

Result<std::unique_ptr<HeadsetLoop>> HeadsetLoop::create(StreamingReplica& replica,
                                                         const HeadsetOptions& options) {
  if (!(options.hz > 0 && options.hz <= 1000) || !(options.min_scale > 0 && options.min_scale <= 1) ||
      !(options.fixed_scale > 0 && options.fixed_scale <= 1) || options.eyes.width == 0 ||
      options.eyes.height == 0 || options.eyes.width > 16384 || options.eyes.height > 16384)
    return gpu_error(GpuErrc::bad_argument,
                     "headset loop: hz in (0, 1000], render scales in (0, 1], eye sizes 1..16384");
  std::unique_ptr<HeadsetLoop> loop(new HeadsetLoop(replica, options));
  auto made = replica.with_gpu([&](const ResidentState& st) -> Result<void> {
    for (int e = 0; e < (options.mono ? 1 : 2); ++e) {
      auto rc = GpuRaycaster::create(st.replica);
      if (!rc) return std::move(rc).error();
      loop->eyes_[e] = std::move(*rc);
    }
    return {};
  });
  if (!made) return std::move(made).error();
  return loop;
}

HeadsetLoop::~HeadsetLoop() = default;

// Under the GPU lock: each eye located on the resident epoch and ray cast into its output, both
// eyes in one submission unless options_.one_submission is off.
Result<void> HeadsetLoop::render_eyes(const ResidentState& st,
                                      const std::array<client_core::Camera, 2>& cams,
                                      int eye_count, double* gpu_ms) {
  double gpu = 0;
  client_core::RenderOptions ro = options_.render;
  ro.content_bounds.reset();
  ro.content_empty = false;
  ro.content_boxes.reset();
  for (int e = 0; e < eye_count; ++e) {
    const auto& cam = cams[static_cast<std::size_t>(e)];
    if (options_.content_cull) st.cull_for_view(ro, cam);
    auto origin = client_core::make_ray_origin(st.pools, cam.position());
    if (!origin) return std::move(origin).error();
    if (auto v = eyes_[e]->set_frame(cam, *origin, ro); !v) return v;
    if (!options_.one_submission) {
      FrameTiming t;
      if (auto v = eyes_[e]->render(1, &t); !v) return v;
      gpu = gpu < 0 || t.gpu_ms < 0 ? -1 : gpu + t.gpu_ms;
    }
  }
  if (options_.one_submission) {
    GpuRaycaster* const views[2] = {eyes_[0].get(), eyes_[1].get()};
    FrameTiming t;
    if (auto v = GpuRaycaster::render_together({views, static_cast<std::size_t>(eye_count)}, &t);
        !v)
      return v;
    gpu = t.gpu_ms;
  }
  if (gpu_ms) *gpu_ms = gpu;
  return {};
}

// Both eyes rendered at kProbeScale with what is resident (where `warm_up`: to pay for first use:
// pipelines, caches; also on an empty canvas, so that its first frame does not pay for it), then
// timed at kProbeScale and at half of it. {0, 0} while no painted cell is resident (frames of an
// empty canvas are cheap at any scale and would teach the controller that the pixels cost
// nothing).
Result<std::array<double, 2>> HeadsetLoop::probe_render_ms(const ResidentState& st,
                                                          const client_core::ArtistPose& pose,
                                                          int eye_count, bool warm_up) {
  std::array<double, 2> ms{0, 0};
  if (!st.any) return ms;
  const int passes = st.content_bounds ? 3 : 1;  // an empty canvas: the warm-up only
  for (int pass = warm_up ? 0 : 1; pass < passes; ++pass) {
    auto cams =
        client_core::eye_cameras(pose, options_.eyes, pass < 2 ? kProbeScale : kProbeScale / 2);
    if (!cams) return std::move(cams).error();
    const auto t0 = Clock::now();
    if (auto v = render_eyes(st, *cams, eye_count); !v) return std::move(v).error();
    if (pass > 0) ms[static_cast<std::size_t>(pass - 1)] = ms_between(t0, Clock::now());
  }
  return ms;
}

Result<std::vector<HeadsetFrame>> HeadsetLoop::run(
    const std::function<client_core::ArtistPose(double)>& pose_at,
    const std::function<bool(const std::vector<HeadsetFrame>&)>& done) {
  client_core::ResolutionController::Options co;
  co.interval_ms = 1000.0 / options_.hz;
  co.min_scale = options_.min_scale;
  client_core::ResolutionController controller(co);
  const auto interval = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double, std::milli>(co.interval_ms));
  const int eye_count = options_.mono ? 1 : 2;
  // Probes before the first slot, or at the start of the first frame with painted cells.
  bool calibrated = !options_.adapt;
  double probe_ms = 0;  // the last probe at kProbeScale
  const auto calibrate = [&](const ResidentState& st, double t_s, bool warm_up) -> Result<void> {
    auto probe = probe_render_ms(st, pose_at(t_s), eye_count, warm_up);
    if (!probe) return std::move(probe).error();
    if ((*probe)[0] <= 0) return {};
    probe_ms = (*probe)[0];
    controller.calibrate(kProbeScale, (*probe)[0], kProbeScale / 2, (*probe)[1]);
    calibrated = true;
    return {};
  };
  if (!calibrated)
    if (auto r = replica_->with_gpu([&](const ResidentState& st) { return calibrate(st, 0, true); });
        !r)
      return std::move(r).error();
  std::vector<HeadsetFrame> frames;
  const Clock::time_point t0 = Clock::now();
  Clock::time_point slot = t0;
  replica_->attach_frames(true);
  Result<void> failed;
  for (;;) {
    std::this_thread::sleep_until(slot);
    HeadsetFrame f;
    const Clock::time_point start = Clock::now();
    f.start_s = std::chrono::duration<double>(start - t0).count();
    f.render_scale = options_.adapt ? controller.scale() : options_.fixed_scale;
    f.pixel_share = options_.adapt ? controller.pixel_share() : -1;
    replica_->frame_started(co.interval_ms);
    Clock::time_point latched{}, complete{};
    bool probed_in_slot = false;
    auto r = replica_->with_gpu([&](const ResidentState& st) -> Result<void> {
      if (!st.any) return {};
      if (!calibrated) {
        if (auto c = calibrate(st, std::chrono::duration<double>(Clock::now() - t0).count(), false);
            !c)
          return c;
        if (calibrated) {
          // The probes took part of this slot: this one frame is rendered at the scale the
          // model says fits in what is left of `aim` of it (so the first painted frame does not
          // miss for them), and the controller does not learn from it.
          const double left = co.aim * co.interval_ms - ms_between(start, Clock::now());
          f.render_scale = controller.scale_within(left, kProbeScale, probe_ms);
          f.pixel_share = controller.pixel_share();
          probed_in_slot = true;
        }
      }
      latched = Clock::now();
      f.pose_t_s = std::chrono::duration<double>(latched - t0).count();
      const client_core::ArtistPose pose = pose_at(f.pose_t_s);
      auto cams = client_core::eye_cameras(pose, options_.eyes, f.render_scale);
      if (!cams) return std::move(cams).error();
      if (auto v = render_eyes(st, *cams, eye_count, &f.gpu_ms); !v) return v;
      complete = Clock::now();
      eye_width_ = (*cams)[0].width();
      eye_height_ = (*cams)[0].height();
      f.epoch = st.epoch;
      f.empty = false;
      return {};
    });
    if (!r) {
      failed = std::move(r).error();
      break;
    }
    const Clock::time_point end = f.empty ? Clock::now() : complete;
    if (!f.empty) {
      f.render_ms = ms_between(latched, complete);
      f.motion_to_photon_ms = f.render_ms;
      f.missed = end > slot + interval;
      if (options_.adapt && !probed_in_slot) controller.frame_done(f.render_ms);
    }
    // The next slot on the grid after this frame's end (the slots in between are dropped).
    slot += interval;
    while (slot < end) slot += interval;
    replica_->frame_finished(slot);
    frames.push_back(f);
    if (done(frames)) break;
  }
  replica_->attach_frames(false);
  if (!failed) return std::move(failed).error();
  return frames;
}

Result<std::vector<std::uint32_t>> HeadsetLoop::read_side_by_side(std::uint32_t& width,
                                                                  std::uint32_t& height) {
  const int eye_count = options_.mono ? 1 : 2;
  std::vector<std::uint32_t> eyes[2];
  auto r = replica_->with_gpu([&](const ResidentState&) -> Result<void> {
    for (int e = 0; e < eye_count; ++e) {
      auto px = eyes_[e]->read_pixels();
      if (!px) return std::move(px).error();
      eyes[e] = std::move(*px);
    }
    return {};
  });
  if (!r) return std::move(r).error();
  const std::uint32_t w = eye_width_, h = eye_height_;
  if (w == 0 || eyes[0].size() != std::size_t{w} * h)
    return gpu_error(GpuErrc::bad_argument, "headset loop: no frame rendered yet");
  width = w * static_cast<std::uint32_t>(eye_count);
  height = h;
  std::vector<std::uint32_t> out(std::size_t{width} * h);
  for (std::uint32_t y = 0; y < h; ++y)
    for (int e = 0; e < eye_count; ++e)
      std::copy_n(eyes[e].begin() + std::ptrdiff_t{y} * w, w,
                  out.begin() + std::ptrdiff_t{y} * width + std::ptrdiff_t{e} * w);
  return out;
}

}  // namespace deepcanvas::client_gpu
