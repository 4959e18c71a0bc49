// deepcanvas-client studio: the artist's window. Joins a canvas as a painter (or a viewer),
// shows it live through the streaming render loop in a GLFW window, and paints with the mouse.
//
// The frame loop (run_frames) is the whole program, top to bottom:
//   poll the window system -> advance the connection (never blocks) -> start the UI frame ->
//   input (view, strokes, keys) -> replies (pick-up, acks, presence out) -> panels and overlay ->
//   render the 3D view (RenderLoop::render_frame, row bands under the GPU lock) -> present ->
//   screenshot if asked -> keep to the fps cap.
#include <algorithm>
#include <atomic>
#include <csignal>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <string>
#include <thread>

#include "cli_options.hpp"
#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/client_gpu/memory.hpp"
#include "deepcanvas/client_gpu/png.hpp"
#include "deepcanvas/window/window.hpp"
#include <imgui.h>
#include "gpu_options.hpp"
#include "resumable_paint.hpp"
#include "studio.hpp"

namespace deepcanvas::client_app {
namespace {

namespace cli = deepcanvas::base::cli;

// SIGTERM / SIGINT end the frame loop like closing the window (logs flushed, connection closed).
std::atomic<bool> g_stop_requested{false};
extern "C" void request_stop(int) {
  g_stop_requested = true;
}

constexpr const char* kDescription =
    "Opens a window on a canvas: it shows the canvas live as it streams in, the mouse paints\n"
    "streamed strokes into it (on the surface under the pointer, or at the focus depth where\n"
    "there is none) and navigates across every scale, from the whole 20 km canvas down to its\n"
    "0.3 mm cells: right drag orbits, middle or shift+right drag pans, the wheel zooms toward\n"
    "the point under the pointer. Panels set the brush (paint, erase, recolor, smudge,\n"
    "pick-up; colour, density, opacity, hardness, size in screen pixels) and list the other\n"
    "artists, whose cursors appear in the view. H shows every key. The window survives the\n"
    "server going away: it says so and reconnects, keeping the view and the brush.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client studio --connect ws://127.0.0.1:7878/main --name Ada\n"
    "  deepcanvas-client studio --connect wss://canvas.example:7878/main --token T \\\n"
    "      --size 1920x1080 --render-scale 0.5\n";

struct StudioArgs {
  ConnectArgs connect;
  GpuViewArgs gpu;
  std::string name = "studio", size = "1280x720", colour, screenshot_dir = ".", latency_log;
  double max_fps = 60;
  std::string render_scale = "auto";
  bool no_vsync = false, fullscreen = false, viewer = false;
};

void add_studio_options(CLI::App& app, StudioArgs& args) {
  add_connect_options(app, args.connect);
  add_batch_interval_option(app, args.connect);
  app.add_option("--name", args.name, "your name, shown to the other artists (default studio)")
      ->type_name("NAME");
  app.add_flag("--viewer", args.viewer, "join as a viewer: watch and navigate, no painting");
  app.add_option("--size", args.size, "window size (default 1280x720)")
      ->type_name("WxH")
      ->check(image_size());
  app.add_flag("--fullscreen", args.fullscreen, "start fullscreen (F11 toggles)");
  app.add_flag("--no-vsync", args.no_vsync, "present without waiting for the display (V toggles)");
  app.add_option("--fps", args.max_fps, "at most X frames a second (default 60; 0: no cap)")
      ->type_name("X")
      ->transform(number(0, 1000));
  app.add_option("--render-scale", args.render_scale,
                 "render the 3D view at this fraction of the window's pixels (0.1..1) and scale "
                 "it up; auto (the default) keeps the view's render time near 15 ms by choosing "
                 "the fraction frame by frame while the view moves or the canvas changes (a slow "
                 "device gets a softer picture, not a slow window), and renders a still view "
                 "once at full scale")
      ->type_name("F|auto")
      ->check(CLI::Validator(
          [](std::string& v) -> std::string {
            if (v == "auto") return {};
            const auto f = parse_number(v);
            return f && *f >= 0.1 && *f <= 1 ? std::string()
                                             : "expected auto or a number in 0.1..1, got '" + v +
                                                   "'";
          },
          ""));
  app.add_option("--colour", args.colour, "the brush colour to start with (default 0.9,0.35,0.1)")
      ->type_name("R,G,B")
      ->check(rgb());
  app.add_option("--screenshot-dir", args.screenshot_dir,
                 "where P / F12 write screenshots (default: the working directory)")
      ->type_name("DIR")
      ->check(output_folder());
  app.add_option("--latency-log", args.latency_log,
                 "write when each frame was presented, which pointer positions it first showed "
                 "as stroke samples and which other artists' cursors (deepcanvas-bench studio "
                 "reads it; monotonic clock, nanoseconds)")
      ->type_name("FILE")
      ->check(output_file());
  add_device_option(app, args.gpu);
}

// --latency-log: one line per presented frame and per thing it showed first, each with the
// time its present returned (steady clock, ns; the bench on the same machine compares them
// with the times it moved the pointer or sent a presence):
//   frame START_NS PRESENT_NS
//   sample X Y PRESENT_NS          a pointer position turned into a stroke sample
//   presence ARTIST X Y Z PRESENT_NS   another artist's cursor drawn at a new position
void log_latency(std::FILE* f, StudioState& state, StudioClock::time_point start) {
  if (f == nullptr) {
    state.new_sample_px.clear();
    state.drawn_presence.clear();
    return;
  }
  const auto ns = [](StudioClock::time_point t) {
    return static_cast<long long>(
        std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count());
  };
  const long long now = ns(StudioClock::now());
  std::fprintf(f, "frame %lld %lld\n", ns(start), now);
  for (const auto& [x, y] : state.new_sample_px) std::fprintf(f, "sample %.0f %.0f %lld\n", x, y, now);
  state.new_sample_px.clear();
  for (const auto& [artist, p] : state.drawn_presence) {
    auto& last = state.logged_presence[artist];
    if (last == p) continue;  // drawn before at this position
    last = p;
    std::fprintf(f, "presence %llu %.17g %.17g %.17g %lld\n",
                 static_cast<unsigned long long>(artist), p[0], p[1], p[2], now);
  }
  state.drawn_presence.clear();
}

// Writes the last frame of the 3D view as DIR/studio-YYYYMMDD-HHMMSS-N.png.
Result<std::string> write_screenshot(client_gpu::RenderLoop& loop, const client_core::Camera& cam,
                                     const std::string& dir) {
  auto px = loop.read_pixels();
  if (!px) return std::move(px).error();
  static int n = 0;
  const std::time_t t = std::time(nullptr);
  char stamp[32];
  std::strftime(stamp, sizeof stamp, "%Y%m%d-%H%M%S", std::localtime(&t));
  const std::string path = dir + "/studio-" + stamp + "-" + std::to_string(++n) + ".png";
  if (auto w = client_gpu::write_frame_png(path, cam.width(), cam.height(), *px); !w)
    return std::move(w).error();
  return path;
}

// The 3D view's frame: renders it with the current view at the framebuffer's size times the
// render scale. Returns the buffer to present and its size; a 1x1 background buffer while
// there is no canvas (not connected, nothing resident yet).
struct ViewFrame {
  const client_gpu::Buffer* pixels = nullptr;
  std::uint32_t width = 1, height = 1;
};

// Auto render scale: the view's render time is about proportional to its pixels, so the
// fraction that would bring it to kAutoRenderMs is scale * sqrt(kAutoRenderMs / render_ms);
// each frame moves part of the way there, within [kMinAutoScale, 1].
constexpr double kAutoRenderMs = 15, kMinAutoScale = 0.25;
void adapt_render_scale(StudioState& state, double render_ms) {
  if (!(render_ms > 0)) return;
  const double want = state.render_scale * std::sqrt(kAutoRenderMs / render_ms);
  const double step = std::clamp(want / state.render_scale, 0.85, 1.05);
  state.render_scale = std::clamp(state.render_scale * step, kMinAutoScale, 1.0);
}

// A view that has not changed for this long is rendered once more at full scale (auto render
// scale), then not again until something changes.
constexpr auto kStillAfter = std::chrono::milliseconds(300);

Result<ViewFrame> render_view(StudioState& state, StudioLink& link, window::StudioWindow& win,
                              bool auto_scale, const client_gpu::Buffer& blank) {
  ViewFrame out{&blank, 1, 1};
  // Until a connection has a picture: the last one the connection before it rendered, if any
  // (the canvas stays in view while the studio reconnects).
  if (const client_gpu::Buffer* held = link.held_frame();
      held && held->size() == VkDeviceSize{state.rendered_w} * state.rendered_h * 4)
    out = ViewFrame{held, state.rendered_w, state.rendered_h};
  client_gpu::RenderLoop* loop = link.loop();
  const auto [fw, fh] = win.framebuffer_size();
  if (!loop || fw == 0 || fh == 0 || !link.replica()->any_resident()) return out;
  const auto now = StudioClock::now();
  const client_core::OrbitView& v = state.view;
  const ViewKey key{loop, link.replica()->stats().batches, fw, fh, v.focus, v.distance,
                    v.yaw_rad, v.pitch_rad, v.vfov_deg};
  if (!(key == state.view_key)) {
    state.view_key = key;
    state.view_changed = now;
  }
  const bool still = now - state.view_changed >= kStillAfter;
  const double render_scale = auto_scale && still ? 1.0 : state.render_scale;
  // Nothing changed since the last frame rendered: the window presents the same pixels again.
  if (state.rendered_key && *state.rendered_key == key && state.rendered_scale == render_scale)
    return ViewFrame{&loop->output(), state.rendered_w, state.rendered_h};
  const auto w = std::max<std::uint32_t>(1, static_cast<std::uint32_t>(fw * render_scale));
  const auto h = std::max<std::uint32_t>(1, static_cast<std::uint32_t>(fh * render_scale));
  auto cam = state.view.camera(w, h);
  if (!cam) return out;
  // The previous frame's copy out of the buffer must be done before the ray caster writes it.
  if (auto d = win.wait_frame_done(); !d) return std::move(d).error();
  loop->set_camera(*cam);
  auto f = loop->render_frame();
  if (!f) return std::move(f).error();
  if (f->empty) return out;
  state.render_ms = f->render_ms;
  if (auto_scale && !still) adapt_render_scale(state, f->render_ms);  // learn from moving frames
  state.resident_epoch = f->min_epoch;
  if (state.probe && state.probe->ack_epoch && f->min_epoch >= *state.probe->ack_epoch) {
    state.last_latency_ms =
        std::chrono::duration<double, std::milli>(StudioClock::now() - state.probe->sent_at)
            .count();
    state.probe.reset();
  }
  // Keyed by the batches resident before it rendered (a batch that arrived meanwhile renders
  // again).
  state.rendered_key = key;
  state.rendered_scale = render_scale;
  state.rendered_w = w;
  state.rendered_h = h;
  out = {&loop->output(), w, h};
  return out;
}

// When the first epoch is resident: a canvas that has content is framed, so the artist starts
// out seeing the painting; an empty one keeps the default view (framing later would move the
// view under an artist who has started painting).
void frame_content_once(StudioState& state, StudioLink& link, std::uint32_t win_w,
                        std::uint32_t win_h) {
  if (state.view_framed || !link.replica()) return;
  bool resident = false;
  std::optional<client_core::DAabb> box;
  (void)link.replica()->with_gpu([&](const client_gpu::ResidentState& st) -> Result<void> {
    resident = st.any;
    if (st.any) box = st.content_bounds;
    return {};
  });
  if (!resident) return;
  if (box) state.view.frame(*box, win_w, win_h);
  state.view_framed = true;
}

int run_frames(StudioState& state, StudioLink& link, window::StudioWindow& win,
               const StudioArgs& args, const client_gpu::Buffer& blank, std::FILE* latency_log) {
  auto last_start = StudioClock::now();
  while (!win.should_close() && !state.quit && !g_stop_requested) {
    const auto start = StudioClock::now();
    state.frame_ms.push_back(std::chrono::duration<double, std::milli>(start - last_start).count());
    if (state.frame_ms.size() > 120) state.frame_ms.pop_front();
    last_start = start;

    win.poll();
    const auto was = link.state();
    // A lost connection's render loop goes: the window's last frame may still copy from it.
    link.update(start, [&] { (void)win.wait_frame_done(); });
    if (link.state() == StudioLink::State::failed && was != StudioLink::State::failed)
      std::fprintf(stderr, "studio: cannot connect: %s\n", link.reason().c_str());
    state.keys = win.take_key_presses();
    state.moves = win.take_pointer_moves();
    win.begin_ui();
    const ImVec2 display = ImGui::GetIO().DisplaySize;
    const auto win_w = std::max<std::uint32_t>(1, static_cast<std::uint32_t>(display.x));
    const auto win_h = std::max<std::uint32_t>(1, static_cast<std::uint32_t>(display.y));
    frame_content_once(state, link, win_w, win_h);
    bool toggle_fullscreen = false, toggle_vsync = false;
    handle_input(state, link, win_w, win_h, toggle_fullscreen, toggle_vsync);
    handle_replies(state, link);
    draw_panels(state, link, win.present_mode_name(), win.vsync());
    draw_overlay(state, link, win_w, win_h);

    auto view = render_view(state, link, win, args.render_scale == "auto", blank);
    if (!view) {
      std::fprintf(stderr, "studio: rendering failed: %s\n", view.error().message.c_str());
      return 1;
    }
    if (auto p = win.present(*view->pixels, view->width, view->height); !p) {
      std::fprintf(stderr, "studio: presenting failed: %s\n", p.error().message.c_str());
      return 1;
    }
    log_latency(latency_log, state, start);
    // A reconnect joins with the view as it is now (hello "camera"): the canvas comes back
    // nearest what the artist looks at first.
    if (state.view_framed) {
      if (auto cam = state.view.camera(win_w, win_h)) {
        if (auto j = join_camera(*cam)) link.set_join_camera(*j);
      }
    }
    if (state.screenshot_requested && link.loop() && view->pixels != &blank) {
      state.screenshot_requested = false;
      auto cam = state.view.camera(view->width, view->height);
      auto path = cam ? write_screenshot(*link.loop(), *cam, state.screenshot_dir)
                      : Result<std::string>(std::move(cam).error());
      state.note = path ? "wrote " + *path : "screenshot failed: " + path.error().message;
      state.note_at = StudioClock::now();
      std::printf("studio: %s\n", state.note.c_str());
      std::fflush(stdout);
    }
    if (toggle_fullscreen) win.toggle_fullscreen();
    if (toggle_vsync) win.set_vsync(!win.vsync());
    if (args.max_fps > 0) {
      const auto due = start + std::chrono::duration_cast<StudioClock::duration>(
                                   std::chrono::duration<double>(1.0 / args.max_fps));
      std::this_thread::sleep_until(due);
    }
  }
  return 0;
}

int run_studio(int argc, char** argv) {
  StudioArgs args;
  CLI::App app{kDescription, "deepcanvas-client studio"};
  cli::standard(app, kExamples);
  add_studio_options(app, args);
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;

  auto options = client_options(args.connect,
                                args.viewer ? protocol::Role::viewer : protocol::Role::painter,
                                args.name);
  // One id for the whole run: the server keys undo by it, so the artist's undo history holds
  // across the link's reconnects.
  options.client_id = random_client_id();
  window::WindowOptions wo;
  wo.title = "deepcanvas studio: " + options.canvas;
  parse_size(args.size, wo.width, wo.height);
  wo.vsync = !args.no_vsync;
  wo.fullscreen = args.fullscreen;
  wo.device = args.gpu.device;
  auto win = window::StudioWindow::create(wo);
  if (!win) return cli::fail(app, win.error().message);

  StudioState state;
  state.viewer = args.viewer;
  state.render_scale = args.render_scale == "auto" ? 1.0 : *parse_number(args.render_scale);
  state.screenshot_dir = args.screenshot_dir;
  if (!args.colour.empty()) {
    const auto t = parse_triple(args.colour);
    for (int c = 0; c < 3; ++c) state.brush.colour[c] = static_cast<float>((*t)[c]);
  }
  auto blank = client_gpu::Buffer::create((*win)->context(), 4, VK_BUFFER_USAGE_TRANSFER_SRC_BIT,
                                          client_gpu::MemoryUse::upload);
  if (!blank) return cli::fail(app, blank.error().message);
  *static_cast<std::uint32_t*>(blank->mapped()) = 0xFF140F0Du;  // the background, RGBA8
  (void)blank->flush();

  StudioLink link((*win)->context(), options);
  std::printf("studio: window open on %s, canvas '%s' at %s\n",
              (*win)->context().info().name.c_str(), options.canvas.c_str(),
              args.connect.url.c_str());
  std::fflush(stdout);
  std::signal(SIGTERM, request_stop);
  std::signal(SIGINT, request_stop);
  std::FILE* latency_log = nullptr;
  if (!args.latency_log.empty()) {
    latency_log = std::fopen(args.latency_log.c_str(), "w");
    if (latency_log == nullptr) return cli::fail(app, "cannot write " + args.latency_log);
  }
  const int rc = run_frames(state, link, **win, args, *blank, latency_log);
  if (latency_log != nullptr) std::fclose(latency_log);
  return rc != 0 ? rc : (link.state() == StudioLink::State::failed ? 1 : 0);
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("studio", "open a window on a canvas: paint, navigate, see others live",
                          run_studio);

}  // namespace deepcanvas::client_app
