// The studio's panels and the overlay over the 3D view (see studio.hpp).
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "deepcanvas/base/percentile.hpp"
#include "studio.hpp"

namespace deepcanvas::client_app {
namespace {

using client_core::Camera;
using client_core::DVec3;

const char* const kModeNames[] = {"paint", "erase", "recolor", "smudge", "pick-up"};
const char* const kModeKeys[] = {"B", "E", "R", "S", "I"};

ImU32 colour_u32(const float rgb[3], float alpha = 1.0f) {
  return ImGui::ColorConvertFloat4ToU32(ImVec4(rgb[0], rgb[1], rgb[2], alpha));
}

// Projects a point (metres) to window coordinates; nullopt behind the eye.
std::optional<ImVec2> project(const Camera& cam, const DVec3& p) {
  const DVec3 v = p - cam.position();
  const double z = client_core::dot(v, cam.forward());
  if (!(z > 1e-12)) return std::nullopt;
  const double sx = client_core::dot(v, cam.right()) / (z * cam.tan_half_h());
  const double sy = client_core::dot(v, cam.up()) / (z * cam.tan_half_v());
  return ImVec2(static_cast<float>((sx + 1) * 0.5 * cam.width()),
                static_cast<float>((1 - sy) * 0.5 * cam.height()));
}

// A length (metres) at a point, in window pixels.
float pixels_at(const Camera& cam, const DVec3& p, double metres) {
  const double z = client_core::dot(p - cam.position(), cam.forward());
  if (!(z > 1e-12)) return 0;
  return static_cast<float>(metres / (2.0 * z * cam.tan_half_v()) * cam.height());
}

std::string metres_text(double m) {
  char buf[64];
  if (m >= 1000)
    std::snprintf(buf, sizeof buf, "%.3g km", m / 1000);
  else if (m >= 1)
    std::snprintf(buf, sizeof buf, "%.3g m", m);
  else if (m >= 1e-3)
    std::snprintf(buf, sizeof buf, "%.3g mm", m * 1e3);
  else
    std::snprintf(buf, sizeof buf, "%.3g um", m * 1e6);
  return buf;
}

void brush_panel(StudioState& state) {
  ImGui::SetNextWindowPos(ImVec2(10, 10), ImGuiCond_FirstUseEver);
  ImGui::SetNextWindowSize(ImVec2(250, 0), ImGuiCond_FirstUseEver);
  ImGui::Begin("Brush");
  if (state.viewer) ImGui::TextDisabled("viewer: painting is off");
  int mode = static_cast<int>(state.brush.mode);
  for (int m = 0; m < protocol::kBrushModeCount; ++m) {
    char label[32];
    std::snprintf(label, sizeof label, "%s (%s)", kModeNames[m], kModeKeys[m]);
    ImGui::RadioButton(label, &mode, m);
  }
  state.brush.mode = static_cast<protocol::BrushMode>(mode);
  ImGui::ColorEdit3("colour", state.brush.colour);
  ImGui::SliderFloat("density", &state.brush.density, 0.0f, 1.0f);
  ImGui::SliderFloat("opacity", &state.brush.opacity, 0.0f, 1.0f);
  ImGui::SliderFloat("hardness", &state.brush.hardness, 0.0f, 1.0f);
  ImGui::SliderFloat("size (px)", &state.brush.size_px, 1.0f, 400.0f, "%.0f",
                     ImGuiSliderFlags_Logarithmic);
  if (!state.viewer) {
    if (ImGui::Button("Undo")) state.undo_clicked = true;
    ImGui::SameLine();
    if (ImGui::Button("Redo")) state.redo_clicked = true;
    ImGui::SameLine();
    ImGui::TextDisabled("Ctrl+Z  Ctrl+Shift+Z");
  }
  ImGui::End();
}

void artists_panel(StudioState& state, StudioLink& link) {
  ImGui::SetNextWindowPos(ImVec2(10, 290), ImGuiCond_FirstUseEver);
  ImGui::Begin("Artists", nullptr, ImGuiWindowFlags_AlwaysAutoResize);
  client_core::Client* client = link.client();
  if (!client) {
    ImGui::TextDisabled("not connected");
  } else {
    const auto others = client->presence();
    ImGui::Text("you (%s)", state.viewer ? "viewer" : "painter");
    if (others.empty()) ImGui::TextDisabled("nobody else here");
    for (std::size_t i = 0; i < others.size(); ++i) {
      const auto& a = others[i];
      ImGui::PushID(static_cast<int>(a.artist));
      ImGui::ColorButton("##c", ImVec4(a.presence.colour[0], a.presence.colour[1],
                                       a.presence.colour[2], 1.0f),
                         ImGuiColorEditFlags_NoTooltip, ImVec2(14, 14));
      ImGui::SameLine();
      ImGui::Text("%s%s", a.name.empty() ? "(no name)" : a.name.c_str(),
                  a.presence.painting ? "  painting" : "");
      ImGui::SameLine();
      if (ImGui::SmallButton("go to")) {
        const auto& p = a.presence;
        if (auto v = client_core::OrbitView::looking_at({p.eye[0], p.eye[1], p.eye[2]},
                                                        {p.target[0], p.target[1], p.target[2]},
                                                        p.vfov_deg))
          state.view = *v;
      }
      ImGui::PopID();
    }
  }
  ImGui::End();
}

std::string connection_text(const StudioLink& link) {
  char buf[512];
  switch (link.state()) {
    case StudioLink::State::live:
      // The last batch skipped epochs: this link is slower than the canvas changes, and the
      // view shows each block at its newest version as it catches up.
      if (const auto* client = link.client(); client && client->stats().behind_batches > 0) {
        std::snprintf(buf, sizeof buf, "connected, behind the canvas (%llu epochs skipped)",
                      static_cast<unsigned long long>(client->stats().epochs_skipped));
        return buf;
      }
      return "connected";
    case StudioLink::State::connecting:
      std::snprintf(buf, sizeof buf, "connecting (attempt %d)", link.attempts());
      return buf;
    case StudioLink::State::waiting:
      std::snprintf(buf, sizeof buf, "disconnected: %s; retrying in %.1f s (F5: now)",
                    link.reason().c_str(), link.retry_in_s(StudioClock::now()));
      return buf;
    case StudioLink::State::failed:
      return "cannot connect: " + link.reason() + " (F5: retry)";
  }
  return {};
}

void status_bar(StudioState& state, StudioLink& link, const char* present_mode, bool vsync,
                float height) {
  ImGuiIO& io = ImGui::GetIO();
  ImGui::SetNextWindowPos(ImVec2(0, io.DisplaySize.y - height));
  ImGui::SetNextWindowSize(ImVec2(io.DisplaySize.x, height));
  ImGui::Begin("status", nullptr,
               ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_NoMove |
                   ImGuiWindowFlags_NoSavedSettings | ImGuiWindowFlags_NoFocusOnAppearing);
  std::vector<double> ms(state.frame_ms.begin(), state.frame_ms.end());
  const double p50 = base::percentile(ms, 0.5);
  std::uint64_t cells = 0;
  if (auto* client = link.client()) {
    client->with_replica([&](const client_core::Replica& r) { cells = r.high_water_cells(); });
  }
  const double mpp =
      state.view.metres_per_pixel(state.view.distance, static_cast<std::uint32_t>(io.DisplaySize.y));
  char buf[160];
  // The line's items in the order shown, each with its rank: a window too narrow for all of them
  // drops the lowest-ranked first (0: always shown), so the line is never cut mid-item.
  struct Item {
    std::string text;
    int rank;
  };
  std::vector<Item> items;
  items.push_back({connection_text(link) + "  |", 0});
  std::snprintf(buf, sizeof buf, "%.1f fps  frame %.1f ms", p50 > 0 ? 1000.0 / p50 : 0.0, p50);
  items.push_back({buf, 1});
  std::snprintf(buf, sizeof buf, "(view %.1f ms at %.2fx)", state.render_ms, state.rendered_scale);
  items.push_back({buf, 5});
  std::snprintf(buf, sizeof buf, "epoch %llu", static_cast<unsigned long long>(state.resident_epoch));
  items.push_back({buf, 6});
  std::snprintf(buf, sizeof buf, "cells %llu", static_cast<unsigned long long>(cells));
  items.push_back({buf, 3});
  items.push_back({metres_text(mpp) + "/px", 4});
  if (state.last_latency_ms >= 0)
    std::snprintf(buf, sizeof buf, "last stroke sent->visible %.0f ms", state.last_latency_ms);
  else
    std::snprintf(buf, sizeof buf, "last stroke sent->visible -");
  items.push_back({buf, 2});
  items.push_back({std::string(present_mode) + (vsync ? " vsync" : ""), 7});
  const float gap = ImGui::CalcTextSize("  ").x;
  float room = ImGui::GetContentRegionAvail().x;
  std::vector<bool> shown(items.size(), false);
  for (int rank = 0; rank <= 7; ++rank) {
    for (std::size_t i = 0; i < items.size(); ++i) {
      if (items[i].rank != rank) continue;
      const float w = ImGui::CalcTextSize(items[i].text.c_str()).x + gap;
      if (rank > 0 && w > room) continue;
      shown[i] = true;
      room -= w;
    }
  }
  std::string line;
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (!shown[i]) continue;
    if (!line.empty()) line += "  ";
    line += items[i].text;
  }
  ImGui::TextUnformatted(line.c_str());
  ImGui::End();
}

void help_panel(StudioState& state) {
  if (!state.show_help) return;
  ImGui::SetNextWindowPos(ImVec2(280, 10), ImGuiCond_FirstUseEver);
  ImGui::Begin("Keys", &state.show_help, ImGuiWindowFlags_AlwaysAutoResize);
  ImGui::TextUnformatted(
      "left drag       paint (pick-up mode: take the colour under the pointer)\n"
      "right drag      orbit            shift+right / middle drag  pan\n"
      "wheel           zoom toward the point under the pointer\n"
      "arrows          orbit            shift+arrows  pan\n"
      "PgUp PgDn + -   dolly\n"
      "B E R S I       paint, erase, recolor, smudge, pick-up (or 1-5)\n"
      "[ ]             brush size\n"
      "F               frame everything  G  frame the last stroke\n"
      "Tab             jump to the next artist's view\n"
      "P / F12         screenshot (PNG)   F9  print the view\n"
      "V               vsync on/off       F11 fullscreen\n"
      "F5              reconnect now      H / F1  this help\n"
      "Ctrl+Z          undo your last stroke (others' strokes stay)\n"
      "Ctrl+Shift+Z    redo (or Ctrl+Y)\n"
      "Ctrl+Q          quit");
  ImGui::End();
}

}  // namespace

void draw_panels(StudioState& state, StudioLink& link, const char* present_mode, bool vsync) {
  brush_panel(state);
  artists_panel(state, link);
  help_panel(state);
  status_bar(state, link, present_mode, vsync, ImGui::GetFrameHeightWithSpacing() + 8);
  if (!state.note.empty() && StudioClock::now() - state.note_at < std::chrono::seconds(4)) {
    ImGuiIO& io = ImGui::GetIO();
    ImGui::SetNextWindowPos(ImVec2(io.DisplaySize.x * 0.5f, 40), ImGuiCond_Always,
                            ImVec2(0.5f, 0));
    ImGui::Begin("note", nullptr,
                 ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_AlwaysAutoResize |
                     ImGuiWindowFlags_NoSavedSettings | ImGuiWindowFlags_NoFocusOnAppearing);
    ImGui::TextUnformatted(state.note.c_str());
    ImGui::End();
  }
  if (link.state() != StudioLink::State::live) {
    ImGuiIO& io = ImGui::GetIO();
    ImGui::SetNextWindowPos(ImVec2(io.DisplaySize.x * 0.5f, io.DisplaySize.y * 0.5f),
                            ImGuiCond_Always, ImVec2(0.5f, 0.5f));
    ImGui::Begin("connection", nullptr,
                 ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_AlwaysAutoResize |
                     ImGuiWindowFlags_NoSavedSettings);
    ImGui::TextUnformatted(connection_text(link).c_str());
    // Strokes kept for a resend: the artist sees that the dropped connection lost nothing.
    if (!state.unacked.empty())
      ImGui::Text("%s not acknowledged yet, kept: sent when the server is back",
                  strokes_text(state.unacked.size()).c_str());
    ImGui::End();
  }
}

void draw_overlay(StudioState& state, StudioLink& link, std::uint32_t win_w,
                  std::uint32_t win_h) {
  auto cam = state.view.camera(win_w, win_h);
  if (!cam) return;
  ImDrawList* dl = ImGui::GetBackgroundDrawList();
  // A stroke's stamps in its brush's colour (erasing: white).
  const auto draw_stroke = [&](const protocol::Brush& brush,
                               const std::vector<protocol::StrokeSample>& samples) {
    const float rgb[3] = {brush.colour[0], brush.colour[1], brush.colour[2]};
    const ImU32 c = brush.mode == protocol::BrushMode::erase ? IM_COL32(255, 255, 255, 160)
                                                             : colour_u32(rgb, 0.85f);
    std::optional<ImVec2> prev;
    for (const auto& s : samples) {
      const DVec3 p{s.x, s.y, s.z};
      const auto q = project(*cam, p);
      if (!q) continue;
      const float r = std::max(1.0f, pixels_at(*cam, p, s.radius));
      if (prev) dl->AddLine(*prev, *q, c, 2.0f * r);
      dl->AddCircleFilled(*q, r, c);
      prev = q;
    }
  };
  // The strokes kept for the next connection (painted while there was none, or cut off by its
  // end): the canvas does not hold them yet.
  for (const UnackedStroke& u : state.unacked)
    if (u.sent_on != link.connections() || !link.client())
      draw_stroke(u.stroke.brush, u.stroke.samples);
  // The stroke being painted, at once.
  if (state.stroke) draw_stroke(state.stroke->brush, state.stroke->samples);
  // The cursor ring: the brush's size where it would paint.
  const ImGuiIO& io = ImGui::GetIO();
  if (state.cursor_on_view && !state.viewer) {
    const ImVec2 m = io.MousePos;
    dl->AddCircle(m, state.brush.size_px, IM_COL32(0, 0, 0, 200), 48, 3.0f);
    dl->AddCircle(m, state.brush.size_px, colour_u32(state.brush.colour), 48, 1.5f);
  }
  // The other artists' cursors: a ring in their colour, their name beside it.
  if (auto* client = link.client()) {
    for (const auto& a : client->presence()) {
      const auto& p = a.presence;
      if (!p.cursor_on_canvas) continue;
      const DVec3 at{p.cursor[0], p.cursor[1], p.cursor[2]};
      const auto q = project(*cam, at);
      if (!q) continue;
      const float rgb[3] = {p.colour[0], p.colour[1], p.colour[2]};
      const float r = std::clamp(pixels_at(*cam, at, std::max(p.size_m, 0.0)), 6.0f, 200.0f);
      dl->AddCircleFilled(*q, 5.0f, colour_u32(rgb));
      dl->AddCircle(*q, r, colour_u32(rgb), 32, 2.0f);
      state.drawn_presence.push_back({a.artist, {p.cursor[0], p.cursor[1], p.cursor[2]}});
      const std::string name = a.name.empty() ? "artist " + std::to_string(a.artist) : a.name;
      dl->AddText(ImVec2(q->x + r + 4, q->y - 8), IM_COL32(255, 255, 255, 230), name.c_str());
    }
  }
}

}  // namespace deepcanvas::client_app
