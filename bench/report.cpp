// deepcanvas-bench report: every suite's quick mode, one after the other, and one table of the
// headline figures written to docs/performance.md (or --out).
//
// Each suite runs as its own process (this binary, `SUITE --quick --json --quiet`), so a suite
// starts on a fresh heap and Vulkan instance and a crash fails that suite's rows only; the
// suites run one at a time because every one of them needs the CPUs. The figures are read from
// the suites' JSON by JSON pointer (kFigures below); targets come from the suite's own JSON where
// it states them, so a target is written down once.
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <sys/stat.h>

#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench.hpp"

extern char** environ;

namespace deepcanvas::bench {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// One row of the table: a value in a suite's --quick --json output.
struct Figure {
  const char* suite;
  const char* figure;   // what it is, for a reader of the table
  const char* pointer;  // JSON pointer into the suite's output
  double scale;         // value shown = JSON value * scale
  int decimals;
  const char* unit;
  const char* target;  // JSON pointer to the suite's own target ("" for none)
  bool at_most;        // the target is a maximum (else a minimum)
  const char* anchor;  // what the figure is compared with
};

// The headline figures, by suite in the order the suites run.
const Figure kFigures[] = {
    {"machine", "machine: a thread stopped over 5 ms, every vCPU busy",
     "/every_hardware_thread/gaps_over_5_ms_per_thread_second", 1, 1, "gaps/s", "", true,
     "one thread busy: next row; the latency tails below include stalls like these"},
    {"machine", "machine: a thread stopped over 5 ms, one thread busy",
     "/one_thread/gaps_over_5_ms_per_thread_second", 1, 1, "gaps/s", "", true,
     "threads that only read the clock; above 0 when other work wants the CPUs"},
    {"octree", "octree pool bytes per cell (G3 links included)", "/bytes_per_cell", 1, 3, "B",
     "/targets/bytes_per_cell_max", true, "paper: ~16 B a cell on the GPU, plus 12 B of G3"},
    {"octree", "octree bytes allocated per live cell (random strokes, 2M cells)",
     "/allocated_bytes_per_live_cell", 1, 2, "B", "/targets/allocated_bytes_per_live_cell_max",
     true, "pool bytes per cell (row above): the rest is free groups and block bookkeeping"},
    {"octree", "octree refine in stroke bursts (2:1 balance included)", "/refine_cells_per_s", 1e-6,
     1, "M cells/s", "/targets/refine_cells_per_s_min", false,
     "paper: 10^4-10^5 cells created or deleted per stroke"},
    {"octree", "octree refine time per cell, 16M-cell vs 1M-cell tree", "/size_growth_ratio", 1, 3,
     "x", "/targets/size_growth_ratio_max", true, "the same strokes on the 1M-cell tree"},
    {"octree", "octree face neighbour through G3", "/g3_ns", 1, 1, "ns", "", true,
     "locating the cell from the root at depth 24: next row"},
    {"octree", "octree locate a point at depth 24", "/locate_ns", 1, 1, "ns", "", true,
     "descent from the root, 24 levels"},
    {"painter", "painter CPU, demo.apa streamed sample by sample", "/cpu_ms", 1, 0, "ms", "", true,
     "exact shortcuts off, same run: next row"},
    {"painter", "painter speedup from the exact shortcuts", "/shortcut_speedup", 1, 2, "x", "",
     false, "PainterConfig::exact_shortcuts = false, same run (identical pools, checked)"},
    {"painter", "painter heaviest stroke of demo.apa", "/paintings/0/heaviest_stroke_ms", 1, 0,
     "ms", "", true, "the stroke that sets the e2e tail"},
    {"paint", "paint memory, ours / OpenVDB (4 paintings)", "/openvdb_memory_ratio", 1, 3, "x",
     "/memory_target", true,
     "OpenVDB UInt32 grid of RGBA8 voxels at the finest cell, same strokes, pruned"},
    {"paint", "paint time, ours / OpenVDB (4 paintings)", "/openvdb_time_ratio", 1, 3, "x",
     "/time_target", true, "the same OpenVDB grid and strokes, one thread each"},
    {"paint", "paint memory, ours / OpenVDB Vec4f grid", "/openvdb_vec4f_memory_ratio", 1, 3, "x",
     "", true, "OpenVDB Vec4f (float RGBA) grid, what OpenVDB users reach for first"},
    {"protocol", "block frame compression, synthetic octree (zstd 3 + delta transform)",
     "/compression_ratio", 1, 2, "x", "", false,
     "raw payload of 4096-cell blocks; brief: zstd 12x at level 1-3, 16-17x with the index "
     "pools delta-encoded"},
    {"protocol", "block frame compression speed (one thread)", "/compress_mb_per_s", 1, 0, "MB/s",
     "", false, "brief: zstd ~1 GB/s at level 1-3 on octree blocks"},
    {"protocol", "CRC-32 of block frames (ISA-L, one thread)", "/crc32_gb_per_s", 1, 2, "GB/s", "",
     false, "zlib's crc32 on the same bytes: next row"},
    {"protocol", "CRC-32, ISA-L vs zlib", "/crc32_vs_zlib", 1, 1, "x", "", false,
     "zlib 1.2 crc32, same bytes, same run"},
    {"server", "server stroke read -> first block frame written, p99 (1 client)",
     "/server_stroke_to_first_block_ms_p99", 1, 2, "ms",
     "/targets/stroke_to_first_block_ms_p99_max", true,
     "paper: stroke to display under 20 ms on average (the whole path)"},
    {"server", "stroke -> first block frame at the painter, p99 (both loopback hops)",
     "/stroke_to_first_block_ms_p99", 1, 2, "ms", "", true, "the server's own p99: row above"},
    {"server", "wire compression with delta frames (1 client)", "/compression_ratio", 1, 1, "x",
     "/targets/compression_ratio_min", false, "raw block payload bytes / block frame bytes"},
    {"server", "wire compression, full frames only", "/full_frame_ratio", 1, 1, "x", "", false,
     "raw block payload bytes / block frame bytes"},
    {"server", "late joiner: connect -> snapshot applied (largest painting, 60 strokes)",
     "/late_join_snapshot_ms", 1, 0, "ms", "", true,
     "brief: a headset sees the whole canvas within a second of joining"},
    {"load", "load: stroke_end -> ack p99, each painter alone at recorded pace", "/ack_ms_p99_alone",
     1, 1, "ms", "", true, "8 real paintings, each alone with 32 viewers: the next rows' base"},
    {"load", "load: ack p99 with 8 painters / alone", "/ack_p99_ratio_with_8", 1, 2, "x",
     "/targets/ack_p99_ratio_max", true, "the same strokes and 32 viewers, each painter alone"},
    {"load", "load: ack p99 with the hostile mix / alone", "/ack_p99_ratio_hostile", 1, 2, "x",
     "/targets/ack_p99_ratio_max", true,
     "8 painters plus a held stroke, a 10 km stroke, 1,000 connections without hello, 4 stalled "
     "readers"},
    {"load", "load: server stroke_end received -> painted, p99 (8 painters)",
     "/phases/with_8/server_end_to_painted_ms_p99", 1, 1, "ms", "", true,
     "the server's own histogram, free of the clients' share of the CPUs (viewers in SCHED_IDLE, "
     "the hostile mix at nice 10)"},
    {"load", "load: stroke_end -> a viewer's replica at its epoch, p99 (8 painters)",
     "/viewer_epoch_ms_p99", 1, 1, "ms", "", true, "32 viewers keeping CPU replicas"},
    {"load", "load: server peak resident memory (the paced phases)", "/server_rss_peak_bytes", 1e-6,
     0, "MB", "/targets/server_rss_peak_bytes_max", true,
     "bound for a 4M-cell canvas: canvas_memory_bound_bytes + 64 MiB for the process"},
    {"load", "load: server peak resident memory, the canvas painted to capacity at full speed",
     "/capacity_rss_peak_bytes", 1e-6, 0, "MB", "/targets/capacity_rss_peak_bytes_max", true,
     "8 whole paintings, unpaced, until strokes are stopped at a capacity of 4M cells (quick: "
     "1M; cells reached: /capacity_live_cells in the suite's JSON); bound as above for it"},
    {"load", "load: viewer replicas differing from the server at the end",
     "/replicas_differing", 1, 0, "viewers", "/targets/replicas_differing_max", true,
     "pool hash of every viewer vs the quiesced server's, every phase"},
    {"durability", "durable canvas: stroke_end -> ack p99, 2 painters at recorded pace",
     "/ack_ms_p99", 1, 1, "ms", "", true,
     "synchronous=FULL SQLite per canvas; the same painters in memory: next row"},
    {"durability", "durable canvas: ack p99 above the same painters in memory",
     "/ack_p99_durable_minus_memory_ms", 1, 1, "ms",
     "/targets/ack_p99_durable_minus_memory_ms_max", true,
     "same paintings and pacing on a canvas in memory, same run"},
    {"durability", "durable canvas: strokes acked per second, 2 painters at full speed",
     "/strokes_per_s_sustained", 1, 0, "strokes/s", "", false,
     "the same painters in memory: /strokes_per_s_sustained_memory in the suite's JSON"},
    {"durability", "durable canvas: full checkpoint of a 16M-cell canvas (zstd 1 + commit)",
     "/checkpoint_ms_16m", 1, 0, "ms", "", true,
     "written by the store's own thread; the stroke thread copies 64 blocks per step boundary"},
    {"durability", "durable canvas: longest painter step, checkpoint every 64 events",
     "/step_ms_max_with_checkpoints", 1, 1, "ms", "", true,
     "the same strokes without checkpoints: /step_ms_max_without (histogram bucket bound)"},
    {"durability", "durable canvas: restart of a 16M-cell canvas (load checkpoint + replay)",
     "/restart_s_16m", 1, 2, "s", "/targets/restart_s_16m_max", true,
     "1M cells: /restart_s_1m in the suite's JSON"},
    {"durability", "durable canvas: disk bytes per live cell (db + WAL, 16M cells)",
     "/disk_bytes_per_cell", 1, 2, "B", "", true,
     "octree pool bytes per cell in memory: the octree rows"},
    {"durability", "durable canvas: history bytes per stroke (real strokes)",
     "/disk_bytes_per_stroke", 1, 0, "B", "", true, "events table records / strokes ended"},
    {"durability", "durable canvas: acked strokes lost over kill -9 rounds",
     "/acked_strokes_lost", 1, 0, "strokes", "/targets/acked_strokes_lost_max", true,
     "the real deepcanvas-server killed mid-painting and restarted, 3 rounds"},
    {"render", "ray casting 640x360, demo.apa framed", "/mrays_per_s_640x360", 1, 2, "Mrays/s", "",
     false, "brief: a parent-pointer caster on lavapipe, 640x360 in ~50 ms (4.6)"},
    {"render", "ray casting 1280x720, demo.apa", "/mrays_per_s_1280x720", 1, 2, "Mrays/s", "",
     false, "brief: the same caster, 1280x720 in ~160 ms (5.8)"},
    {"render", "CPU time of a 640x360 frame (lavapipe's threads together)", "/frame_cpu_ms_p50", 1,
     1, "ms", "", true,
     "the Mrays/s rows' wall-clock frames; CPU time does not grow when other work takes the cores"},
    {"render", "G3 stepping vs descent from the root (frame time)", "/g3_vs_descent_speedup", 1, 2,
     "x", "/targets/g3_vs_descent_speedup_min", false,
     "descent from the root at every step: same shader, same frames, interleaved"},
    {"render", "frames while a painting streams in: p99 / median", "/stream_p99_over_p50", 1, 2,
     "x", "/targets/stream_p99_over_p50_max", true,
     "median frame of the finished painting, same run"},
    {"render", "masked vs full G3 update after a stroke (4M cells)", "/mask_vs_full_speedup", 1, 0,
     "x", "", false, "G3 of every group; paper: a full tree copy would take 222 ms"},
    {"e2e", "stroke sent -> resident on the viewer's GPU, p99", "/stroke_to_resident_ms_p99", 1, 1,
     "ms", "/targets/stroke_to_resident_ms_p99_max", true,
     "paper: stroke to display under 20 ms on average"},
    {"e2e", "stroke sent -> resident on the viewer's GPU, p50", "/stroke_to_resident_ms_p50", 1, 1,
     "ms", "", true, "paper: stroke to display under 20 ms on average"},
    {"e2e", "stroke sent -> first frame showing it, p99", "/stroke_to_pixel_ms_p99", 1, 1, "ms", "",
     true, "paper: stroke to display under 20 ms on average"},
    {"e2e", "block frame bytes per stroke to a viewer (demo.apa)", "/bytes_per_stroke", 1e-3, 0,
     "KB", "", true, ""},
    {"undo", "undo: undo received -> its blocks published, p99 (demo.apa, every stroke undone)",
     "/paintings/0/undo_ms_p99", 1, 1, "ms", "", true,
     "the same strokes painted, submit -> ack p99: in the suite's own output"},
    {"undo", "undo: time / the same stroke's paint time, median (worse of demo, mozfest)",
     "/undo_vs_paint_p50_worst", 1, 2, "x", "/undo_vs_paint_target", true,
     "each undo against the paint (submit -> ack) of the stroke it takes back"},
    {"undo", "undo: history bytes per stroke, median (demo.apa)",
     "/paintings/0/history_bytes_per_stroke_p50", 1e-3, 1, "KB", "", true,
     "the encoded change the undo history keeps per stroke"},
    {"undo", "undo: history bytes of the heaviest stroke (demo, mozfest)", "/heaviest_history_bytes",
     1e-6, 2, "MB", "/history_target_bytes", true,
     "the stroke with the largest change; it is undone and redone exactly in place"},
    {"export", "export: demo.apa to OpenVDB at its finest level (0.3 mm), seconds",
     "/paintings/0/vdb/seconds", 1, 2, "s", "", true,
     "OpenVDB's own write of the same grids is export.paintings[0].vdb.openvdb_write_seconds"},
    {"export", "export: demo.apa to binary glTF (1M-triangle budget), seconds",
     "/paintings/0/glb/seconds", 1, 2, "s", "", true, "OpenVDB volume-to-mesh + tinygltf"},
    {"export", "export: demo.apa one 1280x720 PNG frame (upload, links, ray cast, write), seconds",
     "/paintings/0/png/seconds", 1, 2, "s", "", true, "what render and each turntable frame do"},
    {"export", "export: largest painting to OpenVDB at its finest level, seconds",
     "/paintings/1/vdb/seconds", 1, 2, "s", "", true, "the largest .apa file"},
    {"export", "import: demo.apa's 1 cm OpenVDB file back into an empty canvas, seconds",
     "/paintings/0/import/seconds", 1, 2, "s", "", true, "import_cells + paste"},
    {"headset", "headset: stereo frame (both eyes) p99 while demo.apa streams in, 2 x 640x576 at 30 Hz",
     "/paintings/0/frame_ms_p99", 1, 1, "ms", "", true,
     "pose trace: head turns, leaning in, an 8x world scale; dynamic resolution on"},
    {"headset", "headset: missed frames (complete after their 33 ms slot)", "/paintings/0/missed_pct",
     1, 1, "%", "/targets/missed_pct_max", true, "the same frames"},
    {"headset", "headset: render scale p50 (fraction of each eye side)", "/paintings/0/render_scale_p50",
     1, 2, "", "", false, "what lavapipe on this machine holds at 30 Hz"},
    {"headset", "headset: motion to photon p99 (pose latched -> both eyes rendered)",
     "/paintings/0/motion_to_photon_ms_p99", 1, 1, "ms", "", true, "no display scan-out here"},
    {"headset", "headset: stereo frame / mono frame render time at scale 1", "/paintings/0/stereo_over_mono",
     1, 2, "x", "/targets/stereo_over_mono_max", true, "the finished painting, blocks of 10 interleaved"},
    {"large", "large: server memory per cell, the larger canvas (quick: ~8M cells)",
     "/canvases/1/server_bytes_per_cell", 1, 1, "B", "", true,
     "resident memory grown by the canvas (serve --playback of replay --tile-to-cells)"},
    {"large", "large: viewer memory per cell (CPU + GPU replica, lavapipe), the larger canvas",
     "/canvases/1/client_bytes_per_cell", 1, 1, "B", "", true, "the viewer process's growth"},
    {"large", "large: a viewer joins the larger canvas: connect -> all resident", "/canvases/1/join_s",
     1, 2, "s", "", true, "loopback; no progressive join yet"},
    {"large", "large: 640x360 frame, larger / smaller canvas, same camera",
     "/render_largest_over_smallest", 1, 2, "x", "/targets/render_ratio_max", true,
     "the camera frames the smaller canvas's paint; culled by the content box refined for the view"},
    {"large", "large: the same frame culled by one content box around everything painted, larger / smaller",
     "/render_one_box_largest_over_smallest", 1, 2, "x", "", true,
     "rays that miss the paint in view cross the rest of the larger canvas up to that box's far side"},
    {"large", "large: the same frame with the rays limited to the smaller canvas's content box, larger / smaller",
     "/render_same_box_largest_over_smallest", 1, 2, "x", "/targets/render_ratio_max", true,
     "the same picture; past the smaller canvas's paint the rays no longer cross the rest of the canvas"},
    {"large", "large: the larger canvas's frame, without / with stepping over empty subtrees whole",
     "/canvases/1/skip_speedup", 1, 2, "x", "", true,
     "RenderOptions::skip_empty_subtrees off, the same frame in the same run"},
    {"network", "network: a viewer joins a ~2.4M-cell canvas over loopback: connect -> first picture",
     "/links/0/join_s", 1, 2, "s", "", true,
     "first picture = all resident (no progressive join yet); bytes: /links/0/join_bytes"},
    {"network", "network: the same join over 50 Mbit/s, 40 ms round trip, 0.5% loss",
     "/links/1/join_s", 1, 2, "s", "/targets/join_first_picture_s_max", true,
     "scripts/shaped-link.py between network namespaces; the target is the issue's, for 128M cells"},
    {"network", "network: the same join over 10 Mbit/s, 80 ms", "/links/2/join_s", 1, 2, "s", "",
     true, "the same canvas and link script"},
    {"network", "network: stroke sent -> resident on a viewer, p99, 50 Mbit/s, 40 ms, 0.5% loss",
     "/links/1/stroke_to_resident_ms_p99", 1, 0, "ms", "", true,
     "demo.apa's strokes, whole, one at a time; loopback: /links/0/stroke_to_resident_ms_p99"},
    {"network", "network: stroke sent -> resident on a viewer, p99, 10 Mbit/s, 80 ms",
     "/links/2/stroke_to_resident_ms_p99", 1, 0, "ms", "", true, "the same strokes"},
    {"network", "network: a viewer beside the server with a viewer behind 1 Mbit/s joined / without, stroke p99",
     "/slow_client/fast_viewer_p99_ratio", 1, 2, "x", "", true,
     "the slow viewer gets coalesced versions; it caught up /slow_client/slow_catch_up_s after the last ack"},
    {"network", "network: server peak memory with the slow viewer joined", "/slow_client/server_rss_peak_bytes_with_slow",
     1e-6, 0, "MB", "", true, "without it: /slow_client/server_rss_peak_bytes_alone"},
    {"studio", "studio: pointer move -> first frame showing its stamp, p99 (1280x720)",
     "/input_to_photon_ms_p99", 1, 1, "ms", "/targets/input_to_photon_ms_p99_max", true,
     "real X input (xdotool) under Xvfb, a second artist painting; p50: /input_to_photon_ms_p50"},
    {"studio", "studio: frames per second at 1280x720 while two artists paint", "/fps_1280x720",
     1, 1, "fps", "/targets/fps_1280x720_min", false,
     "render scale auto (the view ray cast at a fraction of the window's pixels)"},
    {"studio", "studio: frame interval p99 / p50", "/frame_ms_p99_over_p50", 1, 2, "x", "", true,
     "the same frames"},
    {"studio", "studio: another artist's presence sent -> drawn, p99", "/presence_latency_ms_p99",
     1, 1, "ms", "", true, "the server relays at most one per artist per 50 ms"},
};

// Seconds each suite's --quick took on the 2-core CI VM (`deepcanvas-bench report` prints what
// they take here): the progress display's estimate, nothing else.
double expected_seconds(const std::string& suite) {
  static const std::pair<const char*, double> kSeconds[] = {
      {"machine", 6},  {"octree", 4}, {"painter", 3}, {"paint", 20},
      {"protocol", 4}, {"server", 5}, {"load", 55}, {"durability", 60}, {"render", 25},
      {"e2e", 40}, {"studio", 15}, {"undo", 8}, {"export", 12}, {"headset", 20}, {"large", 30}, {"network", 30}};
  for (const auto& [name, s] : kSeconds)
    if (suite == name) return s;
  return 30;
}

std::string cpu_model() {
  std::ifstream in("/proc/cpuinfo");
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("model name", 0) != 0) continue;
    const auto colon = line.find(':');
    if (colon == std::string::npos) break;
    std::string m = line.substr(colon + 1);
    m.erase(0, m.find_first_not_of(" \t"));
    return m;
  }
  return "unknown CPU";
}

std::string machine() {
  return cpu_model() + ", " + std::to_string(std::max(1u, std::thread::hardware_concurrency())) +
         " cores";
}

std::string today() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%d", &tm);
  return buf;
}

double load_average() {
  double load[3] = {0, 0, 0};
  return getloadavg(load, 3) >= 1 ? load[0] : -1;
}

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string last_line(const std::string& text) {
  std::string t = text;
  while (!t.empty() && (t.back() == '\n' || t.back() == '\r')) t.pop_back();
  const auto nl = t.find_last_of('\n');
  return nl == std::string::npos ? t : t.substr(nl + 1);
}

struct SuiteResult {
  std::string suite;
  nlohmann::json json;  // null when the suite failed
  std::string error;    // why it failed
  double seconds = 0;
  std::string date;
};

// Runs `self SUITE --quick --json --quiet` with stdout and stderr in files under `tmp`;
// `tick(elapsed_s)` is called about five times a second while it runs.
SuiteResult run_child(const std::string& self, const std::string& suite, const fs::path& tmp,
                      const std::function<void(double)>& tick) {
  SuiteResult r;
  r.suite = suite;
  const fs::path out = tmp / (suite + ".json"), err = tmp / (suite + ".err");
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
  posix_spawn_file_actions_addopen(&fa, 2, err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
  std::vector<std::string> args = {self, suite, "--quick", "--json", "--quiet"};
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  const auto t0 = Clock::now();
  pid_t pid = 0;
  const int spawned = posix_spawn(&pid, self.c_str(), &fa, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  if (spawned != 0) {
    r.error = std::string("cannot start: ") + std::strerror(spawned);
    return r;
  }
  // A suite that has not finished in 30 minutes is stuck (the slowest takes about a minute).
  constexpr double kLimitS = 1800;
  int status = 0;
  bool killed = false;
  for (;;) {
    const pid_t w = waitpid(pid, &status, WNOHANG);
    if (w == pid) break;
    if (w < 0 && errno != EINTR) {
      r.error = std::string("waitpid: ") + std::strerror(errno);
      return r;
    }
    const double elapsed = std::chrono::duration<double>(Clock::now() - t0).count();
    if (elapsed > kLimitS && !killed) {
      kill(pid, SIGKILL);
      killed = true;
    }
    tick(elapsed);
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  r.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  r.date = today();
  const std::string stdout_text = read_file(out), stderr_text = read_file(err);
  if (killed) {
    r.error = "stopped after " + std::to_string(static_cast<int>(kLimitS)) + " s";
  } else if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    const std::string why = last_line(stderr_text);
    r.error = (WIFEXITED(status) ? "exit " + std::to_string(WEXITSTATUS(status))
                                 : "killed by signal " + std::to_string(WTERMSIG(status))) +
              (why.empty() ? "" : ": " + why);
  } else {
    try {
      r.json = nlohmann::json::parse(stdout_text);
    } catch (const std::exception& e) {
      r.error = std::string("its JSON does not parse: ") + e.what();
    }
  }
  return r;
}

struct Row {
  std::string figure, value, target, anchor, command, date, machine;
  bool target_met = true;  // false: a target not met, or the suite failed
};

std::string format_number(double v, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

std::vector<Row> rows_of(const SuiteResult& r, const std::string& host) {
  std::vector<Row> rows;
  for (const Figure& f : kFigures) {
    if (r.suite != f.suite) continue;
    Row row;
    row.figure = f.figure;
    row.anchor = *f.anchor ? f.anchor : "-";
    row.command = std::string("`deepcanvas-bench ") + f.suite + " --quick`";
    row.date = r.date;
    row.machine = host;
    if (r.json.is_object() && r.json.contains("device") && r.json["device"].is_string())
      row.machine += ", " + r.json["device"].get<std::string>();
    const auto value = [&](const char* pointer) -> std::optional<double> {
      if (!r.json.is_object() || !*pointer) return std::nullopt;
      const nlohmann::json::json_pointer p(pointer);
      if (!r.json.contains(p) || !r.json.at(p).is_number()) return std::nullopt;
      return r.json.at(p).get<double>();
    };
    if (!r.error.empty()) {
      row.value = "failed (" + r.error + ")";
      row.target_met = false;
    } else if (const auto v = value(f.pointer)) {
      const double shown = *v * f.scale;
      int decimals = f.decimals;
      const auto t = value(f.target);
      if (t) {
        const double target = *t * f.scale;
        row.target_met = f.at_most ? shown <= target : shown >= target;
        // A value that misses its target must not print as the target (2.996 as "3.00").
        while (!row.target_met && decimals < f.decimals + 3 &&
               std::stod(format_number(shown, decimals)) == target)
          ++decimals;
      }
      row.value = format_number(shown, decimals) + " " + f.unit;
      if (t) {
        const double target = *t * f.scale;
        // The target to the precision it was set with, not the value's.
        std::ostringstream ts;
        ts << (f.at_most ? "<= " : ">= ") << target << " " << f.unit
           << (row.target_met ? " (met)" : " (not met)");
        row.target = ts.str();
      }
    } else {
      row.value = std::string("missing (") + f.pointer + " not in its JSON)";
      row.target_met = false;
    }
    if (row.target.empty()) row.target = "-";
    rows.push_back(std::move(row));
  }
  return rows;
}

// A table cell: pipes escaped, one line.
std::string cell(std::string s) {
  std::string out;
  for (char c : s) {
    if (c == '|')
      out += "\\|";
    else if (c == '\n')
      out += ' ';
    else
      out += c;
  }
  return out;
}

std::string markdown_table(const std::vector<Row>& rows) {
  std::string t =
      "| figure | value | target | anchor | command | date | machine |\n"
      "|---|---|---|---|---|---|---|\n";
  for (const Row& r : rows)
    t += "| " + cell(r.figure) + " | " + cell(r.value) + " | " + cell(r.target) + " | " +
         cell(r.anchor) + " | " + cell(r.command) + " | " + cell(r.date) + " | " + cell(r.machine) +
         " |\n";
  return t;
}

std::string document(const std::vector<Row>& rows, const std::vector<SuiteResult>& results,
                     double total_s, double load_start, double load_end, bool subset) {
  std::string suites_line;
  for (const auto& r : results) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%s%s %.0f s", suites_line.empty() ? "" : ", ", r.suite.c_str(),
                  r.seconds);
    suites_line += buf;
  }
  char head[2048];
  std::snprintf(
      head, sizeof head,
      "# Performance\n\n"
      "The current figures, one row each, written by `deepcanvas-bench report`, which runs every\n"
      "benchmark suite's quick mode (`--quick`) one after the other and reads their `--json`\n"
      "output. To refresh this file, build and run from the repository root:\n\n"
      "```sh\n"
      "DEEPCANVAS_PAINTINGS=../shared/data/apainter build/bench/deepcanvas-bench report\n"
      "```\n\n"
      "`--out FILE` writes elsewhere; `--suites a,b` runs only those suites (the file then holds\n"
      "only their rows). The figures are noisy on small shared VMs: each comes from one quick "
      "run,\n"
      "under whatever else the machine was doing, and the anchor of a ratio is measured in the\n"
      "same run. The range over runs is in each suite's own output (`deepcanvas-bench SUITE\n"
      "--help`; without `--quick` a suite runs longer and more often); compare two builds with\n"
      "several runs of each, interleaved. A target marked \"not met\" is a fact about this run,\n"
      "not a test failure.\n\n"
      "This run: %.0f s in all (%s); load average %.1f at the start, %.1f at the end.%s\n\n",
      total_s, suites_line.c_str(), load_start, load_end,
      subset ? " Only some suites were run (`--suites`)." : "");
  return head + markdown_table(rows);
}

struct ReportOptions {
  std::string out = "docs/performance.md";
  std::vector<std::string> suites;  // empty: all
  bool quick = false;               // always quick; the flag is accepted, not needed
  // --also SUITE:FILE:MACHINE: rows of a suite's --quick --json output measured elsewhere
  // (a lent GPU machine), added after that suite's rows with that machine's name.
  std::vector<std::string> also;
};

// The rows of one --also entry; an error for a malformed entry or an unreadable file.
Result<std::vector<Row>> also_rows(const std::string& entry) {
  const auto a = entry.find(':'), b = a == std::string::npos ? a : entry.find(':', a + 1);
  if (b == std::string::npos)
    return Error{Errc::invalid_argument, "--also wants SUITE:FILE:MACHINE, not '" + entry + "'"};
  SuiteResult r;
  r.suite = entry.substr(0, a);
  const std::string file = entry.substr(a + 1, b - a - 1);
  std::ifstream in(file);
  std::stringstream text;
  text << in.rdbuf();
  if (!in) return Error{Errc::io_error, "--also: cannot read " + file};
  std::string json_line;
  for (std::string line; std::getline(text, line);)
    if (!line.empty() && line[0] == '{') json_line = line;
  r.json = nlohmann::json::parse(json_line, nullptr, false);
  if (r.json.is_discarded() || !r.json.is_object())
    return Error{Errc::malformed, "--also: " + file + " holds no JSON object"};
  struct stat st {};
  const std::time_t t = ::stat(file.c_str(), &st) == 0 ? st.st_mtime : std::time(nullptr);
  char date[16];
  std::strftime(date, sizeof date, "%Y-%m-%d", std::gmtime(&t));
  r.date = date;
  return rows_of(r, entry.substr(b + 1));
}

// Why `path` cannot be the report's file (its folder does not exist, ...), or "".
std::string unwritable(const std::string& path) {
  if (path.empty()) return "must name a file";
  const fs::path p(path);
  const fs::path dir = p.parent_path().empty() ? fs::path(".") : p.parent_path();
  if (!fs::is_directory(dir))
    return "folder '" + dir.string() + "' does not exist (run from the repository root, or give " +
           "--out)";
  if (fs::is_directory(p)) return "'" + path + "' is a folder, not a file";
  return {};
}

int report_main(const Options& opt, const ReportOptions& ro) {
  // The default --out is checked here, before any suite runs, as a given one is by CLI11.
  if (const std::string why = unwritable(ro.out); !why.empty()) {
    std::fprintf(stderr, "%s: --out: %s\nRun '%s --help' for the options.\n",
                 opt.app->get_name().c_str(), why.c_str(), opt.app->get_name().c_str());
    return base::cli::kExitUsage;
  }
  // The suites to run, in the order of the table.
  std::vector<std::string> names;
  for (const Figure& f : kFigures)
    if (std::find(names.begin(), names.end(), f.suite) == names.end()) names.push_back(f.suite);
  // Suites this build lacks (render and e2e without the Vulkan client) are skipped.
  std::erase_if(names, [](const std::string& n) {
    return std::none_of(suites().begin(), suites().end(),
                        [&](const Suite& s) { return s.name == n; });
  });
  if (!ro.suites.empty())
    std::erase_if(names, [&](const std::string& n) {
      return std::find(ro.suites.begin(), ro.suites.end(), n) == ro.suites.end();
    });
  if (names.empty()) return fail(opt, "none of the suites asked for is in this build");

  char self_buf[4096];
  const ssize_t len = readlink("/proc/self/exe", self_buf, sizeof self_buf - 1);
  if (len <= 0) return fail(opt, "cannot find this program (/proc/self/exe)");
  const std::string self(self_buf, static_cast<std::size_t>(len));
  char tmp_template[] = "/tmp/deepcanvas-bench-report-XXXXXX";
  const char* tmp_dir = mkdtemp(tmp_template);
  if (!tmp_dir)
    return fail(opt, std::string("cannot make a temporary folder: ") + std::strerror(errno));
  const fs::path tmp(tmp_dir);

  double expected_total = 0;
  for (const auto& n : names) expected_total += expected_seconds(n);
  auto progress = bench::progress(opt, "report", expected_total, "s (estimated)");
  progress.set_line_interval(15);
  const double load_start = load_average();
  const auto t0 = Clock::now();
  const std::string host = machine();
  std::vector<SuiteResult> results;
  std::vector<Row> rows;
  double expected_done = 0;
  for (std::size_t i = 0; i < names.size(); ++i) {
    const std::string& n = names[i];
    const double expected = expected_seconds(n);
    note(opt, "report: suite %zu of %zu: deepcanvas-bench %s --quick\n", i + 1, names.size(),
         n.c_str());
    SuiteResult r = run_child(self, n, tmp, [&](double elapsed) {
      progress.update(expected_done + std::min(elapsed, 0.95 * expected));
    });
    expected_done += expected;
    progress.update(expected_done);
    if (r.error.empty())
      note(opt, "report: %s done in %.1f s\n", n.c_str(), r.seconds);
    else
      note(opt, "report: %s failed after %.1f s: %s\n", n.c_str(), r.seconds, r.error.c_str());
    auto more = rows_of(r, host);
    rows.insert(rows.end(), more.begin(), more.end());
    for (const std::string& entry : ro.also) {
      if (entry.rfind(n + ":", 0) != 0) continue;
      auto extra = also_rows(entry);
      if (!extra) return fail(opt, extra.error().message);
      rows.insert(rows.end(), extra->begin(), extra->end());
    }
    results.push_back(std::move(r));
  }
  progress.finish();
  std::error_code ec;
  fs::remove_all(tmp, ec);
  const double total = std::chrono::duration<double>(Clock::now() - t0).count();

  // Written whole to a temporary file beside the target, then renamed over it.
  const fs::path out(ro.out);
  const fs::path part = out.string() + ".part";
  {
    std::ofstream f(part, std::ios::binary | std::ios::trunc);
    f << document(rows, results, total, load_start, load_average(), !ro.suites.empty());
    f.close();
    if (!f) return fail(opt, "cannot write " + part.string());
  }
  fs::rename(part, out, ec);
  if (ec) return fail(opt, "cannot write " + out.string() + ": " + ec.message());

  if (opt.json) {
    nlohmann::json j = {{"suite", "report"}, {"out", ro.out}, {"seconds", total}};
    j["figures"] = nlohmann::json::array();
    for (const Row& r : rows)
      j["figures"].push_back({{"figure", r.figure},
                              {"value", r.value},
                              {"target", r.target},
                              {"anchor", r.anchor},
                              {"command", r.command},
                              {"date", r.date},
                              {"machine", r.machine}});
    std::printf("%s\n", j.dump().c_str());
  } else {
    std::printf("%s", markdown_table(rows).c_str());
  }
  note(opt, "report: wrote %s (%zu figures) in %.0f s\n", ro.out.c_str(), rows.size(), total);
  std::string failed;
  for (const auto& r : results)
    if (!r.error.empty()) failed += (failed.empty() ? "" : ", ") + r.suite;
  if (!failed.empty()) return fail(opt, "suites failed: " + failed + " (their rows say why)");
  return 0;
}

SuiteRun setup(CLI::App& app) {
  auto ro = std::make_shared<ReportOptions>();
  std::vector<std::string> names;
  for (const Figure& f : kFigures)
    if (std::find(names.begin(), names.end(), f.suite) == names.end()) names.push_back(f.suite);
  app.add_option("--out", ro->out,
                 "the file to write (default docs/performance.md, relative to the current "
                 "folder; its folder must exist)")
      ->check(CLI::Validator([](std::string& v) { return unwritable(v); }, "", "writable path"))
      ->type_name("FILE");
  app.add_flag("--quick", ro->quick, "accepted for symmetry: every suite runs --quick anyway");
  app.add_option("--suites", ro->suites, "run only these suites (default: all)")
      ->delimiter(',')
      ->check(CLI::IsMember(names))
      ->type_name("a,b");
  app.add_option("--also", ro->also,
                 "add the rows of a suite's --quick --json output measured on another machine "
                 "(a lent GPU), after that suite's own rows, with that machine's name")
      ->type_name("SUITE:FILE:MACHINE");
  return [ro](const Options& opt) { return report_main(opt, *ro); };
}

}  // namespace

DEEPCANVAS_BENCH_SUITE(Suite{
    "report",
    "every suite's --quick, one table of the headline figures written to docs/performance.md",
    "examples:\n"
    "  deepcanvas-bench report                          # from the repository root\n"
    "  deepcanvas-bench report --suites octree,server --out /tmp/perf.md\n"
    "  deepcanvas-bench report --also render:gpu-render.json:'NVIDIA H200'\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder), passed on to the suites\n",
    setup, /*takes_quick=*/false});

}  // namespace deepcanvas::bench
