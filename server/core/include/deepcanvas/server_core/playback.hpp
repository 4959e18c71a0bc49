// History playback: a canvas that starts empty and paints a recorded history (a data
// directory's, a stroke log's, a painting's) forward one step at a time as its clients ask, so
// that a client can render the history as a time-lapse (PROTOCOL.md 3.13; `deepcanvas-server
// playback`). The canvas paints each step's events with replay_stroke_events, as a restart does,
// so after the step that paints event N the canvas is exactly the history's canvas at event N.
//
// Steps (playback_step_end): by operations (a stroke's end, an undo, a redo, an import: what an
// artist sees as one thing done), or by painting time: a step paints every event before the next
// multiple of T seconds after the first event not yet painted. Hours with no painting (a night, a
// break) thus take one step, not thousands of identical frames.
//
// Painting time (make_playback_history): the events' recorded wall clock where every event has
// one (a data directory's history), else the samples' t_ms where they never go backwards from one
// stroke's begin to the next (an .apa painting, a log of one replayed); else the history is
// untimed and only steps by operations are possible.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"

namespace deepcanvas::server_core {

struct PlaybackHistory {
  std::vector<StrokeEvent> events;  // in painting order
  // Painting time of each event, milliseconds from the first event, never decreasing; empty
  // when the history is untimed.
  std::vector<std::int64_t> time_ms;
  std::uint64_t operations = 0;  // events that end an operation (ends_operation)
  // Where the history paints: every sample's sphere and every import's cells, canvas metres
  // x0 y0 z0 x1 y1 z1 (clamped to the canvas); none when nothing is painted.
  std::optional<std::array<double, 6>> bounds;
  bool timed() const noexcept { return !time_ms.empty(); }
  double seconds_total() const noexcept {
    return time_ms.empty() ? 0.0 : static_cast<double>(time_ms.back()) / 1000.0;
  }
};

// A stroke's end, an undo, a redo or an import (paste).
bool ends_operation(const StrokeEvent& e) noexcept;

// The history of `events` on a canvas of shape `canvas` (bounds of imports decode their cells;
// one that does not decode adds nothing).
PlaybackHistory make_playback_history(std::vector<StrokeEvent> events, const OctreeConfig& canvas);

// Where a step from event `cursor` ends (the index of the first event it does not paint):
// `operations` > 0: just after the `operations`-th operation-ending event from the cursor (the
// end of the history when there are fewer); `seconds` > 0 (a timed history): the first event at
// or past the next multiple of `seconds` after the cursor's event's time; both 0: the cursor.
std::size_t playback_step_end(const PlaybackHistory& history, std::size_t cursor,
                              std::uint64_t operations, double seconds) noexcept;

}  // namespace deepcanvas::server_core
