// The render suite's streaming measurement (bench/render_bench.cpp calls it): a painting is
// painted into an in-process server Octree and captured epoch by epoch first (so the server's
// painting does not compete for the CPUs lavapipe renders on), then the epochs are pushed at a
// fixed pace into a StreamingReplica (upload thread) while a RenderLoop renders continuously
// on its own thread. Frames during which an upload batch became resident are "while streaming";
// after the stream, frames of the finished painting (no uploads) give the static p50 of the same
// run, so the ratio is measured under the same load.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/protocol/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"

namespace deepcanvas::bench {

struct StreamingFrames {
  std::vector<double> streaming_ms;  // frames while uploads arrived
  std::vector<double> static_ms;     // frames of the finished painting, nothing uploading
  double frame_ms_p50 = 0;           // static median
  double frame_ms_p99_while_streaming = 0;
  std::size_t epochs = 0, batches = 0, growths = 0;
  double max_batch_ms = 0;
  std::size_t content_exact = 0;    // exact content-box recomputes (StreamingStats)
  double batch_content_ms_p99 = 0;  // growing the content box, per batch (ResidentBatch)
};

// The painting's first `max_strokes` strokes, a stroke every `epoch_interval_ms` (or when the
// previous one is painted). `step_epochs` (default): the stroke arrives as the server streams
// it, one epoch per painter step with the server's step budgets, each pushed when its step would
// have finished (step times measured while capturing); false: one epoch per whole stroke, pushed
// at once (the pessimistic stream of earlier measurements, --stream-whole-strokes); frames width x
// height framing `box`; then `static_frames` frames of the finished painting. `content_cull`:
// RenderLoopOptions::content_cull (the loop culls rays to the replica's content box); false for the
// comparison without it.
Result<StreamingFrames> measure_streaming_frames(
    const client_gpu::Context& ctx, const std::string& painting_path, std::size_t max_strokes,
    const client_core::DAabb& box, std::uint32_t width, std::uint32_t height,
    double epoch_interval_ms, int static_frames, bool content_cull = true, bool step_epochs = true);

}  // namespace deepcanvas::bench
