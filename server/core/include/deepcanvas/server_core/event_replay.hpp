// Replaying stroke events onto a painter: each event painted to completion before the next, the
// order that reproduces a canvas painted with several strokes interleaved (stroke_log.hpp). Used
// by restart (a checkpoint plus the events after it) and by tools.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"
#include "deepcanvas/server_core/undo_history.hpp"

namespace deepcanvas::server_core {

struct EventReplayTotals {
  std::uint64_t events = 0;
  std::uint64_t strokes_ended = 0;   // end events applied
  std::uint64_t rejected = 0;        // events the painter refused (a stroke never begun, ...)
  std::uint64_t stopped = 0;         // strokes a limit stopped while they painted (as live)
  std::uint64_t undos = 0;           // undo and redo events applied
  std::uint64_t pastes = 0;          // paste events (imports) applied
  std::uint64_t max_stroke_id = 0;   // the largest stroke id seen
  struct OpenStroke {
    std::uint64_t stroke_id = 0;
    std::uint64_t artist = 0;  // its begin event's
  };
  std::vector<OpenStroke> open;      // strokes begun and not ended, in id order
};

// Stroke ids are used as they are (one canvas's history has unique ids). An event the painter
// refuses is counted and skipped, as are the later events of a stroke it refused or stopped:
// the live canvas did the same, so the result is still that canvas.
// `first_step_work`: the budget of the first step after each event (0: the painter's own), as
// the canvas's stroke thread cut it (CanvasServiceConfig::max_cells_first_step): how the work
// is cut into steps decides where cells land in the pools, so a replay that must reproduce
// pool_hash too cuts it the same way.
// Undo and redo events revert the named stroke's recorded change (the painter records changes
// from the first event on). `history` (optional) is the canvas's undo history, as a checkpoint
// left it: strokes that end are added to it (under the artist of the stroke's begin event, as
// the live canvas keeps a stroke under its sender whoever ends it) and undos move its entries,
// as the live canvas did; without one, the changes of the strokes the events undo are kept
// here for the replay. An undo the history cannot answer is counted in `rejected`. A paste event
// (an import) is decoded against the painter's canvas and pasted; its change goes into the
// history like a stroke's; one that does not decode or does not fit is counted in `rejected`.
EventReplayTotals replay_stroke_events(Painter& painter, std::span<const StrokeEvent> events,
                                       std::uint64_t first_step_work = 0,
                                       UndoHistory* history = nullptr);

}  // namespace deepcanvas::server_core
