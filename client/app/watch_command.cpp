// deepcanvas-client watch: joins a canvas as a viewer and runs the render loop headless while
// the canvas streams in (StreamingReplica's upload thread + RenderLoop), then prints frame
// statistics and optionally writes the last frame as a PNG.
#include <algorithm>
#include <bit>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

#include "camera_options.hpp"
#include "cli_options.hpp"
#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/progress.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/png.hpp"
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"

namespace deepcanvas::client_app {
namespace {

namespace cli = deepcanvas::base::cli;
using Clock = std::chrono::steady_clock;

constexpr const char* kDescription =
    "Joins a canvas as a viewer and renders frames headless, continuously, while the canvas\n"
    "streams in: block frames are decoded on the network thread, whole epochs are uploaded to\n"
    "the GPU replica on an upload thread (G3 links recomputed on the GPU), and the render loop\n"
    "renders each frame in short row bands, every band from a whole epoch. At the end it\n"
    "prints frame statistics (frames, frame time p50/p99, frames rendered while uploads\n"
    "arrived, epochs) and, with --out-dir, writes the last frame as DIR/last_frame.png.\n"
    "Catching up on join shows progress on stderr.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client watch --connect ws://127.0.0.1:7878/main\n"
    "  deepcanvas-client watch --connect ws://127.0.0.1:7878/main --seconds 10 --fps 30 \\\n"
    "      --out-dir out\n";

double pct(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(q * (v.size() - 1) + 0.5))];
}

int run_watch(int argc, char** argv) {
  ConnectArgs connect;
  CameraArgs camera_args;
  std::string device, out_dir, size = "320x180";
  std::uint64_t max_frames = 30;
  double seconds = 0, budget_mbps = 0;
  double max_fps = client_gpu::RenderLoopOptions{}.max_fps;
  double upload_share = client_gpu::RenderLoopOptions{}.upload_share;
  double gaps_above = client_gpu::RenderLoopOptions{}.gaps_above;
  std::uint32_t width = 320, height = 180;
  bool no_cull = false, quiet = false;

  CLI::App app{kDescription, "deepcanvas-client watch"};
  cli::standard(app, kExamples);
  add_connect_options(app, connect);
  auto* frames_opt = app.add_option("--frames", max_frames, "stop after N rendered frames (default 30)")
                         ->type_name("N")
                         ->transform(whole(1));
  app.add_option("--seconds", seconds, "stop after S seconds instead")
      ->type_name("S")
      ->transform(positive())
      ->excludes(frames_opt);
  app.add_option("--size", size, "frame size (default 320x180)")
      ->type_name("WxH")
      ->check(image_size());
  add_camera_options(app, camera_args,
                     "frame the painted content from the front (+z), slightly above, with +y "
                     "up, once there is some.");
  app.add_option("--device", device, "Vulkan device (default: see `deepcanvas-client devices`)")
      ->type_name("I|NAME");
  app.add_option("--out-dir", out_dir, "write DIR/last_frame.png (the folder must exist)")
      ->type_name("DIR")
      ->check(output_folder());
  app.add_option("--budget-mbps", budget_mbps, "upload budget in MB/s (default: unlimited)")
      ->type_name("X")
      ->transform(positive());
  app.add_option("--fps", max_fps, "at most X frames a second (default 60; 0: back to back)")
      ->type_name("X")
      ->transform(number(0, 10000));
  app.add_option("--upload-share", upload_share,
                 "once frames are slower than the fps cap (see --gaps-above), keep this part of "
                 "every frame interval free and upload only in those gaps (default 0.25): frames "
                 "undisturbed by uploads; 0, or while frames fit in the cap: uploads go between "
                 "short row bands as soon as they arrive (earlier residency)")
      ->type_name("F")
      ->transform(number(0, 0.9));
  app.add_option("--gaps-above", gaps_above,
                 "uploads wait for gaps only while the median frame takes more than X times the "
                 "fps cap's interval (default 1)")
      ->type_name("X")
      ->transform(number(0.1, 10));
  app.add_flag("--no-cull", no_cull,
               "trace rays through the empty canvas too (by default every band skips what lies "
               "outside the content box of the epoch it shows: the same image, faster; this is "
               "for comparison)");
  app.add_flag("--quiet", quiet, "no progress on stderr");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  const bool cull = !no_cull;
  parse_size(size, width, height);

  client_gpu::RenderLoopOptions lo;
  lo.width = width;
  lo.height = height;
  lo.render.background = {0.05, 0.06, 0.08};
  lo.content_cull = cull;
  lo.max_fps = max_fps;
  lo.upload_share = upload_share;
  lo.gaps_above = gaps_above;
  if (!camera_args.spec.empty()) {
    auto c = make_camera(camera_args, width, height);
    if (!c) return usage_error(app, c.error().message);
    lo.camera = *c;
  }
  auto ctx =
      client_gpu::ContextBuilder().app_name("deepcanvas-client watch").device(device).build();
  if (!ctx) return cli::fail(app, "Vulkan: " + ctx.error().message);
  const auto opts = client_options(connect, protocol::Role::viewer, "deepcanvas-client watch");
  auto client = client_core::Client::connect(opts);
  if (!client)
    return cli::fail(app, "cannot join canvas '" + opts.canvas + "' at " + connect.url + ": " +
                              client.error().message);
  const auto& welcome = (*client)->welcome();
  client_gpu::GpuReplicaConfig cfg;
  cfg.width_log2 = static_cast<std::uint32_t>(std::countr_zero(welcome.texture_width));
  cfg.block_log2 = static_cast<std::uint32_t>(std::countr_zero(welcome.block_cells));
  cfg.roots_per_axis = welcome.geometry.roots_per_axis;
  cfg.edge_m = welcome.geometry.edge_m;
  cfg.max_depth = welcome.geometry.max_depth;
  client_gpu::UploadBudget budget;
  budget.bytes_per_second = budget_mbps * 1e6;
  auto streaming = client_gpu::StreamingReplica::create(**ctx, cfg, budget);
  if (!streaming) return cli::fail(app, "GPU replica: " + streaming.error().message);
  client_gpu::stream_client_into(**client, **streaming);
  auto loop = client_gpu::RenderLoop::create(**streaming, lo);
  if (!loop) {
    (*client)->set_epoch_listener({});
    return cli::fail(app, "render loop: " + loop.error().message);
  }
  // Catching up: the block frames received until the replica holds the epoch the server was at
  // when this client joined (the render loop shows what has arrived meanwhile).
  base::Progress catching_up("catching up with canvas '" + opts.canvas + "'", 0, "blocks",
                             !quiet);
  const std::uint64_t join_epoch = welcome.epoch;
  bool caught_up = false;
  const auto t0 = Clock::now();
  (*loop)->start();
  for (;;) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (!caught_up) {
      const auto cs = (*client)->stats();
      catching_up.update(static_cast<double>(cs.frames));
      caught_up = cs.epochs > 0 && cs.applied_epoch >= join_epoch;
      if (caught_up) catching_up.finish();
    }
    const double el = std::chrono::duration<double>(Clock::now() - t0).count();
    if (seconds > 0 ? el >= seconds : (*loop)->frame_count() >= max_frames) break;
    if (!(*client)->is_open() && !(*streaming)->any_resident()) break;
    if (!(*streaming)->status()) break;
  }
  auto stopped = (*loop)->stop();
  (*client)->set_epoch_listener({});
  catching_up.finish();
  if (!stopped) return cli::fail(app, "rendering failed: " + stopped.error().message);
  if (auto s = (*streaming)->status(); !s)
    return cli::fail(app, "upload failed: " + s.error().message);
  const auto frames = (*loop)->frames();
  std::vector<double> ms, streaming_ms;
  std::uint64_t bands = 0;
  for (const auto& f : frames) {
    ms.push_back(f.ms);
    if (f.streaming) streaming_ms.push_back(f.ms);
    bands += f.bands;
  }
  const auto st = (*streaming)->stats();
  const double span_s =
      frames.size() < 2
          ? 0.0
          : std::chrono::duration<double>(frames.back().end - frames.front().start).count();
  std::printf(
      "watch: canvas '%s' on %s: %zu frames %ux%u (%.1f bands/frame, %.1f fps), frame_ms p50 %.1f "
      "p99 %.1f; %zu frames while uploads arrived, p99 %.1f; %llu epochs in %llu batches "
      "(%.2f MB, longest batch %.1f ms, %llu texture growths), resident epoch %llu; content "
      "cull %s (%llu exact box recomputes, longest %.1f ms)\n",
      opts.canvas.c_str(), (*ctx)->info().name.c_str(), frames.size(), width, height,
      frames.empty() ? 0.0 : static_cast<double>(bands) / frames.size(),
      span_s > 0 ? static_cast<double>(frames.size()) / span_s : 0.0, pct(ms, 0.5), pct(ms, 0.99),
      streaming_ms.size(), pct(streaming_ms, 0.99), static_cast<unsigned long long>(st.epochs),
      static_cast<unsigned long long>(st.batches), st.bytes / 1e6, st.max_batch_lock_ms,
      static_cast<unsigned long long>(st.growths),
      static_cast<unsigned long long>((*streaming)->resident_epoch()), cull ? "on" : "off",
      static_cast<unsigned long long>(st.content_exact), st.max_content_exact_ms);
  if (!out_dir.empty() && !frames.empty()) {
    auto px = (*loop)->read_pixels();
    if (!px) return cli::fail(app, px.error().message);
    std::vector<std::uint8_t> rgba(px->size() * 4);
    for (std::size_t i = 0; i < px->size(); ++i) {
      const std::uint32_t v = (*px)[i];
      rgba[i * 4 + 0] = static_cast<std::uint8_t>(v);
      rgba[i * 4 + 1] = static_cast<std::uint8_t>(v >> 8);
      rgba[i * 4 + 2] = static_cast<std::uint8_t>(v >> 16);
      rgba[i * 4 + 3] = 255;  // composited over the background: store opaque
    }
    const std::string path = out_dir + "/last_frame.png";
    if (auto w = client_gpu::write_png(path, width, height, rgba); !w)
      return cli::fail(app, w.error().message);
    std::printf("watch: wrote %s\n", path.c_str());
  }
  (*client)->close();
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("watch",
                          "join a canvas and run the render loop headless while it streams in",
                          run_watch);

}  // namespace deepcanvas::client_app
