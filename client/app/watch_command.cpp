// deepcanvas-client watch: joins a canvas as a viewer and runs the render loop headless while
// the canvas streams in (StreamingReplica's upload thread + RenderLoop), then prints frame
// statistics and optionally writes the last frame as a PNG.
#include <algorithm>
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
#include "deepcanvas/base/percentile.hpp"
#include "deepcanvas/base/progress.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/png.hpp"
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "gpu_options.hpp"

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

struct WatchArgs {
  ConnectArgs connect;
  CameraArgs camera;
  GpuViewArgs gpu;
  std::string out_dir, size = "320x180";
  std::uint64_t max_frames = 30;
  double seconds = 0, budget_mbps = 0;
  client_gpu::RenderLoopOptions loop;  // max_fps, upload_share, gaps_above from the options
};

void add_watch_options(CLI::App& app, WatchArgs& args) {
  add_connect_options(app, args.connect);
  auto* frames_opt =
      app.add_option("--frames", args.max_frames, "stop after N rendered frames (default 30)")
          ->type_name("N")
          ->transform(whole(1));
  app.add_option("--seconds", args.seconds, "stop after S seconds instead")
      ->type_name("S")
      ->transform(positive())
      ->excludes(frames_opt);
  app.add_option("--size", args.size, "frame size (default 320x180)")
      ->type_name("WxH")
      ->check(image_size());
  add_camera_options(app, args.camera,
                     "frame the painted content from the front (+z), slightly above, with +y "
                     "up, once there is some.");
  add_device_option(app, args.gpu);
  app.add_option("--out-dir", args.out_dir, "write DIR/last_frame.png (the folder must exist)")
      ->type_name("DIR")
      ->check(output_folder());
  app.add_option("--budget-mbps", args.budget_mbps, "upload budget in MB/s (default: unlimited)")
      ->type_name("X")
      ->transform(positive());
  app.add_option("--fps", args.loop.max_fps,
                 "at most X frames a second (default 60; 0: back to back)")
      ->type_name("X")
      ->transform(number(0, 10000));
  app.add_option("--upload-share", args.loop.upload_share,
                 "once frames are slower than the fps cap (see --gaps-above), keep this part of "
                 "every frame interval free and upload only in those gaps (default 0.25): frames "
                 "undisturbed by uploads; 0, or while frames fit in the cap: uploads go between "
                 "short row bands as soon as they arrive (earlier residency)")
      ->type_name("F")
      ->transform(number(0, 0.9));
  app.add_option("--gaps-above", args.loop.gaps_above,
                 "uploads wait for gaps only while the median frame takes more than X times the "
                 "fps cap's interval (default 1)")
      ->type_name("X")
      ->transform(number(0.1, 10));
  add_cull_and_quiet_flags(app, args.gpu,
                           "trace rays through the empty canvas too (by default every band skips "
                           "what lies outside the content box of the epoch it shows: the same "
                           "image, faster; this is for comparison)");
}

// Lets the render loop run until --seconds or --frames is reached, the connection closes with
// nothing on the GPU, or an upload fails; `catching_up` shows the block frames received until the
// replica holds the epoch the server was at on join (the loop shows what arrives meanwhile).
void watch_until_done(const client_core::Client& client,
                      const client_gpu::StreamingReplica& streaming, client_gpu::RenderLoop& loop,
                      const WatchArgs& args, base::Progress& catching_up) {
  const std::uint64_t join_epoch = client.welcome().epoch;
  bool caught_up = false;
  const auto t0 = Clock::now();
  for (;;) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (!caught_up) {
      const auto cs = client.stats();
      catching_up.update(static_cast<double>(cs.frames));
      caught_up = cs.epochs > 0 && cs.applied_epoch >= join_epoch;
      if (caught_up) catching_up.finish();
    }
    const double el = std::chrono::duration<double>(Clock::now() - t0).count();
    if (args.seconds > 0 ? el >= args.seconds : loop.frame_count() >= args.max_frames) break;
    if (!client.is_open() && !streaming.any_resident()) break;
    if (!streaming.status()) break;
  }
}

// The one-line summary on stdout: frames and their times, uploads, the content cull.
void print_watch_stats(const std::string& canvas, const std::string& device,
                       const client_gpu::RenderLoopOptions& lo,
                       const std::vector<client_gpu::FrameRecord>& frames,
                       const client_gpu::StreamingReplica& streaming) {
  std::vector<double> ms, streaming_ms;
  std::uint64_t bands = 0;
  for (const auto& f : frames) {
    ms.push_back(f.ms);
    if (f.streaming) streaming_ms.push_back(f.ms);
    bands += f.bands;
  }
  const auto st = streaming.stats();
  const double span_s =
      frames.size() < 2
          ? 0.0
          : std::chrono::duration<double>(frames.back().end - frames.front().start).count();
  std::printf(
      "watch: canvas '%s' on %s: %zu frames %ux%u (%.1f bands/frame, %.1f fps), frame_ms p50 %.1f "
      "p99 %.1f; %zu frames while uploads arrived, p99 %.1f; %llu epochs in %llu batches "
      "(%.2f MB, longest batch %.1f ms, %llu texture growths), resident epoch %llu; content "
      "cull %s (%llu exact box recomputes, longest %.1f ms)\n",
      canvas.c_str(), device.c_str(), frames.size(), lo.width, lo.height,
      frames.empty() ? 0.0 : static_cast<double>(bands) / frames.size(),
      span_s > 0 ? static_cast<double>(frames.size()) / span_s : 0.0, base::percentile(ms, 0.5),
      base::percentile(ms, 0.99), streaming_ms.size(), base::percentile(streaming_ms, 0.99),
      static_cast<unsigned long long>(st.epochs), static_cast<unsigned long long>(st.batches),
      st.bytes / 1e6, st.max_batch_lock_ms, static_cast<unsigned long long>(st.growths),
      static_cast<unsigned long long>(streaming.resident_epoch()), lo.content_cull ? "on" : "off",
      static_cast<unsigned long long>(st.content_exact), st.max_content_exact_ms);
}

// Writes the loop's last frame as DIR/last_frame.png; the path written.
Result<std::string> write_last_frame(client_gpu::RenderLoop& loop, const std::string& out_dir,
                                     std::uint32_t width, std::uint32_t height) {
  auto px = loop.read_pixels();
  if (!px) return std::move(px).error();
  std::string path = out_dir + "/last_frame.png";
  if (auto w = client_gpu::write_frame_png(path, width, height, *px); !w)
    return std::move(w).error();
  return path;
}

int run_watch(int argc, char** argv) {
  WatchArgs args;
  CLI::App app{kDescription, "deepcanvas-client watch"};
  cli::standard(app, kExamples);
  add_watch_options(app, args);
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;

  client_gpu::RenderLoopOptions lo = args.loop;
  parse_size(args.size, lo.width, lo.height);
  lo.render.background = {0.05, 0.06, 0.08};
  lo.content_cull = !args.gpu.no_cull;
  if (!args.camera.spec.empty()) {
    auto c = make_camera(args.camera, lo.width, lo.height);
    if (!c) return usage_error(app, c.error().message);
    lo.camera = *c;
  }
  auto ctx = client_gpu::ContextBuilder()
                 .app_name("deepcanvas-client watch")
                 .device(args.gpu.device)
                 .build();
  if (!ctx) return cli::fail(app, "Vulkan: " + ctx.error().message);
  const auto& connect = args.connect;
  const auto opts = client_options(connect, protocol::Role::viewer, "deepcanvas-client watch");
  auto client = client_core::Client::connect(opts);
  if (!client)
    return cli::fail(app, "cannot join canvas '" + opts.canvas + "' at " + connect.url + ": " +
                              client.error().message);
  client_gpu::UploadBudget budget;
  budget.bytes_per_second = args.budget_mbps * 1e6;
  auto streaming = client_gpu::StreamingReplica::create(
      **ctx, client_gpu::replica_config_for((*client)->welcome()), budget);
  if (!streaming) return cli::fail(app, "GPU replica: " + streaming.error().message);
  client_gpu::stream_client_into(**client, **streaming);
  auto loop = client_gpu::RenderLoop::create(**streaming, lo);
  if (!loop) {
    (*client)->set_epoch_listener({});
    return cli::fail(app, "render loop: " + loop.error().message);
  }
  base::Progress catching_up("catching up with canvas '" + opts.canvas + "'", 0, "blocks",
                             !args.gpu.quiet);
  (*loop)->start();
  watch_until_done(**client, **streaming, **loop, args, catching_up);
  auto stopped = (*loop)->stop();
  (*client)->set_epoch_listener({});
  catching_up.finish();
  if (!stopped) return cli::fail(app, "rendering failed: " + stopped.error().message);
  if (auto s = (*streaming)->status(); !s)
    return cli::fail(app, "upload failed: " + s.error().message);
  const auto frames = (*loop)->frames();
  print_watch_stats(opts.canvas, (*ctx)->info().name, lo, frames, **streaming);
  if (!args.out_dir.empty() && !frames.empty()) {
    auto path = write_last_frame(**loop, args.out_dir, lo.width, lo.height);
    if (!path) return cli::fail(app, path.error().message);
    std::printf("watch: wrote %s\n", path->c_str());
  }
  (*client)->close();
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("watch",
                          "join a canvas and run the render loop headless while it streams in",
                          run_watch);

}  // namespace deepcanvas::client_app
