// deepcanvas-client render: joins a canvas, waits until its replica has caught up with the
// server's epoch at join, uploads the replica to the GPU, computes G3 links there, ray-casts one
// frame and writes it as a PNG.
#include <array>
#include <bit>
#include <chrono>
#include <cstdio>
#include <optional>
#include <string>

#include "camera_options.hpp"
#include "cli_options.hpp"
#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/png.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/replica_gpu.hpp"

namespace deepcanvas::client_app {

namespace {

namespace cli = deepcanvas::base::cli;
using Clock = std::chrono::steady_clock;

constexpr const char* kDescription =
    "Joins a canvas as a viewer, waits until its replica has caught up with the server's\n"
    "epoch at join (progress on stderr), ray-casts one frame on the Vulkan device and writes a\n"
    "PNG. The camera it used goes to stderr as --camera/--up arguments, to paste back.\n";

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

int run_render(int argc, char** argv) {
  ConnectArgs connect;
  CameraArgs camera_args;
  std::string out, size = "960x540", background, device;
  std::uint32_t width = 960, height = 540;
  double timeout_s = 120;
  bool no_cull = false, quiet = false;
  client_core::RenderOptions options;
  options.background = {0.05, 0.06, 0.08};

  CLI::App app{kDescription, "deepcanvas-client render"};
  cli::standard(app, kExamples);
  add_connect_options(app, connect);
  app.add_option("--out", out, "where to write the image, required (its folder must exist)")
      ->type_name("FILE.png")
      ->check(output_file());
  app.add_option("--size", size, "image size in pixels (default 960x540)")
      ->type_name("WxH")
      ->check(image_size());
  add_camera_options(app, camera_args,
                     "frame the painted content from the front (+z), slightly above, with +y up.");
  app.add_option("--device", device, "Vulkan device (default: see `deepcanvas-client devices`)")
      ->type_name("I|NAME");
  app.add_option("--background", background, "background colour in 0..1 (default 0.05,0.06,0.08)")
      ->type_name("R,G,B")
      ->check(rgb());
  app.add_option("--timeout", timeout_s, "how long to wait for the canvas (default 120)")
      ->type_name("SECONDS")
      ->transform(positive());
  app.add_flag("--no-cull", no_cull,
               "trace rays through the empty canvas too (by default rays skip what lies outside "
               "the painted content's box: the same image, faster; this is for comparison)");
  app.add_flag("--quiet", quiet, "no progress on stderr");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  // Checked here rather than with CLI11's required(), which would report a missing --out before
  // a misspelt option.
  if (out.empty()) return usage_error(app, "--out FILE.png is required");
  auto fail = [&](const char* what, const Error& e) {
    return cli::fail(app, std::string(what) + ": " + e.message);
  };
  const bool cull = !no_cull;
  parse_size(size, width, height);
  if (!background.empty()) options.background = *parse_triple(background);
  // The camera before anything connects, so that a mistake fails fast.
  std::optional<client_core::Camera> camera;
  if (!camera_args.spec.empty()) {
    auto cam = make_camera(camera_args, width, height);
    if (!cam) return usage_error(app, cam.error().message);
    camera = *cam;
  }

  // The Vulkan device first: without one there is nothing to render with.
  auto ctx =
      client_gpu::ContextBuilder().app_name("deepcanvas-client render").device(device).build();
  if (!ctx) return fail("Vulkan", ctx.error());

  const auto opts = client_options(connect, protocol::Role::viewer, "deepcanvas-client render");
  const auto t0 = Clock::now();
  auto client = client_core::Client::connect(opts);
  if (!client)
    return cli::fail(app, "cannot join canvas '" + opts.canvas + "' at " + connect.url + ": " +
                              client.error().message);
  auto& c = **client;
  const auto& welcome = c.welcome();
  if (auto caught_up = catch_up(c, opts.canvas, timeout_s, quiet); !caught_up)
    return fail("waiting for the canvas", caught_up.error());
  const auto t_caught_up = Clock::now();

  client_gpu::GpuReplicaConfig cfg;
  cfg.width_log2 = static_cast<std::uint32_t>(std::countr_zero(welcome.texture_width));
  cfg.block_log2 = static_cast<std::uint32_t>(std::countr_zero(welcome.block_cells));
  cfg.roots_per_axis = welcome.geometry.roots_per_axis;
  cfg.edge_m = welcome.geometry.edge_m;
  cfg.max_depth = welcome.geometry.max_depth;
  auto replica = client_gpu::GpuReplica::create(**ctx, cfg);
  if (!replica) return fail("GPU replica", replica.error());

  Result<void> status;
  std::optional<client_core::DVec3> target;  // where the default camera looks
  client_core::RayOrigin origin;
  std::uint64_t cells = 0;
  bool empty = false;
  c.with_replica([&](const client_core::Replica& r) {
    const auto view = r.view();
    cells = view.cell_count();
    if (auto u = (*replica)->upload_all(view); !u) {
      status = std::move(u).error();
      return;
    }
    if (auto l = (*replica)->compute_all_links(view); !l) {
      status = std::move(l).error();
      return;
    }
    // The painted content's box: the content cull (the same image, rays skip the empty canvas
    // around it) and, without --camera, the framing.
    auto bounds = client_core::painted_bounds(view);
    if (!bounds) {
      status = std::move(bounds).error();
      return;
    }
    if (cull && *bounds) options.content_bounds = **bounds;
    if (!camera) {
      client_core::DAabb box;
      if (*bounds) {
        box = **bounds;
      } else {
        empty = true;  // nothing painted: look at the canvas centre
        box = {{-1, -1, -1}, {1, 1, 1}};
      }
      // Paintings are y-up (A-Painter's convention); look from the front, slightly above, at
      // the painted leaves themselves (their box's corners can lie far outside the painting).
      auto cam = empty ? client_core::Camera::fit_box(box, width, height, kDefaultFovDeg,
                                                      {-0.45, -0.35, -0.82}, {0, 1, 0})
                       : client_core::fit_painted(view, width, height, kDefaultFovDeg,
                                                  {-0.45, -0.35, -0.82}, {0, 1, 0});
      if (!cam) {
        status = std::move(cam).error();
        return;
      }
      camera = *cam;
      target = target_on_ray(*camera, box);
    }
    auto o = client_core::make_ray_origin(view, camera->position());
    if (!o) {
      status = std::move(o).error();
      return;
    }
    origin = *o;
  });
  if (!status) return fail("preparing the frame", status.error());
  if (target) {
    std::fprintf(stderr, "%s: camera %s\n", app.get_name().c_str(),
                 camera_arguments(*camera, *target, "+y").c_str());
  } else {
    std::fprintf(stderr, "%s: camera %s\n", app.get_name().c_str(),
                 camera_arguments(*camera, parse_camera_spec(camera_args.spec)->target,
                                  camera_args.up)
                     .c_str());
  }

  auto raycaster = client_gpu::GpuRaycaster::create(**replica);
  if (!raycaster) return fail("ray caster", raycaster.error());
  const auto t_render = Clock::now();
  auto pixels = (*raycaster)->render_rgba8(*camera, origin, options);
  if (!pixels) return fail("rendering", pixels.error());
  const auto t_done = Clock::now();
  // The frame is composited over the background: store it opaque (alpha is the volume's own
  // opacity, which an image viewer would otherwise blend with its own background).
  for (std::size_t i = 3; i < pixels->size(); i += 4) (*pixels)[i] = 255;
  if (auto w = client_gpu::write_png(out, width, height, *pixels); !w)
    return cli::fail(app, w.error().message);

  auto ms = [](auto a, auto b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
  if (empty)
    std::fprintf(stderr, "%s: the canvas is empty; the image shows only background\n",
                 app.get_name().c_str());
  std::printf(
      "wrote %s (%ux%u) of canvas '%s' at epoch %llu: %llu cells; joined and caught up in "
      "%.0f ms, frame %.0f ms on %s%s\n",
      out.c_str(), width, height, opts.canvas.c_str(),
      static_cast<unsigned long long>(c.applied_epoch()), static_cast<unsigned long long>(cells),
      ms(t0, t_caught_up), ms(t_render, t_done), (*ctx)->info().name.c_str(),
      cull ? "" : " (no content cull)");
  c.close();
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("render", "join a canvas, ray-cast one frame on the GPU, write a PNG",
                          run_render);

}  // namespace deepcanvas::client_app
