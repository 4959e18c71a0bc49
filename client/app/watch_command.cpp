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

#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/png.hpp"
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"

namespace deepcanvas::client_app {
namespace {

using Clock = std::chrono::steady_clock;

void watch_usage(FILE* out) {
  std::fprintf(
      out,
      "usage: deepcanvas-client watch [--connect URL] [--frames N | --seconds S] [--size WxH]\n"
      "                               [--camera SPEC] [--device I|NAME] [--out-dir DIR]\n"
      "                               [--budget-mbps X] [--fps X] [--upload-share F]\n"
      "                               [--gaps-above X] [--no-cull]\n\n"
      "Joins a canvas as a viewer and renders frames headless, continuously, while the canvas\n"
      "streams in: block frames are decoded on the network thread, whole epochs are uploaded to\n"
      "the GPU replica on an upload thread (G3 links recomputed on the GPU), and the render loop\n"
      "renders each frame in short row bands, every band from a whole epoch. At the end it\n"
      "prints frame statistics (frames, frame time p50/p99, frames rendered while uploads\n"
      "arrived, epochs) and, with --out-dir, writes the last frame as DIR/last_frame.png.\n\n"
      "%s"
      "  --frames N         stop after N rendered frames (default 30)\n"
      "  --seconds S        stop after S seconds instead\n"
      "  --size WxH         frame size (default 320x180)\n"
      "  --camera SPEC      EX,EY,EZ,TX,TY,TZ[,FOV] in metres (default: frame the painted\n"
      "                     content once there is some)\n"
      "  --device I|NAME    Vulkan device (default: see `deepcanvas-client devices`)\n"
      "  --out-dir DIR      write DIR/last_frame.png\n"
      "  --budget-mbps X    upload budget in MB/s (default: unlimited)\n"
      "  --fps X            at most X frames a second (default 60; 0: back to back)\n"
      "  --upload-share F   once frames are slower than the fps cap (see --gaps-above), keep\n"
      "                     this part of every frame interval free and upload only in those\n"
      "                     gaps (0..0.9, default 0.25): frames undisturbed by uploads; 0, or\n"
      "                     while frames fit in the cap: uploads go between short row bands as\n"
      "                     soon as they arrive (earlier residency)\n"
      "  --gaps-above X     uploads wait for gaps only while the median frame takes more than\n"
      "                     X times the fps cap's interval (0.1..10, default 1)\n"
      "  --no-cull          trace rays through the empty canvas too (by default every band\n"
      "                     skips what lies outside the content box of the epoch it shows:\n"
      "                     the same image, faster; this is for comparison)\n",
      kConnectHelp);
}

double pct(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(q * (v.size() - 1) + 0.5))];
}

int run_watch(int argc, char** argv) {
  ConnectArgs connect;
  std::string camera_spec, device, out_dir;
  std::uint64_t max_frames = 30;
  double seconds = 0, budget_mbps = 0;
  double max_fps = client_gpu::RenderLoopOptions{}.max_fps;
  double upload_share = client_gpu::RenderLoopOptions{}.upload_share;
  double gaps_above = client_gpu::RenderLoopOptions{}.gaps_above;
  std::uint32_t width = 320, height = 180;
  bool cull = true;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto shared = parse_connect_option(argc, argv, i, connect);
    if (!shared) {
      std::fprintf(stderr, "watch: %s\n", shared.error().message.c_str());
      return 2;
    }
    if (*shared) continue;
    if (a == "-h" || a == "--help") {
      watch_usage(stdout);
      return 0;
    }
    if (a == "--no-cull") {
      cull = false;
      continue;
    }
    if (a != "--frames" && a != "--seconds" && a != "--size" && a != "--camera" &&
        a != "--device" && a != "--out-dir" && a != "--budget-mbps" && a != "--fps" &&
        a != "--upload-share" && a != "--gaps-above") {
      std::fprintf(stderr, "watch: unknown option '%s'\n\n", a.c_str());
      watch_usage(stderr);
      return 2;
    }
    if (i + 1 >= argc) {
      std::fprintf(stderr, "watch: %s needs a value\n", a.c_str());
      return 2;
    }
    const std::string v = argv[++i];
    char* end = nullptr;
    if (a == "--frames") {
      max_frames = std::strtoull(v.c_str(), &end, 10);
      if (*end || max_frames == 0) {
        std::fprintf(stderr, "watch: --frames must be a positive integer\n");
        return 2;
      }
    } else if (a == "--seconds") {
      seconds = std::strtod(v.c_str(), &end);
      if (*end || !(seconds > 0)) {
        std::fprintf(stderr, "watch: --seconds must be a positive number\n");
        return 2;
      }
    } else if (a == "--size") {
      unsigned w = 0, h = 0;
      char tail = 0;
      if (std::sscanf(v.c_str(), "%ux%u%c", &w, &h, &tail) != 2 || w < 1 || h < 1 || w > 8192 ||
          h > 8192) {
        std::fprintf(stderr, "watch: --size must be WxH with 1..8192 each\n");
        return 2;
      }
      width = w;
      height = h;
    } else if (a == "--camera") {
      camera_spec = v;
    } else if (a == "--device") {
      device = v;
    } else if (a == "--out-dir") {
      out_dir = v;
    } else if (a == "--fps") {
      max_fps = std::strtod(v.c_str(), &end);
      if (*end || !(max_fps >= 0 && max_fps <= 10000)) {
        std::fprintf(stderr, "watch: --fps must be a number in 0..10000\n");
        return 2;
      }
    } else if (a == "--upload-share") {
      upload_share = std::strtod(v.c_str(), &end);
      if (*end || !(upload_share >= 0 && upload_share <= 0.9)) {
        std::fprintf(stderr, "watch: --upload-share must be a number in 0..0.9\n");
        return 2;
      }
    } else if (a == "--gaps-above") {
      gaps_above = std::strtod(v.c_str(), &end);
      if (*end || !(gaps_above >= 0.1 && gaps_above <= 10)) {
        std::fprintf(stderr, "watch: --gaps-above must be a number in 0.1..10\n");
        return 2;
      }
    } else if (a == "--budget-mbps") {
      budget_mbps = std::strtod(v.c_str(), &end);
      if (*end || !(budget_mbps > 0)) {
        std::fprintf(stderr, "watch: --budget-mbps must be a positive number\n");
        return 2;
      }
    }
  }
  client_gpu::RenderLoopOptions lo;
  lo.width = width;
  lo.height = height;
  lo.render.background = {0.05, 0.06, 0.08};
  lo.content_cull = cull;
  lo.max_fps = max_fps;
  lo.upload_share = upload_share;
  lo.gaps_above = gaps_above;
  if (!camera_spec.empty()) {
    auto c = client_core::Camera::parse(camera_spec, width, height);
    if (!c) {
      std::fprintf(stderr, "watch: --camera: %s\n", c.error().message.c_str());
      return 2;
    }
    lo.camera = *c;
  }
  auto ctx =
      client_gpu::ContextBuilder().app_name("deepcanvas-client watch").device(device).build();
  if (!ctx) {
    std::fprintf(stderr, "watch: Vulkan: %s\n", ctx.error().message.c_str());
    return 1;
  }
  auto opts = client_options(connect, protocol::Role::viewer, "deepcanvas-client watch");
  if (!opts) {
    std::fprintf(stderr, "watch: --connect: %s\n", opts.error().message.c_str());
    return 2;
  }
  auto client = client_core::Client::connect(*opts);
  if (!client) {
    std::fprintf(stderr, "watch: cannot join canvas '%s' at %s: %s\n", opts->canvas.c_str(),
                 connect.url.c_str(), client.error().message.c_str());
    return 1;
  }
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
  if (!streaming) {
    std::fprintf(stderr, "watch: GPU replica: %s\n", streaming.error().message.c_str());
    return 1;
  }
  client_gpu::stream_client_into(**client, **streaming);
  auto loop = client_gpu::RenderLoop::create(**streaming, lo);
  if (!loop) {
    (*client)->set_epoch_listener({});
    std::fprintf(stderr, "watch: render loop: %s\n", loop.error().message.c_str());
    return 1;
  }
  const auto t0 = Clock::now();
  (*loop)->start();
  for (;;) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    const double el = std::chrono::duration<double>(Clock::now() - t0).count();
    if (seconds > 0 ? el >= seconds : (*loop)->frame_count() >= max_frames) break;
    if (!(*client)->is_open() && !(*streaming)->any_resident()) break;
    if (!(*streaming)->status()) break;
  }
  auto stopped = (*loop)->stop();
  (*client)->set_epoch_listener({});
  if (!stopped) {
    std::fprintf(stderr, "watch: rendering failed: %s\n", stopped.error().message.c_str());
    return 1;
  }
  if (auto s = (*streaming)->status(); !s) {
    std::fprintf(stderr, "watch: upload failed: %s\n", s.error().message.c_str());
    return 1;
  }
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
      opts->canvas.c_str(), (*ctx)->info().name.c_str(), frames.size(), width, height,
      frames.empty() ? 0.0 : static_cast<double>(bands) / frames.size(),
      span_s > 0 ? static_cast<double>(frames.size()) / span_s : 0.0, pct(ms, 0.5), pct(ms, 0.99),
      streaming_ms.size(), pct(streaming_ms, 0.99), static_cast<unsigned long long>(st.epochs),
      static_cast<unsigned long long>(st.batches), st.bytes / 1e6, st.max_batch_lock_ms,
      static_cast<unsigned long long>(st.growths),
      static_cast<unsigned long long>((*streaming)->resident_epoch()), cull ? "on" : "off",
      static_cast<unsigned long long>(st.content_exact), st.max_content_exact_ms);
  if (!out_dir.empty() && !frames.empty()) {
    auto px = (*loop)->read_pixels();
    if (!px) {
      std::fprintf(stderr, "watch: %s\n", px.error().message.c_str());
      return 1;
    }
    std::vector<std::uint8_t> rgba(px->size() * 4);
    for (std::size_t i = 0; i < px->size(); ++i) {
      const std::uint32_t v = (*px)[i];
      rgba[i * 4 + 0] = static_cast<std::uint8_t>(v);
      rgba[i * 4 + 1] = static_cast<std::uint8_t>(v >> 8);
      rgba[i * 4 + 2] = static_cast<std::uint8_t>(v >> 16);
      rgba[i * 4 + 3] = 255;  // composited over the background: store opaque
    }
    const std::string path = out_dir + "/last_frame.png";
    if (auto w = client_gpu::write_png(path, width, height, rgba); !w) {
      std::fprintf(stderr, "watch: %s\n", w.error().message.c_str());
      return 1;
    }
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
