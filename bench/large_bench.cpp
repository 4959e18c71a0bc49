// deepcanvas-bench large: canvases of millions of cells from the real paintings, served and
// joined, over loopback.
//
//   cells                    the canvas (deepcanvas-server replay --tile-to-cells N --seed 7 of
//                            demo.apa and dancer.apa: each placement one of them at 0.01x..100x)
//   generate_s               that replay alone (offline, one process)
//   server_paint_s           the served canvas painting it (serve --playback, one step of all)
//   server_bytes_per_cell    the server's resident memory grown by the canvas, per cell
//   first_picture_s          a viewer's connect -> the first part of its snapshot resident on
//                            its GPU replica (progressive join: the shallowest blocks, missing
//                            subtrees shown as their filtered parents)
//   join_s                   a viewer's connect -> every block resident on its GPU replica
//   client_bytes_per_cell    the viewer process's resident memory grown by the canvas (CPU
//                            replica, GPU replica: lavapipe's device memory is host memory), per cell
//   quiet_wait_s             waited before the frames until the CPUs were 90 % idle (at most 60 s:
//                            after a large join the viewer's upload thread and the server work on)
//   render_ms                a 640x360 frame, median of 7, the same camera for every size (framing
//                            the smallest canvas's paint), content cull on as the render loops
//                            have it: the content box refined into boxes around the paint the
//                            camera sees (ResidentState::cull_for_view)
//   render_largest_over_1m   the largest canvas's render_ms over the 1M canvas's
//   content_boxes(_ms)       how many boxes that refinement gave, and its time on the CPU (per
//                            frame and view in the render loops, not in render_ms)
//   render_one_box_ms        the same frame culled by the one content box around everything
//                            painted (render_one_box_largest_over_smallest): a ray that misses
//                            the paint in view crosses the rest of the canvas up to its far side
//   render_same_box_ms       the same frame with the rays limited to the smallest canvas's
//                            content box instead of each canvas's own: the picture is the same
//                            (the later placements are out of view or far behind), but past the
//                            smaller canvas's paint the rays no longer cross the rest of the
//                            canvas (render_same_box_largest_over_smallest)
//   render_no_skip_ms        render_ms's frame without stepping over empty subtrees whole
//                            (RenderOptions::skip_empty_subtrees off), in the same run:
//                            skip_speedup = render_no_skip_ms / render_ms
//
// Sizes: --quick 1M and 8M cells; otherwise 1M, 16M and 64M (--cells N,N,... for others: the
// paper's 128M needs about 7.2 GB on the server and 10.6 GB on a lavapipe client).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "bench.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "durability_run.hpp"
#include "join_report.hpp"
#include "tiled_canvas.hpp"

namespace {

namespace bench = deepcanvas::bench;
namespace cc = deepcanvas::client_core;
namespace cg = deepcanvas::client_gpu;
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using deepcanvas::Errc;
using deepcanvas::Result;
using deepcanvas::make_error;

struct LargeArgs {
  std::string cells, device;
};

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

struct Row {
  std::uint64_t target = 0, cells = 0;
  double generate_s = 0, server_paint_s = 0, server_bpc = 0, join_s = 0, client_bpc = 0, render_ms = 0;
  double first_picture_s = 0;
  double render_one_box_ms = 0;
  double content_boxes_ms = 0;  // the render loops' cull_for_view, per frame
  double quiet_wait_s = 0;      // waited for quiet CPUs before the frames
  std::size_t content_boxes = 0;
  double render_same_box_ms = 0;
  double render_no_skip_ms = 0;
};

// Busy share of all CPUs over `window_s` (from /proc/stat); -1 where it cannot be read.
double cpu_busy_share(double window_s) {
  const auto read = [](std::uint64_t& busy, std::uint64_t& total) {
    std::ifstream in("/proc/stat");
    std::string cpu;
    std::uint64_t v[8] = {};
    if (!(in >> cpu >> v[0] >> v[1] >> v[2] >> v[3] >> v[4] >> v[5] >> v[6] >> v[7]) || cpu != "cpu") return false;
    total = v[0] + v[1] + v[2] + v[3] + v[4] + v[5] + v[6] + v[7];
    busy = total - v[3] - v[4];  // less idle and iowait
    return true;
  };
  std::uint64_t b0 = 0, t0 = 0, b1 = 0, t1 = 0;
  if (!read(b0, t0)) return -1;
  std::this_thread::sleep_for(std::chrono::duration<double>(window_s));
  if (!read(b1, t1) || t1 <= t0) return -1;
  return static_cast<double>(b1 - b0) / static_cast<double>(t1 - t0);
}

// Waits (at most max_s) until the CPUs were busy under `share` for half a second; the seconds
// waited.
double wait_for_quiet_cpus(double share, double max_s) {
  const auto t0 = Clock::now();
  while (seconds_since(t0) < max_s) {
    const double busy = cpu_busy_share(0.5);
    if (busy < 0 || busy < share) break;
  }
  return seconds_since(t0);
}

Result<Row> measure(const bench::Options& opt, const cg::Context& ctx, const std::string& server,
                    const fs::path& paintings, std::uint64_t n, std::optional<cc::Camera>& camera,
                    std::optional<cc::DAabb>& first_box) {
  Row row;
  row.target = n;
  const std::string log = (fs::temp_directory_path() / ("deepcanvas_large_" + std::to_string(::getpid()) + "_" +
                                                          std::to_string(n) + ".dcs")).string();
  const auto g0 = Clock::now();
  auto gen = bench::generate_tiled_log(server, paintings, n, log);
  if (!gen) return std::move(gen).error();
  row.generate_s = seconds_since(g0);
  row.cells = (*gen)["cells"].get<std::uint64_t>();
  bench::note(opt, "large: %llu cells generated in %.1f s\n", static_cast<unsigned long long>(row.cells), row.generate_s);
  auto child = bench::durability::ChildServer::start(server, {"--playback", log}, std::chrono::seconds(120));
  fs::remove(log);
  if (!child) return std::move(child).error();
  const std::uint64_t server0 = bench::rss_bytes((*child)->pid());
  const std::string url = "ws://127.0.0.1:" + std::to_string((*child)->port()) + "/default";
  cc::ClientOptions co;
  co.url = url;
  co.canvas = "default";
  co.role = deepcanvas::protocol::Role::viewer;
  co.block_frames = false;
  auto stepper = cc::Client::connect(co);
  if (!stepper) return std::move(stepper).error();
  deepcanvas::protocol::PlaybackStep all;
  all.strokes = deepcanvas::protocol::kMaxJsonInteger;
  const auto p0 = Clock::now();
  auto id = (*stepper)->request_playback_step(all);
  if (!id) return std::move(id).error();
  auto pos = (*stepper)->wait_for_playback(*id, std::chrono::minutes(20));
  if (!pos) return std::move(pos).error();
  row.server_paint_s = seconds_since(p0);
  row.server_bpc = static_cast<double>(bench::rss_bytes((*child)->pid()) - std::min(server0, bench::rss_bytes((*child)->pid()))) /
                   static_cast<double>(row.cells);
  // A viewer joins: connect -> every block resident on the GPU.
  const std::uint64_t client0 = bench::rss_bytes(0);
  const auto j0 = Clock::now();
  co.block_frames = true;
  auto viewer = cc::Client::connect(co);
  if (!viewer) return std::move(viewer).error();
  auto replica = cg::StreamingReplica::create(ctx, cg::replica_config_for((*viewer)->welcome()));
  if (!replica) return std::move(replica).error();
  cg::stream_client_into(**viewer, **replica);
  const bool resident = (*replica)->wait_resident((*viewer)->welcome().epoch, std::chrono::minutes(20));
  row.join_s = seconds_since(j0);
  if (const auto batches = (*replica)->take_resident_log(); !batches.empty()) {
    const auto& b = batches.front();
    row.first_picture_s = std::chrono::duration<double>(b.resident_at - j0).count();
    bench::note(opt, "large: %s\n", bench::first_picture_text(batches, j0).c_str());
  }
  if (!resident) {
    (*viewer)->set_epoch_listener({});
    return make_error(Errc::io_error, "the canvas did not become resident");
  }
  row.client_bpc = static_cast<double>(bench::rss_bytes(0) - std::min(client0, bench::rss_bytes(0))) / static_cast<double>(row.cells);
  // The same camera for every size: the first (smallest) canvas's paint.
  std::vector<double> ms, one_box_ms, same_box_ms, no_skip_ms;
  // The frames are timed on a quiet machine: after a large join the viewer's upload thread (the
  // exact content box, growth) and the server may still work for seconds, and lavapipe's
  // threads would share the cores with them.
  row.quiet_wait_s = wait_for_quiet_cpus(0.10, 60.0);
  auto r = (*replica)->with_gpu([&](const cg::ResidentState& st) -> Result<void> {
    if (!camera) {
      auto b = cc::painted_bounds(st.pools);
      if (!b || !*b) return make_error(Errc::not_found, "nothing painted");
      auto cam = cc::Camera::fit_box(**b, 640, 360, 45.0, {-0.45, -0.35, -0.82}, {0, 1, 0});
      if (!cam) return std::move(cam).error();
      camera = *cam;
      first_box = st.content_bounds;
    }
    auto rc = cg::GpuRaycaster::create(st.replica);
    if (!rc) return std::move(rc).error();
    auto origin = cc::make_ray_origin(st.pools, camera->position());
    if (!origin) return std::move(origin).error();
    // The render loops' per-frame cost of refining the box for the camera (on the CPU, under
    // the GPU lock), apart from the frame's.
    std::vector<double> boxes_ms;
    for (int k = 0; k < 7; ++k) {
      cc::RenderOptions ro;
      const auto t0 = Clock::now();
      st.cull_for_view(ro, *camera);
      boxes_ms.push_back(seconds_since(t0) * 1000);
      row.content_boxes = ro.content_boxes ? ro.content_boxes->count : 0;
    }
    row.content_boxes_ms = bench::median(boxes_ms);
    struct Variant {
      std::optional<cc::DAabb> box;
      bool view_boxes;  // the product's cull: the box refined for the camera (cull_for_view)
      bool skip;
      std::vector<double>* out;
    };
    for (const Variant& var : {Variant{st.content_bounds, true, true, &ms},
                               Variant{st.content_bounds, false, true, &one_box_ms},
                               Variant{first_box, false, true, &same_box_ms},
                               Variant{st.content_bounds, true, false, &no_skip_ms}}) {
      cc::RenderOptions ro;
      ro.content_bounds = var.box;
      if (var.view_boxes) st.cull_for_view(ro, *camera);
      ro.skip_empty_subtrees = var.skip;
      auto* out = var.out;
      if (auto v = (*rc)->set_frame(*camera, *origin, ro); !v) return v;
      for (int f = 0; f < 8; ++f) {
        const auto t0 = Clock::now();
        if (auto v = (*rc)->render(1); !v) return v;
        if (f > 0) out->push_back(seconds_since(t0) * 1000);
      }
    }
    return {};
  });
  (*viewer)->set_epoch_listener({});
  if (!r) return std::move(r).error();
  row.render_ms = bench::median(ms);
  row.render_one_box_ms = bench::median(one_box_ms);
  row.render_same_box_ms = bench::median(same_box_ms);
  row.render_no_skip_ms = bench::median(no_skip_ms);
  (*viewer)->close();
  (*stepper)->close();
  (*child)->terminate(std::chrono::seconds(30));
  return row;
}

int run(const bench::Options& opt, const LargeArgs& a) {
  std::vector<std::uint64_t> sizes = opt.quick ? std::vector<std::uint64_t>{1'000'000, 8'000'000}
                                               : std::vector<std::uint64_t>{1'000'000, 16'000'000, 64'000'000};
  if (!a.cells.empty()) {
    sizes.clear();
    std::stringstream ss(a.cells);
    for (std::string t; std::getline(ss, t, ',');) sizes.push_back(std::stoull(t));
  }
  auto dir = bench::paintings_dir();
  if (!dir) return bench::fail(opt, dir.error().message);
  auto server = bench::durability::ChildServer::find_binary();
  if (!server) return bench::fail(opt, server.error().message);
  auto ctx = cg::ContextBuilder().app_name("deepcanvas-bench large").device(a.device).build();
  if (!ctx) return bench::fail(opt, ctx.error().message);
  auto progress = bench::progress(opt, "large", static_cast<double>(sizes.size()), "canvases");
  std::optional<cc::Camera> camera;
  std::optional<cc::DAabb> first_box;
  std::vector<Row> rows;
  for (std::uint64_t n : sizes) {
    auto row = measure(opt, **ctx, *server, *dir, n, camera, first_box);
    if (!row) return bench::fail(opt, std::to_string(n) + " cells: " + row.error().message);
    rows.push_back(*row);
    progress.add(1);
  }
  progress.finish();
  const double ratio = rows.front().render_ms > 0 ? rows.back().render_ms / rows.front().render_ms : 0;
  const double one_box_ratio = rows.front().render_one_box_ms > 0
                                   ? rows.back().render_one_box_ms / rows.front().render_one_box_ms
                                   : 0;
  const double same_box_ratio = rows.front().render_same_box_ms > 0
                                    ? rows.back().render_same_box_ms / rows.front().render_same_box_ms
                                    : 0;
  if (opt.json) {
    nlohmann::json j;
    j["suite"] = "large";
    j["device"] = (*ctx)->info().name;
    for (const auto& r : rows)
      j["canvases"].push_back({{"target_cells", r.target}, {"cells", r.cells}, {"generate_s", r.generate_s},
                               {"server_paint_s", r.server_paint_s}, {"server_bytes_per_cell", r.server_bpc},
                               {"first_picture_s", r.first_picture_s},
                               {"join_s", r.join_s}, {"client_bytes_per_cell", r.client_bpc},
                               {"render_ms", r.render_ms}, {"render_one_box_ms", r.render_one_box_ms},
                               {"content_boxes", r.content_boxes}, {"content_boxes_ms", r.content_boxes_ms},
                               {"quiet_wait_s", r.quiet_wait_s},
                               {"render_same_box_ms", r.render_same_box_ms},
                               {"render_no_skip_ms", r.render_no_skip_ms},
                               {"skip_speedup", r.render_ms > 0 ? r.render_no_skip_ms / r.render_ms : 0.0}});
    j["render_largest_over_smallest"] = ratio;
    j["render_one_box_largest_over_smallest"] = one_box_ratio;
    j["render_same_box_largest_over_smallest"] = same_box_ratio;
    j["targets"] = {{"render_ratio_max", 1.2}};
    std::printf("%s\n", j.dump().c_str());
    return 0;
  }
  for (const auto& r : rows)
    bench::print("large: %.1fM cells (generated in %.1f s): server paints it in %.1f s, %.1f B a cell; a "
                 "viewer joins: first picture %.2f s, whole in %.2f s, %.1f B a cell; 640x360 frame %.1f ms "
                 "(%.1f ms without stepping over empty subtrees: %.2fx)\n",
                 static_cast<double>(r.cells) / 1e6, r.generate_s, r.server_paint_s, r.server_bpc,
                 r.first_picture_s, r.join_s, r.client_bpc, r.render_ms, r.render_no_skip_ms,
                 r.render_ms > 0 ? r.render_no_skip_ms / r.render_ms : 0.0);
  bench::print("large: render at %.1fM cells / at %.1fM cells, same camera: %.2fx (target <= 1.2x); with one "
               "content box around everything painted: %.2fx; rays limited to the smaller canvas's content "
               "box: %.2fx\n",
               static_cast<double>(rows.back().cells) / 1e6, static_cast<double>(rows.front().cells) / 1e6, ratio,
               one_box_ratio, same_box_ratio);
  return 0;
}

bench::SuiteRun setup(CLI::App& app) {
  auto a = std::make_shared<LargeArgs>();
  app.add_option("--cells", a->cells, "canvas sizes, comma-separated (default 1M,16M,64M; --quick 1M,8M)")
      ->type_name("N,N,...");
  app.add_option("--device", a->device, "Vulkan device (else DEEPCANVAS_VK_DEVICE / automatic)")->type_name("SPEC");
  return [a](const bench::Options& opt) { return run(opt, *a); };
}

}  // namespace

DEEPCANVAS_BENCH_SUITE(deepcanvas::bench::Suite{
    "large", "canvases of millions of cells: memory per cell, join time, render time by size",
    "examples:\n"
    "  deepcanvas-bench large --quick\n"
    "  deepcanvas-bench large --cells 1000000,128000000 --json\n"
    "environment: DEEPCANVAS_PAINTINGS, DEEPCANVAS_SERVER (the server binary), DEEPCANVAS_VK_DEVICE\n",
    setup});
