// RenderLoop: renders frames from a StreamingReplica while it streams (headless: the frames stay
// in the ray caster's output buffer; read_pixels() copies the last one back).
//
// A frame is cut into row bands; each band runs under the StreamingReplica's GPU lock, sees the
// resident epoch (whole epochs only, see streaming_replica.hpp) and locates the camera on the
// mirror of that epoch, so a band is always a consistent state. The number of bands adapts so a
// band takes about `band_target_ms` (from the previous frame's device time; see "Bands" for the
// capped case): an upload batch waits at most one band for the queue, and a band at most one
// batch. Frames before the first resident epoch render nothing (FrameRecord::empty).
//
// Bands: a paced loop whose median frame fits in the fps cap's interval cuts its
// frames into bands of about `capped_band_target_ms` (2 ms) instead of `band_target_ms` (8 ms):
// there the batches go between bands, and a batch arriving during a frame waits for the band in
// progress, so shorter bands lower stroke -> resident latency; their overhead (more submissions
// per frame) lengthens each frame, but inside the idle time the cap leaves anyway. Where frames
// are slower than the cap or the loop is unpaced, that overhead would slow every frame, so bands
// stay at band_target_ms. choose_pace() holds the rule; deepcanvas-bench e2e --capped-band-ms
// and --band-ms measure the alternatives (latency and frame times), deepcanvas-bench render the
// frames.
//
// Content cull (RenderLoopOptions::content_cull, on by default): every band passes the
// StreamingReplica's content box of the epoch it renders (ResidentState::content_bounds, read
// under the same lock, so it always contains that epoch's painted leaves) as
// RenderOptions::content_bounds: rays skip the empty cells outside it (the image is the same;
// without it most rays of a framed painting walk the empty cells around it to the canvas edge,
// which costs several times the frame: deepcanvas-bench render --stream-nocull, and e2e
// --no-cull).
// An epoch with no painted leaf (no box) is background without a step
// (RenderOptions::content_empty): an empty canvas costs no traversal.
// RenderLoopOptions::render.content_bounds is ignored: a fixed box cannot follow a canvas that
// streams in.
//
// Camera: fixed when given; otherwise it frames the content box (Camera::fit_box) once there
// is some, and again at most once a second, between frames, while the content changes.
//
// Pacing (start() only; RenderLoopOptions::max_fps). A display shows at most its refresh rate,
// so a loop that renders faster only takes CPU time (lavapipe renders on the same CPUs as
// everything else) from the uploads and, on one machine, from the server. A paced loop starts a
// frame every `interval` = max(1 / max_fps, render_p50 / (1 - upload_share)) (render_p50: the
// median render time of the last 15 frames). max_fps == 0: frames back to back.
//
// Uploads in gaps (upload_share > 0, default 0.25), once the median frame is slower than the
// fps cap's interval (gaps_above, default 1; below it the cap, or the share kept free, leaves
// idle time anyway and batches go between short bands as soon as they are ready: latency
// first): that share of every interval is kept free and the
// StreamingReplica runs its batches in those gaps (frame_started() / frame_finished(),
// "Frame gaps" in streaming_replica.hpp): a batch waits for the end of the frame in progress
// (one interval at most, then between bands), so frames are not slowed by uploads; the price is
// fewer frames a second where frames are slow and a later residency. upload_share == 0: batches
// go between row bands as soon as they are ready (latency first). Why gaps only where frames set
// the pace: there, uploads between bands would make the frames that overlap a stream markedly
// slower than the others (deepcanvas-bench render compares frames while streaming with the
// finished painting's); where the cap sets the pace, the cap already leaves idle time, and gaps
// would only delay residency (deepcanvas-bench e2e). Why past the cap itself (gaps_above = 1)
// rather than somewhat below it: frames near the cap would switch the loop to gaps of a few ms,
// which batches often miss, so stroke -> resident latency rises by far more than the frames
// gain in steadiness (deepcanvas-bench e2e --gaps-above X and --upload-share F measure both).
//
// Threading: render_frame()/read_pixels() from one thread at a time; start() runs frames on an
// own thread until stop() (then render_frame() must not be called concurrently). frames() is
// thread-safe. The StreamingReplica must outlive the loop.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_gpu {

struct RenderLoopOptions {
  std::uint32_t width = 320, height = 180;
  std::optional<client_core::Camera> camera;  // none: frame the content box
  client_core::RenderOptions render;          // content_bounds ignored, see content_cull
  // Cull rays to the replica's content box (see "Content cull"); false: no cull (comparisons).
  bool content_cull = true;
  double max_fps = 60.0;       // start() only; 0: unpaced (see "Pacing")
  double upload_share = 0.25;  // part of each paced interval kept free for uploads, [0, 0.9]
  // Uploads wait for gaps only while the median frame takes longer than gaps_above x the fps
  // cap's interval (see "Uploads in gaps"); > 0.
  double gaps_above = 1.0;
  double band_target_ms = 8.0;
  // The band target while a paced loop's median frame fits in the cap's interval (start()
  // only): batches then go between bands as soon as they are ready, so shorter bands mean
  // shorter waits for the lock, and their overhead goes into the time the cap leaves idle.
  double capped_band_target_ms = 2.0;
  std::uint32_t max_bands = 64;
  std::uint32_t fixed_bands = 0;  // non-zero: always this many (tests)
};

struct BandRecord {
  std::uint32_t row0 = 0, rows = 0;
  std::uint64_t epoch = 0;
  std::optional<client_core::DAabb> content_bounds;  // the cull box it was rendered with
};

struct FrameRecord {
  SteadyTime start{}, end{};
  double ms = 0;           // start to end, wall clock (waits for uploads included)
  double render_ms = 0;    // its bands' time under the GPU lock (waits for uploads excluded)
  double interval_ms = 0;  // since the previous frame's start (start() only; 0 for the first)
  double cpu_ms = 0;       // process CPU time over the frame
  std::uint64_t min_epoch = 0, max_epoch = 0;  // over its bands
  std::uint32_t bands = 0;
  bool empty = true;  // no epoch was resident: nothing rendered
  // An upload batch became resident during the frame or since the previous frame ended.
  bool streaming = false;
  std::vector<BandRecord> band_list;  // filled when RenderLoopOptions::fixed_bands or tests ask
};

// How a paced loop runs its next frames (see "Pacing", "Uploads in gaps", "Bands"), from its
// options and the median render time of its last frames (0: none yet).
struct LoopPace {
  double interval_ms = 0;     // frame start to frame start
  bool gaps = false;          // uploads wait for the gaps between frames
  double band_target_ms = 0;  // the band target for the next frame
};
LoopPace choose_pace(const RenderLoopOptions& options, double render_p50_ms) noexcept;

class RenderLoop {
 public:
  static Result<std::unique_ptr<RenderLoop>> create(StreamingReplica& replica,
                                                    const RenderLoopOptions& options);
  ~RenderLoop();
  RenderLoop(const RenderLoop&) = delete;
  RenderLoop& operator=(const RenderLoop&) = delete;

  Result<FrameRecord> render_frame(bool keep_bands = false);
  // The last frame's pixels (RGBA8 words), under the GPU lock.
  Result<std::vector<std::uint32_t>> read_pixels();
  // The camera (and so the size) of the frames from the next one on, for a loop driven frame
  // by frame (the studio window): like RenderLoopOptions::camera. Not while start() runs.
  void set_camera(const client_core::Camera& camera);
  // The ray caster's output buffer: the last frame's pixels on the device (see
  // GpuRaycaster::output()). Valid until the next render_frame(); not while start() runs.
  const Buffer& output() const noexcept { return raycaster_->output(); }

  // Background frames until stop(); frames() collects their records.
  void start();
  Result<void> stop();  // the first frame error, if any
  std::vector<FrameRecord> frames() const;
  std::uint64_t frame_count() const noexcept { return frame_count_.load(); }
  const client_core::Camera* camera() const noexcept { return camera_ ? &*camera_ : nullptr; }

 private:
  RenderLoop(StreamingReplica& replica, const RenderLoopOptions& options)
      : replica_(&replica), options_(options) {}

  StreamingReplica* replica_;
  RenderLoopOptions options_;
  std::unique_ptr<GpuRaycaster> raycaster_;
  std::optional<client_core::Camera> camera_;
  bool camera_from_content_ = false;
  std::uint64_t framed_epoch_ = 0;
  bool framed_partial_ = false;  // framed on part of a snapshot (progressive join)
  SteadyTime framed_at_{};
  // The last frame's bands' device time on a GPU (timestamps), their wall time on a CPU device
  // or without timestamps: the band count of the next frame.
  double last_frame_work_ms_ = 0;
  // The band target in use: band_target_ms, or capped_band_target_ms while the loop thread
  // finds its frames within the cap (choose_pace).
  double band_target_now_ms_ = options_.band_target_ms;
  std::uint64_t batches_at_frame_end_ = 0;
  std::thread thread_;
  std::atomic<bool> running_{false};
  std::atomic<std::uint64_t> frame_count_{0};
  mutable std::mutex mutex_;
  std::vector<FrameRecord> frames_;
  Result<void> error_;
};

}  // namespace deepcanvas::client_gpu
