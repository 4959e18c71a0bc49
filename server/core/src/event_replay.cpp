#include "deepcanvas/server_core/event_replay.hpp"

#include <algorithm>
#include <set>

namespace deepcanvas::server_core {

EventReplayTotals replay_stroke_events(Painter& painter, std::span<const StrokeEvent> events,
                                       std::uint64_t first_step_work) {
  using Kind = StrokeEvent::Kind;
  EventReplayTotals t;
  std::set<std::uint64_t> open;
  std::set<std::uint64_t> dead;  // refused or stopped: their later events are skipped
  for (const StrokeEvent& e : events) {
    ++t.events;
    t.max_stroke_id = std::max(t.max_stroke_id, e.stroke_id);
    if (dead.count(e.stroke_id)) continue;
    Result<void> r = e.kind == Kind::begin     ? painter.begin_stroke(e.brush, e.stroke_id, e.samples)
                     : e.kind == Kind::samples ? painter.add_samples(e.stroke_id, e.samples)
                                               : painter.end_stroke(e.stroke_id);
    if (!r) {
      ++t.rejected;
      dead.insert(e.stroke_id);
      open.erase(e.stroke_id);
      continue;
    }
    if (e.kind == Kind::begin) open.insert(e.stroke_id);
    bool stopped = false;
    for (bool first = true;; first = false) {
      auto more = first && first_step_work > 0 ? painter.step(std::max<std::uint64_t>(8, first_step_work))
                                               : painter.step();
      if (!more) {
        stopped = true;
        break;
      }
      if (!*more) break;
    }
    if (stopped) {
      ++t.stopped;
      dead.insert(e.stroke_id);
      open.erase(e.stroke_id);
    } else if (e.kind == Kind::end) {
      ++t.strokes_ended;
      open.erase(e.stroke_id);
    }
  }
  t.open.assign(open.begin(), open.end());
  return t;
}

}  // namespace deepcanvas::server_core
