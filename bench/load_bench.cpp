// deepcanvas-bench load: many artists and hostile clients on one canvas. Eight painters replay
// slices of eight real paintings at the recorded pace (load_run.hpp: the strokes begun within
// the first --seconds of each painting, pauses capped at 1 s) while 32 viewers keep replicas;
// the server runs in a child process (server_process.hpp), so its memory is its own, and the
// viewers and the hostile mix in another (load_clients.hpp), so that they share no locks with
// the painters. Phases,
// each on a fresh server with the same 32 viewers' load:
//   alone     each painter by itself (eight runs): the baseline of its ack latency;
//   with_8    the eight together;
//   hostile   the eight together with the hostile mix alongside (load_hostile.hpp: a stroke
//             held open, an attempted 10 km stroke, 1,000 unauthenticated connections, 4
//             stalled readers);
//   capacity  the eight whole paintings at full speed (no pacing) with 4 viewers, into a canvas
//             they fill: the server's memory at its configured capacity (4M cells; 1M with
//             --quick), where later strokes are stopped with limit_exceeded.
//
// Figures:
//   ack_ms_p99_alone / _with_8 / _hostile  stroke_end sent -> its ack read by the painter
//       (client side, loopback), p99 over every acked stroke of the eight painters in the phase
//       (alone: of the eight solo runs together); per_painter holds each painter's own p99s
//   ack_p99_ratio_with_8 / _hostile  those p99s over the alone p99 (target <= 2: a painter's
//       latency does not depend on what the others do)
//   viewer_epoch_ms_p99 (with 8; _alone, _hostile)  stroke_end sent -> a viewer's replica
//       committed the epoch its ack names, p99 over (acked stroke, viewer) pairs
//   server_rss_peak_bytes  the server process's peak resident set (VmHWM), the largest of the
//       paced phases; memory_bound_bytes its bound for the configured capacity (below)
//   capacity_rss_peak_bytes  the same in the capacity phase, against capacity_memory_bound_bytes
//       (its capacity: capacity_max_cells); capacity_live_cells the cells it ended with,
//       capacity_strokes_stopped the strokes refused or stopped there (the canvas full)
//   replicas_identical  at the end of every phase (server quiesced), every viewer's replica
//       pool hash equals the server's; replicas_differing counts those that do not
//   strokes_failed  strokes that got an error or no answer (ack figures are over acked ones)
//   server_end_to_painted_ms_p99 (per phase)  the server's own view: stroke_end received -> all
//       of its paint in the tree (the ack is due), p99 over the phase's strokes (alone: the
//       largest of the solo runs); free of the clients' share of the CPUs
//   server_answer_wait_ms_p99 (per phase)  a stroke's answer given by the canvas -> its
//       session's network thread running it (the time acks wait behind other sessions' work)
//   server_threads (per phase)  each server thread name's time on a CPU (cpu_cores) and
//       runnable but waiting for one (wait_cores) over the phase's wall time: the stroke
//       thread (dc-stroke) near 1 core is the painting's limit, its wait what the shared CPUs add
//   server_cpu_cores / clients_cpu_cores (per phase)  CPU time of the server process and of
//       the clients' two (every client) over the phase's wall time: when they add up to about the
//       machine's cores, the latencies measure the shared CPUs more than the server's fairness
// Targets are printed with met / not met and never asserted. Percentiles over few strokes
// (--quick: a few per painter) are close to the maximum.
#include <sys/resource.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "bench.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/canvas_service.hpp"
#include "load_run.hpp"
#include "server_process.hpp"

namespace deepcanvas::bench {
namespace {

namespace fs = std::filesystem;

constexpr std::size_t kPainters = 8;
constexpr double kMaxGapMs = 1000;
constexpr double kAckRatioTarget = 2.0;
// The canvas capacity the benchmark's server is configured with (otherwise the defaults:
// server_process.cpp), and the memory that allows: the canvas's bound
// (server_core::canvas_memory_bound_bytes: its pools and frames at capacity, the undo budgets)
// plus 64 MiB for the process, its threads and the sessions' buffers.
constexpr std::uint64_t kMaxCells = 1u << 22;
constexpr std::uint64_t kQuickCapacityCells = 1u << 20;  // the capacity phase with --quick
constexpr std::uint64_t kProcessBytes = 64ull << 20;
constexpr std::size_t kCapacityViewers = 4;

std::uint64_t memory_bound_bytes(std::uint64_t max_cells) {
  server_core::CanvasServiceConfig canvas;
  canvas.octree.max_cells = max_cells;
  return server_core::canvas_memory_bound_bytes(canvas) + kProcessBytes;
}

struct LoadOptions {
  double seconds = 0;  // 0: 3 with --quick, else 20
  bool same_priority = false;  // the clients keep the servers' CPU priority
  bool nice_viewers = false;   // the viewers at nice 19 rather than in SCHED_IDLE
  double turn_seconds = -1;    // the server's turn size; negative: its default
};

double p(const std::vector<double>& v, double q) {
  return base::percentile(v, q);
}

std::vector<double> acks_of(const std::vector<StrokeOutcome>& strokes) {
  std::vector<double> out;
  for (const auto& s : strokes)
    if (s.acked) out.push_back(s.ack_ms);
  return out;
}

std::size_t failed_of(const std::vector<StrokeOutcome>& strokes) {
  std::size_t n = 0;
  for (const auto& s : strokes) n += s.sent && !s.acked ? 1 : 0;
  return n;
}

// The first error of a phase's strokes (for the report), or "".
std::string first_error(const PhaseResult& r) {
  for (const auto& strokes : r.painters)
    for (const auto& s : strokes)
      if (!s.error.empty()) return s.error;
  return "";
}

// Eight paintings spread over the range of sizes (smallest to largest), by name when fewer.
Result<std::vector<std::pair<std::string, paintings::ApaPainting>>> load_paintings() {
  auto dir = paintings_dir();
  if (!dir) return std::move(dir).error();
  std::vector<std::pair<std::string, paintings::ApaPainting>> all;
  for (const auto& e : fs::directory_iterator(*dir)) {
    if (e.path().extension() != ".apa") continue;
    auto pt = paintings::read_apa_file(e.path().string(), {});
    if (!pt) return std::move(pt).error();
    all.emplace_back(e.path().stem().string(), std::move(*pt));
  }
  if (all.empty()) return make_error(Errc::not_found, "no .apa files in " + dir->string());
  std::sort(all.begin(), all.end(), [](const auto& a, const auto& b) {
    return a.second.sample_count != b.second.sample_count
               ? a.second.sample_count < b.second.sample_count
               : a.first < b.first;
  });
  std::vector<std::pair<std::string, paintings::ApaPainting>> out;
  for (std::size_t i = 0; i < kPainters; ++i) {
    // With fewer than eight paintings some painters repeat one (each its own copy).
    const std::size_t k = all.size() == 1 ? 0 : i * (all.size() - 1) / (kPainters - 1);
    out.push_back(all[std::min(k, all.size() - 1)]);
  }
  return out;
}

// The phase's figures as JSON.
nlohmann::json phase_json(const PhaseResult& r) {
  std::vector<double> acks;
  std::size_t strokes = 0, failed = 0;
  nlohmann::json per = nlohmann::json::array();
  for (const auto& s : r.painters) {
    const auto a = acks_of(s);
    acks.insert(acks.end(), a.begin(), a.end());
    strokes += s.size();
    failed += failed_of(s);
    per.push_back({{"strokes", s.size()},
                   {"acked", a.size()},
                   {"ack_ms_p50", p(a, 0.5)},
                   {"ack_ms_p99", p(a, 0.99)}});
  }
  // Each server thread's time on a CPU and waiting for one, in cores over the phase.
  nlohmann::json threads = nlohmann::json::object();
  for (const auto& [name, t] : r.server_threads)
    threads[name] = {{"cpu_cores", r.wall_s > 0 ? t.run_s / r.wall_s : 0.0},
                     {"wait_cores", r.wall_s > 0 ? t.wait_s / r.wall_s : 0.0}};
  return {{"strokes", strokes},
          {"strokes_failed", failed},
          {"first_error", first_error(r)},
          {"ack_ms_p50", p(acks, 0.5)},
          {"ack_ms_p99", p(acks, 0.99)},
          {"ack_ms_max", p(acks, 1.0)},
          {"viewer_epoch_ms_p50", p(r.viewer_epoch_ms, 0.5)},
          {"viewer_epoch_ms_p99", p(r.viewer_epoch_ms, 0.99)},
          {"viewers", r.viewers},
          {"viewers_differing", r.viewers_differing},
          {"replica_check_error", r.replica_check_error},
          {"epoch", r.quiet.epoch},
          {"live_cells", r.quiet.live_cells},
          {"server_rss_peak_bytes", r.memory.peak_rss_bytes},
          {"wall_s", r.wall_s},
          // The server's and the clients' CPU over the phase, in cores (this machine's total is
          // machine.cores): near the total, latencies measure the shared CPUs, not the server.
          {"server_end_to_painted_ms_p99", r.quiet.end_to_painted_ms_p99},
          {"server_answer_wait_ms_p99", r.quiet.answer_wait_ms_p99},
          {"server_cpu_cores", r.wall_s > 0 ? r.memory.cpu_seconds / r.wall_s : 0.0},
          {"clients_cpu_cores", r.wall_s > 0 ? r.clients_cpu_s / r.wall_s : 0.0},
          {"server_threads", threads},
          {"painters", per},
          {"hostile", r.hostile}};
}

// The alone runs merged into one PhaseResult (painter i from run i).
PhaseResult merge_alone(std::vector<PhaseResult>& runs) {
  PhaseResult m;
  m.name = "alone";
  for (auto& r : runs) {
    m.painters.push_back(r.painters.at(0));
    m.viewer_epoch_ms.insert(m.viewer_epoch_ms.end(), r.viewer_epoch_ms.begin(),
                             r.viewer_epoch_ms.end());
    m.viewers += r.viewers;
    m.viewers_differing += r.viewers_differing;
    if (m.replica_check_error.empty()) m.replica_check_error = r.replica_check_error;
    m.memory.peak_rss_bytes = std::max(m.memory.peak_rss_bytes, r.memory.peak_rss_bytes);
    const double painted_p99 = std::max(m.quiet.end_to_painted_ms_p99, r.quiet.end_to_painted_ms_p99);
    const double wait_p99 = std::max(m.quiet.answer_wait_ms_p99, r.quiet.answer_wait_ms_p99);
    if (r.quiet.live_cells >= m.quiet.live_cells) m.quiet = r.quiet;  // the largest solo canvas
    m.quiet.end_to_painted_ms_p99 = painted_p99;  // the largest of the solo runs
    m.quiet.answer_wait_ms_p99 = wait_p99;
    m.wall_s += r.wall_s;
    m.clients_cpu_s += r.clients_cpu_s;
    m.memory.cpu_seconds += r.memory.cpu_seconds;
    for (const auto& [name, t] : r.server_threads) {
      m.server_threads[name].run_s += t.run_s;
      m.server_threads[name].wait_s += t.wait_s;
    }
  }
  return m;
}

const char* met(bool ok) {
  return ok ? "met" : "NOT MET";
}

void print_summary(const nlohmann::json& out) {
  const auto d = [&](const char* k) { return out[k].get<double>(); };
  print("load: %zu painters (%s), %zu viewers, %.0f s of each painting at recorded pace\n",
        kPainters, out["paintings_list"].get<std::string>().c_str(),
        out["viewers"].get<std::size_t>(), d("seconds"));
  print("load: ack p99 alone %.1f ms; with 8 painters %.1f ms (%.2fx, target <= %.0fx: %s); "
        "with the hostile mix %.1f ms (%.2fx: %s)\n",
        d("ack_ms_p99_alone"), d("ack_ms_p99_with_8"), d("ack_p99_ratio_with_8"), kAckRatioTarget,
        met(out["met"]["ack_with_8"].get<bool>()), d("ack_ms_p99_hostile"),
        d("ack_p99_ratio_hostile"), met(out["met"]["ack_hostile"].get<bool>()));
  print("load: strokes failed: alone %zu, with 8 %zu, hostile %zu\n",
        out["strokes_failed"]["alone"].get<std::size_t>(),
        out["strokes_failed"]["with_8"].get<std::size_t>(),
        out["strokes_failed"]["hostile"].get<std::size_t>());
  print("load: viewer epoch p99 alone %.1f ms, with 8 %.1f ms, hostile %.1f ms\n",
        d("viewer_epoch_ms_p99_alone"), d("viewer_epoch_ms_p99"), d("viewer_epoch_ms_p99_hostile"));
  print("load: server peak RSS %.0f MB (bound %.0f MB for %llu cells: %s)\n",
        d("server_rss_peak_bytes") / 1e6, d("memory_bound_bytes") / 1e6,
        static_cast<unsigned long long>(kMaxCells), met(out["met"]["memory"].get<bool>()));
  print("load: canvas filled to capacity: %llu live cells of %llu, %zu strokes stopped; server "
        "peak RSS %.0f MB (bound %.0f MB: %s)\n",
        out["capacity_live_cells"].get<unsigned long long>(),
        out["capacity_max_cells"].get<unsigned long long>(),
        out["capacity_strokes_stopped"].get<std::size_t>(), d("capacity_rss_peak_bytes") / 1e6,
        d("capacity_memory_bound_bytes") / 1e6, met(out["met"]["memory_at_capacity"].get<bool>()));
  print("load: replicas identical: %s (%zu differing: %s)\n",
        out["replicas_identical"].get<bool>() ? "yes" : "no",
        out["replicas_differing"].get<std::size_t>(), met(out["met"]["replicas"].get<bool>()));
  const auto& h = out["phases"]["hostile"]["hostile"];
  print("load: hostile: held stroke %s\nload: hostile: huge stroke %s\n"
        "load: hostile: unauthenticated %s\nload: hostile: viewer joining meanwhile %s\n"
        "load: hostile: stalled readers %s\n",
        h["holder"].dump().c_str(), h["huge_stroke"].dump().c_str(),
        h["unauthenticated"].dump().c_str(), h["viewer_joining_during_flood"].dump().c_str(),
        h["stalled_readers"].dump().c_str());
}

// The headline figures, targets and per-painter ratios from the phases' JSON.
void add_figures(const nlohmann::json& phases, const std::vector<PaintingSlice>& slices,
                 std::uint64_t capacity_cells, nlohmann::json& out) {
  for (const char* ph : {"alone", "with_8", "hostile"})
    out[std::string("ack_ms_p99_") + ph] = phases[ph]["ack_ms_p99"];
  const double alone99 = phases["alone"]["ack_ms_p99"].get<double>();
  const auto ratio = [&](const char* ph) {
    return alone99 > 0 ? phases[ph]["ack_ms_p99"].get<double>() / alone99 : 0.0;
  };
  out["ack_p99_ratio_with_8"] = ratio("with_8");
  out["ack_p99_ratio_hostile"] = ratio("hostile");
  out["viewer_epoch_ms_p99"] = phases["with_8"]["viewer_epoch_ms_p99"];
  out["viewer_epoch_ms_p99_alone"] = phases["alone"]["viewer_epoch_ms_p99"];
  out["viewer_epoch_ms_p99_hostile"] = phases["hostile"]["viewer_epoch_ms_p99"];
  std::uint64_t rss = 0;
  std::size_t differing = 0;
  for (const char* ph : {"alone", "with_8", "hostile"}) {
    rss = std::max(rss, phases[ph]["server_rss_peak_bytes"].get<std::uint64_t>());
    differing += phases[ph]["viewers_differing"].get<std::size_t>();
    out["strokes_failed"][ph] = phases[ph]["strokes_failed"];
  }
  const auto& cap = phases["capacity"];
  differing += cap["viewers_differing"].get<std::size_t>();
  out["strokes_failed"]["capacity"] = cap["strokes_failed"];
  const std::uint64_t cap_rss = cap["server_rss_peak_bytes"].get<std::uint64_t>();
  out["server_rss_peak_bytes"] = rss;
  out["memory_bound_bytes"] = memory_bound_bytes(kMaxCells);
  out["max_cells"] = kMaxCells;
  out["capacity_rss_peak_bytes"] = cap_rss;
  out["capacity_memory_bound_bytes"] = memory_bound_bytes(capacity_cells);
  out["capacity_max_cells"] = capacity_cells;
  out["capacity_live_cells"] = cap["live_cells"];
  out["capacity_strokes_stopped"] = cap["strokes_failed"];
  out["replicas_differing"] = differing;
  out["replicas_identical"] = differing == 0;
  out["targets"] = {{"ack_p99_ratio_max", kAckRatioTarget},
                    {"server_rss_peak_bytes_max", memory_bound_bytes(kMaxCells)},
                    {"capacity_rss_peak_bytes_max", memory_bound_bytes(capacity_cells)},
                    {"replicas_differing_max", 0}};
  out["met"] = {{"ack_with_8", out["ack_p99_ratio_with_8"].get<double>() <= kAckRatioTarget},
                {"ack_hostile", out["ack_p99_ratio_hostile"].get<double>() <= kAckRatioTarget},
                {"memory", rss <= memory_bound_bytes(kMaxCells)},
                {"memory_at_capacity", cap_rss <= memory_bound_bytes(capacity_cells)},
                {"replicas", differing == 0}};
  nlohmann::json per = nlohmann::json::array();
  for (std::size_t i = 0; i < kPainters; ++i) {
    const double a = phases["alone"]["painters"][i]["ack_ms_p99"].get<double>();
    const double w = phases["with_8"]["painters"][i]["ack_ms_p99"].get<double>();
    const double h = phases["hostile"]["painters"][i]["ack_ms_p99"].get<double>();
    per.push_back({{"painting", slices[i].painting},
                   {"strokes", slices[i].strokes.size()},
                   {"ack_ms_p99_alone", a},
                   {"ack_ms_p99_with_8", w},
                   {"ack_ms_p99_hostile", h},
                   {"ratio_with_8", a > 0 ? w / a : 0.0},
                   {"ratio_hostile", a > 0 ? h / a : 0.0}});
  }
  out["per_painter"] = per;
}

// Runs the phases; the servers were forked before anything else.
Result<nlohmann::json> run_all(const Options& opt, const LoadOptions& lo,
                               std::vector<std::unique_ptr<ServerProcess>>& servers,
                               std::vector<std::unique_ptr<LoadClientsProcess>>& others) {
  auto pts = load_paintings();
  if (!pts) return std::move(pts).error();
  const double seconds = lo.seconds > 0 ? lo.seconds : (opt.quick ? 3.0 : 20.0);
  std::vector<PaintingSlice> slices;
  std::string names;
  for (const auto& [name, painting] : *pts) {
    slices.push_back(slice_painting(name, painting, seconds, kMaxGapMs));
    names += (names.empty() ? "" : ", ") + name;
  }
  PhaseSpec base;
  base.server.max_cells = kMaxCells;
  base.server.turn_seconds = lo.turn_seconds;
  // The clients (8 painters here; 32 viewers decoding every frame and the hostile mix in a
  // process of their own, load_clients.hpp) stand in for other machines. On a machine of few
  // cores they would otherwise take the server's CPU thread for thread, and the latencies would
  // measure that: the viewers' threads run in the SCHED_IDLE class (a CPU only when no other
  // thread wants it, and a waking server thread takes it from them at once) and the hostile
  // mix's at nice 10; the painters and the servers keep their priority. At nice 10 the 32
  // viewers held the server's stroke thread off the CPU for about 70% of its turns on two
  // cores; at nice 19 (--nice-viewers), in 60 s phases, the server's threads still waited for a
  // CPU about as long as they ran (server_threads), since a waking thread waits out the running
  // one's slice. server_cpu_cores and clients_cpu_cores show the split; the viewers' epoch
  // latency then shows how far behind they fall.
  base.viewer_idle_class = !lo.nice_viewers && !lo.same_priority;
  if (lo.same_priority) base.viewer_nice = base.hostile_nice = 0;
  auto progress = bench::progress(opt, "load", double(kPainters + 3), "phases");
  std::vector<PhaseResult> alone;
  for (std::size_t i = 0; i < kPainters; ++i) {
    PhaseSpec s = base;
    s.name = "alone " + slices[i].painting;
    s.painters = {&slices[i]};
    auto r = run_phase(*servers[i], *others[i], s);
    if (!r) return make_error(r.error().code, s.name + ": " + r.error().message);
    note(opt, "load: %-28s %3zu strokes, ack p99 %8.1f ms\n", s.name.c_str(),
         r->painters[0].size(), p(acks_of(r->painters[0]), 0.99));
    alone.push_back(std::move(*r));
    progress.add(1);
  }
  std::vector<PhaseResult> together;
  for (const bool hostile : {false, true}) {
    PhaseSpec s = base;
    s.name = hostile ? "hostile" : "with_8";
    s.hostile = hostile;
    for (const auto& sl : slices) s.painters.push_back(&sl);
    const std::size_t k = kPainters + (hostile ? 1 : 0);
    auto r = run_phase(*servers[k], *others[k], s);
    if (!r) return make_error(r.error().code, s.name + ": " + r.error().message);
    note(opt, "load: %-28s ack p99 %8.1f ms\n", s.name.c_str(), phase_json(*r)["ack_ms_p99"].get<double>());
    together.push_back(std::move(*r));
    progress.add(1);
  }
  // The whole paintings, every sample due at once: the canvas fills as fast as the server paints.
  std::vector<PaintingSlice> whole;
  for (const auto& [name, painting] : *pts)
    whole.push_back(slice_painting(name, painting, 1e12, 0.0));
  PhaseSpec fill = base;
  fill.name = "capacity";
  fill.viewers = kCapacityViewers;
  fill.server.max_cells = opt.quick ? kQuickCapacityCells : kMaxCells;
  for (const auto& sl : whole) fill.painters.push_back(&sl);
  auto filled = run_phase(*servers[kPainters + 2], *others[kPainters + 2], fill);
  if (!filled) return make_error(filled.error().code, "capacity: " + filled.error().message);
  note(opt, "load: %-28s %llu live cells, server peak RSS %.0f MB\n", "capacity",
       static_cast<unsigned long long>(filled->quiet.live_cells),
       double(filled->memory.peak_rss_bytes) / 1e6);
  progress.add(1);
  progress.finish();
  const PhaseResult merged = merge_alone(alone);
  nlohmann::json phases = {{"alone", phase_json(merged)},
                           {"with_8", phase_json(together[0])},
                           {"hostile", phase_json(together[1])},
                           {"capacity", phase_json(*filled)}};
  nlohmann::json out = {{"suite", "load"}, {"quick", opt.quick}, {"seconds", seconds},
                        {"paintings_list", names}, {"viewers", base.viewers}};
  add_figures(phases, slices, fill.server.max_cells, out);
  out["phases"] = phases;
  return out;
}

int load_main(const Options& opt, const LoadOptions& lo) {
  base::set_log_level(base::LogLevel::warn);
  if (auto dir = paintings_dir(); !dir) return fail(opt, dir.error().message);
  // The servers' and the other clients' processes first, while this process is one thread and
  // small (see server_process.hpp): one of each per phase.
  std::vector<std::unique_ptr<ServerProcess>> servers;
  std::vector<std::unique_ptr<LoadClientsProcess>> others;
  for (std::size_t i = 0; i < kPainters + 3; ++i) {
    auto s = ServerProcess::fork_idle();
    if (!s) return fail(opt, s.error().message);
    servers.push_back(std::move(*s));
    auto c = LoadClientsProcess::fork_idle();
    if (!c) return fail(opt, c.error().message);
    others.push_back(std::move(*c));
  }
  auto out = run_all(opt, lo, servers, others);
  if (!out) return fail(opt, out.error().message);
  if (opt.json)
    print("%s\n", out->dump().c_str());
  else
    print_summary(*out);
  return 0;
}

SuiteRun setup(CLI::App& app) {
  auto lo = std::make_shared<LoadOptions>();
  app.add_option("--seconds", lo->seconds,
                 "recorded seconds of each painting replayed per phase (default 20; 3 with "
                 "--quick)")
      ->type_name("S")
      ->transform(number(0.5, 3600));
  app.add_flag("--same-priority", lo->same_priority,
               "run every client at the servers' CPU priority (by default the viewers run in the "
               "SCHED_IDLE class and the hostile mix at nice 10, standing in for other machines)");
  app.add_flag("--nice-viewers", lo->nice_viewers,
               "run the viewers at nice 19 instead of in the SCHED_IDLE class");
  app.add_option(
         "--turn-seconds", lo->turn_seconds,
         "the servers' painting per turn while other strokes are open, as `serve "
         "--turn-seconds` (default: the server's, 0.016; 0: turns of up to 64 samples, unsized)")
      ->type_name("S")
      ->transform(number(0, 10));
  return [lo](const Options& opt) { return load_main(opt, *lo); };
}

DEEPCANVAS_BENCH_SUITE(Suite{
    "load",
    "8 painters at recorded pace + 32 viewers, alone / together / with hostile clients; the "
    "canvas filled to capacity",
    "examples:\n"
    "  deepcanvas-bench load --quick\n"
    "  deepcanvas-bench load --seconds 60 --json > load.json\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder)\n",
    setup});

}  // namespace
}  // namespace deepcanvas::bench
