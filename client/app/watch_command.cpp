// deepcanvas-client watch: joins a canvas as a viewer and runs the render loop headless while
// the canvas streams in (StreamingReplica's upload thread + RenderLoop, or with --stereo the
// headset's HeadsetLoop driven by a pose trace), then prints frame statistics and optionally
// writes the last frame as a PNG.
#include <algorithm>
#include <chrono>
#include <cmath>
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
#include "deepcanvas/client_core/pose_trace.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/headset_loop.hpp"
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
    "Catching up on join shows progress on stderr.\n"
    "\n"
    "--stereo runs a headset's frame loop instead: both eyes from the head pose of --pose-trace\n"
    "(a recorded or generated head and controller motion: `deepcanvas-client pose-trace`) at\n"
    "--hz, each eye --eye-size at render scale 1, the render scale adapted every frame to stay\n"
    "inside the frame interval (--fixed-scale S to hold it). It prints frame_ms p50/p99,\n"
    "missed frames (complete after their interval), render scale p50/min and motion to photon\n"
    "(pose latched -> both eyes rendered) p50/p99; --out-dir writes the last frame's eyes side\n"
    "by side as DIR/stereo_last.png.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client watch --connect ws://127.0.0.1:7878/main\n"
    "  deepcanvas-client watch --connect ws://127.0.0.1:7878/main --seconds 10 --fps 30 \\\n"
    "      --out-dir out\n"
    "  deepcanvas-client pose-trace --painting demo.apa --seconds 30 --out head.trace\n"
    "  deepcanvas-client watch --connect ws://127.0.0.1:7878/main --stereo --pose-trace head.trace \\\n"
    "      --eye-size 640x576 --hz 30 --seconds 30 --out-dir out\n";

struct WatchArgs {
  ConnectArgs connect;
  CameraArgs camera;
  GpuViewArgs gpu;
  std::string out_dir, size = "320x180";
  std::uint64_t max_frames = 30;
  double seconds = 0, budget_mbps = 0;
  client_gpu::RenderLoopOptions loop;  // max_fps, upload_share, gaps_above from the options
  // --stereo
  bool stereo = false;
  std::string pose_trace, eye_size = "640x576";
  double hz = 30, fixed_scale = 0, ipd_mm = 63, vfov_deg = 100;
};

void add_watch_options(CLI::App& app, WatchArgs& args) {
  add_connect_options(app, args.connect);
  add_batch_interval_option(app, args.connect);
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
  app.add_flag("--stereo", args.stereo,
               "a headset's frame loop: both eyes from --pose-trace's head pose (see below)");
  app.add_option("--pose-trace", args.pose_trace, "--stereo: the head and controller motion")
      ->type_name("FILE");
  app.add_option("--eye-size", args.eye_size, "--stereo: each eye at render scale 1 (default 640x576)")
      ->type_name("WxH")
      ->check(image_size());
  app.add_option("--hz", args.hz, "--stereo: the headset's refresh rate (default 30)")
      ->type_name("HZ")
      ->transform(number(1, 1000));
  app.add_option("--fixed-scale", args.fixed_scale,
                 "--stereo: render at this scale of --eye-size always (default: adapt)")
      ->type_name("S")
      ->transform(number(0.05, 1));
  app.add_option("--ipd-mm", args.ipd_mm, "--stereo: distance between the eyes (default 63)")
      ->type_name("MM")
      ->transform(number(0, 200));
  app.add_option("--vfov", args.vfov_deg, "--stereo: each eye's vertical field of view (default 100)")
      ->type_name("DEGREES")
      ->transform(number(1, 170));
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
  // Falling behind: told once the batches have been skipping epochs for 2 s (a moment's load
  // is not worth a line), again every 10 s while they go on, and once they have skipped none
  // for 2 s.
  constexpr auto kBehindAfter = std::chrono::seconds(2), kRetell = std::chrono::seconds(10);
  std::uint64_t skipped_seen = 0, skipped_told = 0;
  Clock::time_point skip_started{}, last_skip{}, told_at{};
  bool skipping = false, told = false;
  for (;;) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    const auto cs = client.stats();
    const auto now = Clock::now();
    if (!caught_up) {
      catching_up.update(static_cast<double>(cs.frames));
      caught_up = cs.epochs > 0 && cs.applied_epoch >= join_epoch;
      if (caught_up) catching_up.finish();
    }
    if (cs.epochs_skipped > skipped_seen) {
      skipped_seen = cs.epochs_skipped;
      last_skip = now;
      if (!skipping) skip_started = now;
      skipping = true;
    } else if (skipping && now - last_skip > kBehindAfter) {
      skipping = false;
      if (told)
        std::fprintf(stderr, "watch: caught up with the canvas again (epoch %llu)\n",
                     static_cast<unsigned long long>(cs.applied_epoch));
      told = false;
    }
    if (skipping && now - skip_started >= kBehindAfter && skipped_seen > skipped_told &&
        (!told || now - told_at >= kRetell)) {
      std::fprintf(stderr,
                   "watch: behind the canvas: the connection is slower than its changes; %llu "
                   "epochs skipped so far, each block shown at its newest version (epoch %llu)\n",
                   static_cast<unsigned long long>(skipped_seen),
                   static_cast<unsigned long long>(cs.applied_epoch));
      skipped_told = skipped_seen;
      told_at = now;
      told = true;
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

// --stereo: the headset loop over the streaming replica, the pose from the trace (its time
// wraps around), until --seconds or --frames; statistics on stdout.
int watch_stereo(CLI::App& app, const WatchArgs& args, const client_gpu::Context& ctx,
                 client_core::Client& client, client_gpu::StreamingReplica& streaming,
                 const std::string& canvas) {
  auto trace = client_core::read_pose_trace_file(args.pose_trace);
  if (!trace) return cli::fail(app, trace.error().message);
  client_gpu::HeadsetOptions ho;
  parse_size(args.eye_size, ho.eyes.width, ho.eyes.height);
  ho.eyes.ipd_m = args.ipd_mm / 1000;
  ho.eyes.vfov_deg = args.vfov_deg;
  ho.hz = args.hz;
  ho.adapt = args.fixed_scale == 0;
  if (!ho.adapt) ho.fixed_scale = args.fixed_scale;
  ho.render.background = {0.05, 0.06, 0.08};
  ho.content_cull = !args.gpu.no_cull;
  auto loop = client_gpu::HeadsetLoop::create(streaming, ho);
  if (!loop) return cli::fail(app, "headset loop: " + loop.error().message);
  const double period = std::max(trace->duration_s(), 1e-3);
  auto frames = (*loop)->run(
      [&](double t) { return trace->at(std::fmod(t, period)).pose; },
      [&](const std::vector<client_gpu::HeadsetFrame>& f) {
        if (!client.is_open() && !streaming.any_resident()) return true;
        if (!streaming.status()) return true;
        if (args.seconds > 0) return !f.empty() && f.back().start_s >= args.seconds;
        std::uint64_t rendered = 0;
        for (const auto& x : f) rendered += x.empty ? 0 : 1;
        return rendered >= args.max_frames;
      });
  if (!frames) return cli::fail(app, "rendering failed: " + frames.error().message);
  if (auto s = streaming.status(); !s) return cli::fail(app, "upload failed: " + s.error().message);
  std::vector<double> ms, mtp, scale;
  std::size_t missed = 0;
  for (const auto& f : *frames) {
    if (f.empty) continue;
    ms.push_back(f.render_ms);
    mtp.push_back(f.motion_to_photon_ms);
    scale.push_back(f.render_scale);
    missed += f.missed ? 1 : 0;
  }
  const double min_scale = scale.empty() ? 0.0 : *std::min_element(scale.begin(), scale.end());
  std::printf(
      "watch --stereo: canvas '%s' on %s: %zu frames, 2 x %ux%u at %.0f Hz (interval %.1f ms): "
      "frame_ms p50 %.1f p99 %.1f; missed_frames %zu (%.1f%%); render_scale p50 %.2f min %.2f; "
      "motion_to_photon_ms p50 %.1f p99 %.1f\n",
      canvas.c_str(), ctx.info().name.c_str(), ms.size(), ho.eyes.width, ho.eyes.height, ho.hz,
      1000.0 / ho.hz, base::percentile(ms, 0.5), base::percentile(ms, 0.99), missed,
      ms.empty() ? 0.0 : 100.0 * static_cast<double>(missed) / static_cast<double>(ms.size()),
      base::percentile(scale, 0.5), min_scale, base::percentile(mtp, 0.5),
      base::percentile(mtp, 0.99));
  if (!args.out_dir.empty() && !ms.empty()) {
    std::uint32_t w = 0, h = 0;
    auto px = (*loop)->read_side_by_side(w, h);
    if (!px) return cli::fail(app, px.error().message);
    const std::string path = args.out_dir + "/stereo_last.png";
    if (auto wr = client_gpu::write_frame_png(path, w, h, *px); !wr)
      return cli::fail(app, wr.error().message);
    std::printf("watch: wrote %s (%ux%u: left eye, right eye)\n", path.c_str(), w, h);
  }
  client.close();
  return 0;
}

int run_watch(int argc, char** argv) {
  WatchArgs args;
  CLI::App app{kDescription, "deepcanvas-client watch"};
  cli::standard(app, kExamples);
  add_watch_options(app, args);
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  if (args.stereo && args.pose_trace.empty())
    return usage_error(app, "--stereo needs --pose-trace FILE (deepcanvas-client pose-trace makes one)");
  if (!args.stereo && !args.pose_trace.empty()) return usage_error(app, "--pose-trace is for --stereo");

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
  auto opts = client_options(connect, protocol::Role::viewer, "deepcanvas-client watch");
  // With --camera the snapshot comes nearest that view first (a progressive join refines it first).
  if (lo.camera) opts.camera = join_camera(*lo.camera);
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
  if (args.stereo) {
    const int rc = watch_stereo(app, args, **ctx, **client, **streaming, opts.canvas);
    (*client)->set_epoch_listener({});
    return rc;
  }
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
