// RenderLoop: banded frames under the StreamingReplica's GPU lock (see render_loop.hpp).
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/base/thread_name.hpp"

#include <algorithm>
#include <cmath>

#include <time.h>

#include "deepcanvas/client_gpu/errors.hpp"

namespace deepcanvas::client_gpu {
namespace {

using Clock = std::chrono::steady_clock;

double process_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) * 1e3 + static_cast<double>(ts.tv_nsec) * 1e-6;
}

}  // namespace

LoopPace choose_pace(const RenderLoopOptions& options, double render_p50_ms) noexcept {
  LoopPace pace;
  if (options.max_fps <= 0) {  // unpaced: frames back to back, batches between bands
    pace.band_target_ms = options.band_target_ms;
    return pace;
  }
  const double cap_ms = 1000.0 / options.max_fps;
  pace.interval_ms = std::max(cap_ms, render_p50_ms / (1.0 - options.upload_share));
  pace.gaps = options.upload_share > 0 && render_p50_ms > options.gaps_above * cap_ms;
  // Short bands while the frames fit in the cap's interval: their overhead goes into time the
  // cap leaves idle (see "Bands").
  pace.band_target_ms =
      render_p50_ms <= cap_ms ? options.capped_band_target_ms : options.band_target_ms;
  return pace;
}

Result<std::unique_ptr<RenderLoop>> RenderLoop::create(StreamingReplica& replica,
                                                       const RenderLoopOptions& options) {
  if (options.width == 0 || options.height == 0 || options.width > 16384 ||
      options.height > 16384 || !(options.band_target_ms > 0) ||
      !(options.capped_band_target_ms > 0) || options.max_bands == 0 ||
      !(options.max_fps >= 0 && options.max_fps <= 10000) ||
      !(options.upload_share >= 0 && options.upload_share <= 0.9) ||
      !(options.gaps_above > 0 && options.gaps_above <= 100)) {
    return gpu_error(GpuErrc::bad_argument,
                     "render loop: bad size, band, max_fps (0..10000), upload_share (0..0.9) or "
                     "gaps_above (0..100]");
  }
  std::unique_ptr<RenderLoop> loop(new RenderLoop(replica, options));
  loop->camera_ = options.camera;
  auto made = replica.with_gpu([&](const ResidentState& st) -> Result<void> {
    auto rc = GpuRaycaster::create(st.replica);
    if (!rc) return std::move(rc).error();
    loop->raycaster_ = std::move(*rc);
    return {};
  });
  if (!made) return std::move(made).error();
  return loop;
}

void RenderLoop::set_camera(const client_core::Camera& camera) {
  options_.camera = camera;
  options_.width = camera.width();
  options_.height = camera.height();
  camera_ = camera;
  camera_from_content_ = true;
}

RenderLoop::~RenderLoop() {
  (void)stop();
  // The raycaster's Vulkan objects are destroyed here; nothing of it is in flight (every band
  // waits for its submission).
}

Result<FrameRecord> RenderLoop::render_frame(bool keep_bands) {
  FrameRecord f;
  f.start = Clock::now();
  const double cpu0 = process_cpu_ms();
  const std::uint32_t h = options_.height;
  std::uint32_t bands = options_.fixed_bands;
  if (bands == 0) {
    // From the last frame's work: on a GPU its device time (timestamps), not its wall time,
    // since each band's submission and wait cost a fixed overhead that more bands would only
    // multiply (deepcanvas-bench e2e on a lent H200: frames while streaming p99 67-83 ms
    // by wall time, 23-24 ms by device time). On a CPU device (lavapipe) the wall time is the
    // work, overhead and all, and what a waiting upload batch waits for.
    bands = last_frame_work_ms_ > 0
                ? static_cast<std::uint32_t>(std::ceil(last_frame_work_ms_ / band_target_now_ms_))
                : 4;
    bands = std::clamp(bands, 1u, std::min(options_.max_bands, h));
  }
  const std::uint32_t per = (h + bands - 1) / bands;
  double gpu_ms = 0, work_ms = 0;
  bool first = true;
  for (std::uint32_t row0 = 0; row0 < h; row0 += per) {
    const std::uint32_t rows = std::min(per, h - row0);
    auto r = replica_->with_gpu([&](const ResidentState& st) -> Result<void> {
      if (!st.any) return {};
      // Without a fixed camera: frame the content box, again at the start of a frame at most
      // once a second while the content changes.
      const bool reframe = !options_.camera && first && camera_from_content_ &&
                           (st.epoch != framed_epoch_ || st.partial != framed_partial_) &&
                           Clock::now() - framed_at_ > std::chrono::seconds(1);
      if (!camera_ || !camera_from_content_ || reframe) {
        if (!options_.camera) {
          framed_epoch_ = st.epoch;
          framed_partial_ = st.partial;
          framed_at_ = Clock::now();
          // The content box, not painted_bounds (O(cells) under the lock): after erases it
          // may be looser than the paint until the replica shrinks it, and then re-frames.
          if (const auto& box = st.content_bounds) {
            // Paintings are y-up (A-Painter's convention): from the front, slightly above, as
            // the render command does.
            auto cam = client_core::Camera::fit_box(*box, options_.width, options_.height, 45.0,
                                                    {-0.45, -0.35, -0.82}, {0, 1, 0});
            if (!cam) return std::move(cam).error();
            camera_ = *cam;
            camera_from_content_ = true;
          } else if (!camera_) {
            auto cam = client_core::Camera::frame_box({{-1, -1, -1}, {1, 1, 1}}, options_.width,
                                                      options_.height);
            if (!cam) return std::move(cam).error();
            camera_ = *cam;
          }
        } else {
          camera_from_content_ = true;
        }
      }
      auto origin = client_core::make_ray_origin(st.pools, camera_->position());
      if (!origin) return std::move(origin).error();
      client_core::RenderOptions render = options_.render;
      render.content_bounds.reset();
      render.content_empty = false;
      render.content_boxes.reset();
      if (options_.content_cull) st.cull_for_view(render, *camera_);
      if (auto v = raycaster_->set_frame(*camera_, *origin, render); !v) return v;
      FrameTiming t;
      if (auto v = raycaster_->render_rows(row0, rows, &t); !v) return v;
      gpu_ms += t.wall_ms;
      work_ms += t.gpu_ms >= 0 && !raycaster_->cpu_device() ? t.gpu_ms : t.wall_ms;
      if (first || st.epoch < f.min_epoch) f.min_epoch = st.epoch;
      if (first || st.epoch > f.max_epoch) f.max_epoch = st.epoch;
      first = false;
      f.empty = false;
      ++f.bands;
      if (keep_bands) f.band_list.push_back({row0, rows, st.epoch, render.content_bounds});
      return {};
    });
    if (!r) return std::move(r).error();
  }
  if (!f.empty) last_frame_work_ms_ = work_ms;
  f.render_ms = gpu_ms;
  f.end = Clock::now();
  f.ms = std::chrono::duration<double, std::milli>(f.end - f.start).count();
  f.cpu_ms = process_cpu_ms() - cpu0;
  // Batches since the previous frame ended: during this frame, or in the gap before it.
  const std::uint64_t batches_now = replica_->stats().batches;
  f.streaming = batches_now != batches_at_frame_end_;
  batches_at_frame_end_ = batches_now;
  return f;
}

Result<std::vector<std::uint32_t>> RenderLoop::read_pixels() {
  std::vector<std::uint32_t> out;
  auto r = replica_->with_gpu([&](const ResidentState&) -> Result<void> {
    auto px = raycaster_->read_pixels();
    if (!px) return std::move(px).error();
    out = std::move(*px);
    return {};
  });
  if (!r) return std::move(r).error();
  return out;
}

void RenderLoop::start() {
  if (running_.exchange(true)) return;
  replica_->attach_frames(true);
  thread_ = std::thread([this] {
    base::set_thread_name("dc-render");
    const bool paced = options_.max_fps > 0;
    std::vector<double> recent;  // render_ms of the last frames (pacing)
    std::size_t recent_next = 0;
    LoopPace pace = choose_pace(options_, 0.0);
    SteadyTime due = Clock::now();
    SteadyTime previous_start{};
    bool have_previous = false;
    while (running_.load()) {
      if (paced) std::this_thread::sleep_until(due);
      const SteadyTime started = Clock::now();
      // Uploads in the gaps kept free (upload_share) when frames are slower than the cap;
      // otherwise batches go between short bands as soon as they are ready. A batch that has
      // waited one interval for a gap goes between bands after all.
      band_target_now_ms_ = pace.band_target_ms;
      replica_->frame_started(pace.gaps ? pace.interval_ms : 0.0);
      auto f = render_frame();
      if (f && paced && !f->empty) {
        if (recent.size() < 15) {
          recent.push_back(f->render_ms);
        } else {
          recent[recent_next] = f->render_ms;
          recent_next = (recent_next + 1) % recent.size();
        }
        std::vector<double> sorted = recent;
        std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
        pace = choose_pace(options_, sorted[sorted.size() / 2]);
      }
      // The next frame is due one interval after this one started (at once when late).
      due = std::max(Clock::now(),
                     started + std::chrono::duration_cast<Clock::duration>(
                                   std::chrono::duration<double, std::milli>(pace.interval_ms)));
      replica_->frame_finished(due);
      if (!f) {
        std::lock_guard l(mutex_);
        error_ = std::move(f).error();
        running_ = false;
        return;
      }
      if (f->empty) {  // nothing resident yet: do not spin
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
        due = Clock::now();
        continue;
      }
      f->start = started;
      f->ms = std::chrono::duration<double, std::milli>(f->end - f->start).count();
      f->interval_ms =
          have_previous
              ? std::chrono::duration<double, std::milli>(started - previous_start).count()
              : 0.0;
      previous_start = started;
      have_previous = true;
      ++frame_count_;
      std::lock_guard l(mutex_);
      frames_.push_back(std::move(*f));
    }
  });
}

Result<void> RenderLoop::stop() {
  running_ = false;
  if (thread_.joinable()) {
    thread_.join();
    band_target_now_ms_ = options_.band_target_ms;  // render_frame() on its own
    replica_->attach_frames(false);
  }
  std::lock_guard l(mutex_);
  return error_;
}

std::vector<FrameRecord> RenderLoop::frames() const {
  std::lock_guard l(mutex_);
  return frames_;
}

}  // namespace deepcanvas::client_gpu
