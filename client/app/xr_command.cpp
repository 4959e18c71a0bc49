// deepcanvas-client xr: the headset client, a real OpenXR application. It joins a canvas as a
// painter, streams it into a GPU replica on the Vulkan device the OpenXR runtime drives, and
// runs the runtime's frame loop: both eyes ray cast from the runtime's view poses (scaled and
// placed in the canvas by the artist's world scale) into the runtime's swapchains, a stereo
// projection layer a frame; strokes painted with a tracked controller (samples from its tip,
// the trigger as pressure) and the world scaled and moved with a two-handed grab. Where the
// runtime has no controllers, --pose-trace supplies the controller tip, the trigger and the
// world scale (the same scripted input path the headless runs use).
// The frame loop runs from the start: frames go to the runtime (without layers) while the canvas
// streams in, the first picture as soon as part of its snapshot is resident (a progressive join:
// coarse first, finer as blocks arrive), never after the whole of a large canvas.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "cli_options.hpp"
#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/percentile.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_core/pose_trace.hpp"
#include "deepcanvas/client_core/stereo.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/xr/xr_session.hpp"

namespace deepcanvas::client_app {
namespace {

namespace cli = deepcanvas::base::cli;
using client_core::DVec3;
using Clock = std::chrono::steady_clock;

constexpr const char* kDescription =
    "The headset client: joins a canvas as a painter and renders it in an OpenXR headset, both\n"
    "eyes ray cast from the runtime's view poses into its swapchains (XR_KHR_vulkan_enable2; the\n"
    "runtime picks the GPU). The artist's world scale places the room in the canvas: the\n"
    "runtime's eyes 63 mm apart are 63 mm x world scale apart in the canvas. Paint with a\n"
    "tracked controller (the aim pose's tip; the trigger is the pressure); hold both grips and\n"
    "move the hands apart or together to scale and move the world about them.\n"
    "\n"
    "The canvas shows as soon as part of it has arrived (coarse first, finer as the rest streams\n"
    "in). Without --world-scale its content is placed about 1.5 m across in front of you.\n"
    "--pose-trace FILE (deepcanvas-client pose-trace) drives the controller tip, the trigger and\n"
    "the world scale from a recorded motion where the runtime has no controllers (tests, demos).\n"
    "A clear error says so when no OpenXR runtime is installed. It runs until the runtime ends\n"
    "the session (or --frames N rendered frames), then prints a summary.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client xr --connect ws://127.0.0.1:7878/main\n"
    "  deepcanvas-client xr --connect ws://127.0.0.1:7878/main --frames 600 --pose-trace head.trace --json\n";

struct XrArgs {
  ConnectArgs connect;
  std::string pose_trace, colour = "0.9,0.35,0.2", world_origin;
  std::uint64_t frames = 0;
  double world_scale = 0, radius_mm = 8, timeout_s = 30, min_scale = 0.25, fixed_scale = 0;
  bool json = false, quiet = false;
};

// The painted content (`box`: the resident content's bounds when the canvas is first shown),
// placed 1.5 m across with its centre 1.2 m up and 1 m ahead of the room's origin (the
// pose-trace generator's placement); no content: life size at the canvas centre.
client_core::ArtistPose initial_pose(const XrArgs& a, const std::optional<client_core::DAabb>& box) {
  client_core::ArtistPose p;
  const DVec3 content_room{0, 1.2, -1.0};
  if (a.world_scale > 0) {
    p.world_scale = a.world_scale;
  } else if (box) {
    const DVec3 e = box->max - box->min;
    p.world_scale = std::max({e.x, e.y, e.z, 1e-6}) / 1.5;
  }
  DVec3 centre{0, 0, 0};
  if (box) centre = (box->min + box->max) * 0.5;
  p.world_origin = centre - content_room * p.world_scale;
  if (!a.world_origin.empty()) {
    const auto v = *parse_triple(a.world_origin);  // checked by the option's triple() validator
    p.world_origin = {v[0], v[1], v[2]};
  }
  return p;
}

// Seconds with millisecond precision, as JSON.
std::string seconds_json(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3f", s);
  return buf;
}

int run_xr(int argc, char** argv) {
  XrArgs a;
  CLI::App app{kDescription, "deepcanvas-client xr"};
  cli::standard(app, kExamples);
  add_connect_options(app, a.connect);
  add_batch_interval_option(app, a.connect);
  app.add_option("--frames", a.frames, "end the session after N rendered frames (default: run until the runtime ends it)")
      ->type_name("N");
  app.add_option("--pose-trace", a.pose_trace, "scripted controller tip, trigger and world scale")
      ->type_name("FILE");
  app.add_option("--world-scale", a.world_scale, "canvas metres per room metre (default: fit the content)")
      ->type_name("S")
      ->transform(positive());
  app.add_option("--world-origin", a.world_origin, "the canvas point at the room's origin")
      ->type_name("X,Y,Z")
      ->check(triple());
  app.add_option("--colour", a.colour, "brush colour R,G,B in 0..1 (default 0.9,0.35,0.2)")
      ->type_name("R,G,B")
      ->check(rgb());
  app.add_option("--radius-mm", a.radius_mm, "brush radius in the room (default 8 mm)")
      ->type_name("MM")
      ->transform(number(0.1, 1000));
  app.add_option("--timeout", a.timeout_s, "seconds to wait for the canvas and for acks (default 30)")
      ->type_name("S")
      ->transform(positive());
  app.add_option("--fixed-scale", a.fixed_scale,
                 "render each eye at this fraction of its swapchain size always (default: adapt "
                 "to the runtime's frame interval, down to --min-scale)")
      ->type_name("S")
      ->transform(number(0.05, 1));
  app.add_option("--min-scale", a.min_scale, "the lowest render scale when adapting (default 0.25)")
      ->type_name("S")
      ->transform(number(0.05, 1));
  app.add_flag("--json", a.json, "the summary as one JSON object on stdout");
  app.add_flag("--quiet", a.quiet, "no progress on stderr");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  protocol::Brush brush;
  const auto rgb_value = *parse_triple(a.colour);  // checked by the option's rgb() validator
  for (int c = 0; c < 3; ++c) brush.colour[c] = static_cast<float>(rgb_value[static_cast<std::size_t>(c)]);
  brush.colour[3] = 1.0f;
  std::optional<client_core::PoseTrace> trace;
  if (!a.pose_trace.empty()) {
    auto t = client_core::read_pose_trace_file(a.pose_trace);
    if (!t) return cli::fail(app, t.error().message);
    trace = std::move(*t);
  }

  auto headset = xr::XrHeadset::create("deepcanvas-client xr");
  if (!headset) return cli::fail(app, headset.error().message);
  auto& hs = **headset;
  const auto opts = client_options(a.connect, protocol::Role::painter, "deepcanvas-client xr");
  const Clock::time_point t_connect = Clock::now();
  auto client = client_core::Client::connect(opts);
  if (!client)
    return cli::fail(app, "cannot join canvas '" + opts.canvas + "' at " + a.connect.url + ": " +
                              client.error().message);
  auto& c = **client;
  auto streaming = client_gpu::StreamingReplica::create(hs.context(), client_gpu::replica_config_for(c.welcome()));
  if (!streaming) return cli::fail(app, "GPU replica: " + streaming.error().message);
  client_gpu::stream_client_into(c, **streaming);
  const auto timeout = std::chrono::milliseconds(static_cast<std::int64_t>(a.timeout_s * 1000));
  std::unique_ptr<client_gpu::GpuRaycaster> eyes[2];
  auto made = (*streaming)->with_gpu([&](const client_gpu::ResidentState& st) -> Result<void> {
    for (auto& e : eyes) {
      auto rc = client_gpu::GpuRaycaster::create(st.replica);
      if (!rc) return std::move(rc).error();
      e = std::move(*rc);
    }
    return {};
  });
  if (!made) {
    c.set_epoch_listener({});
    return cli::fail(app, "ray caster: " + made.error().message);
  }
  // Placed when the canvas is first shown (its content's bounds are known then).
  client_core::ArtistPose world = initial_pose(a, std::nullopt);
  client_core::RenderOptions ro;
  ro.background = {0.05, 0.06, 0.08};
  // Dynamic resolution (client_core::ResolutionController) against the runtime's frame interval.
  std::optional<client_core::ResolutionController> resolution;
  bool calibrated = false;  // the probe renders have set the starting scale
  std::vector<double> render_ms, scales;

  // The loop.
  std::uint64_t submitted = 0, rendered = 0, strokes_begun = 0, samples_sent = 0, grabs = 0;
  double eye_sep_room = 0, eye_sep_canvas = 0, scale_used = world.world_scale;
  std::vector<std::uint64_t> handles;
  bool stroke_open = false;  // a stroke is being painted: its handle is open_stroke
  std::uint64_t open_stroke = 0;
  bool exit_requested = false, grabbing = false;
  client_core::ArtistPose grab_start;
  DVec3 grab_left, grab_right;
  Result<void> failure;
  const Clock::time_point t0 = Clock::now();
  // Shown: part of the snapshot or more is resident; the scripted input's clock starts then.
  bool shown = false;
  Clock::time_point t_shown{};
  double first_picture_s = 0, whole_canvas_s = 0;  // connect -> shown; -> the snapshot whole
  for (;;) {
    auto alive = hs.poll();
    if (!alive) {
      failure = std::move(alive).error();
      break;
    }
    if (!*alive) break;
    if (!shown && (*streaming)->any_resident()) {
      std::optional<client_core::DAabb> box;
      (void)(*streaming)->with_gpu([&](const client_gpu::ResidentState& st) -> Result<void> {
        box = st.content_bounds;
        return {};
      });
      world = initial_pose(a, box);
      scale_used = world.world_scale;
      shown = true;
      t_shown = Clock::now();
      first_picture_s = std::chrono::duration<double>(t_shown - t_connect).count();
    }
    if (whole_canvas_s == 0 && (*streaming)->wait_resident(c.welcome().epoch, std::chrono::milliseconds(0)))
      whole_canvas_s = std::chrono::duration<double>(Clock::now() - t_connect).count();
    if (!shown) {
      if (auto st = (*streaming)->status(); !st) {
        failure = make_error(st.error().code, "GPU replica: " + st.error().message);
        break;
      }
      if (Clock::now() - t0 > timeout) {
        failure = make_error(Errc::io_error, "the canvas did not arrive within --timeout");
        break;
      }
    }
    if (!hs.running()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
      if (Clock::now() - t0 > timeout && submitted == 0) {
        failure = make_error(Errc::io_error, "the OpenXR session did not start within --timeout");
        break;
      }
      continue;
    }
    auto frame = hs.begin_frame();
    if (!frame) {
      failure = std::move(frame).error();
      break;
    }
    const double t = shown ? std::chrono::duration<double>(Clock::now() - t_shown).count() : 0.0;
    // Input: the tracked right controller, else the scripted one; the scripted world scale.
    DVec3 tip;
    double trigger = 0;
    if (frame->hands[1].active) {
      tip = frame->hands[1].tip;
      trigger = frame->hands[1].trigger;
    } else if (trace) {
      const auto s = trace->at(t);
      tip = s.tip;
      trigger = s.trigger;
      world.world_scale = s.pose.world_scale;
      world.world_origin = s.pose.world_origin;
    }
    const auto& hands = frame->hands;
    if (hands[0].active && hands[1].active && hands[0].grip && hands[1].grip) {
      if (!grabbing) {
        grabbing = true;
        ++grabs;
        grab_start = world;
        grab_left = hands[0].tip;
        grab_right = hands[1].tip;
      }
      world = client_core::grab_world(grab_start, grab_left, grab_right, hands[0].tip, hands[1].tip);
    } else {
      grabbing = false;
    }
    const bool render = shown && frame->should_render && frame->views_valid;
    if (!resolution && frame->display_period_ms > 0) {
      client_core::ResolutionController::Options o;
      o.interval_ms = frame->display_period_ms;
      o.min_scale = a.min_scale;
      resolution.emplace(o);
    }
    // Both eyes at `scale` of the runtime's recommended size, from this frame's views.
    std::array<std::array<std::uint32_t, 2>, 2> sizes{};
    const auto set_sizes = [&](double scale) {
      for (std::size_t e = 0; e < 2; ++e)
        for (int k = 0; k < 2; ++k)
          sizes[e][static_cast<std::size_t>(k)] = std::max<std::uint32_t>(
              1, static_cast<std::uint32_t>(std::lround((k == 0 ? frame->eyes[e].width : frame->eyes[e].height) * scale)));
    };
    const auto render_eyes = [&](double scale) -> Result<void> {
      set_sizes(scale);
      return (*streaming)->with_gpu([&](const client_gpu::ResidentState& st) -> Result<void> {
        for (std::size_t e = 0; e < 2; ++e) {
          const auto& v = frame->eyes[e];
          const DVec3 eye = client_core::room_to_canvas(world, v.position);
          const DVec3 forward = client_core::rotate(v.orientation, {0, 0, -1});
          const DVec3 up = client_core::rotate(v.orientation, {0, 1, 0});
          auto cam = client_core::Camera::look_at(eye, eye + forward, up, xr::covering_vfov_deg(v),
                                                  sizes[e][0], sizes[e][1]);
          if (!cam) return std::move(cam).error();
          auto origin = client_core::make_ray_origin(st.pools, eye);
          if (!origin) return std::move(origin).error();
          st.cull_for_view(ro, *cam);
          if (auto s = eyes[e]->set_frame(*cam, *origin, ro); !s) return s;
        }
        client_gpu::GpuRaycaster* const views[2] = {eyes[0].get(), eyes[1].get()};
        return client_gpu::GpuRaycaster::render_together(views);
      });
    };
    const auto painted_resident = [&] {
      bool painted = false;
      auto r = (*streaming)->with_gpu([&](const client_gpu::ResidentState& st) -> Result<void> {
        painted = st.content_bounds.has_value();
        return {};
      });
      return r && painted;
    };
    if (render && resolution && !calibrated && a.fixed_scale <= 0 && painted_resident()) {
      // Probe renders before the first frame with painted cells (half scale to pay for first
      // use, then timed at half and at quarter scale) set dynamic resolution's starting scale
      // and pixel share, so the first frames need not miss while the controller finds it (as
      // client_gpu::HeadsetLoop does; an empty canvas costs the same at any scale and would
      // teach it that the pixels cost nothing).
      calibrated = true;
      double probe_ms[2] = {0, 0};
      for (int pass = 0; pass < 3 && failure; ++pass) {
        const auto p0 = Clock::now();
        if (auto r = render_eyes(pass < 2 ? 0.5 : 0.25); !r) failure = std::move(r).error();
        if (pass > 0)
          probe_ms[pass - 1] = std::chrono::duration<double, std::milli>(Clock::now() - p0).count();
      }
      if (!failure) break;
      resolution->calibrate(0.5, probe_ms[0], 0.25, probe_ms[1]);
    }
    const double scale = a.fixed_scale > 0 ? a.fixed_scale : resolution ? resolution->scale() : 1.0;
    set_sizes(scale);
    if (render) {
      const auto r0 = Clock::now();
      auto r = render_eyes(scale);
      if (!r) {
        failure = std::move(r).error();
        break;
      }
      const double ms = std::chrono::duration<double, std::milli>(Clock::now() - r0).count();
      render_ms.push_back(ms);
      scales.push_back(scale);
      if (resolution) resolution->frame_done(ms);
      eye_sep_room = client_core::length(frame->eyes[1].position - frame->eyes[0].position);
      eye_sep_canvas = eye_sep_room * world.world_scale;
      scale_used = world.world_scale;
    }
    auto ended = hs.end_frame(*frame, {render ? &eyes[0]->output() : nullptr,
                                       render ? &eyes[1]->output() : nullptr}, sizes);
    if (!ended) {
      failure = std::move(ended).error();
      break;
    }
    ++submitted;
    rendered += render ? 1 : 0;
    // Painting: a stroke while the trigger is held, one sample a frame at the tip (once the
    // artist sees the canvas).
    if (shown && !exit_requested) {
      const DVec3 p = client_core::room_to_canvas(world, tip);
      protocol::StrokeSample s{p.x, p.y, p.z,
                               static_cast<float>(a.radius_mm / 1000 * world.world_scale),
                               static_cast<float>(std::max(trigger, 1e-3)),
                               static_cast<std::uint32_t>(t * 1000)};
      if (trigger > 0) {
        if (!stroke_open) {
          auto h = c.begin_stroke(brush, {s});
          if (h) {
            stroke_open = true;
            open_stroke = *h;
            handles.push_back(*h);
            ++strokes_begun;
            ++samples_sent;
          }
        } else if (c.add_samples(open_stroke, {s})) {
          ++samples_sent;
        }
      } else if (stroke_open) {
        (void)c.end_stroke(open_stroke);
        stroke_open = false;
      }
    }
    if (a.frames > 0 && rendered >= a.frames && !exit_requested) {
      if (stroke_open) {
        (void)c.end_stroke(open_stroke);
        stroke_open = false;
      }
      exit_requested = true;
      if (auto r = hs.request_exit(); !r) {
        failure = std::move(r).error();
        break;
      }
    }
  }
  if (stroke_open) (void)c.end_stroke(open_stroke);
  std::uint64_t acked = 0;
  for (auto h : handles)
    if (c.wait_for_ack(h, timeout)) ++acked;
  c.set_epoch_listener({});
  if (!failure) return cli::fail(app, failure.error().message);
  if (a.json) {
    std::printf(
        "{\"runtime\":\"%s\",\"system\":\"%s\",\"device\":\"%s\",\"frames_submitted\":%llu,"
        "\"frames_rendered\":%llu,\"eye_separation_room_m\":%.6f,\"world_scale\":%.9g,"
        "\"eye_separation_canvas_m\":%.9g,\"strokes_begun\":%llu,\"strokes_acked\":%llu,"
        "\"samples_sent\":%llu,\"grabs\":%llu,\"render_ms_p50\":%.3f,\"render_ms_p99\":%.3f,"
        "\"render_scale_p50\":%.3f,\"frame_interval_ms\":%.3f,\"first_picture_s\":%.3f,"
        "\"whole_canvas_s\":%s}\n",
        hs.runtime_name().c_str(), hs.system_name().c_str(), hs.context().info().name.c_str(),
        static_cast<unsigned long long>(submitted), static_cast<unsigned long long>(rendered),
        eye_sep_room, scale_used, eye_sep_canvas, static_cast<unsigned long long>(strokes_begun),
        static_cast<unsigned long long>(acked), static_cast<unsigned long long>(samples_sent),
        static_cast<unsigned long long>(grabs), base::percentile(render_ms, 0.5),
        base::percentile(render_ms, 0.99), base::percentile(scales, 0.5),
        resolution ? resolution->options().interval_ms : 0.0, first_picture_s,
        whole_canvas_s > 0 ? seconds_json(whole_canvas_s).c_str() : "null");
  } else {
    std::printf("xr: %s (%s) on %s: %llu frames submitted, %llu rendered; eyes %.1f mm apart in "
                "the room, %.3g m in the canvas (world scale %.3g); %llu strokes painted, %llu "
                "acked\n",
                hs.runtime_name().c_str(), hs.system_name().c_str(), hs.context().info().name.c_str(),
                static_cast<unsigned long long>(submitted), static_cast<unsigned long long>(rendered),
                eye_sep_room * 1000, eye_sep_canvas, scale_used,
                static_cast<unsigned long long>(strokes_begun), static_cast<unsigned long long>(acked));
  }
  c.close();
  return acked == strokes_begun ? 0 : cli::fail(app, "not every stroke was acked");
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("xr", "paint in an OpenXR headset (stereo, tracked controllers)", run_xr);

}  // namespace deepcanvas::client_app
