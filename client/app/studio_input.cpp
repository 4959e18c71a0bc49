// The studio's input: navigation, painting, pick-up and shortcuts (see studio.hpp).
#include <GLFW/glfw3.h>
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "studio.hpp"

namespace deepcanvas::client_app {
namespace {

using client_core::Camera;
using client_core::DVec3;

constexpr double kPresenceInterval = 0.05;  // s: at most 20 presence messages a second
constexpr std::size_t kSamplesPerMessage = 256;

// The transient line over the view, also printed (tests and logs read it).
void show_note(StudioState& state, std::string text) {
  state.note = std::move(text);
  state.note_at = StudioClock::now();
  std::printf("studio: %s\n", state.note.c_str());
  std::fflush(stdout);
}

// This frame's presses of `glfw_key` (with `repeats`, the held key's repeats too); with
// `ctrl`, only with Ctrl held, else only without it.
int presses(const StudioState& state, int glfw_key, bool repeats = false, bool ctrl = false) {
  int n = 0;
  for (const auto& k : state.keys)
    if (k.key == glfw_key && (repeats || !k.repeat) &&
        ((k.mods & GLFW_MOD_CONTROL) != 0) == ctrl)
      ++n;
  return n;
}

// The pointer's 3D point: the surface under it, else the point at the focus depth.
DVec3 pointer_point(StudioLink& link, const StudioState& state, const Camera& cam, double px,
                    double py, double* depth_out = nullptr) {
  const DVec3 dir = client_core::ray_direction_at(cam, px, py);
  const auto hit = surface_distance(link, cam, px, py);
  // The focus plane: the depth along this ray at which it meets the plane through the focus.
  const double along = client_core::dot(dir, cam.forward());
  const double plane = state.view.distance / std::max(along, 1e-6);
  const double depth = hit ? *hit : plane;
  if (depth_out) *depth_out = depth;
  return cam.position() + dir * depth;
}

void navigate(StudioState& state, StudioLink& link, const Camera& cam, std::uint32_t win_h) {
  ImGuiIO& io = ImGui::GetIO();
  const bool on_view = !io.WantCaptureMouse;
  const bool pan_drag = ImGui::IsMouseDragging(ImGuiMouseButton_Middle, 0) ||
                        (io.KeyShift && ImGui::IsMouseDragging(ImGuiMouseButton_Right, 0));
  if (on_view && pan_drag) {
    state.view.pan(io.MouseDelta.x, io.MouseDelta.y, win_h);
  } else if (on_view && ImGui::IsMouseDragging(ImGuiMouseButton_Right, 0)) {
    state.view.orbit(io.MouseDelta.x, io.MouseDelta.y, win_h);
  }
  if (on_view && io.MouseWheel != 0 && !state.stroke) {
    // The point under the pointer, kept while the pointer stays put and only the wheel moves
    // the view: a zoom out then retraces the zoom in exactly, even where the eye has come
    // close enough for the surface under the pointer to change.
    const bool same = state.zoom_anchor && state.zoom_anchor->px == io.MousePos.x &&
                      state.zoom_anchor->py == io.MousePos.y &&
                      state.zoom_anchor->view_distance == state.view.distance &&
                      state.zoom_anchor->focus == state.view.focus;
    if (!same)
      state.zoom_anchor = ZoomAnchor{pointer_point(link, state, cam, io.MousePos.x, io.MousePos.y),
                                     io.MousePos.x, io.MousePos.y, 0, {}};
    state.view.zoom_toward(state.zoom_anchor->point, io.MouseWheel);
    state.zoom_anchor->view_distance = state.view.distance;
    state.zoom_anchor->focus = state.view.focus;
  }
  if (io.WantCaptureKeyboard) return;
  const double step = 20.0;  // pixels' worth per key press
  for (const auto& k : state.keys) {
    const bool shift = (k.mods & GLFW_MOD_SHIFT) != 0;
    const double dx = k.key == GLFW_KEY_LEFT ? step : (k.key == GLFW_KEY_RIGHT ? -step : 0);
    const double dy = k.key == GLFW_KEY_UP ? step : (k.key == GLFW_KEY_DOWN ? -step : 0);
    if (dx != 0 || dy != 0) shift ? state.view.pan(dx, dy, win_h) : state.view.orbit(dx, dy, win_h);
    if (k.key == GLFW_KEY_PAGE_UP || k.key == GLFW_KEY_EQUAL || k.key == GLFW_KEY_KP_ADD)
      state.view.dolly(client_core::OrbitView::kNotchFactor);
    if (k.key == GLFW_KEY_PAGE_DOWN || k.key == GLFW_KEY_MINUS || k.key == GLFW_KEY_KP_SUBTRACT)
      state.view.dolly(1.0 / client_core::OrbitView::kNotchFactor);
  }
}

void frame_keys(StudioState& state, StudioLink& link, std::uint32_t win_w, std::uint32_t win_h) {
  if (ImGui::GetIO().WantCaptureKeyboard) return;
  if (presses(state, GLFW_KEY_F)) {  // frame everything
    std::optional<client_core::DAabb> box;
    if (auto* replica = link.replica()) {
      (void)replica->with_gpu([&](const client_gpu::ResidentState& st) -> Result<void> {
        box = st.content_bounds;
        return {};
      });
    }
    if (box) state.view.frame(*box, win_w, win_h);
  }
  if (presses(state, GLFW_KEY_G) && state.selection) state.view.frame(*state.selection, win_w, win_h);
}

void brush_keys(StudioState& state) {
  if (ImGui::GetIO().WantCaptureKeyboard) return;
  using protocol::BrushMode;
  const auto key = [&](int k) { return presses(state, k) > 0; };
  if (key(GLFW_KEY_B) || key(GLFW_KEY_1)) state.brush.mode = BrushMode::paint;
  if (key(GLFW_KEY_E) || key(GLFW_KEY_2)) state.brush.mode = BrushMode::erase;
  if (key(GLFW_KEY_R) || key(GLFW_KEY_3)) state.brush.mode = BrushMode::recolor;
  if (key(GLFW_KEY_S) || key(GLFW_KEY_4)) state.brush.mode = BrushMode::smudge;
  if (key(GLFW_KEY_I) || key(GLFW_KEY_5)) state.brush.mode = BrushMode::pick_up;
  for (int n = presses(state, GLFW_KEY_LEFT_BRACKET, true); n > 0; --n)
    state.brush.size_px = std::max(1.0f, state.brush.size_px * 0.8f);
  for (int n = presses(state, GLFW_KEY_RIGHT_BRACKET, true); n > 0; --n)
    state.brush.size_px = std::min(400.0f, state.brush.size_px * 1.25f);
}

// Sends an undo (redo) of this artist's last stroke; the answer comes in handle_replies().
void request_undo(StudioState& state, StudioLink& link, bool redo) {
  client_core::Client* client = link.client();
  if (state.viewer || client == nullptr) {
    state.note = state.viewer ? "a viewer has nothing to undo" : "not connected: nothing undone";
    state.note_at = StudioClock::now();
    return;
  }
  auto id = client->request_undo(redo);
  if (id) state.undo_requests.emplace_back(*id, redo);
}

void app_keys(StudioState& state, StudioLink& link, bool& toggle_fullscreen, bool& toggle_vsync) {
  ImGuiIO& io = ImGui::GetIO();
  if (presses(state, GLFW_KEY_Q, false, true)) state.quit = true;
  if (state.undo_clicked) request_undo(state, link, false);
  if (state.redo_clicked) request_undo(state, link, true);
  state.undo_clicked = state.redo_clicked = false;
  if (io.WantCaptureKeyboard) return;
  for (const auto& k : state.keys) {
    if (!(k.mods & GLFW_MOD_CONTROL)) continue;
    if (k.key == GLFW_KEY_Z) request_undo(state, link, (k.mods & GLFW_MOD_SHIFT) != 0);
    if (k.key == GLFW_KEY_Y) request_undo(state, link, true);
  }
  const auto key = [&](int k) { return presses(state, k) > 0; };
  if (key(GLFW_KEY_F11)) toggle_fullscreen = true;
  if (key(GLFW_KEY_V)) toggle_vsync = true;
  if (key(GLFW_KEY_F12) || key(GLFW_KEY_P)) state.screenshot_requested = true;
  if (key(GLFW_KEY_F1) || key(GLFW_KEY_H)) state.show_help = !state.show_help;
  if (key(GLFW_KEY_F9)) {
    std::printf("view %s\n", view_json(state.view).c_str());
    std::fflush(stdout);
  }
  if (key(GLFW_KEY_F5)) link.retry_now();
  if (key(GLFW_KEY_TAB)) {  // jump to the next artist's view
    if (auto* client = link.client()) {
      const auto others = client->presence();
      if (!others.empty()) {
        const auto& p = others[state.jump_index++ % others.size()].presence;
        if (auto v = client_core::OrbitView::looking_at({p.eye[0], p.eye[1], p.eye[2]},
                                                        {p.target[0], p.target[1], p.target[2]},
                                                        p.vfov_deg))
          state.view = *v;
      }
    }
  }
}

protocol::Brush wire_brush(const BrushSettings& b) {
  protocol::Brush w;
  w.mode = b.mode;
  for (int c = 0; c < 3; ++c) w.colour[c] = b.colour[c];
  w.colour[3] = b.density;
  w.opacity = b.opacity;
  w.hardness = b.hardness;
  return w;
}

// Adds a sample where the pointer is, once it has moved a pixel or more.
void sample_pointer(StudioState& state, const Camera& cam, std::uint32_t win_h, double px,
                    double py) {
  LocalStroke& s = *state.stroke;
  if (std::hypot(px - s.last_px, py - s.last_py) < 1.0) return;
  s.last_px = px;
  s.last_py = py;
  const DVec3 dir = client_core::ray_direction_at(cam, px, py);
  const DVec3 p = cam.position() + dir * s.depth_m;
  protocol::StrokeSample sample;
  sample.x = p.x;
  sample.y = p.y;
  sample.z = p.z;
  const double along = std::max(client_core::dot(dir, cam.forward()), 1e-6);
  sample.radius = static_cast<float>(
      std::max(1e-6, state.brush.size_px * state.view.metres_per_pixel(s.depth_m * along, win_h)));
  sample.pressure = 1.0f;
  sample.t_ms = static_cast<std::uint32_t>(
      std::chrono::duration_cast<std::chrono::milliseconds>(StudioClock::now() - s.started)
          .count());
  s.samples.push_back(sample);
  state.new_sample_px.emplace_back(px, py);
}

void flush_samples(StudioState& state, client_core::Client& client) {
  LocalStroke& s = *state.stroke;
  while (s.sent < s.samples.size()) {
    const std::size_t n = std::min(kSamplesPerMessage, s.samples.size() - s.sent);
    std::vector<protocol::StrokeSample> piece(s.samples.begin() + s.sent,
                                              s.samples.begin() + s.sent + n);
    if (s.handle == 0) {
      auto h = client.begin_stroke(s.brush, std::move(piece));
      if (!h) return;
      s.handle = *h;
    } else if (!client.add_samples(s.handle, std::move(piece))) {
      return;
    }
    s.sent += n;
  }
}

// Resends of unacknowledged strokes wait for this connection (see UnackedStroke).
bool resends_pending(const StudioState& state, const StudioLink& link) {
  return std::any_of(state.unacked.begin(), state.unacked.end(),
                     [&](const UnackedStroke& u) { return u.sent_on != link.connections(); });
}

// Ends the stroke being painted: on `client`, or (null) where the connection went. Either way it
// waits among the unacknowledged strokes until its ack comes, and is sent again after a
// reconnect if none does.
void end_stroke(StudioState& state, const StudioLink& link, client_core::Client* client) {
  LocalStroke& s = *state.stroke;
  bool ended = false;
  if (s.answered) {
    state.stroke.reset();
    return;
  }
  if (client && !resends_pending(state, link)) {
    flush_samples(state, *client);
    ended = s.handle != 0 && s.sent == s.samples.size() && client->end_stroke(s.handle).ok();
    if (ended) state.probe = LatencyProbe{s.handle, StudioClock::now(), std::nullopt};
  }
  if (!s.samples.empty()) {
    client_core::DAabb box = client_core::empty_box();
    client_core::grow_by_samples(box, s.samples);
    state.selection = box;
    protocol::Stroke stroke;
    stroke.brush = s.brush;
    stroke.samples = std::move(s.samples);
    state.unacked.push_back(
        UnackedStroke{s.handle, std::move(stroke), ended ? link.connections() : -1});
  }
  state.stroke.reset();
}

// Sends `u` whole on `client`, streamed in pieces under its own handle (a whole-stroke message
// could pass the frame limit); false when the connection went.
bool send_unacked(UnackedStroke& u, client_core::Client& client) {
  if (u.handle == 0) {
    auto h = client.send_stroke(u.stroke);
    if (!h) return false;
    u.handle = *h;
    return true;
  }
  const auto& samples = u.stroke.samples;
  const auto piece = [&](std::size_t from) {
    const std::size_t n = std::min(kSamplesPerMessage, samples.size() - from);
    return std::vector<protocol::StrokeSample>(samples.begin() + from, samples.begin() + from + n);
  };
  const auto send = [&](const protocol::Message& m) {
    return client.send_text(protocol::encode_message(m)).ok();
  };
  if (!send(protocol::StrokeBegin{u.handle, u.stroke.brush, piece(0)})) return false;
  for (std::size_t from = kSamplesPerMessage; from < samples.size(); from += kSamplesPerMessage)
    if (!send(protocol::StrokeSamples{u.handle, piece(from)})) return false;
  return send(protocol::StrokeEnd{u.handle});
}

// After a reconnect: the unacknowledged strokes again, oldest first, a little under the server's
// stroke rate (a burst past it would be refused); then takes the answers: an ack, or an error
// about the stroke (the server refused it: the note says why), ends its wait.
void resend_and_settle(StudioState& state, StudioLink& link, client_core::Client& client) {
  const int connection = link.connections();
  if (state.resent_on != connection) {
    state.resent_on = connection;
    state.resent = 0;
    state.sent_late = 0;
  }
  const auto now = StudioClock::now();
  const double rate = std::max<std::uint32_t>(1, client.welcome().limits.max_strokes_per_second);
  const auto interval = std::chrono::duration_cast<StudioClock::duration>(
      std::chrono::duration<double>(1.1 / rate));
  // A server that keeps no receipts (welcome.limits.stroke_receipts 0) would paint a stroke it
  // already has again: only the strokes no part of which went out are sent then.
  if (client.welcome().limits.stroke_receipts == 0) {
    const auto dropped = std::erase_if(state.unacked, [&](const UnackedStroke& u) {
      return u.handle != 0 && u.sent_on != connection;
    });
    if (dropped > 0)
      show_note(state, "not sending again " + strokes_text(dropped) +
                           " without an ack: this server keeps no receipts, so one it already "
                           "has would show twice");
  }
  for (UnackedStroke& u : state.unacked) {
    if (u.sent_on == connection) continue;
    if (now < state.resend_at) break;
    const bool went_out_before = u.handle != 0;
    if (!send_unacked(u, client)) break;
    u.sent_on = connection;
    state.resend_at = std::max(state.resend_at + interval, now);
    ++(went_out_before ? state.resent : state.sent_late);
    if (!resends_pending(state, link)) {
      std::string note;
      if (state.resent > 0)
        note = "sent again " + strokes_text(static_cast<std::size_t>(state.resent)) +
               " the server had not acknowledged";
      if (state.sent_late > 0)
        note += (note.empty() ? "sent " : "; sent ") +
                strokes_text(static_cast<std::size_t>(state.sent_late)) +
                " painted while it was away";
      show_note(state, note);
    }
  }
  while (auto e = client.wait_for_error(std::chrono::milliseconds(0))) {
    // An undo's error is its answer: handle_replies shows it.
    if (e->in_reply_to == "undo" || e->in_reply_to == "redo") continue;
    // Samples already on their way when the server ended the stroke: each is refused again.
    if (e->handle && *e->handle == state.answered_handle) continue;
    // The stroke being painted: the server ended or refused it, so its samples stop here.
    const bool about_current = e->handle && state.stroke && state.stroke->handle == *e->handle;
    if (about_current) {
      state.stroke->answered = true;
      state.answered_handle = *e->handle;
    }
    const bool about_stroke =
        about_current || (e->handle && std::erase_if(state.unacked, [&](const UnackedStroke& u) {
                            return u.handle == *e->handle;
                          }) > 0);
    show_note(state, (about_stroke ? "stroke: " : "server: ") + e->message);
  }
  std::erase_if(state.unacked, [&](const UnackedStroke& u) {
    return u.handle != 0 && u.sent_on == connection &&
           client.wait_for_ack(u.handle, std::chrono::milliseconds(0)).ok();
  });
}

void paint(StudioState& state, StudioLink& link, const Camera& cam, std::uint32_t win_h) {
  ImGuiIO& io = ImGui::GetIO();
  client_core::Client* client = link.client();
  // A stroke ends at the release, or where the connection went or came back during it (one
  // stroke is sent on one connection, or kept whole for the next).
  if (state.stroke && (!ImGui::IsMouseDown(ImGuiMouseButton_Left) ||
                       state.stroke->offline != (client == nullptr))) {
    // No sample at the release: the pointer may already have left (a release and a move can
    // arrive in one frame), and the stroke ends where the drag was last seen.
    end_stroke(state, link, client);
    return;
  }
  if (state.viewer) return;
  const bool start = ImGui::IsMouseClicked(ImGuiMouseButton_Left) && !io.WantCaptureMouse &&
                     !io.KeyShift;
  if (start && state.brush.mode == protocol::BrushMode::pick_up) {
    if (client && state.cursor_point) {
      auto id = client->request_pick_up(state.cursor_point->x, state.cursor_point->y,
                                        state.cursor_point->z);
      if (id) state.pick_request = *id;
    }
    return;
  }
  if (start) {
    LocalStroke s;
    s.started = StudioClock::now();
    s.brush = wire_brush(state.brush);
    s.offline = client == nullptr;
    (void)pointer_point(link, state, cam, io.MousePos.x, io.MousePos.y, &s.depth_m);
    state.stroke = std::move(s);
  }
  if (!state.stroke) return;
  // Every position the pointer went through since the last frame, then where it is now.
  if (!start)
    for (const auto& [x, y] : state.moves) sample_pointer(state, cam, win_h, x, y);
  sample_pointer(state, cam, win_h, io.MousePos.x, io.MousePos.y);
  // Strokes from before a reconnect go out first: overlapping strokes land in painting order.
  if (client && !resends_pending(state, link) && !state.stroke->answered)
    flush_samples(state, *client);
}

void send_presence(StudioState& state, client_core::Client& client) {
  const auto now = StudioClock::now();
  if (std::chrono::duration<double>(now - state.presence_sent).count() < kPresenceInterval) return;
  protocol::Presence p;
  if (state.cursor_point && state.cursor_on_view) {
    p.cursor = {state.cursor_point->x, state.cursor_point->y, state.cursor_point->z};
    p.cursor_on_canvas = true;
  }
  const DVec3 eye = state.view.eye();
  p.eye = {eye.x, eye.y, eye.z};
  p.target = {state.view.focus.x, state.view.focus.y, state.view.focus.z};
  p.vfov_deg = state.view.vfov_deg;
  for (int c = 0; c < 3; ++c) p.colour[c] = state.brush.colour[c];
  p.colour[3] = state.brush.density;
  p.mode = state.brush.mode;
  p.painting = state.stroke.has_value();
  if (state.stroke && !state.stroke->samples.empty())
    p.size_m = state.stroke->samples.back().radius;
  const std::string key = protocol::encode_message(p);
  if (key == state.presence_last) return;  // nothing changed
  if (client.send_presence(p)) {
    state.presence_last = key;
    state.presence_sent = now;
  }
}

}  // namespace

std::optional<double> surface_distance(StudioLink& link, const Camera& camera, double px,
                                       double py) {
  client_gpu::StreamingReplica* replica = link.replica();
  if (!replica) return std::nullopt;
  std::optional<double> hit;
  const DVec3 dir = client_core::ray_direction_at(camera, px, py);
  (void)replica->with_gpu([&](const client_gpu::ResidentState& st) -> Result<void> {
    if (!st.any || !st.content_bounds) return {};
    auto origin = client_core::make_ray_origin(st.pools, camera.position());
    if (!origin) return {};
    client_core::RenderOptions opts;
    opts.content_bounds = st.content_bounds;
    // The mirror keeps no links (they live on the GPU only): step by descending from the root,
    // which visits the same cells (reference_renderer.hpp, "Descent variant").
    opts.stepping = client_core::Stepping::descent;
    const auto r = client_core::trace_ray(st.pools, *origin, dir, opts);
    if (r.surface_m >= 0) hit = r.surface_m;
    return {};
  });
  return hit;
}

std::string view_json(const client_core::OrbitView& v) {
  char buf[320];
  std::snprintf(buf, sizeof buf,
                "{\"focus\":[%.17g,%.17g,%.17g],\"distance\":%.17g,\"yaw\":%.17g,\"pitch\":%.17g,"
                "\"vfov\":%.17g}",
                v.focus.x, v.focus.y, v.focus.z, v.distance, v.yaw_rad, v.pitch_rad, v.vfov_deg);
  return buf;
}

void handle_input(StudioState& state, StudioLink& link, std::uint32_t win_w, std::uint32_t win_h,
                  bool& toggle_fullscreen, bool& toggle_vsync) {
  auto cam = state.view.camera(win_w, win_h);
  if (!cam) return;
  ImGuiIO& io = ImGui::GetIO();
  state.cursor_on_view = !io.WantCaptureMouse && io.MousePos.x >= 0 && io.MousePos.y >= 0;
  state.cursor_point.reset();
  if (state.cursor_on_view)
    state.cursor_point = pointer_point(link, state, *cam, io.MousePos.x, io.MousePos.y);
  paint(state, link, *cam, win_h);
  // The view holds still while a stroke is painted, and while the server is down with the last
  // picture on screen: that picture is of this view, so strokes painted on it land where shown.
  const bool held_picture = !link.client() && link.held_frame();
  if (!state.stroke && !held_picture) {
    navigate(state, link, *cam, win_h);
    frame_keys(state, link, win_w, win_h);
  }
  brush_keys(state);
  app_keys(state, link, toggle_fullscreen, toggle_vsync);
}

void handle_replies(StudioState& state, StudioLink& link) {
  client_core::Client* client = link.client();
  if (!client) {
    state.pick_request.reset();
    state.probe.reset();
    state.undo_requests.clear();
    return;
  }
  std::erase_if(state.undo_requests, [&](const std::pair<std::uint64_t, bool>& u) {
    auto r = client->wait_for_undo(u.first, std::chrono::milliseconds(0));
    if (!r && r.error().code == Errc::io_error) return false;  // not yet
    show_note(state, r ? std::string(u.second ? "redid" : "undid") + " stroke " +
                             std::to_string(r->stroke_id)
                       : std::string(u.second ? "redo: " : "undo: ") + r.error().message);
    return true;
  });
  if (state.pick_request) {
    auto r = client->wait_for_pick_up(*state.pick_request, std::chrono::milliseconds(0));
    if (r) {
      if (r->density > 0) {  // empty space has no colour to take: the brush stays as it was
        for (int c = 0; c < 3; ++c) state.brush.colour[c] = r->colour[c];
        state.brush.density = r->density;
        state.brush.mode = protocol::BrushMode::paint;
      } else {
        state.note = "nothing painted there to pick up";
        state.note_at = StudioClock::now();
      }
      state.pick_request.reset();
    } else if (r.error().code != Errc::io_error) {  // io_error: not yet
      state.pick_request.reset();
    }
  }
  if (state.probe && !state.probe->ack_epoch) {
    auto a = client->wait_for_ack(state.probe->handle, std::chrono::milliseconds(0));
    if (a) state.probe->ack_epoch = a->epoch;
    else if (a.error().code != Errc::io_error) state.probe.reset();
  }
  resend_and_settle(state, link, *client);
  if (!state.viewer) send_presence(state, *client);
}

}  // namespace deepcanvas::client_app
