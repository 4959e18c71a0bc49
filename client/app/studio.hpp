// The studio window's state and the steps of its frame loop (studio_command.cpp runs them top
// to bottom each frame): input -> view and strokes (studio_input.cpp), panels and the overlay
// drawn over the 3D view (studio_ui.cpp).
//
// Coordinates: ImGui reports the pointer in window coordinates; the view's camera for picking
// and for the overlay is made at the window's size (OrbitView::camera(window w, h)), the frames
// are rendered at the framebuffer's size times --render-scale with the same view, so a point
// projects to the same place in both.
//
// Threading: the frame loop's thread only.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "deepcanvas/client_core/navigation.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/window/window.hpp"
#include "studio_link.hpp"

namespace deepcanvas::client_app {

using StudioClock = std::chrono::steady_clock;

struct BrushSettings {
  protocol::BrushMode mode = protocol::BrushMode::paint;
  float colour[3] = {0.9f, 0.35f, 0.1f};
  float density = 1.0f;
  float opacity = 1.0f;
  float hardness = 0.6f;
  float size_px = 12.0f;  // the brush radius on screen; metres follow from the depth
};

// A stroke being painted: its samples go out every frame; all of them stay for the preview.
struct LocalStroke {
  std::uint64_t handle = 0;
  protocol::Brush brush;  // the brush when the stroke began (the server gets it once)
  double depth_m = 0;  // distance from the eye along each pointer ray (fixed at the start)
  StudioClock::time_point started{};
  std::vector<protocol::StrokeSample> samples;  // everything painted, for the preview
  std::size_t sent = 0;                         // samples[0, sent) have gone out
  bool answered = false;  // the server sent an error about it (ended or refused it): no more goes
  bool offline = false;   // begun with no connection: kept whole, sent when one is back
  double last_px = -1e9, last_py = -1e9;        // where the last sample was taken
};

// A stroke that went out (or was being painted when the connection went) with no answer yet.
// A new connection sends it again whole with the same handle: the server answers a stroke it
// has with that stroke's ack, paints one it never got, and repaints whole one a disconnect or a
// restart cut short (taking the cut part back first), so no stroke is lost to a dropped
// connection or a server restart and none is painted twice.
struct UnackedStroke {
  std::uint64_t handle = 0;  // 0: no part of it went out; it goes as a new stroke
  protocol::Stroke stroke;
  int sent_on = -1;  // the StudioLink::connections() it was last sent whole on (-1: none)
};

// "1 stroke", "2 strokes".
inline std::string strokes_text(std::size_t n) {
  return std::to_string(n) + (n == 1 ? " stroke" : " strokes");
}

// Sent -> visible latency of the artist's last stroke: from the end of the stroke to the first
// presented frame that renders the epoch its ack names.
struct LatencyProbe {
  std::uint64_t handle = 0;
  StudioClock::time_point sent_at{};
  std::optional<std::uint64_t> ack_epoch;
};

// The point the wheel zooms toward, and the pointer and view it was taken for.
struct ZoomAnchor {
  client_core::DVec3 point;
  double px = 0, py = 0;
  double view_distance = 0;
  client_core::DVec3 focus;
};

// What a frame of the 3D view shows: the same key and render scale as the last frame rendered
// means the buffer the window has is still right, and nothing is ray cast.
struct ViewKey {
  const void* loop = nullptr;  // a new connection has a new render loop
  // Batches made resident (StreamingStats::batches): a new epoch, or a new part of the
  // snapshot while it arrives (progressive join: the resident epoch does not change then).
  std::uint64_t resident_batches = 0;
  std::uint32_t width = 0, height = 0;  // the framebuffer
  client_core::DVec3 focus;
  double distance = 0, yaw = 0, pitch = 0, vfov = 0;
  friend bool operator==(const ViewKey&, const ViewKey&) = default;
};

struct StudioState {
  client_core::OrbitView view;
  bool view_framed = false;  // framed the canvas's content once it arrived
  BrushSettings brush;
  bool viewer = false;
  std::optional<LocalStroke> stroke;
  std::deque<UnackedStroke> unacked;  // oldest first
  StudioClock::time_point resend_at{};  // the next resend, paced under the server's stroke rate
  // Strokes sent on connection `resent_on` from `unacked`: again (they had gone out before) and
  // for the first time (painted while no server was there).
  int resent = 0, sent_late = 0, resent_on = 0;
  std::uint64_t answered_handle = 0;    // the last stroke the server ended early (its note shown)
  std::optional<ZoomAnchor> zoom_anchor;
  std::optional<client_core::DAabb> selection;  // the last stroke's box ("frame selection")
  std::optional<LatencyProbe> probe;
  double last_latency_ms = -1;
  std::optional<std::uint64_t> pick_request;  // pick-up (eyedropper) in flight
  // Undo and redo (Ctrl+Z, Ctrl+Shift+Z or Ctrl+Y, the panel's buttons): requests in flight by
  // id (true: redo), and a button pressed this frame (handled with the keys).
  std::vector<std::pair<std::uint64_t, bool>> undo_requests;
  bool undo_clicked = false, redo_clicked = false;
  // The pointer's 3D point (surface under it, else at the focus depth) and whether it is over
  // the 3D view (not over a panel).
  std::optional<client_core::DVec3> cursor_point;
  bool cursor_on_view = false;
  // Presence: when the last one went out, and what it said.
  StudioClock::time_point presence_sent{};
  std::string presence_last;
  std::size_t jump_index = 0;  // Tab: the next artist whose view to take
  // Frame statistics.
  std::deque<double> frame_ms;  // the last 120 frames, start to start
  double render_ms = 0;
  double render_scale = 1.0;  // the 3D view's pixels per window pixel (--render-scale)
  // The view as last seen and since when (a still view is rendered once at full scale), and
  // what the last rendered frame showed, at which scale and size.
  ViewKey view_key;
  StudioClock::time_point view_changed{};
  std::optional<ViewKey> rendered_key;
  double rendered_scale = 0;
  std::uint32_t rendered_w = 0, rendered_h = 0;
  std::uint64_t resident_epoch = 0;
  // Messages.
  std::string note;  // a transient line (screenshot written, ...)
  StudioClock::time_point note_at{};
  bool show_help = false;
  std::string screenshot_dir = ".";
  bool screenshot_requested = false;
  bool quit = false;
  // This frame's key presses (StudioWindow::take_key_presses).
  std::vector<window::KeyPress> keys;
  // This frame's pointer positions (StudioWindow::take_pointer_moves).
  std::vector<std::pair<double, double>> moves;
  // --latency-log (deepcanvas-bench studio): the pointer positions this frame turned into
  // stroke samples, and the other artists' cursors (by artist) as last drawn.
  std::vector<std::pair<double, double>> new_sample_px;
  std::vector<std::pair<std::uint64_t, std::array<double, 3>>> drawn_presence;
  std::map<std::uint64_t, std::array<double, 3>> logged_presence;
};

// ---- studio_input.cpp ----
// Navigation (orbit, pan, dolly, wheel zoom toward the point under the pointer, frame keys),
// painting (streamed strokes on the surface under the pointer or at the focus depth), pick-up,
// brush shortcuts and the other keys. `win_w` x `win_h`: the window in ImGui's coordinates.
void handle_input(StudioState& state, StudioLink& link, std::uint32_t win_w, std::uint32_t win_h,
                  bool& toggle_fullscreen, bool& toggle_vsync);
// Replies that arrive on their own: the pick-up's colour, the latency probe's ack; presence out.
void handle_replies(StudioState& state, StudioLink& link);
// The distance along the pointer ray at (px, py) to the first surface, if any (CPU trace on the
// resident mirror, under the GPU lock: the same cells the frame shows).
std::optional<double> surface_distance(StudioLink& link, const client_core::Camera& camera,
                                       double px, double py);
// One line describing the view, as JSON (F9 prints it; tests compare views with it).
std::string view_json(const client_core::OrbitView& view);

// ---- studio_ui.cpp ----
// The panels (brush, artists, status) and, over the 3D view, the cursor ring, the local stroke
// preview and the other artists' cursors.
void draw_panels(StudioState& state, StudioLink& link, const char* present_mode, bool vsync);
void draw_overlay(StudioState& state, StudioLink& link, std::uint32_t win_w,
                  std::uint32_t win_h);

}  // namespace deepcanvas::client_app
