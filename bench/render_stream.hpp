// The render suite's streaming measurement (bench/render_bench.cpp calls it): a painting is
// painted into an in-process server Octree and captured epoch by epoch first (so the server's
// painting does not compete for the CPUs lavapipe renders on), then the epochs are pushed at a
// fixed pace into a StreamingReplica (upload thread) while a RenderLoop renders continuously
// on its own thread. Frames that start between the first push and the last epoch becoming
// resident are "while streaming";
// after the stream, frames of the finished painting (no uploads) give the static p50 of the same
// run, so the ratio is measured under the same load. DEEPCANVAS_BENCH_TRACE=1 (environment):
// one stderr line per frame and per batch.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"

namespace deepcanvas::bench {

struct StreamingFrames {
  std::vector<double> streaming_ms;  // frames started while the stream was being pushed/uploaded
  // Of those, the frames right after or during an upload batch (FrameRecord::streaming): the
  // stricter set, reported beside it as batch_frames_p99_over_p50.
  std::vector<double> batch_frame_ms;
  std::vector<double> static_ms;  // frames of the finished painting, nothing uploading
  double frame_ms_p50 = 0;        // static median
  double frame_ms_p99_while_streaming = 0;
  // Start-to-start intervals of the same frames (a paced loop's rhythm: a late frame shows
  // here even when its own time does not).
  std::vector<double> streaming_interval_ms, static_interval_ms;
  // Upload batches: how many were scheduled in a gap between frames, and how many went
  // mid-frame because no gap came in time (loops with gaps only); commit -> resident per epoch.
  std::size_t gap_batches = 0, mid_frame_batches = 0;
  double max_fps = 0, upload_share = 0;  // the loop's options
  std::vector<double> commit_to_resident_ms;
  // Per batch (after the snapshot): time under the GPU lock and its parts, the content box's
  // growth (before the lock), rows uploaded.
  std::vector<double> batch_lock_ms, batch_mirror_ms, batch_upload_ms, batch_links_ms,
      batch_content_ms, batch_rows;
  std::size_t epochs = 0, batches = 0, growths = 0, growth_steps = 0;
  double max_growth_step_ms = 0, max_growth_at_once_ms = 0;
  double max_batch_ms = 0;
  std::size_t content_exact = 0;    // exact content-box recomputes (StreamingStats)
  double batch_content_ms_p99 = 0;  // growing the content box, per batch (ResidentBatch)
};

// The painting's first `max_strokes` strokes, a stroke every `epoch_interval_ms` (or when the
// previous one is painted). `step_epochs` (default): the stroke arrives as the server streams
// it, one epoch per painter step with the server's step budgets, each pushed when its step would
// have finished (step times measured while capturing); false: one epoch per whole stroke, pushed
// at once (a pessimistic stream: --stream-whole-strokes); frames width x
// height framing `box`; then `static_frames` frames of the finished painting. `content_cull`:
// RenderLoopOptions::content_cull (the loop culls rays to the replica's content box); false for the
// comparison without it. `max_fps`, `upload_share`: RenderLoopOptions (max_fps 0: frames back
// to back).
Result<StreamingFrames> measure_streaming_frames(
    const client_gpu::Context& ctx, const std::string& painting_path, std::size_t max_strokes,
    const client_core::DAabb& box, std::uint32_t width, std::uint32_t height,
    double epoch_interval_ms, int static_frames, bool content_cull = true, bool step_epochs = true,
    double max_fps = client_gpu::RenderLoopOptions{}.max_fps,
    double upload_share = client_gpu::RenderLoopOptions{}.upload_share);

// The figures of one run: a summary on stdout (`label` names the loop) and a JSON object.
void print_streaming(const std::string& label, const StreamingFrames& f);
std::string streaming_json(const StreamingFrames& f);

}  // namespace deepcanvas::bench
