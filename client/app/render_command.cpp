// deepcanvas-client render: joins a canvas, waits until its replica has caught up with the
// server's epoch at join, uploads the replica to the GPU, computes G3 links there, ray-casts one
// frame and writes it as a PNG.
#include <array>
#include <bit>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <string>

#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/png.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/replica_gpu.hpp"

namespace deepcanvas::client_app {

namespace {

using Clock = std::chrono::steady_clock;

void render_usage(FILE* out) {
  std::fprintf(
      out,
      "usage: deepcanvas-client render [--connect URL] --out FILE.png [--size WxH]\n"
      "                                [--camera EX,EY,EZ,TX,TY,TZ[,FOV]] [--device I|NAME]\n"
      "                                [--background R,G,B] [--timeout SECONDS] [--no-cull]\n\n"
      "Joins a canvas as a viewer, waits until its replica has caught up with the server's\n"
      "epoch at join, ray-casts one frame on the Vulkan device and writes a PNG.\n\n"
      "%s"
      "  --out FILE.png     where to write the image (required)\n"
      "  --size WxH         image size in pixels (default 960x540)\n"
      "  --camera SPEC      eye and target in canvas metres, optional vertical field of\n"
      "                     view in degrees (default: frame the painted content)\n"
      "  --device I|NAME    Vulkan device (default: see `deepcanvas-client devices`)\n"
      "  --background R,G,B background colour in 0..1 (default 0.05,0.06,0.08)\n"
      "  --timeout SECONDS  how long to wait for the canvas (default 120)\n"
      "  --no-cull          trace rays through the empty canvas too (by default rays skip\n"
      "                     what lies outside the painted content's box: the same image,\n"
      "                     faster; this is for comparison)\n",
      kConnectHelp);
}

bool parse_size(const std::string& s, std::uint32_t& w, std::uint32_t& h) {
  unsigned a = 0, b = 0;
  char tail = 0;
  if (std::sscanf(s.c_str(), "%ux%u%c", &a, &b, &tail) != 2) return false;
  if (a < 1 || b < 1 || a > 8192 || b > 8192) return false;
  w = a;
  h = b;
  return true;
}

bool parse_rgb(const std::string& s, std::array<double, 3>& rgb) {
  double v[3];
  char tail = 0;
  if (std::sscanf(s.c_str(), "%lf,%lf,%lf%c", &v[0], &v[1], &v[2], &tail) != 3) return false;
  for (int i = 0; i < 3; ++i) {
    if (!(v[i] >= 0 && v[i] <= 1)) return false;
    rgb[i] = v[i];
  }
  return true;
}

int fail(const char* what, const Error& e) {
  std::fprintf(stderr, "render: %s: %s\n", what, e.message.c_str());
  return 1;
}

int run_render(int argc, char** argv) {
  ConnectArgs connect;
  std::string out, camera_spec, device;
  std::uint32_t width = 960, height = 540;
  double timeout_s = 120;
  bool cull = true;
  client_core::RenderOptions options;
  options.background = {0.05, 0.06, 0.08};
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto shared = parse_connect_option(argc, argv, i, connect);
    if (!shared) {
      std::fprintf(stderr, "render: %s\n", shared.error().message.c_str());
      return 2;
    }
    if (*shared) continue;
    if (a == "-h" || a == "--help") {
      render_usage(stdout);
      return 0;
    }
    if (a == "--no-cull") {
      cull = false;
      continue;
    }
    if (a != "--out" && a != "--size" && a != "--camera" && a != "--device" &&
        a != "--background" && a != "--timeout") {
      std::fprintf(stderr, "render: unknown option '%s'\n\n", a.c_str());
      render_usage(stderr);
      return 2;
    }
    if (i + 1 >= argc) {
      std::fprintf(stderr, "render: %s needs a value\n", a.c_str());
      return 2;
    }
    const std::string v = argv[++i];
    if (a == "--out") {
      out = v;
    } else if (a == "--size") {
      if (!parse_size(v, width, height)) {
        std::fprintf(stderr, "render: --size must be WxH with 1..8192 each, got '%s'\n", v.c_str());
        return 2;
      }
    } else if (a == "--camera") {
      camera_spec = v;
    } else if (a == "--device") {
      device = v;
    } else if (a == "--background") {
      if (!parse_rgb(v, options.background)) {
        std::fprintf(stderr, "render: --background must be R,G,B in 0..1, got '%s'\n", v.c_str());
        return 2;
      }
    } else if (a == "--timeout") {
      timeout_s = std::atof(v.c_str());
      if (!(timeout_s > 0)) {
        std::fprintf(stderr, "render: --timeout must be a positive number of seconds\n");
        return 2;
      }
    }
  }
  if (out.empty()) {
    std::fprintf(stderr, "render: --out FILE.png is required\n\n");
    render_usage(stderr);
    return 2;
  }
  // Check the camera before connecting, so a typo fails fast.
  if (!camera_spec.empty()) {
    if (auto c = client_core::Camera::parse(camera_spec, width, height); !c)
      return fail("--camera", c.error());
  }

  // The Vulkan device first: without one there is nothing to render with.
  auto ctx =
      client_gpu::ContextBuilder().app_name("deepcanvas-client render").device(device).build();
  if (!ctx) return fail("Vulkan", ctx.error());

  auto opts = client_options(connect, protocol::Role::viewer, "deepcanvas-client render");
  if (!opts) return fail("--connect", opts.error());
  const auto t0 = Clock::now();
  auto client = client_core::Client::connect(*opts);
  if (!client) {
    std::fprintf(stderr, "render: cannot join canvas '%s' at %s: %s\n", opts->canvas.c_str(),
                 connect.url.c_str(), client.error().message.c_str());
    return 1;
  }
  auto& c = **client;
  const auto& welcome = c.welcome();
  const auto join_epoch = welcome.epoch;
  auto caught_up = c.wait_for_epoch(
      join_epoch, std::chrono::milliseconds(static_cast<std::int64_t>(timeout_s * 1000)));
  if (!caught_up) return fail("waiting for the canvas", caught_up.error());
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
  std::optional<client_core::Camera> camera;
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
    if (!camera_spec.empty()) {
      camera = *client_core::Camera::parse(camera_spec, width, height);
    } else {
      client_core::DAabb box;
      if (*bounds) {
        box = **bounds;
      } else {
        empty = true;  // nothing painted: look at the canvas centre
        box = {{-1, -1, -1}, {1, 1, 1}};
      }
      // Paintings are y-up (A-Painter's convention); look from the front, slightly above, at
      // the painted leaves themselves (their box's corners can lie far outside the painting).
      auto cam = empty ? client_core::Camera::fit_box(box, width, height, 45.0,
                                                      {-0.45, -0.35, -0.82}, {0, 1, 0})
                       : client_core::fit_painted(view, width, height, 45.0, {-0.45, -0.35, -0.82},
                                                  {0, 1, 0});
      if (!cam) {
        status = std::move(cam).error();
        return;
      }
      camera = *cam;
    }
    auto o = client_core::make_ray_origin(view, camera->position());
    if (!o) {
      status = std::move(o).error();
      return;
    }
    origin = *o;
  });
  if (!status) return fail("preparing the frame", status.error());

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
    return fail(out.c_str(), w.error());

  auto ms = [](auto a, auto b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
  if (empty) std::fprintf(stderr, "render: the canvas is empty; the image shows only background\n");
  std::printf(
      "wrote %s (%ux%u) of canvas '%s' at epoch %llu: %llu cells; joined and caught up in "
      "%.0f ms, frame %.0f ms on %s%s\n",
      out.c_str(), width, height, opts->canvas.c_str(),
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
