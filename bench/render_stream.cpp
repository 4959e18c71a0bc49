// See render_stream.hpp.
#include "render_stream.hpp"

#include "bench.hpp"
#include "tree_stream.hpp"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <thread>

#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/canvas_service.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas::bench {
namespace {

namespace cc = client_core;
namespace cg = client_gpu;
namespace sc = server_core;
using Clock = std::chrono::steady_clock;
using Micros = std::chrono::microseconds;

// Each epoch with the time (from the start of the stream) at which it is pushed.
using TimedEpochs = std::vector<std::pair<Micros, cg::EpochUpload>>;

// The server side (a tree and its painter) and the client side (the streaming replica and its
// render loop, not started) of one measurement, the tree's snapshot resident.
struct StreamRig {
  std::unique_ptr<sc::Octree> tree;
  std::unique_ptr<sc::Painter> painter;
  cg::GpuReplicaConfig cfg;
  std::unique_ptr<cg::StreamingReplica> replica;
  std::unique_ptr<cg::RenderLoop> loop;
};

Result<std::vector<protocol::Stroke>> first_strokes(const std::string& painting_path,
                                                    std::size_t max_strokes) {
  std::vector<protocol::Stroke> strokes;
  if (painting_path.empty()) return strokes;
  auto p = paintings::read_apa_file(painting_path, {});
  if (!p) return std::move(p).error();
  strokes = std::move(p->strokes);
  if (strokes.size() > max_strokes) strokes.resize(max_strokes);
  return strokes;
}

Result<void> open_rig(StreamRig& rig, const cg::Context& ctx, const cc::DAabb& box,
                      std::uint32_t width, std::uint32_t height, bool content_cull, double max_fps,
                      double upload_share) {
  auto tree = sc::Octree::create({});
  if (!tree) return std::move(tree).error();
  rig.tree = std::move(*tree);
  auto painter = sc::Painter::create(*rig.tree);
  if (!painter) return std::move(painter).error();
  rig.painter = std::move(*painter);
  rig.cfg.width_log2 = 12;
  rig.cfg.block_log2 = static_cast<std::uint32_t>(std::countr_zero(rig.tree->config().block_cells));
  rig.cfg.roots_per_axis = rig.tree->config().roots_per_axis;
  rig.cfg.edge_m = rig.tree->config().edge_m;
  auto sr = cg::StreamingReplica::create(ctx, rig.cfg);
  if (!sr) return std::move(sr).error();
  rig.replica = std::move(*sr);
  auto cam = cc::Camera::frame_box(box, width, height);
  if (!cam) return std::move(cam).error();
  cg::RenderLoopOptions lo;
  lo.width = width;
  lo.height = height;
  lo.camera = *cam;
  lo.render.background = {0.1, 0.1, 0.12};
  lo.content_cull = content_cull;
  lo.max_fps = max_fps;
  lo.upload_share = upload_share;
  auto loop = cg::RenderLoop::create(*rig.replica, lo);
  if (!loop) return std::move(loop).error();
  rig.loop = std::move(*loop);
  rig.replica->push(capture_tree_epoch(*rig.tree, 0, rig.cfg.width_log2, true));
  if (!rig.replica->wait_resident(0, std::chrono::seconds(60)))
    return make_error(Errc::io_error, "streaming frames: snapshot not resident");
  return {};
}

// One whole stroke per epoch (a pessimistic stream: a stroke's blocks land at once), one epoch
// every `epoch_interval_ms`.
TimedEpochs capture_whole_stroke_epochs(StreamRig& rig,
                                        const std::vector<protocol::Stroke>& strokes,
                                        double epoch_interval_ms) {
  const std::size_t strokes_per_epoch = 1;
  TimedEpochs epochs;
  for (std::size_t i = 0; i < strokes.size(); i += strokes_per_epoch) {
    for (std::size_t k = i; k < std::min(strokes.size(), i + strokes_per_epoch); ++k)
      (void)rig.painter->apply_stroke(strokes[k]);
    const auto at =
        Micros(static_cast<std::int64_t>((epochs.size() + 1) * epoch_interval_ms * 1e3));
    epochs.emplace_back(
        at, capture_tree_epoch(*rig.tree, epochs.size() + 1, rig.cfg.width_log2, false));
  }
  return epochs;
}

// As the server streams: one epoch per painter step (its step budgets, the first step of a
// stroke small), each pushed when the server would have finished that step (the step times
// measured here), a new stroke every `epoch_interval_ms` or when the previous one is done,
// whichever is later.
TimedEpochs capture_step_epochs(StreamRig& rig, const std::vector<protocol::Stroke>& strokes,
                                double epoch_interval_ms) {
  const sc::CanvasServiceConfig server_defaults;
  TimedEpochs epochs;
  Micros clock{0};
  for (std::size_t i = 0; i < strokes.size(); ++i) {
    clock = std::max(clock, Micros(static_cast<std::int64_t>(i * epoch_interval_ms * 1e3)));
    if (!rig.painter->begin_stroke(strokes[i].brush, i + 1, strokes[i].samples) ||
        !rig.painter->end_stroke())
      continue;
    bool first = true;
    for (bool more = true; more;) {
      const auto t0 = Clock::now();
      auto r = rig.painter->step(first ? server_defaults.max_cells_first_step
                                       : server_defaults.max_cells_per_step);
      clock += std::chrono::duration_cast<Micros>(Clock::now() - t0);
      first = false;
      more = r && *r;
      if (rig.tree->dirty_blocks().empty()) continue;
      epochs.emplace_back(
          clock, capture_tree_epoch(*rig.tree, epochs.size() + 1, rig.cfg.width_log2, false));
    }
  }
  return epochs;
}

// When the stream began (the first push) and ended (the last epoch resident).
struct StreamWindow {
  Clock::time_point begin, end;
  std::uint64_t last_epoch = 0;
};

// Pushes each epoch at its time while the render loop renders; returns when the last is
// resident.
Result<StreamWindow> push_epochs(StreamRig& rig, TimedEpochs& epochs) {
  StreamWindow w;
  const auto t0 = Clock::now();
  w.begin = Clock::now();
  for (auto& [at, e] : epochs) {
    std::this_thread::sleep_until(t0 + at);
    e.committed_at = Clock::now();  // captured before the stream: committed as it is pushed
    rig.replica->push(std::move(e));
    ++w.last_epoch;
  }
  if (!rig.replica->wait_resident(w.last_epoch, std::chrono::seconds(120)))
    return make_error(Errc::io_error, "streaming frames: last epoch not resident");
  w.end = Clock::now();
  return w;
}

double ms_since(Clock::time_point begin, cg::SteadyTime t) {
  return std::chrono::duration<double, std::milli>(t - begin).count();
}

// While streaming: every frame that started between the first push and the last epoch becoming
// resident (with or without a batch of its own); static: the frames of the finished painting.
void collect_frames(const std::vector<cg::FrameRecord>& frames, const StreamWindow& w,
                    StreamingFrames& out) {
  for (const auto& f : frames) {
    if (std::getenv("DEEPCANVAS_BENCH_TRACE"))
      std::fprintf(stderr,
                   "frame at %.1f ms %.2f render %.2f interval %.2f cpu %.2f bands %u stream %d\n",
                   ms_since(w.begin, f.start), f.ms, f.render_ms, f.interval_ms, f.cpu_ms, f.bands,
                   f.streaming ? 1 : 0);
    if (f.start >= w.begin && f.start <= w.end) {
      out.streaming_ms.push_back(f.ms);
      if (f.streaming) out.batch_frame_ms.push_back(f.ms);
      if (f.interval_ms > 0) out.streaming_interval_ms.push_back(f.interval_ms);
    } else if (f.min_epoch == w.last_epoch) {
      out.static_ms.push_back(f.ms);
      if (f.interval_ms > 0) out.static_interval_ms.push_back(f.interval_ms);
    }
  }
  out.frame_ms_p50 = base::percentile(out.static_ms, 0.5);
  out.frame_ms_p99_while_streaming = base::percentile(out.streaming_ms, 0.99);
}

// The upload batches after the snapshot: gaps, their parts under the GPU lock, commit ->
// resident per epoch; the content box's growth of every batch.
void collect_batches(const std::vector<cg::ResidentBatch>& log, const StreamWindow& w,
                     StreamingFrames& out) {
  std::vector<double> content_ms;
  for (const auto& b : log) {
    content_ms.push_back(b.content_ms);
    if (b.first_epoch == 0) continue;  // the snapshot, before the loop started
    out.gap_batches += b.in_gap ? 1 : 0;
    out.mid_frame_batches += b.mid_frame ? 1 : 0;
    if (std::getenv("DEEPCANVAS_BENCH_TRACE"))
      std::fprintf(stderr,
                   "batch at %.1f-%.1f ms %llu-%llu lock %.2f mirror %.2f grow %.2f up %.2f links "
                   "%.2f content %.2f exact %.2f rows %llu gapwait %.2f mid %d\n",
                   ms_since(w.begin, b.taken_at), ms_since(w.begin, b.resident_at),
                   (unsigned long long)b.first_epoch, (unsigned long long)b.last_epoch,
                   b.gpu_lock_ms, b.mirror_ms, b.grow_ms, b.upload_ms, b.links_ms, b.content_ms,
                   b.content_exact_ms, (unsigned long long)b.rows, b.gap_wait_ms,
                   b.mid_frame ? 1 : 0);
    out.batch_lock_ms.push_back(b.gpu_lock_ms);
    out.batch_mirror_ms.push_back(b.mirror_ms);
    out.batch_upload_ms.push_back(b.upload_ms);
    out.batch_links_ms.push_back(b.links_ms);
    out.batch_content_ms.push_back(b.content_ms);
    out.batch_rows.push_back(static_cast<double>(b.rows));
    for (const auto& [e, at] : b.commits)
      out.commit_to_resident_ms.push_back(
          std::chrono::duration<double, std::milli>(b.resident_at - at).count());
  }
  out.batch_content_ms_p99 = base::percentile(content_ms, 0.99);
}

void collect_stats(const cg::StreamingStats& st, StreamingFrames& out) {
  out.epochs = st.epochs;
  out.batches = st.batches;
  out.growths = st.growths;
  out.growth_steps = st.growth_steps;
  out.max_growth_step_ms = st.max_growth_step_ms;
  out.max_growth_at_once_ms = st.max_growth_ms;
  out.max_batch_ms = st.max_batch_lock_ms;
  out.content_exact = st.content_exact;
}

}  // namespace

Result<StreamingFrames> measure_streaming_frames(
    const cg::Context& ctx, const std::string& painting_path, std::size_t max_strokes,
    const cc::DAabb& box, std::uint32_t width, std::uint32_t height, double epoch_interval_ms,
    int static_frames, bool content_cull, bool step_epochs, double max_fps, double upload_share) {
  auto strokes = first_strokes(painting_path, max_strokes);
  if (!strokes) return std::move(strokes).error();
  StreamRig rig;
  if (auto r = open_rig(rig, ctx, box, width, height, content_cull, max_fps, upload_share); !r)
    return std::move(r).error();
  // The epochs are painted and captured first, so that the server's painting (CPU work that a
  // real client does not share its machine with) does not compete with lavapipe during the
  // measurement: what is measured is the client's streaming (upload thread + render loop).
  TimedEpochs epochs = step_epochs ? capture_step_epochs(rig, *strokes, epoch_interval_ms)
                                   : capture_whole_stroke_epochs(rig, *strokes, epoch_interval_ms);
  rig.loop->start();
  while (rig.loop->frame_count() < 2) std::this_thread::sleep_for(std::chrono::milliseconds(2));
  auto window = push_epochs(rig, epochs);
  if (!window) return std::move(window).error();
  // Frames of the finished painting.
  const std::uint64_t before = rig.loop->frame_count();
  while (rig.loop->frame_count() < before + static_cast<std::uint64_t>(static_frames) + 1)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  if (auto s = rig.loop->stop(); !s) return std::move(s).error();
  if (auto s = rig.replica->status(); !s) return std::move(s).error();
  StreamingFrames out;
  out.max_fps = max_fps;
  out.upload_share = upload_share;
  collect_frames(rig.loop->frames(), *window, out);
  collect_stats(rig.replica->stats(), out);
  collect_batches(rig.replica->take_resident_log(), *window, out);
  return out;
}

void print_streaming(const std::string& label, const StreamingFrames& f) {
  const double p50 = f.frame_ms_p50;
  print(
      "render: %s (max_fps %.0f, upload_share %.2f): %zu frames while streaming, p99 "
      "%.2f ms = %.2fx the p50 of %zu frames of the finished painting (%.2f ms; their own "
      "p99 %.2fx); the %zu frames right after or during a batch: p99 %.2fx; intervals "
      "p50 %.2f (finished) p99 %.2f (streaming) ms; %zu epochs in %zu batches (%zu in "
      "gaps between frames, %zu mid-frame after waiting for one); commit->resident p50 "
      "%.2f p99 %.2f ms; %zu texture growths "
      "(%zu steps, longest %.2f ms; longest at once %.2f ms)\n",
      label.c_str(), f.max_fps, f.upload_share, f.streaming_ms.size(),
      f.frame_ms_p99_while_streaming, f.frame_ms_p99_while_streaming / p50, f.static_ms.size(), p50,
      base::percentile(f.static_ms, 0.99) / p50, f.batch_frame_ms.size(),
      base::percentile(f.batch_frame_ms, 0.99) / p50, base::percentile(f.static_interval_ms, 0.5),
      base::percentile(f.streaming_interval_ms, 0.99), f.epochs, f.batches, f.gap_batches,
      f.mid_frame_batches, base::percentile(f.commit_to_resident_ms, 0.5),
      base::percentile(f.commit_to_resident_ms, 0.99), f.growths, f.growth_steps,
      f.max_growth_step_ms, f.max_growth_at_once_ms);
  double sum = 0;
  for (std::size_t i = 0; i < f.batch_lock_ms.size(); ++i)
    sum += f.batch_lock_ms[i] + f.batch_content_ms[i];
  print(
      "render:   batches p50/p99 ms: lock %.2f/%.2f = mirror %.2f/%.2f + upload "
      "%.2f/%.2f + links %.2f/%.2f; content box %.2f/%.2f (outside the lock); rows "
      "%.0f/%.0f; all batches %.0f ms\n",
      base::percentile(f.batch_lock_ms, 0.5), base::percentile(f.batch_lock_ms, 0.99),
      base::percentile(f.batch_mirror_ms, 0.5), base::percentile(f.batch_mirror_ms, 0.99),
      base::percentile(f.batch_upload_ms, 0.5), base::percentile(f.batch_upload_ms, 0.99),
      base::percentile(f.batch_links_ms, 0.5), base::percentile(f.batch_links_ms, 0.99),
      base::percentile(f.batch_content_ms, 0.5), base::percentile(f.batch_content_ms, 0.99),
      base::percentile(f.batch_rows, 0.5), base::percentile(f.batch_rows, 0.99), sum);
}

std::string streaming_json(const StreamingFrames& f) {
  const double p50 = f.frame_ms_p50;
  char buf[1024];
  std::snprintf(
      buf, sizeof buf,
      "{\"max_fps\":%.1f,\"upload_share\":%.2f,\"frames\":%zu,"
      "\"frame_ms_p99_while_streaming\":%.3f,\"frame_ms_p50\":%.3f,"
      "\"p99_over_p50\":%.3f,\"static_p99_over_p50\":%.3f,"
      "\"batch_frames_p99_over_p50\":%.3f,\"interval_ms_p50\":%.3f,"
      "\"interval_ms_p99_while_streaming\":%.3f,\"batches\":%zu,"
      "\"gap_batches\":%zu,\"mid_frame_batches\":%zu,"
      "\"commit_to_resident_ms_p50\":%.3f,\"commit_to_resident_ms_p99\":%.3f,"
      "\"growths\":%zu,\"growth_steps\":%zu,\"max_growth_at_once_ms\":%.3f}",
      f.max_fps, f.upload_share, f.streaming_ms.size(), f.frame_ms_p99_while_streaming, p50,
      f.frame_ms_p99_while_streaming / p50, base::percentile(f.static_ms, 0.99) / p50,
      base::percentile(f.batch_frame_ms, 0.99) / p50, base::percentile(f.static_interval_ms, 0.5),
      base::percentile(f.streaming_interval_ms, 0.99), f.batches, f.gap_batches,
      f.mid_frame_batches, base::percentile(f.commit_to_resident_ms, 0.5),
      base::percentile(f.commit_to_resident_ms, 0.99), f.growths, f.growth_steps,
      f.max_growth_at_once_ms);
  return buf;
}

}  // namespace deepcanvas::bench
