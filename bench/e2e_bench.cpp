// deepcanvas-bench e2e: server (in process) + a headless painter + a headless viewer with the
// GPU replica on loopback; a real painting is sent at its recorded pace while the viewer's
// render loop renders continuously.
//
// Figures (per stroke, then p50/p99 over all strokes of all paintings run):
//   stroke_to_resident_ms  the painter sends the stroke -> the viewer's GPU replica holds the
//                          epoch the stroke's ack names (all its blocks uploaded, G3 done)
//   stroke_to_pixel_ms     the painter sends the stroke -> the end of the first frame whose
//                          every band shows that epoch or a later one
//   bytes_per_stroke       block frame bytes the viewer received / strokes
//   frame_ms_p50, frame_ms_p99_while_streaming  the viewer's frames (all; those during which
//                          an upload batch became resident)
// Pace: samples are sent as the artist painted them (stroke_begin with the first sample,
// stroke_samples with those due at each wake-up, stroke_end right after the last one), by the
// .apa timestamps, steps between samples capped at --max-gap-ms (default 1000; 400 with
// --quick) so a run stays short; "sent" is the stroke_end. --whole-strokes: each stroke sent
// whole when the artist finished it ("sent" = then; the server then paints all of it at once).
// Checks: the viewer's CPU replica converges to the server's pool hash and its GPU links equal
// its CPU links (exit 1 otherwise).
// Options (`deepcanvas-bench e2e --help`): the paintings, the frame size, the render loop's and
// the upload budget's settings, the server's compress settings; --no-render shows how much the
// rendering (lavapipe, on the same CPUs as the server) slows the rest.
// DEEPCANVAS_BENCH_TRACE=1 (environment): one stderr line per stroke, where its epoch's
// commit -> resident time went (gap wait, content box, lock: mirror/growth/upload/links), and
// one per batch that held the GPU lock over 10 ms.
#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <iterator>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <thread>

#include "bench.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/log.hpp"
#include "deepcanvas/server_net/server.hpp"

namespace deepcanvas::bench {
namespace {

using Clock = std::chrono::steady_clock;
namespace cg = client_gpu;

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

struct E2eConfig {
  std::size_t max_strokes = 100000;
  double max_gap_ms = 1000;
  std::uint32_t width = 320, height = 180;
  cg::UploadBudget budget;
  std::string device;
  double band_ms = 8.0;  // RenderLoopOptions::band_target_ms
  double capped_band_ms = cg::RenderLoopOptions{}.capped_band_target_ms;
  double max_fps = cg::RenderLoopOptions{}.max_fps;  // RenderLoopOptions::max_fps (0: unpaced)
  double upload_share = cg::RenderLoopOptions{}.upload_share;
  double gaps_above = cg::RenderLoopOptions{}.gaps_above;
  bool whole_strokes = false;  // true: each stroke sent whole when finished
  bool render = true;          // false: no render loop (how much rendering slows the rest)
  bool content_cull = true;    // RenderLoopOptions::content_cull
  int compress_backlog = -1;   // CanvasServiceConfig::max_compress_backlog (-1: its default)
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
  double wall_s = 0;
  // The server's own view (its histograms, this run): stroke_end read -> all its paint in the
  // tree, and stroke read -> its first blocks published.
  double server_end_to_painted_ms_p50 = 0, server_end_to_painted_ms_p99 = 0;
  double server_stroke_to_publish_ms_p99 = 0;
  std::uint64_t batches = 0, epochs = 0, growths = 0;
  double max_batch_ms = 0;
  bool converged = false, links_equal = false;
};

// `progress` advances by one per stroke sent.
Result<E2eRun> run_one(const cg::Context& ctx, const paintings::ApaPainting& painting,
                       const E2eConfig& cfg, base::Progress& progress) {
  server_net::ServerConfig scfg;
  scfg.port = 0;
  scfg.limits.max_strokes_per_second = 100000;
  server_core::CanvasServiceConfig c;
  c.name = "e2e";
  if (cfg.compress_backlog >= 0) c.max_compress_backlog = cfg.compress_backlog;
  c.replies_first = cfg.replies_first;
  scfg.canvases.push_back(c);
  auto server = server_net::Server::create(scfg);
  if (!server) return std::move(server).error();
  if (auto r = (*server)->start(); !r) return std::move(r).error();
  const std::string url = "ws://127.0.0.1:" + std::to_string((*server)->port()) + "/";
  client_core::ClientOptions po;
  po.url = url;
  po.canvas = "e2e";
  po.role = protocol::Role::painter;
  po.keep_replica = false;
  po.block_frames = false;  // the painter only paints (as `deepcanvas-client paint` does)
  auto painter = client_core::Client::connect(po);
  if (!painter) return std::move(painter).error();
  client_core::ClientOptions vo = po;
  vo.role = protocol::Role::viewer;
  vo.keep_replica = true;
  vo.block_frames = true;
  auto viewer = client_core::Client::connect(vo);
  if (!viewer) return std::move(viewer).error();
  const auto& w = (*viewer)->welcome();
  cg::GpuReplicaConfig rcfg;
  rcfg.width_log2 = static_cast<std::uint32_t>(std::countr_zero(w.texture_width));
  rcfg.block_log2 = static_cast<std::uint32_t>(std::countr_zero(w.block_cells));
  rcfg.roots_per_axis = w.geometry.roots_per_axis;
  rcfg.edge_m = w.geometry.edge_m;
  rcfg.max_depth = w.geometry.max_depth;
  auto streaming = cg::StreamingReplica::create(ctx, rcfg, cfg.budget);
  if (!streaming) return std::move(streaming).error();
  cg::StreamingReplica& sr = **streaming;
  if (auto e = (*viewer)->wait_for_epoch(0, std::chrono::seconds(30)); !e)
    return std::move(e).error();
  cg::stream_client_into(**viewer, sr);
  // Frame the finished painting (its sample bounds), as a viewer looking at the artist's work.
  client_core::DAabb box{{1e300, 1e300, 1e300}, {-1e300, -1e300, -1e300}};
  for (const auto& s : painting.strokes)
    for (const auto& p : s.samples) {
      const double r = p.radius;
      box.min = {std::min(box.min.x, p.x - r), std::min(box.min.y, p.y - r),
                 std::min(box.min.z, p.z - r)};
      box.max = {std::max(box.max.x, p.x + r), std::max(box.max.y, p.y + r),
                 std::max(box.max.z, p.z + r)};
    }
  auto cam = client_core::Camera::frame_box(box, cfg.width, cfg.height, 45.0, {-0.45, -0.35, -0.82},
                                            {0, 1, 0});
  if (!cam) return std::move(cam).error();
  cg::RenderLoopOptions lo;
  lo.width = cfg.width;
  lo.height = cfg.height;
  lo.camera = *cam;
  lo.render.background = {0.05, 0.06, 0.08};
  lo.band_target_ms = cfg.band_ms > 0 ? cfg.band_ms : 8.0;
  if (cfg.capped_band_ms > 0) lo.capped_band_target_ms = cfg.capped_band_ms;
  lo.content_cull = cfg.content_cull;
  lo.max_fps = cfg.max_fps;
  lo.upload_share = cfg.upload_share;
  lo.gaps_above = cfg.gaps_above;
  auto loop = cg::RenderLoop::create(sr, lo);
  if (!loop) {
    (*viewer)->set_epoch_listener({});
    return std::move(loop).error();
  }
  if (!sr.wait_resident(0, std::chrono::seconds(30))) {
    (*viewer)->set_epoch_listener({});
    return make_error(Errc::io_error, "e2e: the snapshot never became resident");
  }
  if (cfg.render) {
    (*loop)->start();
    // Let the loop settle (adaptive bands) before the first stroke.
    while ((*loop)->frame_count() < 3) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }

  E2eRun out;
  const std::size_t n = std::min(cfg.max_strokes, painting.strokes.size());
  std::vector<std::uint64_t> handles(n);
  std::vector<Clock::time_point> sent(n);
  const auto t0 = Clock::now();
  // Artist time -> run time: each step between consecutive samples (within and between
  // strokes) as recorded, capped at max_gap_ms.
  double at_ms = 0;
  std::uint32_t prev_t = 0;
  bool have_prev = false;
  auto advance = [&](std::uint32_t t) {
    if (have_prev && t >= prev_t) at_ms += std::min<double>(t - prev_t, cfg.max_gap_ms);
    prev_t = t;
    have_prev = true;
    return t0 + std::chrono::microseconds(static_cast<std::int64_t>(at_ms * 1000));
  };
  auto fail = [&](Error e) -> Result<E2eRun> {
    (*viewer)->set_epoch_listener({});
    return e;
  };
  // Acks are awaited as they come (in stroke order) so that their arrival is known: where a
  // stroke's time went (trace) starts with sent -> acked.
  std::vector<std::uint64_t> epochs(n);
  std::vector<Clock::time_point> acked(n);
  std::vector<Result<protocol::Ack>> acks(n, make_error(Errc::io_error, "stroke never sent"));
  // Strokes whose handles are set; kAbandoned: stop (an early return).
  constexpr std::size_t kAbandoned = std::numeric_limits<std::size_t>::max();
  std::atomic<std::size_t> handed{0};
  std::thread ack_waiter([&] {
    for (std::size_t i = 0; i < n; ++i) {
      for (std::size_t h = handed.load(); h <= i; h = handed.load()) handed.wait(h);
      if (handed.load() == kAbandoned) return;
      acks[i] = (*painter)->wait_for_ack(handles[i], std::chrono::seconds(120));
      acked[i] = Clock::now();
      if (!acks[i]) return;
    }
  });
  // On an early return: stop the waiter (closing the painter ends a wait in progress).
  struct JoinOnExit {
    std::thread& t;
    std::atomic<std::size_t>& handed;
    client_core::Client& painter;
    ~JoinOnExit() {
      if (!t.joinable()) return;
      handed.store(kAbandoned);
      handed.notify_all();
      painter.close();
      t.join();
    }
  } join_on_exit{ack_waiter, handed, **painter};
  for (std::size_t i = 0; i < n; ++i) {
    const auto& s = painting.strokes[i];
    if (cfg.whole_strokes || s.samples.size() < 2) {
      // The whole stroke when the artist finished it.
      for (const auto& smp : s.samples) (void)advance(smp.t_ms);
      std::this_thread::sleep_until(
          t0 + std::chrono::microseconds(static_cast<std::int64_t>(at_ms * 1000)));
      sent[i] = Clock::now();
      auto h = (*painter)->send_stroke(s);
      if (!h) return fail(std::move(h).error());
      handles[i] = *h;
      handed.store(i + 1);
      handed.notify_one();
      progress.add(1);
      continue;
    }
    // Streamed as the artist paints: begin with the first sample, then the samples due at each
    // wake-up, then the end right after the last one.
    std::this_thread::sleep_until(advance(s.samples[0].t_ms));
    auto h = (*painter)->begin_stroke(s.brush, {s.samples[0]});
    if (!h) return fail(std::move(h).error());
    handles[i] = *h;
    handed.store(i + 1);
    handed.notify_one();
    std::size_t k = 1;
    while (k < s.samples.size()) {
      std::this_thread::sleep_until(advance(s.samples[k].t_ms));
      std::vector<protocol::StrokeSample> chunk{s.samples[k++]};
      const double due_ms =
          std::chrono::duration<double, std::milli>(Clock::now() - t0).count() + 1.0;
      while (k < s.samples.size()) {
        const double save_ms = at_ms;
        const std::uint32_t save_t = prev_t;
        (void)advance(s.samples[k].t_ms);
        if (at_ms > due_ms) {
          at_ms = save_ms;
          prev_t = save_t;
          break;
        }
        chunk.push_back(s.samples[k++]);
      }
      if (auto r = (*painter)->add_samples(*h, std::move(chunk)); !r)
        return fail(std::move(r).error());
    }
    sent[i] = Clock::now();
    if (auto r = (*painter)->end_stroke(*h); !r) return fail(std::move(r).error());
    progress.add(1);
  }
  ack_waiter.join();
  for (std::size_t i = 0; i < n; ++i) {
    if (!acks[i]) {
      (*viewer)->set_epoch_listener({});
      return std::move(acks[i]).error();
    }
    epochs[i] = acks[i]->epoch;
  }
  auto quiet = (*server)->canvas("e2e")->quiesce(std::chrono::seconds(120));
  if (!quiet) {
    (*viewer)->set_epoch_listener({});
    return std::move(quiet).error();
  }
  const std::uint64_t last = quiet->epoch;
  const bool resident = sr.wait_resident(last, std::chrono::seconds(120));
  // Until a whole frame shows the last epoch.
  const auto deadline = Clock::now() + std::chrono::seconds(60);
  while (cfg.render && Clock::now() < deadline) {
    const auto fr = (*loop)->frames();
    if (!fr.empty() && fr.back().min_epoch >= last) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  auto stopped = (*loop)->stop();
  (*viewer)->set_epoch_listener({});
  out.wall_s = std::chrono::duration<double>(Clock::now() - t0).count();
  if (!stopped) return std::move(stopped).error();
  if (auto s = sr.status(); !s) return std::move(s).error();
  if (!resident) return make_error(Errc::io_error, "e2e: the last epoch never became resident");

  const auto log = sr.take_resident_log();
  const auto frames = (*loop)->frames();
  const bool trace = std::getenv("DEEPCANVAS_BENCH_TRACE") != nullptr;
  for (const auto& b : log) {
    // Long batches, whichever strokes they carried (the per-stroke lines below show only the
    // batch holding each stroke's last epoch).
    if (trace && b.gpu_lock_ms > 10.0)
      std::fprintf(stderr,
                   "long batch %llu-%llu: lock %.2f (mirror %.2f grow %.2f upload %.2f links "
                   "%.2f), lock wait %.2f, content %.2f, rows %llu, late %llu, grew %d\n",
                   (unsigned long long)b.first_epoch, (unsigned long long)b.last_epoch,
                   b.gpu_lock_ms, b.mirror_ms, b.grow_ms, b.upload_ms, b.links_ms, b.lock_wait_ms,
                   b.content_ms, (unsigned long long)b.rows, (unsigned long long)b.late_epochs,
                   b.grew ? 1 : 0);
    out.batch_lock_ms.push_back(b.gpu_lock_ms);
    out.batch_mirror_ms.push_back(b.mirror_ms);
    out.batch_upload_ms.push_back(b.upload_ms);
    out.batch_links_ms.push_back(b.links_ms);
    out.batch_content_ms.push_back(b.content_ms);
    out.batch_gap_wait_ms.push_back(b.gap_wait_ms);
    out.mid_frame_batches += b.mid_frame ? 1 : 0;
    out.batch_rows.push_back(static_cast<double>(b.rows));
  }
  for (std::size_t i = 0; i < n; ++i) {
    for (const auto& b : log)
      if (b.last_epoch >= epochs[i]) {
        out.resident_ms.push_back(ms_between(sent[i], b.resident_at));
        for (const auto& [e, t] : b.commits)
          if (e >= epochs[i]) {
            out.committed_ms.push_back(ms_between(sent[i], t));
            out.commit_resident_ms.push_back(ms_between(t, b.resident_at));
            if (trace) {
              const auto first = (*viewer)->first_frame_after(epochs[i] - 1);
              std::fprintf(stderr,
                           "stroke %zu epoch %llu: sent->acked %.2f, ->first frame %.2f, "
                           "->committed %.2f, ->resident %.2f\n",
                           i, (unsigned long long)epochs[i], ms_between(sent[i], acked[i]),
                           first ? ms_between(sent[i], *first) : -1.0, ms_between(sent[i], t),
                           ms_between(sent[i], b.resident_at));
              std::fprintf(
                  stderr,
                  "stroke %zu epoch %llu: commit->resident %.2f = gap wait %.2f + "
                  "content %.2f + lock wait %.2f + lock %.2f (mirror %.2f grow %.2f upload %.2f "
                  "links %.2f) + other; taken %.2f after commit; batch %llu-%llu rows "
                  "%llu mid %d late %llu\n",
                  i, (unsigned long long)e, ms_between(t, b.resident_at), b.gap_wait_ms,
                  b.content_ms, b.lock_wait_ms, b.gpu_lock_ms, b.mirror_ms, b.grow_ms, b.upload_ms,
                  b.links_ms, ms_between(t, b.taken_at), (unsigned long long)b.first_epoch,
                  (unsigned long long)b.last_epoch, (unsigned long long)b.rows, b.mid_frame ? 1 : 0,
                  (unsigned long long)b.late_epochs);
            }
            break;
          }
        break;
      }
    for (const auto& f : frames)
      if (f.min_epoch >= epochs[i] && f.start >= sent[i]) {
        out.pixel_ms.push_back(ms_between(sent[i], f.end));
        break;
      }
  }
  for (const auto& f : frames) {
    out.frame_ms.push_back(f.ms);
    if (f.streaming) out.frame_stream_ms.push_back(f.ms);
  }
  out.strokes = n;
  out.bytes_per_stroke = static_cast<double>((*viewer)->stats().frame_bytes) /
                         static_cast<double>(std::max<std::size_t>(n, 1));
  const auto st = sr.stats();
  out.batches = st.batches;
  out.epochs = st.epochs;
  out.growths = st.growths;
  out.max_batch_ms = st.max_batch_lock_ms;
  out.converged = (*viewer)->wait_for_epoch(last, std::chrono::seconds(10)).ok() &&
                  (*viewer)->pool_hash() == quiet->pool_hash;
  // The GPU links (G3 on the GPU, masked groups only) equal the CPU replica's links.
  std::vector<std::uint32_t> gpu_links;
  auto read = sr.with_gpu([&](const cg::ResidentState& s) -> Result<void> {
    auto l = s.replica.read_links();
    if (!l) return std::move(l).error();
    gpu_links = std::move(*l);
    return {};
  });
  if (!read) return std::move(read).error();
  (*viewer)->with_replica([&](const client_core::Replica& r) {
    const auto cpu = r.group_links();
    out.links_equal = gpu_links.size() == cpu.size() &&
                      std::equal(gpu_links.begin(), gpu_links.end(), cpu.begin());
  });
  if (const auto* canvas = (*server)->canvas("e2e")) {
    const auto& m = canvas->metrics();
    out.server_end_to_painted_ms_p50 = m.end_to_painted_seconds.quantile_seconds(0.5) * 1e3;
    out.server_end_to_painted_ms_p99 = m.end_to_painted_seconds.quantile_seconds(0.99) * 1e3;
    out.server_stroke_to_publish_ms_p99 = m.stroke_to_publish_seconds.quantile_seconds(0.99) * 1e3;
    if (trace) {
      auto qms = [](const server_core::Histogram& h, double p) {
        return h.quantile_seconds(p) * 1e3;
      };
      std::fprintf(stderr,
                   "server: step p50 %.2f p99 %.2f, stage p99 %.2f, compress wait p50 %.2f p99 "
                   "%.2f, compress p50 %.2f p99 %.2f, stroke->publish p50 %.2f p99 %.2f ms; "
                   "%llu epochs (%llu inline)\n",
                   qms(m.step_seconds, 0.5), qms(m.step_seconds, 0.99), qms(m.stage_seconds, 0.99),
                   qms(m.compress_wait_seconds, 0.5), qms(m.compress_wait_seconds, 0.99),
                   qms(m.compress_seconds, 0.5), qms(m.compress_seconds, 0.99),
                   qms(m.stroke_to_publish_seconds, 0.5), qms(m.stroke_to_publish_seconds, 0.99),
                   (unsigned long long)m.epochs.value(),
                   (unsigned long long)m.inline_epochs.value());
    }
  }
  loop->reset();
  (*painter)->close();
  (*viewer)->close();
  (*server)->stop();
  return out;
}

struct E2eOptions {
  E2eConfig cfg;
  std::vector<std::string> paintings;
  double budget_mbps = 0;
  bool no_render = false, no_cull = false, replies_wait = false;
  const CLI::Option* max_gap = nullptr;  // given on the command line, or the default per --quick
  const CLI::Option* budget = nullptr;
};

int e2e_main(const Options& opt, const E2eOptions& eo) {
  server_core::set_log_level(server_core::LogLevel::warn);
  E2eConfig cfg = eo.cfg;
  if (eo.max_gap->count() == 0) cfg.max_gap_ms = opt.quick ? 400 : 1000;
  if (eo.budget->count() > 0) cfg.budget.bytes_per_second = eo.budget_mbps * 1e6;
  cfg.render = !eo.no_render;
  cfg.content_cull = !eo.no_cull;
  cfg.replies_first = !eo.replies_wait;
  std::vector<std::string> names = eo.paintings;
  if (names.empty()) {
    names = opt.quick ? std::vector<std::string>{"demo.apa"}
                      : std::vector<std::string>{"demo.apa", "mozfest.apa", "winner.apa"};
  }
  auto dir = paintings_dir();
  if (!dir) return fail(opt, dir.error().message);
  std::vector<paintings::ApaPainting> paintings;
  std::size_t total_strokes = 0;
  for (const auto& name : names) {
    auto p = paintings::read_apa_file((*dir / name).string(), {});
    if (!p) return fail(opt, p.error().message);
    total_strokes += std::min(cfg.max_strokes, p->strokes.size());
    paintings.push_back(std::move(*p));
  }
  auto ctx = cg::ContextBuilder().app_name("deepcanvas-bench e2e").device(cfg.device).build();
  if (!ctx) return fail(opt, ctx.error().message);
  note(opt, "e2e: device %s, frames %ux%u, budget %s, max gap %.0f ms\n",
       (*ctx)->info().name.c_str(), cfg.width, cfg.height,
       cfg.budget.bytes_per_second > 0
           ? (std::to_string(cfg.budget.bytes_per_second / 1e6) + " MB/s").c_str()
           : "unlimited",
       cfg.max_gap_ms);
  auto progress = bench::progress(opt, "e2e", double(total_strokes), "strokes");
  std::vector<double> res, pix, fr, frs, bps, com, cres, blk, bmir, bup, blnk, brows, bcon, bgap;
  std::uint64_t mid_frame = 0;
  bool ok = true;
  nlohmann::json runs = nlohmann::json::array();
  for (std::size_t k = 0; k < names.size(); ++k) {
    const std::string& name = names[k];
    auto r = run_one(**ctx, paintings[k], cfg, progress);
    if (!r) return fail(opt, name + ": " + r.error().message);
    ok = ok && r->converged && r->links_equal && r->resident_ms.size() == r->strokes;
    res.insert(res.end(), r->resident_ms.begin(), r->resident_ms.end());
    pix.insert(pix.end(), r->pixel_ms.begin(), r->pixel_ms.end());
    fr.insert(fr.end(), r->frame_ms.begin(), r->frame_ms.end());
    frs.insert(frs.end(), r->frame_stream_ms.begin(), r->frame_stream_ms.end());
    bps.push_back(r->bytes_per_stroke);
    com.insert(com.end(), r->committed_ms.begin(), r->committed_ms.end());
    cres.insert(cres.end(), r->commit_resident_ms.begin(), r->commit_resident_ms.end());
    blk.insert(blk.end(), r->batch_lock_ms.begin(), r->batch_lock_ms.end());
    bmir.insert(bmir.end(), r->batch_mirror_ms.begin(), r->batch_mirror_ms.end());
    bup.insert(bup.end(), r->batch_upload_ms.begin(), r->batch_upload_ms.end());
    blnk.insert(blnk.end(), r->batch_links_ms.begin(), r->batch_links_ms.end());
    bcon.insert(bcon.end(), r->batch_content_ms.begin(), r->batch_content_ms.end());
    brows.insert(brows.end(), r->batch_rows.begin(), r->batch_rows.end());
    bgap.insert(bgap.end(), r->batch_gap_wait_ms.begin(), r->batch_gap_wait_ms.end());
    mid_frame += r->mid_frame_batches;
    note(opt,
         "e2e: %-14s %4zu strokes in %5.1f s: resident p50 %6.1f p99 %6.1f ms, pixel p50 "
         "%6.1f p99 %6.1f ms, %7.0f B/stroke, %zu frames p50 %.1f ms (streaming p99 "
         "%.1f), %llu epochs in %llu batches (max %.1f ms, %llu growths), converged %s, "
         "GPU links = CPU %s\n",
         name.c_str(), r->strokes, r->wall_s, base::percentile(r->resident_ms, 0.5),
         base::percentile(r->resident_ms, 0.99), base::percentile(r->pixel_ms, 0.5),
         base::percentile(r->pixel_ms, 0.99), r->bytes_per_stroke, r->frame_ms.size(),
         base::percentile(r->frame_ms, 0.5), base::percentile(r->frame_stream_ms, 0.99),
         static_cast<unsigned long long>(r->epochs), static_cast<unsigned long long>(r->batches),
         r->max_batch_ms, static_cast<unsigned long long>(r->growths), r->converged ? "yes" : "NO",
         r->links_equal ? "yes" : "NO");
    note(opt,
         "e2e: %-14s server: stroke_end -> painted p50 %.1f p99 %.1f ms, stroke -> first "
         "blocks published p99 %.1f ms\n",
         name.c_str(), r->server_end_to_painted_ms_p50, r->server_end_to_painted_ms_p99,
         r->server_stroke_to_publish_ms_p99);
    runs.push_back({{"painting", name},
                    {"server_end_to_painted_ms_p50", r->server_end_to_painted_ms_p50},
                    {"server_end_to_painted_ms_p99", r->server_end_to_painted_ms_p99},
                    {"server_stroke_to_publish_ms_p99", r->server_stroke_to_publish_ms_p99},
                    {"strokes", r->strokes},
                    {"stroke_to_resident_ms_p50", base::percentile(r->resident_ms, 0.5)},
                    {"stroke_to_resident_ms_p99", base::percentile(r->resident_ms, 0.99)},
                    {"stroke_to_pixel_ms_p50", base::percentile(r->pixel_ms, 0.5)},
                    {"stroke_to_pixel_ms_p99", base::percentile(r->pixel_ms, 0.99)},
                    {"bytes_per_stroke", r->bytes_per_stroke},
                    {"frames", r->frame_ms.size()},
                    {"batches", r->batches},
                    {"epochs", r->epochs},
                    {"converged", r->converged},
                    {"gpu_links_equal_cpu", r->links_equal}});
  }
  progress.finish();
  nlohmann::json out = {{"suite", "e2e"},
                        {"quick", opt.quick},
                        {"device", (*ctx)->info().name},
                        {"frame", std::to_string(cfg.width) + "x" + std::to_string(cfg.height)},
                        {"upload_budget_bytes_per_s", cfg.budget.bytes_per_second},
                        {"epochs_per_batch", cfg.budget.max_epochs_per_batch},
                        {"batches_per_frame", cfg.budget.max_batches_per_frame},
                        {"max_fps", cfg.max_fps},
                        {"upload_share", cfg.upload_share},
                        {"gaps_above", cfg.gaps_above},
                        {"band_target_ms", cfg.band_ms},
                        {"capped_band_target_ms", cfg.capped_band_ms},
                        {"max_gap_ms", cfg.max_gap_ms},
                        {"strokes", res.size()},
                        {"stroke_to_resident_ms_p50", base::percentile(res, 0.5)},
                        {"stroke_to_resident_ms_p99", base::percentile(res, 0.99)},
                        {"stroke_to_pixel_ms_p50", base::percentile(pix, 0.5)},
                        {"stroke_to_pixel_ms_p99", base::percentile(pix, 0.99)},
                        {"bytes_per_stroke", median(bps)},
                        {"stroke_to_committed_ms_p50", base::percentile(com, 0.5)},
                        {"stroke_to_committed_ms_p99", base::percentile(com, 0.99)},
                        {"committed_to_resident_ms_p50", base::percentile(cres, 0.5)},
                        {"committed_to_resident_ms_p99", base::percentile(cres, 0.99)},
                        {"batch_gap_wait_ms_p50", base::percentile(bgap, 0.5)},
                        {"batch_gap_wait_ms_p99", base::percentile(bgap, 0.99)},
                        {"mid_frame_batches", mid_frame},
                        {"batch_lock_ms_p50", base::percentile(blk, 0.5)},
                        {"batch_lock_ms_p99", base::percentile(blk, 0.99)},
                        {"batch_mirror_ms_p99", base::percentile(bmir, 0.99)},
                        {"batch_upload_ms_p99", base::percentile(bup, 0.99)},
                        {"batch_links_ms_p99", base::percentile(blnk, 0.99)},
                        {"batch_content_ms_p99", base::percentile(bcon, 0.99)},
                        {"batch_rows_p50", base::percentile(brows, 0.5)},
                        {"batch_rows_p99", base::percentile(brows, 0.99)},
                        {"render", cfg.render},
                        {"content_cull", cfg.content_cull},
                        {"whole_strokes", cfg.whole_strokes},
                        {"replies_first", cfg.replies_first},
                        {"frame_ms_p50", base::percentile(fr, 0.5)},
                        {"frame_ms_p99_while_streaming", base::percentile(frs, 0.99)},
                        {"targets", {{"stroke_to_resident_ms_p99_max", 20.0}}},
                        {"ok", ok},
                        {"runs", runs}};
  std::printf("%s\n", opt.json ? out.dump().c_str() : out.dump(2).c_str());
  if (!ok) return fail(opt, "a viewer did not converge to the server's canvas or its GPU links");
  return 0;
}

// WxH, each 1..4096.
CLI::Validator frame_size(std::uint32_t& width, std::uint32_t& height) {
  return CLI::Validator(
      [&width, &height](std::string& v) -> std::string {
        unsigned w = 0, h = 0;
        char tail = 0;
        if (std::sscanf(v.c_str(), "%ux%u%c", &w, &h, &tail) != 2 || w == 0 || h == 0 || w > 4096 ||
            h > 4096)
          return "must be WxH, each 1..4096, not '" + v + "'";
        width = w;
        height = h;
        return {};
      },
      "", "size");
}

SuiteRun setup(CLI::App& app) {
  auto eo = std::make_shared<E2eOptions>();
  E2eConfig& c = eo->cfg;
  app.add_option("--painting", eo->paintings,
                 "a painting to send (repeatable; default demo, mozfest, winner; --quick: demo)")
      ->type_name("NAME.apa");
  app.add_option("--max-strokes", c.max_strokes, "at most N strokes of each painting")
      ->transform(number(1, 1e9, true))
      ->type_name("N");
  eo->max_gap = app.add_option("--max-gap-ms", c.max_gap_ms,
                               "cap on the pause between two samples (default 1000; --quick 400)")
                    ->transform(number(0, 1e6))
                    ->type_name("MS");
  app.add_flag("--whole-strokes", c.whole_strokes,
               "send each stroke whole when the artist finished it");
  app.add_option("--size", "the viewer's frames (default 320x180)")
      ->check(frame_size(c.width, c.height))
      ->type_name("WxH");
  app.add_flag("--no-render", eo->no_render, "no render loop (how much rendering slows the rest)");
  app.add_flag("--no-cull", eo->no_cull, "the render loop without its content cull");
  app.add_option("--fps", c.max_fps, "the render loop's pace (default 60; 0: unpaced)")
      ->transform(number(0, 10000))
      ->type_name("X");
  app.add_option("--band-ms", c.band_ms, "the render loop's band target (default 8)")
      ->transform(number(0.01, 1000))
      ->type_name("MS");
  app.add_option("--capped-band-ms", c.capped_band_ms,
                 "its band target while the fps cap sets the pace (default 2)")
      ->transform(number(0.01, 1000))
      ->type_name("MS");
  app.add_option("--upload-share", c.upload_share, "RenderLoopOptions::upload_share")
      ->transform(number(0, 0.9))
      ->type_name("F");
  app.add_option("--gaps-above", c.gaps_above,
                 "uploads wait for frame gaps once frames take X times the fps cap's interval "
                 "(RenderLoopOptions::gaps_above, default 1)")
      ->transform(number(0.01, 100))
      ->type_name("X");
  eo->budget =
      app.add_option("--budget-mbps", eo->budget_mbps, "upload budget in MB/s (default unlimited)")
          ->transform(number(0, 1e6))
          ->type_name("X");
  app.add_option("--epochs-per-batch", c.budget.max_epochs_per_batch,
                 "upload budget: epochs per batch")
      ->transform(number(0, 1e6, true))
      ->type_name("N");
  app.add_option("--batches-per-frame", c.budget.max_batches_per_frame,
                 "upload budget: batches per frame")
      ->transform(number(0, 1e6, true))
      ->type_name("N");
  app.add_option("--compress-backlog", c.compress_backlog, "the server's max_compress_backlog")
      ->transform(number(0, 1e6, true))
      ->type_name("N");
  app.add_flag("--replies-wait", eo->replies_wait,
               "the server stages an epoch with acks only when its compress thread is free "
               "(CanvasServiceConfig::replies_first = false)");
  app.add_option("--device", c.device, "Vulkan device (else DEEPCANVAS_VK_DEVICE / automatic)")
      ->type_name("SPEC");
  return [eo](const Options& opt) { return e2e_main(opt, *eo); };
}

DEEPCANVAS_BENCH_SUITE(Suite{
    "e2e", "server + headless GPU viewer on loopback: stroke to resident / to pixel",
    "examples:\n"
    "  deepcanvas-bench e2e --quick\n"
    "  deepcanvas-bench e2e --painting winner.apa --max-strokes 50 --json\n"
    "  DEEPCANVAS_BENCH_TRACE=1 deepcanvas-bench e2e --quick   # where each stroke's time went\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder), DEEPCANVAS_VK_DEVICE,\n"
    "DEEPCANVAS_BENCH_TRACE=1 (one stderr line per stroke: where its time went)\n",
    setup});

}  // namespace
}  // namespace deepcanvas::bench
