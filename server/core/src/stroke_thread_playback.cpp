// The stroke thread's history playback: a playback step at a pick-up's place
// (stroke_thread.hpp; CanvasService::play, playback.hpp).
#include "deepcanvas/server_core/event_replay.hpp"
#include "stroke_thread.hpp"

namespace deepcanvas::server_core {

using base::log_event;
using base::LogLevel;
using stroke_thread_detail::seconds_between;

// The history's next events, painted as a restart replays them (each to completion, the first
// step of each cut as the live canvas cut it), with the canvas's own undo history keeping the
// changes later undo events take back. The answer goes out with the epoch that holds them.
void CanvasService::Impl::StrokeThread::run_playback(Job& j) {
  PlaybackFn done = std::move(j.playback_done);
  if (!painter) {
    done(painter_error);
    return;
  }
  const PlaybackHistory& h = *config.playback;
  const std::size_t end =
      playback_step_end(h, playback_cursor, j.playback_operations, j.playback_seconds);
  if (end > playback_cursor) {
    const auto t0 = Clock::now();
    const std::span<const StrokeEvent> step(h.events.data() + playback_cursor, end - playback_cursor);
    const EventReplayTotals t = replay_stroke_events(*painter, step, config.max_cells_first_step, &history);
    for (const StrokeEvent& e : step)
      if (ends_operation(e)) ++playback_operations;
    playback_cursor = end;
    metrics.strokes.add(t.strokes_ended);
    metrics.undos.add(t.undos);
    metrics.imports.add(t.pastes);
    log_event(LogLevel::debug, "playback_step",
              {{"canvas", config.name},
               {"events", t.events},
               {"rejected", t.rejected},
               {"stopped", t.stopped},
               {"position", playback_cursor},
               {"seconds", seconds_between(t0, Clock::now())}});
  }
  PlaybackDone answer;
  answer.epoch = epoch + 1;
  answer.events = playback_cursor;
  answer.operations = playback_operations;
  answer.painting_seconds =
      h.timed() && playback_cursor > 0 ? static_cast<double>(h.time_ms[playback_cursor - 1]) / 1000.0 : 0.0;
  force_epoch = true;
  after_publish.push_back([done = std::move(done), answer] { done(answer); });
}

}  // namespace deepcanvas::server_core
