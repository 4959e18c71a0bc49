// deepcanvas-client render: joins a canvas, waits until its replica has caught up with the
// server's epoch at join, uploads the replica to the GPU, computes G3 links there, ray-casts one
// frame and writes it as a PNG.
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>

#include "camera_options.hpp"
#include "cli_options.hpp"
#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/png.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/replica_gpu.hpp"
#include "frame_sequence.hpp"
#include "gpu_options.hpp"
#include "deepcanvas/base/progress.hpp"

namespace deepcanvas::client_app {

namespace {

namespace cli = deepcanvas::base::cli;
using Clock = std::chrono::steady_clock;

constexpr const char* kDescription =
    "Joins a canvas as a viewer, waits until its replica has caught up with the server's\n"
    "epoch at join (progress on stderr), ray-casts one frame on the Vulkan device and writes a\n"
    "PNG. The camera it used goes to stderr as --camera/--up arguments, to paste back.\n"
    "--turntable N writes N frames around the content instead (OUT_0000.png ...), orbiting the\n"
    "camera about the vertical axis through its target, and --video makes a video of them with\n"
    "ffmpeg where it is installed.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client render --connect ws://127.0.0.1:7878/main --out main.png\n"
    "  deepcanvas-client render --connect ws://127.0.0.1:7878/main --out front.png \\\n"
    "      --camera 0,1.6,3,0,1.2,0 --size 1920x1080\n"
    "      from 3 m in front of the origin at eye height, looking slightly down\n";

// The point the default camera looks at: the painted box's centre, moved onto the camera's view
// ray (fit_painted centres the painted leaves, not the box, on that ray).
client_core::DVec3 target_on_ray(const client_core::Camera& cam, const client_core::DAabb& box) {
  const client_core::DVec3 centre = (box.min + box.max) * 0.5;
  const double d = client_core::dot(centre - cam.position(), cam.forward());
  return cam.position() + cam.forward() * (d > 0 ? d : 1.0);
}

struct RenderArgs {
  ConnectArgs connect;
  CameraArgs camera;
  GpuViewArgs gpu;
  std::string out, size = "960x540", background, video;
  double timeout_s = 120, fps = 24;
  unsigned turntable = 0;
};

void add_render_options(CLI::App& app, RenderArgs& args) {
  add_connect_options(app, args.connect);
  app.add_option("--out", args.out, "where to write the image, required (its folder must exist)")
      ->type_name("FILE.png")
      ->check(output_file());
  app.add_option("--size", args.size, "image size in pixels (default 960x540)")
      ->type_name("WxH")
      ->check(image_size());
  add_camera_options(app, args.camera,
                     "frame the painted content from the front (+z), slightly above, with +y up.");
  add_device_option(app, args.gpu);
  app.add_option("--background", args.background,
                 "background colour in 0..1 (default 0.05,0.06,0.08)")
      ->type_name("R,G,B")
      ->check(rgb());
  app.add_option("--timeout", args.timeout_s, "how long to wait for the canvas (default 120)")
      ->type_name("SECONDS")
      ->transform(positive());
  app.add_option("--turntable", args.turntable,
                 "write N frames orbiting the content (OUT_0000.png ...) instead of one")
      ->type_name("N")
      ->check(CLI::Range(2u, 100000u));
  app.add_option("--video", args.video,
                 "with --turntable: also encode the frames into this video with ffmpeg")
      ->type_name("FILE.mp4")
      ->check(output_file());
  app.add_option("--fps", args.fps, "frames per second of --video (default 24)")
      ->type_name("FPS")
      ->check(CLI::Range(1.0, 240.0));
  add_cull_and_quiet_flags(app, args.gpu,
                           "trace rays through the empty canvas too (by default rays skip what "
                           "lies outside the painted content's box: the same image, faster; this "
                           "is for comparison)");
}

// What one frame needs once the replica is on the GPU with its links.
struct PreparedFrame {
  std::optional<client_core::Camera> camera;
  std::optional<client_core::DVec3> target;  // set where the camera was framed here
  client_core::RayOrigin origin;
  std::optional<client_core::DAabb> content_bounds;  // the painted box; none when empty
  std::uint64_t cells = 0;
  bool empty = false;  // nothing painted: the default camera looks at the canvas centre
};

// The default camera: paintings are y-up (A-Painter's convention); look from the front, slightly
// above, at the painted leaves themselves (their box's corners can lie far outside the painting).
Result<client_core::Camera> frame_content(const client_core::PoolView& view,
                                          const client_core::DAabb& box, bool empty,
                                          std::uint32_t width, std::uint32_t height) {
  const client_core::DVec3 forward{-0.45, -0.35, -0.82}, up{0, 1, 0};
  return empty ? client_core::Camera::fit_box(box, width, height, kDefaultFovDeg, forward, up)
               : client_core::fit_painted(view, width, height, kDefaultFovDeg, forward, up);
}

// Uploads the replica and computes its links on the GPU, then finds the painted content's box
// (the content cull: the same image, rays skip the empty canvas around it), the camera where
// `camera` is none, and the ray origin. Runs under the client's replica lock.
Result<PreparedFrame> prepare_frame(client_gpu::GpuReplica& replica,
                                    const client_core::PoolView& view,
                                    std::optional<client_core::Camera> camera, std::uint32_t width,
                                    std::uint32_t height) {
  PreparedFrame frame;
  frame.cells = view.cell_count();
  if (auto u = replica.upload_all(view); !u) return std::move(u).error();
  if (auto l = replica.compute_all_links(view); !l) return std::move(l).error();
  auto bounds = client_core::painted_bounds(view);
  if (!bounds) return std::move(bounds).error();
  frame.content_bounds = *bounds;
  if (!camera) {
    frame.empty = !*bounds;
    const client_core::DAabb box =
        frame.empty ? client_core::DAabb{{-1, -1, -1}, {1, 1, 1}} : **bounds;
    auto cam = frame_content(view, box, frame.empty, width, height);
    if (!cam) return std::move(cam).error();
    camera = *cam;
    frame.target = target_on_ray(*camera, box);
  }
  auto origin = client_core::make_ray_origin(view, camera->position());
  if (!origin) return std::move(origin).error();
  frame.origin = *origin;
  frame.camera = camera;
  return frame;
}

// The camera as --camera/--up arguments on stderr, to paste back.
void print_camera(const CLI::App& app, const PreparedFrame& frame, const CameraArgs& args) {
  const std::string text =
      frame.target ? camera_arguments(*frame.camera, *frame.target, "+y")
                   : camera_arguments(*frame.camera, parse_camera_spec(args.spec)->target, args.up);
  std::fprintf(stderr, "%s: camera %s\n", app.get_name().c_str(), text.c_str());
}

// Ray-casts the frame and writes it to `out`; the milliseconds the frame took.
Result<double> render_to_png(client_gpu::GpuRaycaster& raycaster, const PreparedFrame& frame,
                             const client_core::RenderOptions& options, const std::string& out,
                             std::uint32_t width, std::uint32_t height) {
  const auto t_render = Clock::now();
  auto pixels = raycaster.render_rgba8(*frame.camera, frame.origin, options);
  if (!pixels) return make_error(pixels.error().code, "rendering: " + pixels.error().message);
  const auto t_done = Clock::now();
  // The frame is composited over the background: store it opaque (alpha is the volume's own
  // opacity, which an image viewer would otherwise blend with its own background).
  for (std::size_t i = 3; i < pixels->size(); i += 4) (*pixels)[i] = 255;
  if (auto w = client_gpu::write_png(out, width, height, *pixels); !w) return std::move(w).error();
  return std::chrono::duration<double, std::milli>(t_done - t_render).count();
}

// The turntable: the camera orbits the vertical axis through its target (the up axis of --up),
// one full turn over `args.turntable` frames, each frame written as OUT_NNNN.png.
int render_turntable(CLI::App& app, const RenderArgs& args, client_core::Client& c,
                     client_gpu::GpuRaycaster& raycaster, PreparedFrame frame,
                     const client_core::RenderOptions& options, std::uint32_t width,
                     std::uint32_t height) {
  const client_core::DVec3 target =
      frame.target ? *frame.target : parse_camera_spec(args.camera.spec)->target;
  const client_core::DVec3 up = *parse_up(args.camera.up);
  const client_core::DVec3 eye0 = frame.camera->position();
  const double fov = frame.camera->vfov_rad() * 180.0 / 3.14159265358979323846;
  // The eye's offset from the target, split into its part along the axis and the part that turns.
  const client_core::DVec3 off = eye0 - target;
  const client_core::DVec3 along = up * client_core::dot(off, up);
  const client_core::DVec3 radial = off - along;
  const client_core::DVec3 side = client_core::cross(up, radial);
  base::Progress progress("turntable", args.turntable, "frames", !args.gpu.quiet);
  double total_ms = 0;
  for (unsigned i = 0; i < args.turntable; ++i) {
    const double a = 2 * 3.14159265358979323846 * i / args.turntable;
    const client_core::DVec3 eye = target + along + radial * std::cos(a) + side * std::sin(a);
    auto cam = client_core::Camera::look_at(eye, target, up, fov, width, height);
    if (!cam) return cli::fail(app, "turntable camera: " + cam.error().message);
    frame.camera = *cam;
    Result<client_core::RayOrigin> origin = make_error(Errc::internal, "the replica was not read");
    c.with_replica([&](const client_core::Replica& r) {
      origin = client_core::make_ray_origin(r.view(), eye);
    });
    if (!origin) return cli::fail(app, "turntable: " + origin.error().message);
    frame.origin = *origin;
    auto ms = render_to_png(raycaster, frame, options, frame_path(args.out, i), width, height);
    if (!ms) return cli::fail(app, ms.error().message);
    total_ms += *ms;
    progress.update(i + 1.0);
  }
  std::printf("wrote %u turntable frames %s .. %s (%ux%u), %.0f ms a frame\n", args.turntable,
              frame_path(args.out, 0).c_str(), frame_path(args.out, args.turntable - 1).c_str(),
              width, height, total_ms / args.turntable);
  if (!args.video.empty()) {
    if (auto v = make_video(args.out, args.video, args.fps); !v) return cli::fail(app, v.error().message);
    std::printf("wrote %s (%u frames at %.0f fps)\n", args.video.c_str(), args.turntable, args.fps);
  }
  return 0;
}

int run_render(int argc, char** argv) {
  RenderArgs args;
  CLI::App app{kDescription, "deepcanvas-client render"};
  cli::standard(app, kExamples);
  add_render_options(app, args);
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  // Checked here rather than with CLI11's required(), which would report a missing --out before
  // a misspelt option.
  if (args.out.empty()) return usage_error(app, "--out FILE.png is required");
  if (!args.video.empty() && args.turntable == 0)
    return usage_error(app, "--video needs --turntable N (the frames to encode)");
  auto fail = [&](const char* what, const Error& e) {
    return cli::fail(app, std::string(what) + ": " + e.message);
  };
  const bool cull = !args.gpu.no_cull;
  std::uint32_t width = 960, height = 540;
  parse_size(args.size, width, height);
  client_core::RenderOptions options;
  options.background = {0.05, 0.06, 0.08};
  if (!args.background.empty()) options.background = *parse_triple(args.background);
  // The camera before anything connects, so that a mistake fails fast.
  std::optional<client_core::Camera> camera;
  if (!args.camera.spec.empty()) {
    auto cam = make_camera(args.camera, width, height);
    if (!cam) return usage_error(app, cam.error().message);
    camera = *cam;
  }

  // The Vulkan device first: without one there is nothing to render with.
  auto ctx = client_gpu::ContextBuilder()
                 .app_name("deepcanvas-client render")
                 .device(args.gpu.device)
                 .build();
  if (!ctx) return fail("Vulkan", ctx.error());

  const auto& connect = args.connect;
  const auto opts = client_options(connect, protocol::Role::viewer, "deepcanvas-client render");
  const auto t0 = Clock::now();
  auto client = client_core::Client::connect(opts);
  if (!client)
    return cli::fail(app, "cannot join canvas '" + opts.canvas + "' at " + connect.url + ": " +
                              client.error().message);
  auto& c = **client;
  if (auto caught_up = catch_up(c, opts.canvas, args.timeout_s, args.gpu.quiet); !caught_up)
    return fail("waiting for the canvas", caught_up.error());
  const auto t_caught_up = Clock::now();

  auto replica = client_gpu::GpuReplica::create(**ctx, client_gpu::replica_config_for(c.welcome()));
  if (!replica) return fail("GPU replica", replica.error());
  Result<PreparedFrame> frame = make_error(Errc::internal, "the replica was not read");
  c.with_replica([&](const client_core::Replica& r) {
    frame = prepare_frame(**replica, r.view(), camera, width, height);
  });
  if (!frame) return fail("preparing the frame", frame.error());
  if (cull && frame->content_bounds) options.content_bounds = *frame->content_bounds;
  if (cull && !frame->content_bounds) options.content_empty = true;  // background, no traversal
  print_camera(app, *frame, args.camera);

  auto raycaster = client_gpu::GpuRaycaster::create(**replica);
  if (!raycaster) return fail("ray caster", raycaster.error());
  if (args.turntable > 0)
    return render_turntable(app, args, c, **raycaster, *frame, options, width, height);
  auto frame_ms = render_to_png(**raycaster, *frame, options, args.out, width, height);
  if (!frame_ms) return cli::fail(app, frame_ms.error().message);
  if (frame->empty) {
    base::log_event(base::LogLevel::warn, "canvas_empty",
                    {{"canvas", opts.canvas}, {"note", "the image shows only background"}});
  }
  std::printf(
      "wrote %s (%ux%u) of canvas '%s' at epoch %llu: %llu cells; joined and caught up in "
      "%.0f ms, frame %.0f ms on %s%s\n",
      args.out.c_str(), width, height, opts.canvas.c_str(),
      static_cast<unsigned long long>(c.applied_epoch()),
      static_cast<unsigned long long>(frame->cells),
      std::chrono::duration<double, std::milli>(t_caught_up - t0).count(), *frame_ms,
      (*ctx)->info().name.c_str(), cull ? "" : " (no content cull)");
  c.close();
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("render", "join a canvas, ray-cast one frame on the GPU, write a PNG",
                          run_render);

}  // namespace deepcanvas::client_app
