// The stroke thread's state (CanvasService::Impl::StrokeThread) and the strokes it knows,
// shared by its source files: stroke_thread.cpp (queue, turns, steps, staging, replies) and
// stroke_thread_undo.cpp (undo and the undo history), stroke_thread_paste.cpp (imports). Private
// to server_core.
#pragma once

#include <algorithm>
#include <map>
#include <set>

#include "canvas_service_impl.hpp"
#include "change_encoder.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "stroke_scheduler.hpp"

namespace deepcanvas::server_core {

namespace stroke_thread_detail {

// A stroke known to the stroke thread: whole, or streamed (pieces may arrive before it is
// active).
struct PendingStroke {
  std::uint64_t id = 0;
  std::uint64_t artist = 0;  // its strokes are painted in order (CanvasService::submit_stroke)
  std::uint64_t handle = 0;  // its sender's handle (journaled with the begin; 0: none)
  bool begun = false;                             // the begin (or whole stroke) arrived
  bool ended = false;                             // end arrived (whole strokes: at once)
  bool opened = false;                            // the painter has begun it
  bool end_given = false;                         // the painter has its end
  std::optional<protocol::ValidatedBrush> brush;  // from the begin (or whole stroke)
  protocol::ValidatedSamples samples;             // samples [given, size) wait for the painter
  std::size_t given = 0;
  Clock::time_point received;
  Clock::time_point last_input;
  Clock::time_point ended_at;    // stroke_end (or the whole stroke) received
  Clock::time_point painted_at;  // all of its paint in the tree (Painter::stroke_painted)
  // What its samples cost to paint (stroke_scheduler::turn_samples): the painter's step time of
  // its last turn of samples over their count; 0 until one is done.
  double seconds_per_sample = 0;
  double turn_step_seconds = 0;    // the current turn's steps so far
  std::size_t turn_samples = 0;    // the current turn's samples (the end's held-back one: 1)
  bool painted = false;
  bool idle_ended = false;  // the server ended it after idle_stroke_timeout without samples
  bool cut = false;  // ended for its sender's closed connection (end_stroke, EndedBy::server)
  bool stopped = false;  // a limit stopped it (add_samples): its sender has the error
  std::uint64_t last_seq = 0;  // the journal's number of its last recorded event
  AckFn done;  // fired (and emptied) by the ack, or by the error that replaces it
  // An undo or redo (CanvasService::undo) waiting for its turn among the artist's strokes.
  enum class Op { stroke, undo, redo, paste } op = Op::stroke;
  std::uint64_t undo_stroke = 0;  // undo: this stroke instead of the artist's latest (0)
  UndoFn undo_done;
  // An import (CanvasService::paste) waiting for its turn.
  std::shared_ptr<const CellPaste> paste;
  ImportFn import_done;
};

inline std::string idle_reason_for(std::chrono::milliseconds timeout) {
  return "the server ended it after " + std::to_string(timeout.count()) +
         " ms without samples (its paint is kept and acked); begin a new stroke to go on";
}

inline double seconds_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

}  // namespace stroke_thread_detail
using stroke_thread_detail::PendingStroke;

// The stroke thread's state, named: the queue's strokes (the first is the active one), the
// painter's progress, what the next epoch carries, and the requests waiting on strokes.
struct CanvasService::Impl::StrokeThread {
  StrokeThread(Impl& impl, const CanvasServiceConfig& config, CanvasMetrics& metrics);
  void run();

  // One iteration, in order.
  std::deque<Job> take_jobs(bool& stop_now);
  void take(Job& j, Clock::time_point now);
  bool feed_painter(Clock::time_point now);  // true: samples were given to the painter
  void refuse_strokes(const Error& e);  // every stroke waiting gets `e` (no painter, stopping)
  bool run_step();                           // true: it was the first step after new samples
  void stroke_failed(const Error& e);
  void stroke_painted(PendingStroke& s);
  void stroke_settled(PendingStroke& s);
  bool epoch_too_soon() const;  // the last epoch is within min_epoch_interval, and it applies
  bool interiors_due() const;    // no stroke is open and interior values lag: stage an epoch
  void maybe_stage(bool stop_now, bool first_step_ran);
  void answer_picks();
  void shut_down();

  // Helpers.
  bool idle() const;
  bool stream_open() const;
  bool acks_waiting() const;  // a stroke's end has come and its paint is not all in the tree
  bool waits_for_budget() const;
  bool has_turn_input(const PendingStroke& s) const;
  std::vector<std::uint64_t> ready_strokes() const;
  void refill_budgets(Clock::time_point now);
  void charge_turn(std::uint64_t artist, Clock::time_point now);
  void give_turn(PendingStroke& s, Clock::time_point now, bool others_open);
  void end_idle_streams(Clock::time_point now);
  void record(StrokeEvent::Kind kind, PendingStroke& s,
              std::span<const protocol::StrokeSample> samples);
  void checkpoint_poll();
  void checkpoint_step(bool all_at_once);
  bool checkpoint_can_step() const {
    return checkpoint_active && painter && !painter_busy && painter->open_strokes() == 0;
  }
  void fail_stroke(PendingStroke& s, const Error& e);
  void run_undo(std::uint64_t id);
  void run_paste(std::uint64_t id);
  void run_playback(Job& j);  // a playback step (CanvasService::play), at a pick-up's place
  // An operation's answer (undo, import) once the next epoch is numbered and its history event
  // `seq` is durable where the canvas keeps a journal.
  template <class T>
  void answer_when_durable(std::uint64_t seq, std::function<void(Result<T>)> done, T answer) {
    if (!config.journal) {
      replies.push_back([done = std::move(done), answer] { done(answer); });
      return;
    }
    replies.push_back([journal = config.journal, seq, done = std::move(done), answer]() mutable {
      journal->when_durable(seq, [done = std::move(done), answer](Result<void> r) {
        if (r)
          done(answer);
        else
          done(std::move(r).error());
      });
    });
  }
  // The undo history's changes: handed to the encoder (the oldest `at_most` of those waiting:
  // finished strokes' first, then reverts), taken back into `history` (in order), and all at
  // once, waiting for the encoder (before an undo, import or checkpoint).
  void hand_over_changes(std::size_t at_most = static_cast<std::size_t>(-1));
  void keep_encoded(std::vector<ChangeEncoder::Change> done);
  void keep_changes();
  void add_quiesce_replies();
  std::string idle_reason() const { return stroke_thread_detail::idle_reason_for(config.idle_stroke_timeout); }
  void end_epoch(bool force, bool inline_ok = false);

  Impl& m;
  const CanvasServiceConfig& config;
  CanvasMetrics& metrics;
  const int max_backlog;
  std::unique_ptr<Painter> painter;  // null if it could not be made: see painter_error
  Error painter_error;               // why there is no painter; each stroke is answered with it
  UndoHistory history;               // each artist's strokes that may be undone (undo_history.hpp)
  // Strokes finished whose changes are not in `history` yet (artist, stroke): sorting and
  // encoding a change waits until the epoch with the stroke's ack is staged, and while other
  // strokes' acks wait (stroke_scheduler::changes_to_hand_over).
  std::vector<std::pair<std::uint64_t, std::uint64_t>> unkept;
  // Undos and redos done whose change is not encoded into `history` yet (the same wait).
  struct UnkeptRevert {
    std::uint64_t artist = 0, stroke = 0;
    bool redo = false;
    CellDiff change;
  };
  std::vector<UnkeptRevert> unkept_reverts;
  ChangeEncoder encoder;  // encodes the changes handed over, on a thread of its own

  // Strokes by id: open ones and those whose begin waits for its turn.
  std::map<std::uint64_t, PendingStroke> strokes;
  // Turns and steps.
  std::uint64_t active = 0;       // the stroke whose turn the painter is painting, 0 = none
  std::uint64_t last_turn = 0;    // the stroke that had the last turn (round robin)
  std::uint64_t last_turn_artist = 0;
  int finishing_run = 0;  // finishing turns in a row up to the last (stroke_scheduler::next_turn)
  std::uint64_t turn_cells = 0;   // the active stroke's cells_created when its turn began
  // Cell growth budgets of the artists with strokes here (stroke_scheduler::CellBudget), and whether one
  // of them was in debt with input waiting at the last refill (counts throttled turns once).
  std::map<std::uint64_t, stroke_scheduler::CellBudget> budgets;
  bool throttled = false;
  bool painter_busy = false;      // step() said more work is pending
  bool first_step_next = false;
  Clock::time_point last_epoch_at{};  // when the last epoch was staged (min_epoch_interval)
  Clock::time_point last_exact_interiors_at{};  // its last exact take (interior_refresh_interval)
  bool epoch_painting_steps = false;  // since the last epoch: a step of a stroke not yet painted
  bool epoch_merging_steps = false;   // ... a step of a painted stroke (merging back)   // the next step is the first after new samples: keep it small
  std::uint64_t completed = 0;    // strokes painted and settled
  // Staging: what the next epoch carries.
  std::uint64_t epoch = 0;                   // last staged epoch
  // Answers the next epoch carries: replies go out once it is numbered (acks, errors, undo and
  // import replies: they need its number only); after_publish once it is published (quiesce
  // replies, playback positions: they describe what the viewers have).
  std::vector<std::function<void()>> replies;
  std::vector<std::function<void()>> after_publish;
  bool answers_waiting() const { return !replies.empty() || !after_publish.empty(); }
  void send_replies();
  // Durable storage (CanvasServiceConfig::journal): the last event recorded, the largest stroke
  // id recorded, and the checkpoint being copied out (see checkpoint_step).
  std::uint64_t last_seq = 0;
  std::uint64_t max_recorded_id = 0;
  std::uint64_t checkpoint_seq = 0;  // the event the last checkpoint handed over ends with
  bool checkpoint_active = false;
  Clock::time_point checkpoint_since;  // when the journal asked for the one being taken
  bool holding_begins = false;         // it has waited long: new strokes wait for it
  std::vector<std::uint64_t> checkpoint_versions;  // per block: the version the store holds
  std::map<BlockId, CheckpointBlock> checkpoint_copies;
  std::vector<Clock::time_point> receipts;   // strokes whose first paint is pending
  bool force_epoch = false;
  // Requests waiting on the strokes before them.
  std::vector<std::shared_ptr<std::promise<Result<Quiescent>>>> quiesce_waiting;
  std::deque<Job> picks_waiting;  // pick-ups in arrival order, waiting for earlier strokes
  // History playback (config.playback): the first event not painted yet, and the operations
  // painted.
  std::size_t playback_cursor = 0;
  std::uint64_t playback_operations = 0;
};

}  // namespace deepcanvas::server_core
