// deepcanvas-bench durability: what keeping canvases on disk (storage/canvas_store.hpp,
// storage/durable_canvas.hpp) costs and whether it keeps its promise.
//
// Figures (each comparison measured in the same run, same painters, same pacing):
//   ack_ms_p50 / ack_ms_p99  two painters stream slices of two real paintings at the recorded
//       pace (bench/load_run.hpp's slices; the two paintings with the most strokes in the first
//       --seconds) to an in-process server whose canvas is durable (temp
//       data directory, StoreOptions defaults: synchronous=FULL); ack = stroke_end sent -> ack
//       read, client side over loopback. _memory: the same painters on a canvas in memory.
//       ack_p99_durable_minus_memory_ms and ack_p99_ratio compare the two (target: at most 5 ms
//       above in memory). With few strokes (--quick) the p99 is close to the maximum.
//   strokes_per_s_sustained  the same two painters sending whole strokes as fast as acks come
//       back (8 unanswered each, the session stroke rate limit off), durable canvas: strokes
//       acked per second over the run; _memory the same on a canvas in memory.
//   strokes_per_s_small_durable / _memory  one-sample synthetic strokes (radius 1 cm) submitted
//       straight to a CanvasService, 64 unanswered: what group commit sustains when painting
//       is cheap (the real strokes above are bound by the painter, durable or not).
//   checkpoint_ms_1m / _16m  a checkpoint of the whole canvas (every block) handed to a fresh
//       CanvasStore -> written (checkpoints_written() increments): zstd + one SQLite
//       transaction; restart/SIZE/checkpoint/copy_ms the copy-out (Octree::save_block of every
//       block; the stroke thread does it 64 blocks per step boundary, copy_ms_per_64_blocks).
//   step_ms_max_with_checkpoints / step_ms_max_without  a durable CanvasService painting
//       synthetic strokes one at a time (between strokes nothing is open, so a checkpoint that
//       falls due is taken at once) with a checkpoint every 64 events vs never: longest step
//       (deepcanvas_step_seconds histogram: the upper bound of the highest non-empty bucket) and
//       p99; the stroke thread copies checkpoint blocks between steps, outside that histogram, so
//       the submit -> ack p99/max of the same strokes and end_to_painted p99 are reported too.
//   restart_s_1m / _16m (/ _64m without --quick; / _Nm with --restart-cells N)  a durable
//       canvas grown in-process to that many live cells with synthetic strokes
//       (synchronous=OFF while growing: the build is not what is measured), stopped cleanly (a final checkpoint), then open_durable_canvas timed until
//       it returns (load the newest checkpoint + replay; target 16M cells under 5 s).
//   disk_bytes_per_cell  database + WAL bytes / live cells after that clean stop (16M; _1m).
//       Synthetic strokes are one colour each and compress well: checkpoint_bytes_per_cell_real
//       is the real strokes' canvas (every checkpoint's bytes / live cells, an upper bound).
//   disk_bytes_per_stroke  sum(length(record)) of the events table / strokes ended, for the
//       durable paced run's real strokes; disk_file_bytes_per_stroke the file growth per stroke.
//   rounds / acked_strokes_lost  the real `deepcanvas-server serve --data DIR` as a child
//       process, two painters at fast pace, kill -9 at a random moment (0.3-1.5 s in), restart;
//       after each restart every stroke id an ack named (acks carry the canvas stroke id) must
//       have an end event (kind 3) in DIR/NAME.canvas's events table (read-only SQLite query
//       while the restarted server runs). Cumulative over the rounds; 3 rounds with --quick, 20
//       without. crash/restart_s_*: process start -> listening; crash/events_replayed and
//       restore_s: what each restart's canvas_restored log line says.
// Targets are printed with met / not met and never asserted.
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "bench.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_net/server.hpp"
#include "deepcanvas/storage/canvas_store.hpp"
#include "deepcanvas/storage/durable_canvas.hpp"
#include "durability_run.hpp"

namespace deepcanvas::bench {
namespace {

namespace fs = std::filesystem;
using namespace durability;
using json = nlohmann::json;

constexpr const char* kCanvas = "dur";
constexpr double kAckDeltaTargetMs = 5.0;
constexpr double kRestart16mTargetS = 5.0;

struct DurOptions {
  double seconds = 0;  // recorded seconds per painter; 0: 6 with --quick, else 30
  int rounds = 0;      // crash rounds; 0: 3 with --quick, else 20
  std::string only;    // one part only: acks, throughput, steps, restart, crash (empty: all)
  std::uint64_t restart_cells = 0;  // one more restart size (0: none)
};

double p(const std::vector<double>& v, double q) {
  return v.empty() ? 0.0 : base::percentile(v, q);
}

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// The highest non-empty bucket's upper bound, in ms (the histogram keeps no maximum).
double hist_max_ms(const server_core::Histogram& h) {
  for (int i = server_core::Histogram::kBuckets; i >= 0; --i)
    if (h.bucket(i) > 0)
      return i == server_core::Histogram::kBuckets ? INFINITY
                                                   : server_core::Histogram::bound(i) * 1e3;
  return 0;
}

// A temporary folder, removed with what it holds.
struct TempDir {
  fs::path path;
  TempDir() {
    std::string t = (fs::temp_directory_path() / "deepcanvas-durability-XXXXXX").string();
    if (mkdtemp(t.data())) path = t;
  }
  ~TempDir() {
    std::error_code ec;
    if (!path.empty()) fs::remove_all(path, ec);
  }
  std::string db() const { return (path / (std::string(kCanvas) + ".canvas")).string(); }
};

server_core::CanvasServiceConfig canvas_config() {
  server_core::CanvasServiceConfig c;
  c.name = kCanvas;
  return c;
}

// Two slices of real paintings: the two with the most strokes begun within `seconds` of
// recorded time (ties by name), so that the ack percentiles rest on as many strokes as the
// recorded pace allows.
Result<std::vector<PaintingSlice>> load_slices(double seconds) {
  auto dir = paintings_dir();
  if (!dir) return std::move(dir).error();
  std::vector<PaintingSlice> all;
  for (const auto& e : fs::directory_iterator(*dir)) {
    if (e.path().extension() != ".apa") continue;
    auto pt = paintings::read_apa_file(e.path().string(), {});
    if (!pt) return std::move(pt).error();
    all.push_back(slice_painting(e.path().stem().string(), *pt, seconds, 1000));
  }
  if (all.empty()) return make_error(Errc::not_found, "no .apa files in " + dir->string());
  std::sort(all.begin(), all.end(), [](const auto& a, const auto& b) {
    return a.strokes.size() != b.strokes.size() ? a.strokes.size() > b.strokes.size()
                                                : a.painting < b.painting;
  });
  if (all.size() == 1) all.push_back(all[0]);
  all.resize(2);
  return all;
}

// Runs the painters on `port` and joins them.
Result<std::vector<PainterResult>> run_painters(std::uint16_t port,
                                                const std::vector<PaintingSlice>& slices,
                                                bool paced, std::chrono::milliseconds fast_for) {
  std::vector<std::unique_ptr<DurablePainter>> ps;
  for (const auto& s : slices) {
    DurablePainter::Spec spec;
    spec.port = port;
    spec.canvas = kCanvas;
    spec.slice = &s;
    spec.paced = paced;
    spec.fast_for = fast_for;
    auto c = DurablePainter::connect(spec);
    if (!c) return make_error(c.error().code, "painter: " + c.error().message);
    ps.push_back(std::move(*c));
  }
  const auto t0 = Clock::now() + std::chrono::milliseconds(100);
  for (auto& x : ps) x->start(t0);
  std::vector<PainterResult> out;
  for (auto& x : ps) {
    x->join();
    out.push_back(x->result());
  }
  return out;
}

struct ServerRun {
  std::vector<double> ack_ms;
  std::size_t sent = 0, acked = 0, failed = 0;
  std::string first_error;
  double wall_s = 0;
  std::uint64_t live_cells = 0;  // the canvas at the end (set on the paced run's)
};

ServerRun merge(const std::vector<PainterResult>& rs) {
  ServerRun r;
  for (const auto& x : rs) {
    r.ack_ms.insert(r.ack_ms.end(), x.ack_ms.begin(), x.ack_ms.end());
    r.sent += x.sent;
    r.acked += x.ack_ms.size();
    r.failed += x.failed;
    if (r.first_error.empty()) r.first_error = x.first_error;
    r.wall_s = std::max(r.wall_s, x.wall_s);
  }
  return r;
}

// Painters (paced, then fast) on an in-process server: durable in `dir` when given, else in
// memory.
Result<std::pair<ServerRun, ServerRun>> serve_and_paint(const std::vector<PaintingSlice>& slices,
                                                        const TempDir* dir, double fast_s) {
  server_net::ServerConfig cfg;
  cfg.port = 0;
  cfg.limits.max_strokes_per_second = 0;  // the fast phase measures storage, not the limit
  cfg.canvases.push_back(canvas_config());
  if (dir)
    cfg.make_canvas = [d = dir->path.string()](const server_core::CanvasServiceConfig& c) {
      return storage::open_durable_canvas(d, c, storage::StoreOptions{}, false);
    };
  auto server = server_net::Server::create(cfg);
  if (!server) return std::move(server).error();
  if (auto st = (*server)->start(); !st) return std::move(st).error();
  const std::uint16_t port = (*server)->port();
  auto paced = run_painters(port, slices, true, {});
  if (!paced) return std::move(paced).error();
  auto fast = run_painters(port, slices, false,
                           std::chrono::milliseconds(static_cast<int>(fast_s * 1000)));
  if (!fast) return std::move(fast).error();
  std::uint64_t live = 0;
  if (auto q = (*server)->canvas(kCanvas)->quiesce(); q) live = q->live_cells;
  (*server)->stop();
  auto runs = std::make_pair(merge(*paced), merge(*fast));
  runs.first.live_cells = live;
  return runs;
}

json run_json(const ServerRun& r) {
  return {{"sent", r.sent},          {"acked", r.acked},
          {"failed", r.failed},      {"first_error", r.first_error},
          {"ack_ms_p50", p(r.ack_ms, 0.5)}, {"ack_ms_p99", p(r.ack_ms, 0.99)},
          {"ack_ms_max", p(r.ack_ms, 1.0)}, {"wall_s", r.wall_s}};
}

// Figures 1, 2 and disk_bytes_per_stroke.
Result<json> measure_acks(const Options& opt, const std::vector<PaintingSlice>& slices,
                          double fast_s) {
  json out;
  auto mem = serve_and_paint(slices, nullptr, fast_s);
  if (!mem) return make_error(mem.error().code, "in memory: " + mem.error().message);
  note(opt, "durability: in memory: ack p99 %.1f ms, %zu strokes; fast %.0f strokes/s\n",
       p(mem->first.ack_ms, 0.99), mem->first.acked,
       mem->second.wall_s > 0 ? double(mem->second.acked) / mem->second.wall_s : 0.0);
  TempDir dir;
  auto dur = serve_and_paint(slices, &dir, fast_s);
  if (!dur) return make_error(dur.error().code, "durable: " + dur.error().message);
  note(opt, "durability: durable:   ack p99 %.1f ms, %zu strokes; fast %.0f strokes/s\n",
       p(dur->first.ack_ms, 0.99), dur->first.acked,
       dur->second.wall_s > 0 ? double(dur->second.acked) / dur->second.wall_s : 0.0);
  out["paced_memory"] = run_json(mem->first);
  out["paced_durable"] = run_json(dur->first);
  out["fast_memory"] = run_json(mem->second);
  out["fast_durable"] = run_json(dur->second);
  const double m99 = p(mem->first.ack_ms, 0.99), d99 = p(dur->first.ack_ms, 0.99);
  out["ack_ms_p50"] = p(dur->first.ack_ms, 0.5);
  out["ack_ms_p99"] = d99;
  out["ack_ms_p50_memory"] = p(mem->first.ack_ms, 0.5);
  out["ack_ms_p99_memory"] = m99;
  out["ack_p99_durable_minus_memory_ms"] = d99 - m99;
  out["ack_p99_ratio"] = m99 > 0 ? d99 / m99 : 0.0;
  const auto rate = [](const ServerRun& r) { return r.wall_s > 0 ? double(r.acked) / r.wall_s : 0.0; };
  out["strokes_per_s_sustained"] = rate(dur->second);
  out["strokes_per_s_sustained_memory"] = rate(mem->second);
  // The durable canvas's history: both runs' strokes (paced real strokes, then the fast ones
  // repeating them), each event a row.
  auto ev = event_stats(dir.db(), false);
  if (!ev) return std::move(ev).error();
  const std::uint64_t file = file_bytes(dir.db()) + file_bytes(dir.db() + "-wal");
  out["disk_bytes_per_stroke"] =
      ev->ended_strokes ? double(ev->record_bytes) / double(ev->ended_strokes) : 0.0;
  out["disk_file_bytes_per_stroke"] =
      ev->ended_strokes ? double(file) / double(ev->ended_strokes) : 0.0;
  // The real strokes' canvas as the checkpoints hold it (every checkpoint's allocator and
  // compressed blocks; incremental, so a block rewritten later counts more than once: an upper
  // bound of what one full checkpoint of this canvas weighs).
  if (auto sum = storage::summarize(dir.db()); sum) {
    std::uint64_t bytes = 0;
    for (const auto& c : sum->checkpoints) bytes += c.bytes;
    out["checkpoint_bytes_per_cell_real"] =
        dur->first.live_cells ? double(bytes) / double(dur->first.live_cells) : 0.0;
    out["real_canvas_live_cells"] = dur->first.live_cells;
    out["real_canvas_checkpoints"] = sum->checkpoints.size();
  }
  out["history"] = {{"events", ev->events},
                    {"record_bytes", ev->record_bytes},
                    {"strokes", ev->ended_strokes},
                    {"file_bytes", file}};
  return out;
}

// Figure 3b: a durable canvas painting with checkpoints often vs never.
Result<json> measure_steps(const Options& opt, bool with_checkpoints, std::uint64_t strokes) {
  TempDir dir;
  storage::StoreOptions so;
  so.checkpoint_every_events = with_checkpoints ? 64 : ~std::uint64_t{0} >> 1;
  so.checkpoint_every = with_checkpoints ? std::chrono::milliseconds(200) : std::chrono::hours(24);
  auto cfg = canvas_config();
  cfg.max_cells_per_second_per_artist = 0;
  auto svc = storage::open_durable_canvas(dir.path.string(), cfg, so, false);
  if (!svc) return std::move(svc).error();
  std::mt19937_64 rng(7);
  std::vector<double> ack_ms;
  const auto t0 = Clock::now();
  // One stroke at a time, as one artist paints: between strokes nothing is open, so a
  // checkpoint that falls due is copied out then (not after kCheckpointHold of waiting).
  auto n = paint_strokes(**svc, rng, strokes, 0.05, 1, &ack_ms);
  if (!n) return std::move(n).error();
  const double wall = seconds_since(t0);
  auto q = (*svc)->quiesce();
  if (!q) return std::move(q).error();
  const auto& m = (*svc)->metrics();
  json out = {{"strokes", *n},
              {"live_cells", q->live_cells},
              {"wall_s", wall},
              {"step_ms_max", hist_max_ms(m.step_seconds)},
              {"step_ms_p99", m.step_seconds.quantile_seconds(0.99) * 1e3},
              {"steps", m.step_seconds.count()},
              {"end_to_painted_ms_p99", m.end_to_painted_seconds.quantile_seconds(0.99) * 1e3},
              {"ack_ms_p99", p(ack_ms, 0.99)},
              {"ack_ms_max", p(ack_ms, 1.0)}};
  svc->reset();
  auto s = storage::summarize(dir.db());
  out["checkpoints"] = s ? s->checkpoints.size() : 0;
  note(opt, "durability: %s checkpoints: step max %.2f ms, ack p99 %.1f ms, %zu checkpoints\n",
       with_checkpoints ? "with" : "without", out["step_ms_max"].get<double>(),
       out["ack_ms_p99"].get<double>(), out["checkpoints"].get<std::size_t>());
  return out;
}

// Figure 2b: small synthetic strokes submitted straight to a CanvasService (no network), 64
// unanswered, durable (synchronous=FULL) vs in memory: what group commit sustains when the
// painter is not the bottleneck.
Result<json> measure_small_strokes(const Options& opt, std::uint64_t strokes) {
  json out;
  for (const bool durable : {false, true}) {
    TempDir dir;
    auto cfg = canvas_config();
    cfg.max_cells_per_second_per_artist = 0;
    auto svc = durable ? storage::open_durable_canvas(dir.path.string(), cfg,
                                                      storage::StoreOptions{}, false)
                       : server_core::CanvasService::create(cfg);
    if (!svc) return std::move(svc).error();
    std::mt19937_64 rng(3);
    std::vector<double> ack_ms;
    const auto t0 = Clock::now();
    auto n = paint_strokes(**svc, rng, strokes, 0.01, 64, &ack_ms, 2);
    if (!n) return std::move(n).error();
    const double wall = seconds_since(t0);
    svc->reset();
    const char* k = durable ? "durable" : "memory";
    out[k] = {{"strokes", *n},
              {"strokes_per_s", wall > 0 ? double(*n) / wall : 0.0},
              {"ack_ms_p50", p(ack_ms, 0.5)},
              {"ack_ms_p99", p(ack_ms, 0.99)}};
    note(opt, "durability: small strokes %s: %.0f strokes/s, ack p99 %.1f ms\n", k,
         out[k]["strokes_per_s"].get<double>(), out[k]["ack_ms_p99"].get<double>());
  }
  return out;
}

// Figure 3a on the canvas stored at `db_dir`: every block handed to a fresh store.
Result<json> measure_checkpoint(const std::string& db_dir) {
  auto src = storage::CanvasStore::open(db_dir, kCanvas, canvas_config().octree);
  if (!src) return std::move(src).error();
  auto loaded = (*src)->load();
  if (!loaded) return std::move(loaded).error();
  (*src)->close();
  const server_core::Octree& tree = *loaded->tree;
  TempDir dir;
  auto dst = storage::CanvasStore::open(dir.path.string(), kCanvas, loaded->config);
  if (!dst) return std::move(dst).error();
  if (auto l = (*dst)->load(); !l) return std::move(l).error();
  (*dst)->start();
  const auto t_copy = Clock::now();
  server_core::CheckpointData cp;
  cp.event_seq = 0;
  cp.next_stroke_id = loaded->next_stroke_id;
  cp.block_count = tree.block_count();
  cp.allocator = tree.save_allocator();
  for (server_core::BlockId b = 0; b < cp.block_count; ++b)
    cp.blocks.push_back({b, tree.block_state(b).version + 1, tree.save_block(b)});
  const double copy_ms = seconds_since(t_copy) * 1e3;
  const std::size_t blocks = cp.blocks.size();
  const auto before = (*dst)->checkpoints_written();
  const auto t = Clock::now();
  (*dst)->checkpoint(std::move(cp));
  while ((*dst)->checkpoints_written() == before && (*dst)->checkpoints_failed() == 0 &&
         seconds_since(t) < 120)
    std::this_thread::sleep_for(std::chrono::microseconds(200));
  const double ms = seconds_since(t) * 1e3;
  const bool written = (*dst)->checkpoints_written() > before;
  (*dst)->close();
  return json{{"checkpoint_ms", written ? ms : -1.0},
              {"copy_ms", copy_ms},
              {"copy_ms_per_64_blocks", blocks ? copy_ms * 64.0 / double(blocks) : 0.0},
              {"blocks", blocks},
              {"written", written},
              {"file_bytes", file_bytes(dir.db()) + file_bytes(dir.db() + "-wal")}};
}

// Figures 4, 5 and 3a for one canvas size.
Result<json> measure_restart(const Options& opt, std::uint64_t cells) {
  TempDir dir;
  storage::StoreOptions so;
  so.sync = false;
  so.checkpoint_every_events = ~std::uint64_t{0} >> 1;
  so.checkpoint_every = std::chrono::hours(24);
  auto cfg = canvas_config();
  cfg.max_cells_per_second_per_artist = 0;
  cfg.stroke_limits.max_stroke_cells = 1u << 24;
  auto svc = storage::open_durable_canvas(dir.path.string(), cfg, so, false);
  if (!svc) return std::move(svc).error();
  std::mt19937_64 rng(cells);
  const auto tg = Clock::now();
  auto strokes = grow_canvas(**svc, rng, cells, 0.25, 600);
  if (!strokes) return std::move(strokes).error();
  const double grow_s = seconds_since(tg);
  auto q = (*svc)->quiesce();
  if (!q) return std::move(q).error();
  const auto ts = Clock::now();
  svc->reset();  // a clean stop: the final checkpoint
  const double stop_s = seconds_since(ts);
  const std::uint64_t disk = file_bytes(dir.db()) + file_bytes(dir.db() + "-wal");
  storage::RestoreReport rep;
  const auto tr = Clock::now();
  auto again = storage::open_durable_canvas(dir.path.string(), cfg, storage::StoreOptions{}, false,
                                            &rep);
  const double restart_s = seconds_since(tr);
  if (!again) return std::move(again).error();
  auto q2 = (*again)->quiesce();
  if (!q2) return std::move(q2).error();
  again->reset();
  json out = {{"target_cells", cells},
              {"live_cells", q->live_cells},
              {"strokes", *strokes},
              {"grow_s", grow_s},
              {"stop_s", stop_s},
              {"restart_s", restart_s},
              {"restore_report_s", rep.seconds},
              {"events_replayed", rep.events_replayed},
              {"restored_same_canvas", q2->canvas_hash == q->canvas_hash},
              {"disk_bytes", disk},
              {"disk_bytes_per_cell", q->live_cells ? double(disk) / double(q->live_cells) : 0.0}};
  auto cp = measure_checkpoint(dir.path.string());
  if (!cp) return make_error(cp.error().code, "checkpoint: " + cp.error().message);
  out["checkpoint"] = *cp;
  note(opt, "durability: %llu cells: grown in %.1f s, stop %.2f s, restart %.2f s, %.1f B/cell, "
       "checkpoint %.0f ms\n", static_cast<unsigned long long>(q->live_cells), grow_s, stop_s,
       restart_s, out["disk_bytes_per_cell"].get<double>(), (*cp)["checkpoint_ms"].get<double>());
  return out;
}

// A number after "KEY=" in the server's canvas_restored log line (-1 when absent).
double restored_field(const std::string& log, const std::string& key) {
  const auto line = log.find("event=canvas_restored");
  if (line == std::string::npos) return -1;
  const auto end = log.find('\n', line);
  const auto at = log.find(" " + key + "=", line);
  if (at == std::string::npos || (end != std::string::npos && at > end)) return -1;
  return std::atof(log.c_str() + at + key.size() + 2);
}

// Figure 6: kill -9 rounds on the real server binary.
Result<json> measure_crashes(const Options& opt, const std::vector<PaintingSlice>& slices,
                             int rounds) {
  auto bin = ChildServer::find_binary();
  if (!bin) return std::move(bin).error();
  TempDir dir;
  const std::vector<std::string> args = {"--data", dir.path.string(), "--canvas", kCanvas,
                                         "--max-strokes-per-second", "0", "--log-level", "info"};
  std::mt19937_64 rng(std::random_device{}());
  std::vector<std::uint64_t> acked;  // every acked stroke id so far
  std::uint64_t lost = 0, sent = 0, ended = 0;
  std::vector<double> restart_s, kill_at_s, replayed, replay_s;
  const auto check = [&]() -> Result<void> {
    auto ev = event_stats(dir.db(), true);
    if (!ev) return std::move(ev).error();
    lost = 0;
    ended = ev->ended_ids.size();
    for (auto id : acked) lost += ev->ended_ids.count(id) ? 0 : 1;
    return {};
  };
  for (int round = 0; round <= rounds; ++round) {
    const auto t = Clock::now();
    auto server = ChildServer::start(*bin, args, std::chrono::seconds(60));
    if (!server) return std::move(server).error();
    if (round > 0) {
      restart_s.push_back(seconds_since(t));
      replayed.push_back(restored_field((*server)->log(), "events_replayed"));
      replay_s.push_back(restored_field((*server)->log(), "seconds"));
    }
    if (auto c = check(); !c) return std::move(c).error();
    if (round == rounds) {
      server->get()->terminate(std::chrono::seconds(30));
      break;
    }
    std::vector<std::unique_ptr<DurablePainter>> ps;
    for (const auto& s : slices) {
      DurablePainter::Spec spec;
      spec.port = (*server)->port();
      spec.canvas = kCanvas;
      spec.slice = &s;
      spec.paced = false;
      auto c = DurablePainter::connect(spec);
      if (!c) return make_error(c.error().code, "painter: " + c.error().message);
      ps.push_back(std::move(*c));
    }
    const auto t0 = Clock::now();
    for (auto& x : ps) x->start(t0);
    const double at = std::uniform_real_distribution<double>(0.3, 1.5)(rng);
    std::this_thread::sleep_until(t0 + std::chrono::microseconds(static_cast<int>(at * 1e6)));
    (*server)->kill9();
    kill_at_s.push_back(at);
    std::size_t round_acked = 0;
    for (auto& x : ps) {
      x->join();
      const auto& r = x->result();
      acked.insert(acked.end(), r.acked_ids.begin(), r.acked_ids.end());
      round_acked += r.acked_ids.size();
      sent += r.sent;
    }
    note(opt, "durability: crash round %d: killed at %.2f s, %zu strokes acked\n", round + 1, at,
         round_acked);
  }
  return json{{"rounds", rounds},
              {"acked_strokes", acked.size()},
              {"strokes_sent", sent},
              {"acked_strokes_lost", lost},
              {"history_strokes_ended", ended},  // at the last check: acked + cut off by kills
              {"kill_at_s", kill_at_s},
              {"restart_s_p50", p(restart_s, 0.5)},
              {"restart_s_max", p(restart_s, 1.0)},
              // What each restart's canvas_restored log line says: events replayed after the
              // newest checkpoint, and the seconds the load + replay took.
              {"events_replayed", replayed},
              {"restore_s", replay_s},
              {"check",
               "after each restart every stroke id named by an ack received so far has an end "
               "event (kind 3) in the events table"}};
}

const char* met(bool ok) {
  return ok ? "met" : "NOT MET";
}

void print_summary(const json& o) {
  const auto d = [&](const char* k) { return o[k].get<double>(); };
  print("durability: ack p50/p99 durable %.1f / %.1f ms, in memory %.1f / %.1f ms: p99 +%.1f ms "
        "(%.2fx; target <= +%.0f ms: %s)\n",
        d("ack_ms_p50"), d("ack_ms_p99"), d("ack_ms_p50_memory"), d("ack_ms_p99_memory"),
        d("ack_p99_durable_minus_memory_ms"), d("ack_p99_ratio"), kAckDeltaTargetMs,
        met(o["met"]["ack"].get<bool>()));
  print("durability: sustained %.0f strokes/s durable, %.0f in memory (fast pace, 2 painters)\n",
        d("strokes_per_s_sustained"), d("strokes_per_s_sustained_memory"));
  print("durability: small synthetic strokes straight to the canvas: %.0f strokes/s durable, "
        "%.0f in memory\n",
        d("strokes_per_s_small_durable"), d("strokes_per_s_small_memory"));
  print("durability: step max %.2f ms with checkpoints every 64 events, %.2f ms without; ack p99 "
        "%.1f vs %.1f ms\n",
        d("step_ms_max_with_checkpoints"), d("step_ms_max_without"),
        o["steps"]["with_checkpoints"]["ack_ms_p99"].get<double>(),
        o["steps"]["without"]["ack_ms_p99"].get<double>());
  for (const auto& item : o["restart"].items()) {
    const std::string& k = item.key();
    const json& r = item.value();
    print("durability: %s cells (%llu live): restart %.2f s, stop %.2f s, %.1f B/cell on disk, "
          "full checkpoint %.0f ms (copy-out %.0f ms)\n",
          k.c_str(), r["live_cells"].get<unsigned long long>(), r["restart_s"].get<double>(),
          r["stop_s"].get<double>(), r["disk_bytes_per_cell"].get<double>(),
          r["checkpoint"]["checkpoint_ms"].get<double>(), r["checkpoint"]["copy_ms"].get<double>());
  }
  print("durability: restart 16M target <= %.0f s: %s\n", kRestart16mTargetS,
        met(o["met"]["restart_16m"].get<bool>()));
  print("durability: %.0f bytes of history per stroke (%.0f file bytes)\n",
        d("disk_bytes_per_stroke"), d("disk_file_bytes_per_stroke"));
  print("durability: %d kill -9 rounds: %llu acked strokes, %llu lost (%s)\n",
        o["rounds"].get<int>(), o["crash"]["acked_strokes"].get<unsigned long long>(),
        o["acked_strokes_lost"].get<unsigned long long>(), met(o["met"]["no_loss"].get<bool>()));
  print("durability: restart after kill -9 (process start -> listening) p50 %.2f s, max %.2f s; "
        "events replayed %s\n",
        o["crash"]["restart_s_p50"].get<double>(), o["crash"]["restart_s_max"].get<double>(),
        o["crash"]["events_replayed"].dump().c_str());
}

// The parts, each adding its figures to `out`.
Result<void> run_parts(const Options& opt, const DurOptions& dopt,
                       const std::vector<PaintingSlice>& slices, int rounds, json& out) {
  const auto part = [&](const char* name) { return dopt.only.empty() || dopt.only == name; };
  if (part("acks")) {
    auto acks = measure_acks(opt, slices, opt.quick ? 3.0 : 15.0);
    if (!acks) return std::move(acks).error();
    out.update(*acks);
  }
  if (part("throughput")) {
    auto small = measure_small_strokes(opt, opt.quick ? 2000 : 20000);
    if (!small) return make_error(small.error().code, "small strokes: " + small.error().message);
    out["small_strokes"] = *small;
    out["strokes_per_s_small_durable"] = (*small)["durable"]["strokes_per_s"];
    out["strokes_per_s_small_memory"] = (*small)["memory"]["strokes_per_s"];
  }
  if (part("steps")) {
    const std::uint64_t step_strokes = opt.quick ? 300 : 2000;
    auto with = measure_steps(opt, true, step_strokes);
    if (!with) return make_error(with.error().code, "steps: " + with.error().message);
    auto without = measure_steps(opt, false, step_strokes);
    if (!without) return make_error(without.error().code, "steps: " + without.error().message);
    out["steps"] = {{"with_checkpoints", *with}, {"without", *without}};
    out["step_ms_max_with_checkpoints"] = (*with)["step_ms_max"];
    out["step_ms_max_without"] = (*without)["step_ms_max"];
  }
  if (part("restart")) {
    std::vector<std::pair<std::string, std::uint64_t>> sizes = {{"1m", 1u << 20},
                                                                {"16m", 1u << 24}};
    if (!opt.quick) sizes.emplace_back("64m", 1u << 26);
    if (dopt.restart_cells > 0)
      sizes.emplace_back(std::to_string((dopt.restart_cells + 500000) / 1000000) + "m",
                         dopt.restart_cells);
    for (const auto& [name, cells] : sizes) {
      auto r = measure_restart(opt, cells);
      if (!r) return make_error(r.error().code, "restart " + name + ": " + r.error().message);
      out["restart"][name] = *r;
      out["restart_s_" + name] = (*r)["restart_s"];
      out["checkpoint_ms_" + name] = (*r)["checkpoint"]["checkpoint_ms"];
      out["disk_bytes_per_cell_" + name] = (*r)["disk_bytes_per_cell"];
    }
    out["disk_bytes_per_cell"] = out["disk_bytes_per_cell_16m"];
    out["checkpoint_ms"] = out["checkpoint_ms_16m"];
  }
  if (part("crash")) {
    auto crash = measure_crashes(opt, slices, rounds);
    if (!crash) return make_error(crash.error().code, "crash rounds: " + crash.error().message);
    out["crash"] = *crash;
    out["rounds"] = rounds;
    out["acked_strokes_lost"] = (*crash)["acked_strokes_lost"];
  }
  return {};
}

int durability_main(const Options& opt, const DurOptions& dopt) {
  base::set_log_level(base::LogLevel::error);
  const double seconds = dopt.seconds > 0 ? dopt.seconds : (opt.quick ? 8.0 : 30.0);
  const int rounds = dopt.rounds > 0 ? dopt.rounds : (opt.quick ? 3 : 20);
  auto slices = load_slices(seconds);
  if (!slices) return fail(opt, slices.error().message);
  json out = {{"suite", "durability"},
              {"quick", opt.quick},
              {"seconds", seconds},
              {"paintings_list", (*slices)[0].painting + ", " + (*slices)[1].painting}};
  if (auto r = run_parts(opt, dopt, *slices, rounds, out); !r) return fail(opt, r.error().message);
  if (!dopt.only.empty()) {  // one part: its figures as JSON, whatever --json says
    print("%s\n", out.dump().c_str());
    return 0;
  }
  out["targets"] = {{"ack_p99_durable_minus_memory_ms_max", kAckDeltaTargetMs},
                    {"restart_s_16m_max", kRestart16mTargetS},
                    {"acked_strokes_lost_max", 0}};
  out["met"] = {
      {"ack", out["ack_p99_durable_minus_memory_ms"].get<double>() <= kAckDeltaTargetMs},
      {"restart_16m", out["restart_s_16m"].get<double>() <= kRestart16mTargetS},
      {"no_loss", out["acked_strokes_lost"].get<std::uint64_t>() == 0}};
  if (opt.json)
    print("%s\n", out.dump().c_str());
  else
    print_summary(out);
  return 0;
}

SuiteRun setup(CLI::App& app) {
  auto d = std::make_shared<DurOptions>();
  app.add_option("--seconds", d->seconds,
                 "recorded seconds of each painting streamed per ack run (default 30; 8 with "
                 "--quick)")
      ->type_name("S")
      ->transform(number(0.5, 3600));
  app.add_option("--rounds", d->rounds, "kill -9 rounds (default 20; 3 with --quick)")
      ->type_name("N")
      ->transform(number(1, 10000, true));
  app.add_option("--only", d->only,
                 "run one part and print its figures as JSON: acks, throughput, steps, restart or "
                 "crash")
      ->type_name("PART")
      ->check(CLI::IsMember({"acks", "throughput", "steps", "restart", "crash"}));
  app.add_option("--restart-cells", d->restart_cells,
                 "also grow a durable canvas of N live cells, checkpoint it, stop and restart it "
                 "(the restart part; e.g. 128000000, the large-canvas size: 8 GB of memory, 5 minutes)")
      ->type_name("N")
      ->transform(number(1, 268435456, true));
  return [d](const Options& opt) { return durability_main(opt, *d); };
}

DEEPCANVAS_BENCH_SUITE(Suite{
    "durability",
    "durable canvases: ack latency vs in memory, checkpoints, restart, disk, kill -9 rounds",
    "examples:\n"
    "  deepcanvas-bench durability --quick\n"
    "  deepcanvas-bench durability --rounds 50 --json > durability.json\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder), DEEPCANVAS_SERVER (the\n"
    "deepcanvas-server binary; default: build/server/deepcanvas-server next to this one)\n",
    setup});

}  // namespace
}  // namespace deepcanvas::bench
