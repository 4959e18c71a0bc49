// deepcanvas-bench server: paintings replayed through the streaming server on loopback to 1, 8
// and 32 headless clients (client_core). One client paints (stroke, wait for its ack and for the
// server to settle it - the ack names the epoch with all of its paint, merging uniform cells back
// may follow - then the next stroke: the server's fastest pace for one artist, each stroke
// arriving at an idle canvas; a stroke that arrives while the previous one still merges waits
// for it, one active stroke per canvas: `deepcanvas-bench e2e` paces strokes as recorded);
// every client keeps a replica.
//
// Figures:
//   stroke_to_first_block_ms_p50/_p99  stroke sent by the painter -> the first block frame of a
//       later epoch read by the painter (client-side, so it includes both loopback hops: an upper
//       bound on the server's "stroke received -> first frame written"); with 1 client
//   server_stroke_to_first_block_ms_p50/_p99  the definition measured by the server itself: stroke
//       read from the socket -> its first block frame written to each client's socket (histogram,
//       interpolated within its 19%-wide bucket), with the breakdown under by_clients.*.server:
//       -> staged (stroke thread), -> published (compress thread), step, stage and compress times
//   compression_ratio   raw block payload bytes / block frame bytes on the painter's wire (delta
//       frames where the painter holds the base, full frames otherwise; client counters);
//       full_frame_ratio the same for full frames only (server encoder counters), what a client
//       without delta frames gets; server_wire_ratio over every session
//   bytes_per_stroke    block frame bytes one client received / strokes
//   late_join_snapshot_ms  a new client on the largest painting: connect -> snapshot applied
//   broadcast_mb_per_s  block frame bytes written to all clients / painting wall time
// Medians over the paintings where several are run. --quick: fewer paintings, 1 and 8 clients.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "bench.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_net/server.hpp"

namespace deepcanvas::bench {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// The server's own latency histograms of one run (merged over runs for the summaries).
struct ServerTimes {
  server_core::Histogram first_block;  // stroke read -> its first block frame written (per client)
  server_core::Histogram to_stage, to_publish, to_take, step, stage, compress, compress_wait;
  void merge(const ServerTimes& o) {
    first_block.merge_from(o.first_block);
    to_stage.merge_from(o.to_stage);
    to_publish.merge_from(o.to_publish);
    to_take.merge_from(o.to_take);
    step.merge_from(o.step);
    stage.merge_from(o.stage);
    compress.merge_from(o.compress);
    compress_wait.merge_from(o.compress_wait);
  }
  nlohmann::json json() const {
    const auto ms = [](const server_core::Histogram& h, double q) {
      return h.count() ? h.quantile_seconds(q) * 1e3 : 0.0;
    };
    return {{"stroke_to_first_block_ms_p50", ms(first_block, 0.5)},
            {"stroke_to_first_block_ms_p99", ms(first_block, 0.99)},
            {"stroke_to_stage_ms_p50", ms(to_stage, 0.5)},
            {"stroke_to_stage_ms_p99", ms(to_stage, 0.99)},
            {"stroke_to_publish_ms_p50", ms(to_publish, 0.5)},
            {"stroke_to_publish_ms_p99", ms(to_publish, 0.99)},
            {"stroke_to_take_ms_p50", ms(to_take, 0.5)},
            {"stroke_to_take_ms_p99", ms(to_take, 0.99)},
            {"step_ms_p50", ms(step, 0.5)},
            {"step_ms_p99", ms(step, 0.99)},
            {"stage_ms_per_epoch_p50", ms(stage, 0.5)},
            {"stage_ms_per_epoch_p99", ms(stage, 0.99)},
            {"stage_ms_per_epoch_mean",
             stage.count() ? stage.sum_seconds() * 1e3 / static_cast<double>(stage.count()) : 0.0},
            {"compress_ms_per_epoch_p50", ms(compress, 0.5)},
            {"compress_ms_per_epoch_p99", ms(compress, 0.99)},
            {"compress_wait_ms_p50", ms(compress_wait, 0.5)},
            {"compress_wait_ms_p99", ms(compress_wait, 0.99)}};
  }
};

struct RunResult {
  std::size_t clients = 0, strokes = 0;
  std::shared_ptr<ServerTimes> times = std::make_shared<ServerTimes>();
  std::vector<double> first_block_ms;
  double wall_s = 0;
  double compression_ratio = 0;    // the painter's wire: raw payload bytes / frame bytes read
  double full_frame_ratio = 0;     // full frames only (what a client without deltas gets)
  double server_wire_ratio = 0;    // all sessions: raw payload bytes / frame bytes written
  double delta_frame_share = 0;    // of the frames the painter read
  double inline_first_epochs = 0;  // first epochs encoded on the stroke thread / strokes
  double bytes_per_stroke = 0;
  double broadcast_mb_per_s = 0;
  double server_p99_ms = 0;
  double late_join_ms = 0;
  bool converged = false;
};

Result<RunResult> run_painting(const paintings::ApaPainting& painting, std::size_t n_clients,
                               std::size_t max_strokes, bool late_join) {
  server_net::ServerConfig cfg;
  cfg.port = 0;
  cfg.limits.max_strokes_per_second = 100000;
  server_core::CanvasServiceConfig c;
  c.name = "bench";
  cfg.canvases.push_back(c);
  auto server = server_net::Server::create(cfg);
  if (!server) return std::move(server).error();
  if (auto r = (*server)->start(); !r) return std::move(r).error();
  const std::string url = "ws://127.0.0.1:" + std::to_string((*server)->port()) + "/";
  std::vector<std::unique_ptr<client_core::Client>> clients;
  for (std::size_t i = 0; i < n_clients; ++i) {
    client_core::ClientOptions o;
    o.url = url;
    o.canvas = "bench";
    o.role = i == 0 ? protocol::Role::painter : protocol::Role::viewer;
    auto cl = client_core::Client::connect(o);
    if (!cl) return std::move(cl).error();
    clients.push_back(std::move(*cl));
  }
  for (auto& cl : clients)
    if (auto r = cl->wait_for_epoch(0, std::chrono::seconds(30)); !r) return std::move(r).error();
  auto& painter = *clients[0];
  auto* canvas = (*server)->canvas("bench");
  RunResult out;
  out.clients = n_clients;
  const auto t0 = Clock::now();
  const std::size_t n = std::min(max_strokes, painting.strokes.size());
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint64_t before = painter.applied_epoch();
    const auto sent = Clock::now();
    auto h = painter.send_stroke(painting.strokes[i]);
    if (!h) return std::move(h).error();
    auto a = painter.wait_for_ack(*h, std::chrono::seconds(60));
    if (!a) return std::move(a).error();
    if (auto e = painter.wait_for_epoch(a->epoch, std::chrono::seconds(60)); !e)
      return std::move(e).error();
    if (auto t = painter.first_frame_after(before))
      out.first_block_ms.push_back(std::chrono::duration<double, std::milli>(*t - sent).count());
    auto settled = canvas->quiesce(std::chrono::seconds(60));
    if (!settled) return std::move(settled).error();
    if (auto e = painter.wait_for_epoch(settled->epoch, std::chrono::seconds(60)); !e)
      return std::move(e).error();
  }
  auto q = canvas->quiesce(std::chrono::seconds(120));
  if (!q) return std::move(q).error();
  out.converged = true;
  for (auto& cl : clients) {
    if (!cl->wait_for_epoch(q->epoch, std::chrono::seconds(120))) out.converged = false;
    if (cl->pool_hash() != q->pool_hash) out.converged = false;
  }
  out.wall_s = std::chrono::duration<double>(Clock::now() - t0).count();
  out.strokes = n;
  const auto& cm = canvas->metrics();
  const auto ps = painter.stats();
  out.compression_ratio =
      ps.frame_bytes ? static_cast<double>(ps.raw_bytes) / static_cast<double>(ps.frame_bytes) : 0;
  out.delta_frame_share =
      ps.frames ? static_cast<double>(ps.delta_frames) / static_cast<double>(ps.frames) : 0;
  out.full_frame_ratio = cm.bytes_compressed.value()
                             ? static_cast<double>(cm.bytes_raw.value()) /
                                   static_cast<double>(cm.bytes_compressed.value())
                             : 0;
  out.inline_first_epochs = static_cast<double>(cm.inline_epochs.value()) /
                            static_cast<double>(std::max<std::size_t>(n, 1));
  const auto& sm = (*server)->metrics();
  out.server_wire_ratio = sm.frame_bytes_sent.value()
                              ? static_cast<double>(sm.frame_raw_bytes_sent.value()) /
                                    static_cast<double>(sm.frame_bytes_sent.value())
                              : 0;
  out.bytes_per_stroke =
      static_cast<double>(painter.stats().frame_bytes) / std::max<std::size_t>(n, 1);
  out.broadcast_mb_per_s =
      static_cast<double>((*server)->metrics().frame_bytes_sent.value()) / 1e6 / out.wall_s;
  out.server_p99_ms =
      (*server)->metrics().stroke_to_first_block_seconds.quantile_seconds(0.99) * 1e3;
  out.times->first_block.merge_from((*server)->metrics().stroke_to_first_block_seconds);
  out.times->to_stage.merge_from(cm.stroke_to_stage_seconds);
  out.times->to_publish.merge_from(cm.stroke_to_publish_seconds);
  out.times->to_take.merge_from((*server)->metrics().stroke_to_take_seconds);
  out.times->step.merge_from(cm.step_seconds);
  out.times->stage.merge_from(cm.stage_seconds);
  out.times->compress.merge_from(cm.compress_seconds);
  out.times->compress_wait.merge_from(cm.compress_wait_seconds);
  if (late_join) {
    const auto j0 = Clock::now();
    client_core::ClientOptions o;
    o.url = url;
    o.canvas = "bench";
    o.role = protocol::Role::viewer;
    auto late = client_core::Client::connect(o);
    if (!late) return std::move(late).error();
    if (auto e = (*late)->wait_for_epoch(q->epoch, std::chrono::seconds(120)); !e)
      return std::move(e).error();
    out.late_join_ms = std::chrono::duration<double, std::milli>(Clock::now() - j0).count();
    if ((*late)->pool_hash() != q->pool_hash) out.converged = false;
  }
  clients.clear();
  (*server)->stop();
  return out;
}

// The human summary on stdout (without --json): a line per client count (ascending), then the
// late join.
void print_summary(const nlohmann::json& out) {
  std::vector<std::pair<unsigned long, const nlohmann::json*>> by_clients;
  for (const auto& [key, c] : out["by_clients"].items())
    by_clients.emplace_back(std::stoul(key.substr(std::string("clients_").size())), &c);
  std::sort(by_clients.begin(), by_clients.end());
  for (const auto& [clients, c] : by_clients)
    print(
        "server, %2lu clients: stroke -> first block frame p50 %.2f ms, p99 %.2f ms "
        "(server's own p99 %.2f ms); compression %.1fx (full frames only %.1fx), "
        "%.0f B/stroke, %.1f MB/s broadcast, %s\n",
        clients, (*c)["stroke_to_first_block_ms_p50"].get<double>(),
        (*c)["stroke_to_first_block_ms_p99"].get<double>(),
        (*c)["server"]["stroke_to_first_block_ms_p99"].get<double>(),
        (*c)["compression_ratio"].get<double>(), (*c)["full_frame_ratio"].get<double>(),
        (*c)["bytes_per_stroke"].get<double>(), (*c)["broadcast_mb_per_s"].get<double>(),
        (*c)["converged"].get<bool>() ? "converged" : "NOT CONVERGED");
  print("server, late join on %s (%zu strokes): snapshot applied in %.1f ms\n",
        out["late_join_painting"].get<std::string>().c_str(),
        out["late_join_strokes"].get<std::size_t>(), out["late_join_snapshot_ms"].get<double>());
}

int server_main(const Options& opt) {
  base::set_log_level(base::LogLevel::warn);
  auto dir = paintings_dir();
  if (!dir) return fail(opt, dir.error().message);
  std::vector<std::pair<std::string, paintings::ApaPainting>> paintings;
  for (const auto& e : fs::directory_iterator(*dir)) {
    if (e.path().extension() != ".apa") continue;
    auto p = paintings::read_apa_file(e.path().string(), {});
    if (!p) return fail(opt, p.error().message);
    paintings.emplace_back(e.path().stem().string(), std::move(*p));
  }
  if (paintings.empty()) return fail(opt, "no .apa files in " + dir->string());
  std::sort(paintings.begin(), paintings.end(), [](const auto& a, const auto& b) {
    return a.second.sample_count < b.second.sample_count;
  });
  // Latency paintings: a few small and medium ones (quick: two); the largest for the late join.
  std::vector<std::size_t> pick =
      opt.quick ? std::vector<std::size_t>{0, 2} : std::vector<std::size_t>{0, 2, 4, 6, 8};
  const std::size_t largest = paintings.size() - 1;
  const std::vector<std::size_t> client_counts =
      opt.quick ? std::vector<std::size_t>{1, 8} : std::vector<std::size_t>{1, 8, 32};
  const std::size_t max_strokes = opt.quick ? 40 : 100000;
  std::size_t total_runs = 1;  // the late join
  for (std::size_t i : pick) total_runs += i < paintings.size() ? client_counts.size() : 0;
  auto progress = bench::progress(opt, "server", double(total_runs), "runs");

  nlohmann::json runs = nlohmann::json::array();
  nlohmann::json summary;
  for (std::size_t nc : client_counts) {
    std::vector<double> lat, ratio, bps, mbps, sp99, full_ratio, wire_ratio, delta_share;
    ServerTimes times;
    bool converged = true;
    for (std::size_t i : pick) {
      if (i >= paintings.size()) continue;
      auto r = run_painting(paintings[i].second, nc, max_strokes, false);
      if (!r)
        return fail(opt, paintings[i].first + " with " + std::to_string(nc) +
                             " clients: " + r.error().message);
      converged = converged && r->converged;
      lat.insert(lat.end(), r->first_block_ms.begin(), r->first_block_ms.end());
      ratio.push_back(r->compression_ratio);
      full_ratio.push_back(r->full_frame_ratio);
      wire_ratio.push_back(r->server_wire_ratio);
      delta_share.push_back(r->delta_frame_share);
      bps.push_back(r->bytes_per_stroke);
      mbps.push_back(r->broadcast_mb_per_s);
      sp99.push_back(r->server_p99_ms);
      times.merge(*r->times);
      const auto sj = r->times->json();
      progress.add(1);
      note(opt,
           "server: %-20s clients %2zu strokes %4zu  first block p50 %6.2f ms p99 %6.2f ms "
           "(server %5.2f / %5.2f)  ratio %5.1f  %8.0f B/stroke  %7.1f MB/s  %s\n",
           paintings[i].first.c_str(), nc, r->strokes, base::percentile(r->first_block_ms, 0.5),
           base::percentile(r->first_block_ms, 0.99),
           sj["stroke_to_first_block_ms_p50"].get<double>(),
           sj["stroke_to_first_block_ms_p99"].get<double>(), r->compression_ratio,
           r->bytes_per_stroke, r->broadcast_mb_per_s,
           r->converged ? "converged" : "NOT CONVERGED");
      runs.push_back({{"painting", paintings[i].first},
                      {"clients", nc},
                      {"strokes", r->strokes},
                      {"stroke_to_first_block_ms_p50", base::percentile(r->first_block_ms, 0.5)},
                      {"stroke_to_first_block_ms_p99", base::percentile(r->first_block_ms, 0.99)},
                      {"compression_ratio", r->compression_ratio},
                      {"full_frame_ratio", r->full_frame_ratio},
                      {"server_wire_ratio", r->server_wire_ratio},
                      {"delta_frame_share", r->delta_frame_share},
                      {"inline_first_epochs_per_stroke", r->inline_first_epochs},
                      {"bytes_per_stroke", r->bytes_per_stroke},
                      {"broadcast_mb_per_s", r->broadcast_mb_per_s},
                      {"server", sj},
                      {"converged", r->converged}});
    }
    const std::string k = std::to_string(nc);
    summary["clients_" + k] = {{"stroke_to_first_block_ms_p50", base::percentile(lat, 0.5)},
                               {"stroke_to_first_block_ms_p99", base::percentile(lat, 0.99)},
                               {"server_stroke_to_first_block_ms_p99_bucket", median(sp99)},
                               {"compression_ratio", median(ratio)},
                               {"full_frame_ratio", median(full_ratio)},
                               {"server_wire_ratio", median(wire_ratio)},
                               {"delta_frame_share", median(delta_share)},
                               {"bytes_per_stroke", median(bps)},
                               {"broadcast_mb_per_s", median(mbps)},
                               {"server", times.json()},
                               {"converged", converged}};
  }
  auto late = run_painting(paintings[largest].second, 1, opt.quick ? 60 : 100000, true);
  if (!late) return fail(opt, "late join: " + late.error().message);
  progress.add(1);
  progress.finish();
  note(opt, "server: late join on %s (%zu strokes): snapshot in %.1f ms\n",
       paintings[largest].first.c_str(), late->strokes, late->late_join_ms);
  const auto& one = summary["clients_1"];
  nlohmann::json out = {
      {"suite", "server"},
      {"quick", opt.quick},
      {"stroke_to_first_block_ms_p50", one["stroke_to_first_block_ms_p50"]},
      {"stroke_to_first_block_ms_p99", one["stroke_to_first_block_ms_p99"]},
      // The definition's own measurement: stroke read by the server -> its first block frame
      // written to the socket (server histograms, interpolated within 19%-wide buckets).
      {"server_stroke_to_first_block_ms_p50", one["server"]["stroke_to_first_block_ms_p50"]},
      {"server_stroke_to_first_block_ms_p99", one["server"]["stroke_to_first_block_ms_p99"]},
      {"compression_ratio", one["compression_ratio"]},
      {"full_frame_ratio", one["full_frame_ratio"]},
      {"bytes_per_stroke", one["bytes_per_stroke"]},
      {"late_join_snapshot_ms", late->late_join_ms},
      {"late_join_painting", paintings[largest].first},
      {"late_join_strokes", late->strokes},
      {"targets", {{"stroke_to_first_block_ms_p99_max", 5.0}, {"compression_ratio_min", 10.0}}},
      {"by_clients", summary},
      {"runs", runs}};
  if (opt.json)
    print("%s\n", out.dump().c_str());
  else
    print_summary(out);
  return 0;
}

DEEPCANVAS_BENCH_SUITE(Suite{"server", "paintings through the server to 1/8/32 loopback clients",
                             "examples:\n"
                             "  deepcanvas-bench server --quick\n"
                             "  deepcanvas-bench server --json > server.json\n"
                             "environment: DEEPCANVAS_PAINTINGS (the paintings' folder)\n",
                             no_options(server_main)});

}  // namespace
}  // namespace deepcanvas::bench
