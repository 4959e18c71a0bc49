// The stroke thread's decisions (stroke_thread.cpp), each a pure function of named inputs: no
// threads, no locks, no clock read (times come in as arguments). The stroke thread gathers the
// inputs and acts on the answer; tests/server/stroke_scheduler_test.cpp pins each decision.
#pragma once

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <optional>
#include <span>

namespace deepcanvas::server_core::stroke_scheduler {

using Clock = std::chrono::steady_clock;

// A streamed stroke that gets no samples for this long is ended by the server, so one idle
// artist cannot hold the canvas (the default of CanvasServiceConfig::idle_stroke_timeout).
inline constexpr auto kIdleStreamTimeout = std::chrono::seconds(2);
// While a streamed stroke is open and nothing else is to do, the stroke thread wakes this often
// (or after the idle timeout, if shorter) to end it once it has been idle for the timeout.
inline constexpr auto kIdleStreamPoll = std::chrono::milliseconds(100);
inline Clock::duration idle_poll(Clock::duration timeout) {
  return std::min<Clock::duration>(kIdleStreamPoll, timeout);
}
// While only staging is left and the compress thread is behind, the stroke thread waits this
// long for it (the compress thread also notifies when it catches up).
inline constexpr auto kCompressPoll = std::chrono::milliseconds(5);
// A stroke's first epoch is encoded on the stroke thread (no hand-off) when it has at most this
// many blocks and the compress thread is idle: a few blocks encode in less time than a hand-off
// takes, more would hold the painting up (histogram deepcanvas_compress_seconds).
inline constexpr std::size_t kMaxInlineBlocks = 16;

// ------------------------------------------------------------------------------------ queue

// How the stroke thread waits before taking the queued jobs.
enum class QueueWait {
  none,         // something is to do: take the queue as it is and go on
  for_job,      // idle: sleep until a job arrives or the canvas stops
  idle_stream,  // idle with a streamed stroke open: sleep at most kIdleStreamPoll
  compress,     // only staging is left and the compress thread is behind: kCompressPoll
  epoch_interval,  // only staging is left and the last epoch is too recent: until it is not
};

struct QueueState {
  bool have_work = false;        // painter busy, dirty blocks, replies or a forced epoch pending
  bool jobs_queued = false;      // the job queue is not empty
  bool stopping = false;         // the canvas is stopping
  bool painter_busy = false;     // the painter has steps to run or a turn to take
  bool stream_open = false;      // a streamed stroke is open, or an artist waits for its budget
  bool compress_behind = false;  // the compress backlog is above max_compress_backlog
  bool epoch_too_soon = false;   // the only work is dirty blocks waiting for the epoch interval
};

inline QueueWait choose_queue_wait(const QueueState& s) {
  if (!s.have_work && !s.jobs_queued && !s.stopping)
    return s.stream_open ? QueueWait::idle_stream : QueueWait::for_job;
  if (s.have_work && s.compress_behind && !s.jobs_queued && !s.painter_busy)
    return QueueWait::compress;
  if (s.have_work && s.epoch_too_soon && !s.jobs_queued && !s.painter_busy && !s.stopping)
    return QueueWait::epoch_interval;
  return QueueWait::none;
}

// ------------------------------------------------------------------------------------ turns

// Strokes take turns: the painter is given one piece of work at a time (a stroke's begin, at
// most kSamplesPerTurn of its samples, or its end) and paints it to completion before the next
// turn, so a stroke held open, or a long one sent whole, delays another artist's stroke by one
// turn, not by the whole stroke. The default of CanvasServiceConfig::samples_per_turn.
inline constexpr std::size_t kSamplesPerTurn = 64;

// A turn's samples are also sized by what the stroke's samples have cost to paint, while other
// strokes are open (`others_open`: their input may arrive during the turn): a heavy brush (a
// wide stamp recolours tens of thousands of cells, ~25 ms a sample on one core) then gets turns
// of about CanvasServiceConfig::turn_seconds of painting, at least one sample, so the others
// wait one such turn instead of up to samples_per_turn of its samples (in deepcanvas-bench load,
// turns of one stroke took up to 414 ms, and every artist's ack waited behind them). The split
// is recorded with the turns (StrokeEvent), so a replay is the same. The samples of the next
// turn: `configured` (samples_per_turn) when the stroke is the only one open, sizing is off
// (turn_seconds 0) or its cost is not known yet (seconds_per_sample 0), else as many as fit
// turn_seconds.
inline std::size_t turn_samples(std::size_t configured, double turn_seconds,
                                double seconds_per_sample, bool others_open) {
  if (!others_open || !(turn_seconds > 0) || !(seconds_per_sample > 0)) return configured;
  const double fit = turn_seconds / seconds_per_sample;
  if (fit >= static_cast<double>(configured)) return configured;
  return std::max<std::size_t>(1, static_cast<std::size_t>(fit));
}

// Round robin: of the strokes with input waiting (`ready`, ascending ids), the first after the
// stroke that had the last turn, wrapping around to the lowest.
inline std::optional<std::uint64_t> next_turn(std::span<const std::uint64_t> ready,
                                              std::uint64_t last_turn) {
  if (ready.empty()) return std::nullopt;
  const auto it = std::upper_bound(ready.begin(), ready.end(), last_turn);
  return it != ready.end() ? *it : ready.front();
}

// Strokes whose end has come (and undos and imports) go first: a stroke_end then waits for the
// turn in progress and at most one other finishing turn, not for a round of every artist's turns
// (deepcanvas-bench load: ack p99 with 8 painters). At most kMaxFinishingRun finishing turns go
// in a row, and the caller leaves out of `finishing` the strokes of the artist whose finishing
// turn was the last, so a stroke still streaming gets at least every third turn and one artist's
// flood of small strokes at most every other turn.
inline constexpr int kMaxFinishingRun = 2;
inline std::optional<std::uint64_t> next_turn(std::span<const std::uint64_t> ready,
                                              std::span<const std::uint64_t> finishing,
                                              std::uint64_t last_turn, int finishing_run) {
  if (!finishing.empty() && finishing_run < kMaxFinishingRun) return next_turn(finishing, last_turn);
  return next_turn(ready, last_turn);
}

// Each artist may grow the canvas by at most CanvasServiceConfig::max_cells_per_second_per_artist
// cells a second on average (a token bucket holding at most one second's worth): an artist in
// debt gets no turn until the bucket is refilled, so one artist cannot fill the canvas for
// everyone, and the others take the turns meanwhile. Cells are charged after the turn that made
// them (a turn is never cut short), so the debt is at most one turn's cells.
struct CellBudget {
  double tokens = 0;  // cells the artist may still create; negative: in debt
  Clock::time_point refilled;
};
inline void refill(CellBudget& b, double cells_per_second, Clock::time_point now) {
  const double dt = std::chrono::duration<double>(now - b.refilled).count();
  b.tokens = std::min(cells_per_second, b.tokens + cells_per_second * std::max(0.0, dt));
  b.refilled = now;
}
inline bool may_take_turn(const CellBudget& b) {
  return b.tokens >= 0;
}
// How long until a budget in debt may take a turn again.
inline Clock::duration until_turn(const CellBudget& b, double cells_per_second) {
  if (b.tokens >= 0 || !(cells_per_second > 0)) return Clock::duration::zero();
  return std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(-b.tokens / cells_per_second));
}

// ------------------------------------------------------------------------------------ steps

// New samples get a small first step, which ends an epoch of its own: the stroke's first blocks
// are then few, so staging, encoding and sending them takes little time (with a full-size first
// step, encoding the first epoch's many blocks would be most of the stroke -> first block
// latency: deepcanvas-bench server). The result does not depend on the step sizes.
inline std::uint64_t step_budget(bool first_step, std::uint64_t max_cells_first_step,
                                 std::uint64_t max_cells_per_step) {
  return first_step ? std::min(max_cells_first_step, max_cells_per_step) : max_cells_per_step;
}

// A streamed stroke whose last input is older than `timeout` is ended by the server.
inline bool idle_stream_expired(bool ended, Clock::time_point last_input, Clock::time_point now,
                                Clock::duration timeout = kIdleStreamTimeout) {
  return !ended && now - last_input > timeout;
}

// An ended stroke's ack is due once its paint is all in the tree: when the painter finished the
// stroke, or said its paint is complete (Painter::stroke_painted; what follows is merging uniform
// children back: storage, not picture, which a client need not wait for).
inline bool ack_due(bool stroke_finishing, bool already_painted, bool finished,
                    bool painter_says_painted) {
  return stroke_finishing && !already_painted && (finished || painter_says_painted);
}

// ------------------------------------------------------------------------------------ undo

// A finished stroke's change is sorted on the stroke thread when it is handed over
// (hand_over_changes: CellDiffRecorder::take, up to ~30 ms for a large stroke on a loaded
// machine) and then encoded on the undo encoder's thread (change_encoder.hpp). While another
// stroke's ack waits (its end has come, its paint is not all in the tree), the hand-over waits
// too, so that the ack does not (deepcanvas-bench load: up to 18 ms of an ack's 62 ms went to
// other strokes' changes). At most kMaxChangesDeferred changes wait: their recordings stay
// counted against the undo budget meanwhile, and an undo, import or checkpoint keeps them first
// anyway. Past that bound, while acks still wait, only the oldest changes over it go, usually
// one per iteration, rather than up to 16 sorts in a row. Returns how many of the waiting
// changes to hand over.
inline constexpr std::size_t kMaxChangesDeferred = 16;
inline std::size_t changes_to_hand_over(bool acks_waiting, std::size_t changes_waiting,
                                        bool stopping) {
  if (!acks_waiting || stopping) return changes_waiting;
  return changes_waiting >= kMaxChangesDeferred ? changes_waiting - kMaxChangesDeferred + 1 : 0;
}

// ------------------------------------------------------------------------------------ staging

struct StagingState {
  bool force_epoch = false;      // an epoch must be staged now (quiesce)
  bool replies_first = false;    // CanvasServiceConfig::replies_first
  bool replies_pending = false;  // acks or replies wait for the next epoch's publish
  int compress_backlog = 0;      // staged epochs not yet published
  int max_backlog = 0;           // CanvasServiceConfig::max_compress_backlog (>= 0)
  bool idle = false;             // nothing for the painter to do
  bool stopping = false;         // the canvas is stopping
  bool too_soon = false;         // less than min_epoch_interval since the last epoch
};

// Whether the stroke thread ends an epoch after this iteration. Replies first: an epoch carrying
// acks is staged now, one epoch beyond the backlog cap, rather than after the steps that follow.
// Any other epoch waits while the last one is more recent than min_epoch_interval (too_soon).
inline bool stage_now(const StagingState& s) {
  const bool replies_now =
      s.replies_first && s.replies_pending && s.compress_backlog <= s.max_backlog + 1;
  if (s.force_epoch || replies_now || (s.idle && s.stopping)) return true;
  return s.compress_backlog <= s.max_backlog && !s.too_soon;
}

// A staged epoch may be encoded and published on the stroke thread: it is a stroke's first epoch,
// small, and nothing is queued or being encoded (the backlog counts both, and only the stroke
// thread adds to it, so publishing there keeps the epoch order).
inline bool publish_inline(bool first_epoch_of_samples, std::size_t blocks, int compress_backlog) {
  return first_epoch_of_samples && blocks <= kMaxInlineBlocks && compress_backlog == 0;
}

}  // namespace deepcanvas::server_core::stroke_scheduler
