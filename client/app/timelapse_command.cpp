// deepcanvas-client timelapse: renders a canvas's history every K strokes (or every T seconds of
// the artists' painting time) from a fixed or orbiting camera: a PNG sequence, and a video where
// ffmpeg is installed. The history is a painting this client paints into an empty canvas, or a
// recorded history a playback server paints forward step by step (serve --playback,
// PROTOCOL.md 3.13).
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
    "Renders a canvas's history after every K strokes (--every) or every T seconds of painting\n"
    "time (--every-seconds): OUT_0000.png, OUT_0001.png, ... and, with --video, a video of them\n"
    "made by ffmpeg where it is installed. The camera frames the whole finished history from\n"
    "the first frame on (or --camera), fixed or orbiting (--orbit degrees per frame).\n"
    "\n"
    "The history is either\n"
    "  a painting (FILE.apa or --generated): its strokes are painted into an empty canvas in the\n"
    "    artist's order (painting time from the samples' timestamps); a canvas that holds paint\n"
    "    is refused unless --onto-existing; or\n"
    "  --playback: a recorded history (a data directory's canvas, a stroke log) that a server\n"
    "    started with `deepcanvas-server serve --playback SOURCE` paints forward as this command\n"
    "    steps it (painting time from the history's wall clock). Undos and imports count as\n"
    "    strokes. A playback goes forward only: restart its server to play it again.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-server serve --in-memory --listen 127.0.0.1:7979 &\n"
    "  deepcanvas-client timelapse demo.apa --connect ws://127.0.0.1:7979/default \\\n"
    "      --out frames/demo.png --every 2 --orbit 3 --video demo.mp4\n"
    "  deepcanvas-client timelapse mozfest.apa --every-seconds 10 --out frames/mozfest.png\n"
    "  deepcanvas-server serve --playback deepcanvas-data/main --listen 127.0.0.1:7900 &\n"
    "  deepcanvas-client timelapse --playback --connect ws://127.0.0.1:7900/main \\\n"
    "      --every-seconds 60 --out frames/main.png --video main.mp4\n";

struct Args {
  ConnectArgs connect;
  CameraArgs camera;
  GpuViewArgs gpu;
  std::string painting, out, video, size = "640x360";
  bool generated = false, onto_existing = false, playback = false;
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

// The camera (framing `box`, or --camera; orbiting its target) and the GPU renderer, shared by
// both kinds of history: render() draws the replica as it stands into the next frame's PNG.
class FrameWriter {
 public:
  static Result<FrameWriter> create(const Args& a, const client_core::DAabb& box,
                                    const protocol::Welcome& welcome) {
    FrameWriter w;
    w.a_ = &a;
    parse_size(a.size, w.width_, w.height_);
    w.target_ = (box.min + box.max) * 0.5;
    Result<client_core::Camera> cam0 = make_error(Errc::internal, "no camera");
    if (!a.camera.spec.empty()) {
      cam0 = make_camera(a.camera, w.width_, w.height_);
      if (!cam0) return make_error(Errc::invalid_argument, cam0.error().message);
      w.target_ = parse_camera_spec(a.camera.spec)->target;
      w.up_ = *parse_up(a.camera.up);
    } else {
      cam0 = client_core::Camera::fit_box(box, w.width_, w.height_, kDefaultFovDeg,
                                          {-0.45, -0.35, -0.82}, w.up_);
      if (!cam0) return Error{cam0.error().code, "framing the history: " + cam0.error().message};
    }
    const DVec3 off = cam0->position() - w.target_;
    w.along_ = w.up_ * client_core::dot(off, w.up_);
    w.radial_ = off - w.along_;
    w.side_ = client_core::cross(w.up_, w.radial_);
    w.fov_ = cam0->vfov_rad() * 180.0 / kPi;
    auto ctx = client_gpu::ContextBuilder().app_name("deepcanvas-client timelapse").device(a.gpu.device).build();
    if (!ctx) return Error{ctx.error().code, "Vulkan: " + ctx.error().message};
    w.ctx_ = std::move(*ctx);
    auto replica = client_gpu::GpuReplica::create(*w.ctx_, client_gpu::replica_config_for(welcome));
    if (!replica) return Error{replica.error().code, "GPU replica: " + replica.error().message};
    w.replica_ = std::move(*replica);
    auto raycaster = client_gpu::GpuRaycaster::create(*w.replica_);
    if (!raycaster) return Error{raycaster.error().code, "ray caster: " + raycaster.error().message};
    w.raycaster_ = std::move(*raycaster);
    w.ro_.background = {0.05, 0.06, 0.08};
    return w;
  }

  Result<void> render(client_core::Client& c) {
    const double angle = a_->orbit_deg * kPi / 180.0 * static_cast<double>(frames_);
    const DVec3 eye = target_ + along_ + radial_ * std::cos(angle) + side_ * std::sin(angle);
    auto cam = client_core::Camera::look_at(eye, target_, up_, fov_, width_, height_);
    if (!cam) return Error{cam.error().code, "camera: " + cam.error().message};
    Result<client_core::RayOrigin> origin = make_error(Errc::internal, "the replica was not read");
    Result<void> uploaded = make_error(Errc::internal, "the replica was not read");
    c.with_replica([&](const client_core::Replica& r) {
      uploaded = replica_->upload_all(r.view());
      if (uploaded) uploaded = replica_->compute_all_links(r.view());
      if (uploaded && !a_->gpu.no_cull) {
        auto b = client_core::painted_bounds(r.view());
        if (b && *b) ro_.content_bounds = **b;
      }
      origin = client_core::make_ray_origin(r.view(), eye);
    });
    if (!uploaded) return Error{uploaded.error().code, "GPU upload: " + uploaded.error().message};
    if (!origin) return Error{origin.error().code, "ray origin: " + origin.error().message};
    auto pixels = raycaster_->render_rgba8(*cam, *origin, ro_);
    if (!pixels) return Error{pixels.error().code, "rendering: " + pixels.error().message};
    for (std::size_t p = 3; p < pixels->size(); p += 4) (*pixels)[p] = 255;
    if (auto w = client_gpu::write_png(frame_path(a_->out, frames_), width_, height_, *pixels); !w)
      return w;
    ++frames_;
    return {};
  }

  std::size_t frames() const noexcept { return frames_; }
  std::uint32_t width() const noexcept { return width_; }
  std::uint32_t height() const noexcept { return height_; }

 private:
  const Args* a_ = nullptr;
  std::uint32_t width_ = 640, height_ = 360;
  DVec3 target_, up_{0, 1, 0}, along_, radial_, side_;
  double fov_ = 45;
  std::unique_ptr<client_gpu::Context> ctx_;
  std::unique_ptr<client_gpu::GpuReplica> replica_;
  std::unique_ptr<client_gpu::GpuRaycaster> raycaster_;
  client_core::RenderOptions ro_;
  std::size_t frames_ = 0;
};

// Connects (a painter to paint, a viewer to watch a playback) and waits for the snapshot.
Result<std::unique_ptr<client_core::Client>> join(const Args& a, protocol::Role role) {
  auto opts = client_options(a.connect, role, "deepcanvas-client timelapse");
  auto client = client_core::Client::connect(opts);
  if (!client)
    return Error{client.error().code, "cannot join canvas '" + opts.canvas + "' at " +
                                          a.connect.url + ": " + client.error().message};
  if (auto up_to_date = catch_up(**client, opts.canvas, a.timeout_s, true); !up_to_date)
    return Error{up_to_date.error().code, "waiting for the canvas: " + up_to_date.error().message};
  return client;
}

std::chrono::milliseconds timeout_of(const Args& a) {
  return std::chrono::milliseconds(static_cast<std::int64_t>(a.timeout_s * 1000));
}

// A painting's history: its strokes sent one after another, a frame after each frame's last
// stroke is acked and its epoch is in the replica.
int paint_and_render(CLI::App& app, const Args& a) {
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
  auto client = join(a, protocol::Role::painter);
  if (!client) return cli::fail(app, client.error().message);
  auto& c = **client;
  bool painted = false;
  c.with_replica([&](const client_core::Replica& r) {
    auto b = client_core::painted_bounds(r.view());
    painted = b && b->has_value();
  });
  if (painted && !a.onto_existing)
    return cli::fail(app, "canvas '" + c.welcome().canvas + "' already holds paint: the time-lapse "
                          "would show it from the first frame (use an empty canvas, or --onto-existing)");
  auto writer = FrameWriter::create(a, strokes_box(strokes), c.welcome());
  if (!writer)
    return writer.error().code == Errc::invalid_argument ? usage_error(app, writer.error().message)
                                                          : cli::fail(app, writer.error().message);
  base::Progress progress("timelapse", static_cast<double>(frames), "frames", !a.gpu.quiet);
  const auto timeout = timeout_of(a);
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
    if (auto r = writer->render(c); !r) return cli::fail(app, r.error().message);
    progress.update(static_cast<double>(writer->frames()));
  }
  std::printf("wrote %zu time-lapse frames of %zu strokes: %s .. %s (%ux%u)\n", writer->frames(),
              strokes.size(), frame_path(a.out, 0).c_str(),
              frame_path(a.out, writer->frames() - 1).c_str(), writer->width(), writer->height());
  c.close();
  return -1;
}

// A recorded history on a playback server: stepped by strokes or painting time, a frame after
// each step once the step's epoch is in the replica.
int play_and_render(CLI::App& app, const Args& a) {
  auto client = join(a, protocol::Role::viewer);
  if (!client) return cli::fail(app, client.error().message);
  auto& c = **client;
  const auto timeout = timeout_of(a);
  auto step = [&](std::uint64_t strokes, double seconds) -> Result<protocol::PlaybackPosition> {
    protocol::PlaybackStep m;
    m.strokes = strokes;
    m.seconds = seconds;
    auto id = c.request_playback_step(m);
    if (!id) return std::move(id).error();
    auto pos = c.wait_for_playback(*id, timeout);
    if (!pos) return std::move(pos).error();
    if (auto e = c.wait_for_epoch(pos->epoch, timeout); !e) return std::move(e).error();
    return pos;
  };
  auto start = step(0, 0);
  if (!start) return cli::fail(app, "canvas '" + c.welcome().canvas + "': " + start.error().message);
  if (start->events > 0)
    return cli::fail(app, "the playback already stands at event " + std::to_string(start->events) +
                              " of " + std::to_string(start->events_total) +
                              " (another client stepped it): restart its server to play it from "
                              "the start");
  if (!start->bounds) return cli::fail(app, "the history paints nothing");
  if (a.every_seconds > 0 && !start->timed)
    return cli::fail(app, "this history has no painting times: use --every N strokes");
  const std::uint64_t every =
      a.every > 0 ? a.every : std::max<std::uint64_t>(1, start->strokes_total / 60);
  const auto& b = *start->bounds;
  auto writer = FrameWriter::create(a, client_core::DAabb{{b[0], b[1], b[2]}, {b[3], b[4], b[5]}},
                                    c.welcome());
  if (!writer)
    return writer.error().code == Errc::invalid_argument ? usage_error(app, writer.error().message)
                                                          : cli::fail(app, writer.error().message);
  base::Progress progress("timelapse", static_cast<double>(start->events_total), "events",
                          !a.gpu.quiet);
  protocol::PlaybackPosition pos = *start;
  while (pos.events < pos.events_total) {
    auto next = a.every_seconds > 0 ? step(0, a.every_seconds) : step(every, 0);
    if (!next) return cli::fail(app, "playback step: " + next.error().message);
    if (next->events == pos.events) return cli::fail(app, "the playback did not move: stopped");
    pos = *next;
    if (auto r = writer->render(c); !r) return cli::fail(app, r.error().message);
    progress.update(static_cast<double>(pos.events));
  }
  std::printf("wrote %zu time-lapse frames of %llu strokes (%.0f s of painting): %s .. %s (%ux%u)\n",
              writer->frames(), static_cast<unsigned long long>(pos.strokes_total),
              pos.painting_seconds_total, frame_path(a.out, 0).c_str(),
              frame_path(a.out, writer->frames() - 1).c_str(), writer->width(), writer->height());
  c.close();
  return writer->frames() == 0 ? cli::fail(app, "the history has no events") : -1;
}

int run_timelapse(int argc, char** argv) {
  Args a;
  CLI::App app{kDescription, "deepcanvas-client timelapse"};
  cli::standard(app, kExamples);
  add_connect_options(app, a.connect);
  app.add_option("PAINTING", a.painting, "the painting whose history to render (or --generated)")
      ->type_name("FILE.apa");
  app.add_flag("--generated", a.generated, "the project's generated scene instead of a file");
  app.add_flag("--playback", a.playback,
               "step the history a playback server plays back (serve --playback) instead");
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
  const int sources = (a.generated ? 1 : 0) + (a.painting.empty() ? 0 : 1) + (a.playback ? 1 : 0);
  if (sources != 1) return usage_error(app, "give one of FILE.apa, --generated or --playback");
  if (a.every > 0 && a.every_seconds > 0) return usage_error(app, "--every or --every-seconds, not both");
  if (a.playback && a.onto_existing) return usage_error(app, "--onto-existing paints: not with --playback");
  const int rc = a.playback ? play_and_render(app, a) : paint_and_render(app, a);
  if (rc >= 0) return rc;
  if (!a.video.empty()) {
    if (auto v = make_video(a.out, a.video, a.fps); !v) return cli::fail(app, v.error().message);
    std::printf("wrote %s at %.0f fps\n", a.video.c_str(), a.fps);
  }
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("timelapse",
                          "render a history every K strokes: a painting, or a playback server's",
                          run_timelapse);

}  // namespace deepcanvas::client_app
