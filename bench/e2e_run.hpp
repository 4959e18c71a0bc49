// One painting through an in-process server, a headless painter and a headless viewer with the
// GPU replica on loopback (the e2e suite, bench/e2e_bench.cpp, runs it per painting and
// reports over all strokes; its header says what each figure means).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "deepcanvas/base/progress.hpp"
#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/paintings/apa.hpp"

namespace deepcanvas::bench {

struct E2eConfig {
  std::size_t max_strokes = 100000;
  double max_gap_ms = 1000;
  std::uint32_t width = 320, height = 180;
  client_gpu::UploadBudget budget;
  std::string device;
  double band_ms = 8.0;  // RenderLoopOptions::band_target_ms
  double capped_band_ms = client_gpu::RenderLoopOptions{}.capped_band_target_ms;
  double max_fps =
      client_gpu::RenderLoopOptions{}.max_fps;  // RenderLoopOptions::max_fps (0: unpaced)
  double upload_share = client_gpu::RenderLoopOptions{}.upload_share;
  double gaps_above = client_gpu::RenderLoopOptions{}.gaps_above;
  bool whole_strokes = false;  // true: each stroke sent whole when finished
  bool render = true;          // false: no render loop (how much rendering slows the rest)
  bool content_cull = true;    // RenderLoopOptions::content_cull
  int compress_backlog = -1;   // CanvasServiceConfig::max_compress_backlog (-1: its default)
  int epoch_interval_ms = -1;  // CanvasServiceConfig::min_epoch_interval (-1: its default)
  int interior_refresh_ms = -1;  // CanvasServiceConfig::interior_refresh_interval (-1: its default)
  int zstd_level = 0;          // CanvasServiceConfig::zstd_level (0: its default)
  std::uint32_t viewer_batch_interval_ms = 0;  // the viewer's hello "batch_interval_ms"
  bool viewer_bundles = true;                  // the viewer's hello "frame_bundles"
  bool replies_first = true;   // CanvasServiceConfig::replies_first
};

struct E2eRun {
  std::size_t strokes = 0;
  std::vector<double> resident_ms, pixel_ms, frame_ms, frame_stream_ms;
  std::vector<double> committed_ms;        // stroke sent -> its epoch committed on the viewer CPU
  std::vector<double> commit_resident_ms;  // that commit -> resident on the GPU (per stroke)
  std::vector<double> batch_lock_ms, batch_mirror_ms, batch_upload_ms, batch_links_ms,
      batch_content_ms;
  std::vector<double> batch_gap_wait_ms;  // waiting for a gap between frames (paced loop)
  std::uint64_t mid_frame_batches = 0;
  std::vector<double> batch_rows;
  double bytes_per_stroke = 0;
  // Where a stroke's bytes go: the server's per-epoch frame bytes split by what the epoch's
  // painter steps did (CanvasMetrics::epoch_bytes_painting / _merging), per stroke; the share
  // of the viewer's frame bytes that is frame headers (64 B each); and what a viewer joining
  // the finished painting receives (the floor: the painting's own size on the wire).
  double painting_bytes_per_stroke = 0, merging_bytes_per_stroke = 0;
  double frame_header_share = 0;  // uncompressed headers: 64 B a frame alone, 32 B a bundle
  // The viewer's bundles against the same frames sent alone (the server's counters, this run):
  // bytes of the bundles / bytes of the frames they hold. 0: no bundle.
  double bundle_ratio = 0;
  double snapshot_bytes = 0;
  double wall_s = 0;
  // The server's own view (its histograms, this run): stroke_end read -> all its paint in the
  // tree, and stroke read -> its first blocks published.
  double server_end_to_painted_ms_p50 = 0, server_end_to_painted_ms_p99 = 0;
  double server_stroke_to_publish_ms_p99 = 0;
  std::uint64_t batches = 0, epochs = 0, growths = 0;
  double max_batch_ms = 0;
  bool converged = false, links_equal = false;
};

// The painting's first cfg.max_strokes strokes sent at the artist's pace while the viewer
// renders; the viewer must converge to the server's canvas (E2eRun::converged, links_equal).
// `progress` advances by one per stroke sent. Errors: the server's, a client's or the GPU's.
Result<E2eRun> run_one(const client_gpu::Context& ctx, const paintings::ApaPainting& painting,
                       const E2eConfig& cfg, base::Progress& progress);

}  // namespace deepcanvas::bench
