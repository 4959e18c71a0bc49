// History playback's bookkeeping: painting times, bounds, and where a step ends (playback.hpp).
#include "deepcanvas/server_core/playback.hpp"

#include <algorithm>
#include <cmath>

#include "deepcanvas/server_core/cell_paste.hpp"

namespace deepcanvas::server_core {

namespace {

using Kind = StrokeEvent::Kind;

// Wall clock where every event has one; else the samples' t_ms, carried forward through events
// without samples, when the strokes' begins never go back in time; else none.
std::vector<std::int64_t> painting_times(const std::vector<StrokeEvent>& events) {
  std::vector<std::int64_t> t;
  if (events.empty()) return t;
  const bool wall = std::all_of(events.begin(), events.end(), [](const StrokeEvent& e) { return e.time_ms > 0; });
  if (wall) {
    t.reserve(events.size());
    const std::int64_t t0 = events.front().time_ms;
    std::int64_t last = 0;
    for (const auto& e : events) t.push_back(last = std::max(last, e.time_ms - t0));
    return t;
  }
  // Sample times: a begin earlier than the previous begin means the times restart per stroke
  // (a client's own clock), which says nothing about painting time.
  std::int64_t last_begin = -1;
  bool any = false;
  for (const auto& e : events) {
    if (e.kind != Kind::begin || e.samples.empty()) continue;
    const std::int64_t b = e.samples.front().t_ms;
    if (b < last_begin) return {};
    last_begin = b;
    any = any || b > 0;
  }
  if (!any) return {};
  t.reserve(events.size());
  std::int64_t t0 = -1, last = 0;
  for (const auto& e : events) {
    if (!e.samples.empty()) {
      const std::int64_t s = e.samples.front().t_ms;
      if (t0 < 0) t0 = s;
      last = std::max(last, s - t0);
    }
    t.push_back(last);
  }
  return t;
}

void grow(std::optional<std::array<double, 6>>& b, double x0, double y0, double z0, double x1,
          double y1, double z1) {
  if (!b) {
    b = std::array<double, 6>{x0, y0, z0, x1, y1, z1};
    return;
  }
  auto& v = *b;
  v[0] = std::min(v[0], x0), v[1] = std::min(v[1], y0), v[2] = std::min(v[2], z0);
  v[3] = std::max(v[3], x1), v[4] = std::max(v[4], y1), v[5] = std::max(v[5], z1);
}

}  // namespace

bool ends_operation(const StrokeEvent& e) noexcept {
  return e.kind == Kind::end || e.kind == Kind::undo || e.kind == Kind::redo ||
         e.kind == Kind::paste;
}

PlaybackHistory make_playback_history(std::vector<StrokeEvent> events, const OctreeConfig& canvas) {
  PlaybackHistory h;
  h.time_ms = painting_times(events);
  const double half = canvas.edge_m / 2;
  const double root_edge = canvas.edge_m / canvas.roots_per_axis;
  for (const auto& e : events) {
    if (ends_operation(e)) ++h.operations;
    for (const auto& s : e.samples) {
      const double r = std::isfinite(s.radius) ? std::max(0.0f, s.radius) : 0.0;
      if (!std::isfinite(s.x) || !std::isfinite(s.y) || !std::isfinite(s.z)) continue;
      grow(h.bounds, s.x - r, s.y - r, s.z - r, s.x + r, s.y + r, s.z + r);
    }
    if (e.kind == Kind::paste) {
      auto cells = decode_cell_paste(e.paste, canvas);
      if (!cells) continue;
      for (const auto& c : cells->cells) {
        const double edge = std::ldexp(root_edge, -c.cell.depth);
        grow(h.bounds, -half + c.cell.x * edge, -half + c.cell.y * edge, -half + c.cell.z * edge,
             -half + (c.cell.x + 1.0) * edge, -half + (c.cell.y + 1.0) * edge,
             -half + (c.cell.z + 1.0) * edge);
      }
    }
  }
  if (h.bounds)
    for (auto& v : *h.bounds) v = std::clamp(v, -half, half);
  h.events = std::move(events);
  return h;
}

std::size_t playback_step_end(const PlaybackHistory& h, std::size_t cursor,
                              std::uint64_t operations, double seconds) noexcept {
  const std::size_t n = h.events.size();
  if (cursor >= n) return n;
  if (operations > 0) {
    std::size_t i = cursor;
    for (std::uint64_t done = 0; i < n && done < operations; ++i)
      if (ends_operation(h.events[i])) ++done;
    return i;
  }
  if (seconds > 0 && h.timed()) {
    const double step_ms = seconds * 1000.0;
    const double mark = (std::floor(static_cast<double>(h.time_ms[cursor]) / step_ms) + 1) * step_ms;
    std::size_t i = cursor;
    while (i < n && static_cast<double>(h.time_ms[i]) < mark) ++i;
    return i;
  }
  return cursor;
}

}  // namespace deepcanvas::server_core
