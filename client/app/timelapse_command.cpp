// deepcanvas-client timelapse: paints a painting's strokes into a canvas in their order and
// renders the canvas every K strokes (or every T seconds of the artist's painting time) from a
// fixed or orbiting camera: a PNG sequence, and a video where ffmpeg is installed.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "camera_options.hpp"
#include "cli_options.hpp"
#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/progress.hpp"
#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/png.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/replica_gpu.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "frame_sequence.hpp"
#include "generated_scene.hpp"
#include "gpu_options.hpp"

namespace deepcanvas::client_app {

namespace {

namespace cli = deepcanvas::base::cli;
using client_core::DVec3;
constexpr double kPi = 3.14159265358979323846;

constexpr const char* kDescription =
    "Paints a painting's strokes into a canvas, in the artist's order, and renders the canvas\n"
    "after every K strokes (--every) or every T seconds of the artist's painting time\n"
    "(--every-seconds, from the samples' timestamps): OUT_0000.png, OUT_0001.png, ... and, with\n"
    "--video, a video of them made by ffmpeg where it is installed. The camera frames the whole\n"
    "finished painting from the first frame on (or --camera), fixed or orbiting (--orbit\n"
    "degrees per frame). Paint into an empty canvas (a scratch server: the main job's steps);\n"
    "a canvas that holds paint is refused unless --onto-existing.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-server serve --in-memory --listen 127.0.0.1:7979 &\n"
    "  deepcanvas-client timelapse demo.apa --connect ws://127.0.0.1:7979/default \\\n"
    "      --out frames/demo.png --every 2 --orbit 3 --video demo.mp4\n"
    "  deepcanvas-client timelapse mozfest.apa --every-seconds 10 --out frames/mozfest.png\n";

struct Args {
  ConnectArgs connect;
  CameraArgs camera;
  GpuViewArgs gpu;
  std::string painting, out, video, size = "640x360";
  bool generated = false, onto_existing = false;
  unsigned every = 0;
  double every_seconds = 0, orbit_deg = 0, fps = 12, timeout_s = 120;
};

// The painting's extent: every sample's sphere.
client_core::DAabb strokes_box(const std::vector<protocol::Stroke>& strokes) {
  client_core::DAabb b{{1e300, 1e300, 1e300}, {-1e300, -1e300, -1e300}};
  for (const auto& s : strokes)
    for (const auto& p : s.samples) {
      const double r = p.radius;
      b.min = {std::min(b.min.x, p.x - r), std::min(b.min.y, p.y - r), std::min(b.min.z, p.z - r)};
      b.max = {std::max(b.max.x, p.x + r), std::max(b.max.y, p.y + r), std::max(b.max.z, p.z + r)};
    }
  return b;
}

// Which strokes end a frame: every K-th (and the last), or the last stroke before each T-second
// mark of the painting time (the samples' t_ms, from the first stroke's first sample).
std::vector<bool> frame_ends(const std::vector<protocol::Stroke>& strokes, const Args& a) {
  std::vector<bool> ends(strokes.size(), false);
  if (a.every_seconds > 0) {
    const double t0 = strokes.front().samples.front().t_ms;
    double next = a.every_seconds * 1000;
    for (std::size_t i = 0; i + 1 < strokes.size(); ++i) {
      const double t_next = strokes[i + 1].samples.front().t_ms - t0;
      if (t_next >= next) {
        ends[i] = true;
        while (next <= t_next) next += a.every_seconds * 1000;
      }
    }
  } else {
    const std::size_t k = a.every == 0 ? std::max<std::size_t>(1, strokes.size() / 60) : a.every;
    for (std::size_t i = k - 1; i < strokes.size(); i += k) ends[i] = true;
  }
  ends.back() = true;
  return ends;
}

int run_timelapse(int argc, char** argv) {
  Args a;
  CLI::App app{kDescription, "deepcanvas-client timelapse"};
  cli::standard(app, kExamples);
  add_connect_options(app, a.connect);
  app.add_option("PAINTING", a.painting, "the painting whose history to render (or --generated)")
      ->type_name("FILE.apa");
  app.add_flag("--generated", a.generated, "the project's generated scene instead of a file");
  app.add_option("--out", a.out, "frames are written as OUT_0000.png ... (required)")
      ->type_name("FILE.png")
      ->check(output_file());
  app.add_option("--every", a.every, "a frame after every N strokes (default: about 60 frames)")
      ->type_name("N")
      ->check(CLI::Range(1u, 1000000u));
  app.add_option("--every-seconds", a.every_seconds,
                 "a frame every T seconds of the artist's painting time instead")
      ->type_name("T")
      ->transform(positive());
  app.add_option("--orbit", a.orbit_deg, "turn the camera this many degrees per frame (default 0)")
      ->type_name("DEGREES")
      ->check(CLI::Range(-360.0, 360.0));
  app.add_option("--size", a.size, "frame size in pixels (default 640x360)")
      ->type_name("WxH")
      ->check(image_size());
  add_camera_options(app, a.camera, "frame the whole finished painting from the front, +y up.");
  add_device_option(app, a.gpu);
  app.add_option("--video", a.video, "also encode the frames into this video with ffmpeg")
      ->type_name("FILE.mp4")
      ->check(output_file());
  app.add_option("--fps", a.fps, "frames per second of --video (default 12)")
      ->type_name("FPS")
      ->check(CLI::Range(1.0, 240.0));
  app.add_flag("--onto-existing", a.onto_existing, "paint even where the canvas holds paint");
  app.add_option("--timeout", a.timeout_s, "how long to wait for each frame's strokes (default 120)")
      ->type_name("SECONDS")
      ->transform(positive());
  add_cull_and_quiet_flags(app, a.gpu, "trace rays through the empty canvas too");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  if (a.out.empty()) return usage_error(app, "--out FILE.png is required");
  if (a.generated == !a.painting.empty()) return usage_error(app, "give a FILE.apa or --generated");
  if (a.every > 0 && a.every_seconds > 0) return usage_error(app, "--every or --every-seconds, not both");
  std::uint32_t width = 640, height = 360;
  parse_size(a.size, width, height);

  std::vector<protocol::Stroke> strokes;
  if (a.generated) {
    strokes = generated_scene();
  } else {
    auto apa = paintings::read_apa_file(a.painting, {});
    if (!apa) return cli::fail(app, apa.error().message);
    strokes = std::move(apa->strokes);
  }
  if (strokes.empty()) return cli::fail(app, "the painting has no strokes");
  const auto ends = frame_ends(strokes, a);
  const std::size_t frames = static_cast<std::size_t>(std::count(ends.begin(), ends.end(), true));

  // The camera: the finished painting framed (or --camera), orbiting its target.
  const client_core::DAabb box = strokes_box(strokes);
  DVec3 target = (box.min + box.max) * 0.5;
  DVec3 up{0, 1, 0};
  Result<client_core::Camera> cam0 = make_error(Errc::internal, "no camera");
  if (!a.camera.spec.empty()) {
    cam0 = make_camera(a.camera, width, height);
    if (!cam0) return usage_error(app, cam0.error().message);
    target = parse_camera_spec(a.camera.spec)->target;
    up = *parse_up(a.camera.up);
  } else {
    cam0 = client_core::Camera::fit_box(box, width, height, kDefaultFovDeg, {-0.45, -0.35, -0.82}, up);
    if (!cam0) return cli::fail(app, "framing the painting: " + cam0.error().message);
  }
  const DVec3 off = cam0->position() - target;
  const DVec3 along = up * client_core::dot(off, up), radial = off - along;
  const DVec3 side = client_core::cross(up, radial);
  const double fov = cam0->vfov_rad() * 180.0 / kPi;

  auto ctx = client_gpu::ContextBuilder().app_name("deepcanvas-client timelapse").device(a.gpu.device).build();
  if (!ctx) return cli::fail(app, "Vulkan: " + ctx.error().message);
  auto opts = client_options(a.connect, protocol::Role::painter, "deepcanvas-client timelapse");
  auto client = client_core::Client::connect(opts);
  if (!client)
    return cli::fail(app, "cannot join canvas '" + opts.canvas + "' at " + a.connect.url + ": " +
                              client.error().message);
  auto& c = **client;
  if (auto up_to_date = catch_up(c, opts.canvas, a.timeout_s, true); !up_to_date)
    return cli::fail(app, "waiting for the canvas: " + up_to_date.error().message);
  bool painted = false;
  c.with_replica([&](const client_core::Replica& r) {
    auto b = client_core::painted_bounds(r.view());
    painted = b && b->has_value();
  });
  if (painted && !a.onto_existing)
    return cli::fail(app, "canvas '" + opts.canvas + "' already holds paint: the time-lapse would "
                          "show it from the first frame (use an empty canvas, or --onto-existing)");
  auto replica = client_gpu::GpuReplica::create(**ctx, client_gpu::replica_config_for(c.welcome()));
  if (!replica) return cli::fail(app, "GPU replica: " + replica.error().message);
  auto raycaster = client_gpu::GpuRaycaster::create(**replica);
  if (!raycaster) return cli::fail(app, "ray caster: " + raycaster.error().message);
  client_core::RenderOptions ro;
  ro.background = {0.05, 0.06, 0.08};

  base::Progress progress("timelapse", static_cast<double>(frames), "frames", !a.gpu.quiet);
  const auto timeout = std::chrono::milliseconds(static_cast<std::int64_t>(a.timeout_s * 1000));
  std::size_t frame = 0;
  std::optional<std::uint64_t> last_handle;
  for (std::size_t i = 0; i < strokes.size(); ++i) {
    auto h = c.send_stroke(strokes[i]);
    if (!h) return cli::fail(app, "sending stroke " + std::to_string(i + 1) + ": " + h.error().message);
    last_handle = *h;
    if (!ends[i]) continue;
    // The frame shows every stroke sent so far: the last one's ack, then its epoch in the replica.
    auto ack = c.wait_for_ack(*last_handle, timeout);
    if (!ack) return cli::fail(app, "stroke " + std::to_string(i + 1) + ": " + ack.error().message);
    if (auto e = c.wait_for_epoch(ack->epoch, timeout); !e)
      return cli::fail(app, "waiting for epoch " + std::to_string(ack->epoch) + ": " + e.error().message);
    const double angle = a.orbit_deg * kPi / 180.0 * static_cast<double>(frame);
    const DVec3 eye = target + along + radial * std::cos(angle) + side * std::sin(angle);
    auto cam = client_core::Camera::look_at(eye, target, up, fov, width, height);
    if (!cam) return cli::fail(app, "camera: " + cam.error().message);
    Result<client_core::RayOrigin> origin = make_error(Errc::internal, "the replica was not read");
    Result<void> uploaded = make_error(Errc::internal, "the replica was not read");
    c.with_replica([&](const client_core::Replica& r) {
      uploaded = (*replica)->upload_all(r.view());
      if (uploaded) uploaded = (*replica)->compute_all_links(r.view());
      if (uploaded && !a.gpu.no_cull) {
        auto b = client_core::painted_bounds(r.view());
        if (b && *b) ro.content_bounds = **b;
      }
      origin = client_core::make_ray_origin(r.view(), eye);
    });
    if (!uploaded) return cli::fail(app, "GPU upload: " + uploaded.error().message);
    if (!origin) return cli::fail(app, "ray origin: " + origin.error().message);
    auto pixels = (*raycaster)->render_rgba8(*cam, *origin, ro);
    if (!pixels) return cli::fail(app, "rendering: " + pixels.error().message);
    for (std::size_t p = 3; p < pixels->size(); p += 4) (*pixels)[p] = 255;
    if (auto w = client_gpu::write_png(frame_path(a.out, frame), width, height, *pixels); !w)
      return cli::fail(app, w.error().message);
    ++frame;
    progress.update(static_cast<double>(frame));
  }
  std::printf("wrote %zu time-lapse frames of %zu strokes: %s .. %s (%ux%u)\n", frame,
              strokes.size(), frame_path(a.out, 0).c_str(), frame_path(a.out, frame - 1).c_str(),
              width, height);
  if (!a.video.empty()) {
    if (auto v = make_video(a.out, a.video, a.fps); !v) return cli::fail(app, v.error().message);
    std::printf("wrote %s (%zu frames at %.0f fps)\n", a.video.c_str(), frame, a.fps);
  }
  c.close();
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("timelapse",
                          "paint a painting into a canvas, rendering a frame every K strokes",
                          run_timelapse);

}  // namespace deepcanvas::client_app
