// See e2e_run.hpp. Pace: samples are sent as the artist painted them (stroke_begin with the
// first sample, stroke_samples with those due at each wake-up, stroke_end right after the last
// one), by the .apa timestamps, steps between samples capped at E2eConfig::max_gap_ms; "sent"
// is the stroke_end. whole_strokes: each stroke sent whole when the artist finished it ("sent"
// = then). DEEPCANVAS_BENCH_TRACE=1 (environment): one stderr line per stroke, where its
// epoch's commit -> resident time went, and one per batch that held the GPU lock over 10 ms.
#include "e2e_run.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <optional>
#include <thread>

#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/server_net/server.hpp"
#include "tree_stream.hpp"

namespace deepcanvas::bench {

namespace {

using Clock = std::chrono::steady_clock;
namespace cg = client_gpu;

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// The server, the two clients and the viewer's GPU side of one run, destroyed in the reverse
// order (render loop first, server last). While the viewer streams into the replica, the
// replica is its epoch listener: detached before either goes.
struct E2eSession {
  std::unique_ptr<server_net::Server> server;
  std::unique_ptr<client_core::Client> painter, viewer;
  std::unique_ptr<cg::StreamingReplica> replica;
  std::unique_ptr<cg::RenderLoop> loop;
  E2eSession() = default;
  E2eSession(const E2eSession&) = delete;
  E2eSession& operator=(const E2eSession&) = delete;
  ~E2eSession() {
    if (viewer && replica) viewer->set_epoch_listener({});
  }
};

Result<std::unique_ptr<server_net::Server>> start_server(const E2eConfig& cfg) {
  server_net::ServerConfig scfg;
  scfg.port = 0;
  scfg.limits.max_strokes_per_second = 100000;
  server_core::CanvasServiceConfig c;
  c.name = "e2e";
  if (cfg.compress_backlog >= 0) c.max_compress_backlog = cfg.compress_backlog;
  if (cfg.epoch_interval_ms >= 0) c.min_epoch_interval = std::chrono::milliseconds(cfg.epoch_interval_ms);
  if (cfg.interior_refresh_ms >= 0)
    c.interior_refresh_interval = std::chrono::milliseconds(cfg.interior_refresh_ms);
  c.replies_first = cfg.replies_first;
  if (cfg.zstd_level != 0) c.zstd_level = cfg.zstd_level;
  scfg.canvases.push_back(c);
  auto server = server_net::Server::create(scfg);
  if (!server) return std::move(server).error();
  if (auto r = (*server)->start(); !r) return std::move(r).error();
  return std::move(*server);
}

// A client of the e2e canvas on this server: `block_frames` whether it receives the canvas
// stream, `keep_replica` whether it keeps a CPU replica of it.
client_core::ClientOptions e2e_client(std::uint16_t port, protocol::Role role, bool block_frames,
                                      bool keep_replica) {
  client_core::ClientOptions o;
  o.url = "ws://127.0.0.1:" + std::to_string(port) + "/";
  o.canvas = "e2e";
  o.role = role;
  o.block_frames = block_frames;
  o.keep_replica = keep_replica;
  return o;
}

// The painter only paints (as `deepcanvas-client paint` does); the viewer keeps a replica and
// receives block frames.
Result<void> connect_clients(E2eSession& s, const E2eConfig& cfg) {
  auto painter = client_core::Client::connect(
      e2e_client(s.server->port(), protocol::Role::painter, false, false));
  if (!painter) return std::move(painter).error();
  s.painter = std::move(*painter);
  auto viewer_options = e2e_client(s.server->port(), protocol::Role::viewer, true, true);
  viewer_options.batch_interval_ms = cfg.viewer_batch_interval_ms;
  viewer_options.frame_bundles = cfg.viewer_bundles;
  auto viewer = client_core::Client::connect(viewer_options);
  if (!viewer) return std::move(viewer).error();
  s.viewer = std::move(*viewer);
  return {};
}

// The finished painting's sample bounds (each sample's sphere).
client_core::DAabb painting_bounds(const paintings::ApaPainting& painting) {
  client_core::DAabb box = client_core::empty_box();
  for (const auto& s : painting.strokes) client_core::grow_by_samples(box, s.samples);
  return box;
}

// The viewer's render loop, framing the finished painting as a viewer looking at the artist's
// work.
Result<cg::RenderLoopOptions> render_loop_options(const paintings::ApaPainting& painting,
                                                  const E2eConfig& cfg) {
  auto cam = client_core::Camera::frame_box(painting_bounds(painting), cfg.width, cfg.height, 45.0,
                                            {-0.45, -0.35, -0.82}, {0, 1, 0});
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
  return lo;
}

// Server, painter and viewer connected; the viewer streaming into its GPU replica, the
// snapshot resident, and (cfg.render) the render loop running and settled.
Result<void> open_session(E2eSession& s, const cg::Context& ctx,
                          const paintings::ApaPainting& painting, const E2eConfig& cfg) {
  auto server = start_server(cfg);
  if (!server) return std::move(server).error();
  s.server = std::move(*server);
  if (auto r = connect_clients(s, cfg); !r) return r;
  auto streaming =
      cg::StreamingReplica::create(ctx, cg::replica_config_for(s.viewer->welcome()), cfg.budget);
  if (!streaming) return std::move(streaming).error();
  if (auto e = s.viewer->wait_for_epoch(0, std::chrono::seconds(30)); !e)
    return std::move(e).error();
  s.replica = std::move(*streaming);
  cg::stream_client_into(*s.viewer, *s.replica);
  auto lo = render_loop_options(painting, cfg);
  if (!lo) return std::move(lo).error();
  auto loop = cg::RenderLoop::create(*s.replica, *lo);
  if (!loop) return std::move(loop).error();
  s.loop = std::move(*loop);
  if (!s.replica->wait_resident(0, std::chrono::seconds(30)))
    return make_error(Errc::io_error, "e2e: the snapshot never became resident");
  if (cfg.render) {
    s.loop->start();
    // Let the loop settle (adaptive bands) before the first stroke.
    while (s.loop->frame_count() < 3) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return {};
}

// Artist time -> run time: each step between consecutive samples (within and between strokes)
// as recorded, capped at max_gap_ms.
class ArtistPace {
 public:
  ArtistPace(Clock::time_point t0, double max_gap_ms) : t0_(t0), max_gap_ms_(max_gap_ms) {}
  // Steps to sample time `t`; returns when it is due.
  Clock::time_point advance(std::uint32_t t) {
    if (have_prev_ && t >= prev_t_) at_ms_ += std::min<double>(t - prev_t_, max_gap_ms_);
    prev_t_ = t;
    have_prev_ = true;
    return due();
  }
  // Steps to sample time `t` only if it is due by `by_ms` (run time, ms since t0).
  bool advance_if_due(std::uint32_t t, double by_ms) {
    const double save_ms = at_ms_;
    const std::uint32_t save_t = prev_t_;
    (void)advance(t);
    if (at_ms_ <= by_ms) return true;
    at_ms_ = save_ms;
    prev_t_ = save_t;
    return false;
  }
  // When the last sample stepped to is due.
  Clock::time_point due() const {
    return t0_ + std::chrono::microseconds(static_cast<std::int64_t>(at_ms_ * 1000));
  }

 private:
  Clock::time_point t0_;
  double max_gap_ms_;
  double at_ms_ = 0;
  std::uint32_t prev_t_ = 0;
  bool have_prev_ = false;
};

// When each stroke was sent, when its ack arrived and the epoch the ack names.
struct SentStrokes {
  std::vector<Clock::time_point> sent, acked;
  std::vector<std::uint64_t> epochs;
};

// Waits for the strokes' acks in stroke order on its own thread, as their handles are handed
// to it, so that each ack's arrival is known (where a stroke's time went, traced, starts with
// sent -> acked). Destroyed before join(), on an early return, it stops the waiter (closing
// the painter ends a wait in progress).
class AckWaiter {
 public:
  AckWaiter(client_core::Client& painter, std::size_t n)
      : painter_(painter),
        handles_(n),
        acked_(n),
        acks_(n, make_error(Errc::io_error, "stroke never sent")),
        thread_([this] { wait_all(); }) {}
  AckWaiter(const AckWaiter&) = delete;
  AckWaiter& operator=(const AckWaiter&) = delete;
  ~AckWaiter() {
    if (!thread_.joinable()) return;
    handed_.store(kAbandoned);
    handed_.notify_all();
    painter_.close();
    thread_.join();
  }
  // Stroke i's handle (strokes handed in order).
  void hand(std::size_t i, std::uint64_t handle) {
    handles_[i] = handle;
    handed_.store(i + 1);
    handed_.notify_one();
  }
  // After every stroke is handed: the acks' arrival times and epochs, or the first failed ack.
  Result<void> join(SentStrokes& out) {
    thread_.join();
    out.acked = acked_;
    out.epochs.resize(acks_.size());
    for (std::size_t i = 0; i < acks_.size(); ++i) {
      if (!acks_[i]) return std::move(acks_[i]).error();
      out.epochs[i] = acks_[i]->epoch;
    }
    return {};
  }

 private:
  // Strokes whose handles are set; kAbandoned: stop.
  static constexpr std::size_t kAbandoned = std::numeric_limits<std::size_t>::max();
  void wait_all() {
    for (std::size_t i = 0; i < handles_.size(); ++i) {
      for (std::size_t h = handed_.load(); h <= i; h = handed_.load()) handed_.wait(h);
      if (handed_.load() == kAbandoned) return;
      acks_[i] = painter_.wait_for_ack(handles_[i], std::chrono::seconds(120));
      acked_[i] = Clock::now();
      if (!acks_[i]) return;
    }
  }
  client_core::Client& painter_;
  std::vector<std::uint64_t> handles_;
  std::vector<Clock::time_point> acked_;
  std::vector<Result<protocol::Ack>> acks_;
  std::atomic<std::size_t> handed_{0};
  std::thread thread_;  // last: starts once the rest is built
};

// The whole stroke when the artist finished it; returns its handle.
Result<std::uint64_t> send_whole_stroke(client_core::Client& painter, const protocol::Stroke& s,
                                        ArtistPace& pace, Clock::time_point& sent) {
  for (const auto& smp : s.samples) (void)pace.advance(smp.t_ms);
  std::this_thread::sleep_until(pace.due());
  sent = Clock::now();
  return painter.send_stroke(s);
}

// Streamed as the artist paints: begin with the first sample (the handle goes to `waiter`),
// then the samples due at each wake-up, then the end right after the last one ("sent").
Result<void> stream_stroke(client_core::Client& painter, const protocol::Stroke& s,
                           ArtistPace& pace, Clock::time_point t0, std::size_t i, AckWaiter& waiter,
                           Clock::time_point& sent) {
  std::this_thread::sleep_until(pace.advance(s.samples[0].t_ms));
  auto h = painter.begin_stroke(s.brush, {s.samples[0]});
  if (!h) return std::move(h).error();
  waiter.hand(i, *h);
  std::size_t k = 1;
  while (k < s.samples.size()) {
    std::this_thread::sleep_until(pace.advance(s.samples[k].t_ms));
    std::vector<protocol::StrokeSample> chunk{s.samples[k++]};
    const double due_ms =
        std::chrono::duration<double, std::milli>(Clock::now() - t0).count() + 1.0;
    while (k < s.samples.size() && pace.advance_if_due(s.samples[k].t_ms, due_ms))
      chunk.push_back(s.samples[k++]);
    if (auto r = painter.add_samples(*h, std::move(chunk)); !r) return r;
  }
  sent = Clock::now();
  return painter.end_stroke(*h);
}

// The painting's first n strokes at the artist's pace from t0; `progress` advances by one per
// stroke sent. Returns once every ack has arrived.
Result<SentStrokes> send_painting(client_core::Client& painter,
                                  const paintings::ApaPainting& painting, std::size_t n,
                                  const E2eConfig& cfg, Clock::time_point t0,
                                  base::Progress& progress) {
  SentStrokes out;
  out.sent.resize(n);
  ArtistPace pace(t0, cfg.max_gap_ms);
  AckWaiter waiter(painter, n);
  for (std::size_t i = 0; i < n; ++i) {
    const auto& s = painting.strokes[i];
    if (cfg.whole_strokes || s.samples.size() < 2) {
      auto h = send_whole_stroke(painter, s, pace, out.sent[i]);
      if (!h) return std::move(h).error();
      waiter.hand(i, *h);
    } else if (auto r = stream_stroke(painter, s, pace, t0, i, waiter, out.sent[i]); !r) {
      return std::move(r).error();
    }
    progress.add(1);
  }
  if (auto r = waiter.join(out); !r) return std::move(r).error();
  return out;
}

// Waits until a whole frame shows `epoch` (at most 60 s).
void wait_for_frame_showing(const cg::RenderLoop& loop, std::uint64_t epoch) {
  const auto deadline = Clock::now() + std::chrono::seconds(60);
  while (Clock::now() < deadline) {
    const auto fr = loop.frames();
    if (!fr.empty() && fr.back().min_epoch >= epoch) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

void trace_long_batch(const cg::ResidentBatch& b) {
  std::fprintf(stderr,
               "long batch %llu-%llu: lock %.2f (mirror %.2f grow %.2f upload %.2f links "
               "%.2f), lock wait %.2f, content %.2f, rows %llu, late %llu, grew %d\n",
               (unsigned long long)b.first_epoch, (unsigned long long)b.last_epoch, b.gpu_lock_ms,
               b.mirror_ms, b.grow_ms, b.upload_ms, b.links_ms, b.lock_wait_ms, b.content_ms,
               (unsigned long long)b.rows, (unsigned long long)b.late_epochs, b.grew ? 1 : 0);
}

// Per upload batch: its time under the GPU lock and the parts of it.
void collect_batches(const std::vector<cg::ResidentBatch>& log, bool trace, E2eRun& out) {
  for (const auto& b : log) {
    // Long batches, whichever strokes they carried (the per-stroke lines show only the batch
    // holding each stroke's last epoch).
    if (trace && b.gpu_lock_ms > 10.0) trace_long_batch(b);
    out.batch_lock_ms.push_back(b.gpu_lock_ms);
    out.batch_mirror_ms.push_back(b.mirror_ms);
    out.batch_upload_ms.push_back(b.upload_ms);
    out.batch_links_ms.push_back(b.links_ms);
    out.batch_content_ms.push_back(b.content_ms);
    out.batch_gap_wait_ms.push_back(b.gap_wait_ms);
    out.mid_frame_batches += b.mid_frame ? 1 : 0;
    out.batch_rows.push_back(static_cast<double>(b.rows));
  }
}

// Where stroke i's time went: sent -> acked / first frame / committed / resident, and the
// commit -> resident of the batch `b` that made its epoch `e` resident.
void trace_stroke(std::size_t i, std::uint64_t e, const SentStrokes& st,
                  std::optional<Clock::time_point> first_frame, Clock::time_point committed,
                  const cg::ResidentBatch& b) {
  const auto sent = st.sent[i];
  std::fprintf(stderr,
               "stroke %zu epoch %llu: sent->acked %.2f, ->first frame %.2f, "
               "->committed %.2f, ->resident %.2f\n",
               i, (unsigned long long)st.epochs[i], ms_between(sent, st.acked[i]),
               first_frame ? ms_between(sent, *first_frame) : -1.0, ms_between(sent, committed),
               ms_between(sent, b.resident_at));
  std::fprintf(stderr,
               "stroke %zu epoch %llu: commit->resident %.2f = gap wait %.2f + "
               "content %.2f + lock wait %.2f + lock %.2f (mirror %.2f grow %.2f upload %.2f "
               "links %.2f) + other; taken %.2f after commit; batch %llu-%llu rows "
               "%llu mid %d late %llu\n",
               i, (unsigned long long)e, ms_between(committed, b.resident_at), b.gap_wait_ms,
               b.content_ms, b.lock_wait_ms, b.gpu_lock_ms, b.mirror_ms, b.grow_ms, b.upload_ms,
               b.links_ms, ms_between(committed, b.taken_at), (unsigned long long)b.first_epoch,
               (unsigned long long)b.last_epoch, (unsigned long long)b.rows, b.mid_frame ? 1 : 0,
               (unsigned long long)b.late_epochs);
}

// Per stroke: sent -> resident (the first batch holding its epoch), -> committed and commit ->
// resident, -> the end of the first frame started after it was sent that shows its epoch.
void collect_stroke_latencies(const SentStrokes& st, const std::vector<cg::ResidentBatch>& log,
                              const std::vector<cg::FrameRecord>& frames,
                              const client_core::Client& viewer, bool trace, E2eRun& out) {
  for (std::size_t i = 0; i < st.sent.size(); ++i) {
    const auto sent = st.sent[i];
    const std::uint64_t epoch = st.epochs[i];
    for (const auto& b : log)
      if (b.last_epoch >= epoch) {
        out.resident_ms.push_back(ms_between(sent, b.resident_at));
        for (const auto& [e, t] : b.commits)
          if (e >= epoch) {
            out.committed_ms.push_back(ms_between(sent, t));
            out.commit_resident_ms.push_back(ms_between(t, b.resident_at));
            if (trace) trace_stroke(i, e, st, viewer.first_frame_after(epoch - 1), t, b);
            break;
          }
        break;
      }
    for (const auto& f : frames)
      if (f.min_epoch >= epoch && f.start >= sent) {
        out.pixel_ms.push_back(ms_between(sent, f.end));
        break;
      }
  }
}

// The GPU links (G3 on the GPU, masked groups only) equal the CPU replica's links.
Result<bool> gpu_links_equal_cpu(cg::StreamingReplica& sr, client_core::Client& viewer) {
  auto gpu_links = resident_links(sr);
  if (!gpu_links) return std::move(gpu_links).error();
  bool equal = false;
  viewer.with_replica([&](const client_core::Replica& r) {
    const auto cpu = r.group_links();
    equal = gpu_links->size() == cpu.size() &&
            std::equal(gpu_links->begin(), gpu_links->end(), cpu.begin());
  });
  return equal;
}

void trace_server(const server_core::CanvasMetrics& m) {
  auto qms = [](const server_core::Histogram& h, double p) { return h.quantile_seconds(p) * 1e3; };
  std::fprintf(stderr,
               "server: step p50 %.2f p99 %.2f, stage p99 %.2f, compress wait p50 %.2f p99 "
               "%.2f, compress p50 %.2f p99 %.2f, stroke->publish p50 %.2f p99 %.2f ms; "
               "%llu epochs (%llu inline)\n",
               qms(m.step_seconds, 0.5), qms(m.step_seconds, 0.99), qms(m.stage_seconds, 0.99),
               qms(m.compress_wait_seconds, 0.5), qms(m.compress_wait_seconds, 0.99),
               qms(m.compress_seconds, 0.5), qms(m.compress_seconds, 0.99),
               qms(m.stroke_to_publish_seconds, 0.5), qms(m.stroke_to_publish_seconds, 0.99),
               (unsigned long long)m.epochs.value(), (unsigned long long)m.inline_epochs.value());
}

// The server's own view (its histograms, this run).
void collect_server_figures(const server_net::Server& server, bool trace, E2eRun& out) {
  const auto* canvas = server.canvas("e2e");
  if (!canvas) return;
  const auto& m = canvas->metrics();
  out.server_end_to_painted_ms_p50 = m.end_to_painted_seconds.quantile_seconds(0.5) * 1e3;
  out.server_end_to_painted_ms_p99 = m.end_to_painted_seconds.quantile_seconds(0.99) * 1e3;
  out.server_stroke_to_publish_ms_p99 = m.stroke_to_publish_seconds.quantile_seconds(0.99) * 1e3;
  const double strokes = static_cast<double>(std::max<std::size_t>(out.strokes, 1));
  out.painting_bytes_per_stroke = static_cast<double>(m.epoch_bytes_painting.value()) / strokes;
  out.merging_bytes_per_stroke = static_cast<double>(m.epoch_bytes_merging.value()) / strokes;
  if (m.bundled_frame_bytes.value() > 0)
    out.bundle_ratio = static_cast<double>(m.bundle_bytes.value()) /
                       static_cast<double>(m.bundled_frame_bytes.value());
  if (trace) trace_server(m);
}

}  // namespace

Result<E2eRun> run_one(const cg::Context& ctx, const paintings::ApaPainting& painting,
                       const E2eConfig& cfg, base::Progress& progress) {
  E2eSession s;
  if (auto r = open_session(s, ctx, painting, cfg); !r) return std::move(r).error();
  cg::StreamingReplica& sr = *s.replica;
  E2eRun out;
  const std::size_t n = std::min(cfg.max_strokes, painting.strokes.size());
  const auto t0 = Clock::now();
  auto sent = send_painting(*s.painter, painting, n, cfg, t0, progress);
  if (!sent) return std::move(sent).error();
  auto quiet = s.server->canvas("e2e")->quiesce(std::chrono::seconds(120));
  if (!quiet) return std::move(quiet).error();
  const std::uint64_t last = quiet->epoch;
  const bool resident = sr.wait_resident(last, std::chrono::seconds(120));
  if (cfg.render) wait_for_frame_showing(*s.loop, last);
  auto stopped = s.loop->stop();
  s.viewer->set_epoch_listener({});
  out.wall_s = std::chrono::duration<double>(Clock::now() - t0).count();
  if (!stopped) return std::move(stopped).error();
  if (auto st = sr.status(); !st) return std::move(st).error();
  if (!resident) return make_error(Errc::io_error, "e2e: the last epoch never became resident");

  const auto log = sr.take_resident_log();
  const auto frames = s.loop->frames();
  const bool trace = std::getenv("DEEPCANVAS_BENCH_TRACE") != nullptr;
  collect_batches(log, trace, out);
  collect_stroke_latencies(*sent, log, frames, *s.viewer, trace, out);
  for (const auto& f : frames) {
    out.frame_ms.push_back(f.ms);
    if (f.streaming) out.frame_stream_ms.push_back(f.ms);
  }
  out.strokes = n;
  out.bytes_per_stroke = static_cast<double>(s.viewer->stats().frame_bytes) /
                         static_cast<double>(std::max<std::size_t>(n, 1));
  const auto st = sr.stats();
  out.batches = st.batches;
  out.epochs = st.epochs;
  out.growths = st.growths;
  out.max_batch_ms = st.max_batch_lock_ms;
  out.converged = s.viewer->wait_for_epoch(last, std::chrono::seconds(10)).ok() &&
                  s.viewer->pool_hash() == quiet->pool_hash;
  auto links_equal = gpu_links_equal_cpu(sr, *s.viewer);
  if (!links_equal) return std::move(links_equal).error();
  out.links_equal = *links_equal;
  collect_server_figures(*s.server, trace, out);
  {
    const auto vs = s.viewer->stats();
    out.frame_header_share = vs.frame_bytes > 0 ? static_cast<double>(vs.header_bytes) /
                                                      static_cast<double>(vs.frame_bytes)
                                                : 0;
    // A viewer joining the finished painting: its snapshot's bytes.
    const auto jo = e2e_client(s.server->port(), protocol::Role::viewer, true, false);
    if (auto joiner = client_core::Client::connect(jo); joiner) {
      if ((*joiner)->wait_for_epoch(last, std::chrono::seconds(60)).ok())
        out.snapshot_bytes = static_cast<double>((*joiner)->stats().frame_bytes);
      (*joiner)->close();
    }
  }
  s.loop.reset();
  s.painter->close();
  s.viewer->close();
  s.server->stop();
  return out;
}

}  // namespace deepcanvas::bench
