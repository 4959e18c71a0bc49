// The stroke thread: one loop that takes the queued jobs, gives the painter what it can take, runs
// one painter step, decides whether to stage an epoch, and answers what waits on the strokes
// before it (pick-ups, quiesce). Its decisions are pure functions in stroke_scheduler.hpp.
//
// Stroke order: the queue assigns stroke ids in arrival order. One artist's strokes are painted
// in that order; different artists' strokes are open at once and take turns at the painter
// (sched::next_turn over each artist's first stroke): a turn gives the painter one stroke's begin
// or at most samples_per_turn of its samples (with its end, once the end has come and these are
// its last samples), or its end alone, and the steps that follow paint it to
// completion before the next turn; strokes whose end has come go first, at most two turns in a
// row (sched::next_turn), so an ack waits for the turn in progress and at most one other
// finishing turn, not a round. The turns, in
// order, are the canvas's stroke events
// (CanvasServiceConfig::on_stroke_event): replaying them reproduces the canvas.
#include "deepcanvas/protocol/pool_hash.hpp"
#include "stroke_thread.hpp"

namespace deepcanvas::server_core {

using base::log_event;
using base::LogLevel;
using stroke_thread_detail::idle_reason_for;
using stroke_thread_detail::seconds_between;

namespace sched = stroke_scheduler;

void CanvasService::Impl::stroke_main() {
  StrokeThread(*this, self->config_, self->metrics_).run();
}

CanvasService::Impl::StrokeThread::StrokeThread(Impl& impl, const CanvasServiceConfig& cfg,
                                                CanvasMetrics& mx)
    : m(impl), config(cfg), metrics(mx), max_backlog(std::max(0, cfg.max_compress_backlog)),
      history(cfg.undo) {
  if (m.restored_undo_history) history = std::move(*m.restored_undo_history);
  last_seq = m.restored_last_seq;
  checkpoint_seq = m.restored_checkpoint_seq;
  {
    std::lock_guard lock(m.qmutex);  // strokes may be queued already
    max_recorded_id = m.next_stroke_id - 1;
  }
  checkpoint_versions = std::move(m.restored_checkpoint_versions);
  auto painter_r = Painter::create(*m.tree, painter_config(config));
  if (painter_r) {
    painter = std::move(*painter_r);
  } else {
    log_event(LogLevel::error, "painter_create_failed",
              {{"canvas", config.name}, {"error", painter_r.error().message}});
    painter_error = Error{painter_r.error().code == Errc::out_of_memory ? Errc::out_of_memory
                                                                          : Errc::internal,
                          "canvas '" + config.name +
                              "' cannot paint: " + painter_r.error().message};
  }
}

void CanvasService::Impl::StrokeThread::run() {
  // A restored canvas that replayed events checkpoints before it takes any stroke: the next
  // restart then replays nothing of them, however soon it comes.
  checkpoint_poll();
  for (;;) {
    bool stop_now = false;
    std::deque<Job> batch = take_jobs(stop_now);
    const auto now = Clock::now();
    for (Job& j : batch) take(j, now);
    const bool just_painted = feed_painter(now);
    bool first_step_ran = false;
    if (painter_busy && painter && !just_painted) first_step_ran = run_step();
    maybe_stage(stop_now, first_step_ran);
    answer_picks();
    if (const std::size_t n = sched::changes_to_hand_over(
            acks_waiting(), unkept.size() + unkept_reverts.size(), stop_now))
      hand_over_changes(n);
    keep_encoded(encoder.take_done());
    if (!stop_now) checkpoint_poll();
    if (stop_now) {
      shut_down();
      return;
    }
  }
}

// ------------------------------------------------------------------------------------ queue

std::deque<Job> CanvasService::Impl::StrokeThread::take_jobs(bool& stop_now) {
  std::deque<Job> batch;
  std::unique_lock lock(m.qmutex);
  sched::QueueState q;
  q.have_work = !idle() || m.tree->dirty_blocks().size() > 0 || answers_waiting() || force_epoch ||
                checkpoint_can_step() || interiors_due();
  q.jobs_queued = !m.jobs.empty();
  q.stopping = m.stopping;
  q.painter_busy = !idle();  // a step to run, or a turn to give
  q.stream_open = stream_open();
  q.compress_behind = m.compress_backlog.load() > max_backlog;
  const auto epoch_due = last_epoch_at + config.min_epoch_interval;
  q.epoch_too_soon = epoch_too_soon() && !answers_waiting() && !force_epoch;
  switch (sched::choose_queue_wait(q)) {
    case sched::QueueWait::none:
      break;
    case sched::QueueWait::for_job:
      if (config.journal)  // wake now and then: a checkpoint may fall due while idle
        m.qcv.wait_for(lock, std::chrono::seconds(1),
                       [&] { return !m.jobs.empty() || m.stopping; });
      else
        m.qcv.wait(lock, [&] { return !m.jobs.empty() || m.stopping; });
      break;
    case sched::QueueWait::idle_stream:  // wake for a job, or to end an idle streamed stroke
      m.qcv.wait_for(lock, sched::idle_poll(config.idle_stroke_timeout));
      break;
    case sched::QueueWait::compress:  // the compress thread notifies when it catches up
      m.qcv.wait_for(lock, sched::kCompressPoll);
      break;
    case sched::QueueWait::epoch_interval:  // a job may come first: take it, stage later
      m.qcv.wait_until(lock, epoch_due, [&] { return !m.jobs.empty() || m.stopping; });
      break;
  }
  batch.swap(m.jobs);
  metrics.queue_depth.set(0);
  stop_now = m.stopping;
  return batch;
}

void CanvasService::Impl::StrokeThread::take(Job& j, Clock::time_point now) {
  switch (j.kind) {
    case Job::Kind::stroke:
    case Job::Kind::begin: {
      PendingStroke& s = strokes[j.id];
      s.id = j.id;
      s.artist = j.artist;
      s.handle = j.handle;
      s.begun = true;
      s.ended = j.kind == Job::Kind::stroke;
      s.ended_at = j.received;
      s.brush = j.brush;
      s.samples.append(j.samples);
      s.received = j.received;
      s.last_input = now;
      s.done = std::move(j.done);
      break;
    }
    case Job::Kind::samples: {
      // Admission answered pieces of strokes that were not open; a piece queued before its
      // stroke failed is dropped (the stroke's sender got the failure).
      auto it = strokes.find(j.id);
      if (it == strokes.end() || it->second.ended) break;
      it->second.samples.append(j.samples);
      it->second.last_input = now;
      break;
    }
    case Job::Kind::end: {
      auto it = strokes.find(j.id);
      if (it != strokes.end()) {
        it->second.ended = true;
        it->second.ended_at = j.received;
        it->second.cut = j.cut;
      }
      break;
    }
    case Job::Kind::undo: {
      PendingStroke& s = strokes[j.id];
      s.id = j.id;
      s.artist = j.artist;
      s.begun = true;
      s.ended = true;
      s.op = j.redo ? PendingStroke::Op::redo : PendingStroke::Op::undo;
      s.undo_stroke = j.undo_stroke;
      s.received = j.received;
      s.undo_done = std::move(j.undo_done);
      break;
    }
    case Job::Kind::paste: {
      PendingStroke& s = strokes[j.id];
      s.id = j.id;
      s.artist = j.artist;
      s.begun = true;
      s.ended = true;
      s.op = PendingStroke::Op::paste;
      s.received = j.received;
      s.paste = std::move(j.paste);
      s.import_done = std::move(j.import_done);
      break;
    }
    case Job::Kind::pick_up:
      picks_waiting.push_back(std::move(j));
      break;
    case Job::Kind::quiesce:
      quiesce_waiting.push_back(std::move(j.quiesce));
      break;
  }
}

bool CanvasService::Impl::StrokeThread::stream_open() const {
  // Poll until the artist's budget is refilled. Asked of the budgets themselves, not of
  // `throttled`: the turn that put an artist in debt may have just ended, after the last refill.
  if (waits_for_budget()) return true;
  for (const auto& [id, s] : strokes)
    if (s.opened && !s.ended) return true;
  return false;
}

bool CanvasService::Impl::StrokeThread::acks_waiting() const {
  for (const auto& [id, s] : strokes)
    if (s.op == PendingStroke::Op::stroke && s.ended && !s.painted) return true;
  return false;
}

bool CanvasService::Impl::StrokeThread::idle() const {
  return !painter_busy && ready_strokes().empty();
}

// The strokes that may take a turn now: each artist's first stroke (ids are arrival order; an
// artist's later strokes wait for it to finish), when it has input for the painter.
std::vector<std::uint64_t> CanvasService::Impl::StrokeThread::ready_strokes() const {
  std::vector<std::uint64_t> ready;
  std::set<std::uint64_t> artists_seen;
  for (const auto& [id, s] : strokes) {
    if (!artists_seen.insert(s.artist).second || !has_turn_input(s)) continue;
    if (holding_begins && !s.opened) continue;  // a checkpoint waits for the open ones to end
    const auto b = budgets.find(s.artist);
    if (b != budgets.end() && !sched::may_take_turn(b->second)) continue;  // waits for its budget
    ready.push_back(id);
  }
  return ready;
}

// Refills every artist's cell budget; notes whether one in debt has input waiting.
void CanvasService::Impl::StrokeThread::refill_budgets(Clock::time_point now) {
  const bool was_throttled = throttled;
  throttled = false;
  const double rate = config.max_cells_per_second_per_artist;
  if (!(rate > 0)) return;
  for (auto& [artist, b] : budgets) sched::refill(b, rate, now);
  if (waits_for_budget()) {
    throttled = true;
    if (!was_throttled) metrics.throttled_turns.add();
    return;
  }
  // Artists with nothing here and a full budget are forgotten (the map stays small).
  std::erase_if(budgets, [&](const auto& e) {
    if (e.second.tokens < rate) return false;
    for (const auto& [id, s] : strokes)
      if (s.artist == e.first) return false;
    return true;
  });
}

// Whether an artist in debt has input waiting.
bool CanvasService::Impl::StrokeThread::waits_for_budget() const {
  if (budgets.empty()) return false;
  for (const auto& [id, s] : strokes) {
    const auto b = budgets.find(s.artist);
    if (b != budgets.end() && !sched::may_take_turn(b->second) && has_turn_input(s)) return true;
  }
  return false;
}

// The cells the turn that just finished created are charged to its artist.
void CanvasService::Impl::StrokeThread::charge_turn(std::uint64_t artist, Clock::time_point now) {
  const double rate = config.max_cells_per_second_per_artist;
  if (!(rate > 0)) return;
  const std::uint64_t cells = painter->stroke_stats().cells_created - turn_cells;
  auto [it, fresh] = budgets.try_emplace(artist);
  if (fresh) it->second = sched::CellBudget{rate, now};
  it->second.tokens -= static_cast<double>(cells);
}

// Whether the stroke has something for the painter: its begin, samples, or its end.
bool CanvasService::Impl::StrokeThread::has_turn_input(const PendingStroke& s) const {
  if (!s.begun) return false;
  return !s.opened || s.given < s.samples.size() || (s.ended && !s.end_given);
}

void CanvasService::Impl::StrokeThread::fail_stroke(PendingStroke& s, const Error& e) {
  if (s.done) replies.push_back([done = std::move(s.done), e] { done(e); });
  s.done = nullptr;
}

void CanvasService::Impl::StrokeThread::record(StrokeEvent::Kind kind, PendingStroke& s,
                                               std::span<const protocol::StrokeSample> samples) {
  if (!config.on_stroke_event && !config.journal) return;
  StrokeEvent e;
  e.kind = kind;
  e.stroke_id = s.id;
  e.artist = s.artist;
  if (kind == StrokeEvent::Kind::begin) {
    e.brush = s.brush->get();
    e.handle = s.handle;
  }
  e.samples.assign(samples.begin(), samples.end());
  if (config.journal) {
    // A stopped stroke's sender has its error whatever happened to the connection after it.
    const EndedBy by = kind != StrokeEvent::Kind::end ? EndedBy::sender
                       : s.stopped                    ? EndedBy::stopped
                       : s.cut || s.idle_ended        ? EndedBy::server
                                                      : EndedBy::sender;
    s.last_seq = last_seq = config.journal->append(e, s.artist, by);
    max_recorded_id = std::max(max_recorded_id, s.id);
  }
  if (config.on_stroke_event) config.on_stroke_event(e);
}

// Checkpoints are copied out where the painter has no stroke open (below). When artists keep
// strokes open back to back, such moments may not come by themselves: after kCheckpointHold the
// painter gives no new stroke its begin until the open ones have ended and the copy is done.
void CanvasService::Impl::StrokeThread::checkpoint_poll() {
  constexpr auto kCheckpointHold = std::chrono::seconds(2);
  if (!config.journal || !painter) return;
  if (!checkpoint_active) {
    if (last_seq == checkpoint_seq || !config.journal->wants_checkpoint()) return;
    checkpoint_active = true;
    checkpoint_since = Clock::now();
  }
  holding_begins = Clock::now() - checkpoint_since > kCheckpointHold;
  if (checkpoint_can_step()) checkpoint_step(false);
  if (!checkpoint_active) holding_begins = false;
}

// A checkpoint for the journal, copied out at step boundaries where no stroke is open, a bounded
// number of blocks at a time so that no boundary holds the painter much longer than a step: each
// boundary copies up to kCheckpointBlocksPerStep blocks whose version differs from both the
// store's and the copy's; once a boundary finds every block copied at its current version, the
// copies are one consistent tree (the one after event last_seq) and go to the journal with the
// allocator's state. A block painted again meanwhile is simply copied again.
void CanvasService::Impl::StrokeThread::checkpoint_step(bool all_at_once) {
  constexpr std::size_t kCheckpointBlocksPerStep = 64;  // ~2.2 MB of 4096-cell blocks
  if (!config.journal || !painter) return;
  if (!checkpoint_active) {
    if (!all_at_once && !config.journal->wants_checkpoint()) return;
    checkpoint_active = true;
  }
  const Octree& tree = *m.tree;
  const std::uint32_t blocks = tree.block_count();
  if (checkpoint_versions.size() < blocks) checkpoint_versions.resize(blocks, 0);
  std::size_t copied = 0;
  for (BlockId b = 0; b < blocks; ++b) {
    const std::uint64_t v = tree.block_state(b).version;
    if (v == checkpoint_versions[b]) {
      checkpoint_copies.erase(b);
      continue;
    }
    auto it = checkpoint_copies.find(b);
    if (it != checkpoint_copies.end() && it->second.version == v) continue;
    if (!all_at_once && copied == kCheckpointBlocksPerStep) return;  // more at the next boundary
    checkpoint_copies[b] = CheckpointBlock{b, v, tree.save_block(b)};
    ++copied;
  }
  if (copied > 0 && !all_at_once) return;  // complete only when a pass copies nothing new
  CheckpointData cp;
  cp.event_seq = last_seq;
  cp.next_stroke_id = max_recorded_id + 1;
  cp.block_count = blocks;
  cp.allocator = tree.save_allocator();
  keep_changes();
  cp.undo_history = history.save();
  cp.blocks.reserve(checkpoint_copies.size());
  for (auto& [b, copy] : checkpoint_copies) {
    checkpoint_versions[b] = copy.version;
    cp.blocks.push_back(std::move(copy));
  }
  checkpoint_copies.clear();
  checkpoint_active = false;
  checkpoint_seq = last_seq;
  config.journal->checkpoint(std::move(cp));
}

// ------------------------------------------------------------------------------------ turns

// Streamed strokes idle for idle_stroke_timeout are ended by the server (their end takes a turn
// like a sent one).
void CanvasService::Impl::StrokeThread::end_idle_streams(Clock::time_point now) {
  for (auto& [id, s] : strokes) {
    if (!s.begun || s.ended || s.given < s.samples.size()) continue;
    if (!sched::idle_stream_expired(s.ended, s.last_input, now, config.idle_stroke_timeout))
      continue;
    if (!m.end_stream_by_server(s.id, idle_reason(), true)) continue;
    log_event(LogLevel::info, "stroke_idle_ended", {{"canvas", config.name}, {"stroke", s.id}});
    s.ended = true;
    s.idle_ended = true;
    s.ended_at = now;
  }
}

// When the painter is free, gives it the next stroke's turn (round robin). Returns true when a
// turn was given.
bool CanvasService::Impl::StrokeThread::feed_painter(Clock::time_point now) {
  if (!painter) {
    refuse_strokes(painter_error);
    return false;
  }
  end_idle_streams(now);
  refill_budgets(now);
  while (!painter_busy) {
    const std::vector<std::uint64_t> ready = ready_strokes();
    std::vector<std::uint64_t> finishing;
    for (std::uint64_t id : ready) {
      const PendingStroke& p = strokes.at(id);
      const bool ends = p.op != PendingStroke::Op::stroke || p.ended;
      if (ends && !(finishing_run > 0 && p.artist == last_turn_artist)) finishing.push_back(id);
    }
    const auto next = sched::next_turn(ready, finishing, last_turn, finishing_run);
    if (!next) return false;
    const bool finishing_turn =
        finishing_run < sched::kMaxFinishingRun &&
        std::find(finishing.begin(), finishing.end(), *next) != finishing.end();
    finishing_run = finishing_turn ? finishing_run + 1 : 0;
    last_turn = *next;
    last_turn_artist = strokes.at(*next).artist;
    PendingStroke& s = strokes.at(*next);
    // Sized by cost whenever another stroke is open, not only when one is ready now: input of
    // streamed strokes arrives during a turn and then waits for all of it.
    give_turn(s, now, strokes.size() > 1);
    if (painter_busy) return true;
  }
  return false;
}

// One turn of stroke `s`: its begin with its first samples, or its next samples; with its end
// when that has come and no samples are left after these.
void CanvasService::Impl::StrokeThread::give_turn(PendingStroke& s, Clock::time_point now,
                                                  bool others_open) {
  if (s.op == PendingStroke::Op::paste) return run_paste(s.id);
  if (s.op != PendingStroke::Op::stroke) return run_undo(s.id);
  const std::size_t per_turn = sched::turn_samples(
      config.samples_per_turn == 0 ? sched::kSamplesPerTurn : config.samples_per_turn,
      config.turn_seconds, s.seconds_per_sample, others_open);
  const std::size_t n = std::min(per_turn, s.samples.size() - s.given);
  s.turn_step_seconds = 0;
  s.turn_samples = n;
  const protocol::ValidatedSamples piece = s.samples.slice(s.given, n);
  if (!s.opened) {
    if (auto r = painter->begin_stroke(*s.brush, s.id, piece); !r) {
      (void)painter->take_stroke_diff(s.id);  // it changed nothing
      m.end_stream_by_server(s.id, "it was refused: " + r.error().message, false);
      fail_stroke(s, r.error());
      strokes.erase(s.id);
      return;
    }
    s.opened = true;
    s.given += n;
    record(StrokeEvent::Kind::begin, s, piece.span());
    receipts.push_back(s.received);
  } else if (n > 0) {
    s.given += n;
    if (auto r = painter->add_samples(s.id, piece); !r) {
      // Past the stroke's extent or stamp limit: the stroke is stopped with what it painted
      // and its sender told; it ends like an idle-ended one.
      log_event(LogLevel::warn, "samples_rejected",
                {{"canvas", config.name}, {"stroke", s.id}, {"error", r.error().message}});
      m.end_stream_by_server(s.id, "it was stopped: " + r.error().message, false);
      fail_stroke(s, r.error());
      s.stopped = true;
      s.given = s.samples.size();
      if (!s.ended) s.ended_at = now;
      s.ended = true;
      return;  // its end takes the next turn it gets
    }
    record(StrokeEvent::Kind::samples, s, piece.span());
  }
  // The end goes with the stroke's last samples, in the same turn: a stroke whose end has
  // arrived then waits for one other artist's turn, not two (its samples, a turn, its end).
  if (s.ended && !s.end_given && s.given == s.samples.size()) {
    if (auto r = painter->end_stroke(s.id); !r)
      log_event(LogLevel::warn, "end_stroke_failed", {{"error", r.error().message}});
    s.end_given = true;
    ++s.turn_samples;  // the held-back last sample is painted now
    record(StrokeEvent::Kind::end, s, {});
  }
  if (s.given == s.samples.size()) {
    s.samples.clear();
    s.given = 0;
  }
  active = s.id;
  painter_busy = true;
  first_step_next = true;
  turn_cells = painter->stroke_stats().cells_created;
}

// A canvas whose painter could not be made cannot paint anything: rather than leave its strokes
// unanswered forever, each gets the creation error (a streamed stroke's later pieces find no
// entry and are dropped).
void CanvasService::Impl::StrokeThread::refuse_strokes(const Error& e) {
  for (auto& [id, s] : strokes) {
    fail_stroke(s, e);
    if (s.undo_done) replies.push_back([done = std::move(s.undo_done), e] { done(e); });
    if (s.import_done) replies.push_back([done = std::move(s.import_done), e] { done(e); });
  }
  strokes.clear();
}

// Runs one painter step of the turn (a small one right after the turn began: sched::step_budget).
bool CanvasService::Impl::StrokeThread::run_step() {
  const auto t0 = Clock::now();
  const bool first_step_ran = first_step_next;
  const std::uint64_t budget =
      sched::step_budget(first_step_next, config.max_cells_first_step, config.max_cells_per_step);
  first_step_next = false;
  {
    const auto before = strokes.find(active);
    (before != strokes.end() && before->second.painted ? epoch_merging_steps
                                                       : epoch_painting_steps) = true;
  }
  auto r = painter->step(budget);
  const double step_s = seconds_between(t0, Clock::now());
  metrics.step_seconds.observe_seconds(step_s);
  metrics.steps.add();
  if (!r) {
    stroke_failed(r.error());
    return first_step_ran;
  }
  painter_busy = *r;
  auto it = strokes.find(active);
  if (it == strokes.end()) return first_step_ran;
  PendingStroke& s = it->second;
  s.turn_step_seconds += step_s;
  if (!painter_busy && s.turn_samples > 0 && !s.painted)
    s.seconds_per_sample = s.turn_step_seconds / static_cast<double>(s.turn_samples);
  const bool finished = s.end_given && !painter->stroke_open(s.id);
  if (sched::ack_due(s.end_given, s.painted, finished, painter->stroke_painted()))
    stroke_painted(s);
  if (!painter_busy) charge_turn(s.artist, Clock::now());
  if (finished) stroke_settled(s);
  if (!painter_busy) active = 0;
  return first_step_ran;
}

// The painter ends the stroke on a failed step (e.g. the canvas is full); the tree is valid, with
// the stroke partly applied. Its sender gets the error instead of an ack.
void CanvasService::Impl::StrokeThread::stroke_failed(const Error& e) {
  log_event(LogLevel::error, "step_failed", {{"canvas", config.name}, {"error", e.message}});
  if (auto it = strokes.find(active); it != strokes.end()) {
    PendingStroke& s = it->second;
    charge_turn(s.artist, Clock::now());
    metrics.cells_changed.add(painter->stroke_stats().cells_changed());
    unkept.emplace_back(s.artist, s.id);  // what it painted until it stopped may be undone
    m.end_stream_by_server(s.id, "it was stopped: " + e.message, false);
    fail_stroke(s, e);
    strokes.erase(it);
  }
  active = 0;
  painter_busy = false;
}

// An ended stroke's paint is all in the tree: its ack goes out with the next epoch (the one in
// which that paint is complete).
void CanvasService::Impl::StrokeThread::stroke_painted(PendingStroke& s) {
  s.painted = true;
  s.painted_at = Clock::now();
  metrics.end_to_painted_seconds.observe_seconds(seconds_between(s.ended_at, s.painted_at));
  if (s.done) {
    const std::uint64_t e = epoch + 1;
    if (config.journal) {
      // The ack means durable too (PROTOCOL.md 3.3): it waits for the journal to have synced
      // the stroke's events, which it often has by the time the epoch is staged.
      replies.push_back([journal = config.journal, seq = s.last_seq, done = std::move(s.done),
                       id = s.id, e, idle = s.idle_ended]() mutable {
        journal->when_durable(seq, [done = std::move(done), id, e, idle](Result<void> r) {
          if (r)
            done(StrokeDone{id, e, idle});
          else
            done(std::move(r).error());
        });
      });
    } else {
      replies.push_back([done = std::move(s.done), id = s.id, e, idle = s.idle_ended] {
        done(StrokeDone{id, e, idle});
      });
    }
    s.done = nullptr;
  }
}

// The stroke is complete (merged back too).
void CanvasService::Impl::StrokeThread::stroke_settled(PendingStroke& s) {
  const StrokeStats& st = painter->stroke_stats();
  metrics.cells_changed.add(st.cells_changed());
  metrics.strokes.add();
  ++completed;
  metrics.painted_to_settled_seconds.observe_seconds(seconds_between(s.painted_at, Clock::now()));
  unkept.emplace_back(s.artist, s.id);
  strokes.erase(s.id);
  active = 0;
}

// ------------------------------------------------------------------------------------ staging

// No stroke is open or waiting and some interior value lags: an epoch writes them (end_epoch).
bool CanvasService::Impl::StrokeThread::interiors_due() const {
  return strokes.empty() && m.tree->interior_colours_lag();
}

// Whether the last epoch is too recent for another (min_epoch_interval). The interval holds
// blocks back only while at most one stroke is in progress. With several, the compress thread
// is busy and epochs coalesce behind it anyway, and blocks held back would only be encoded in
// the epoch that carries the next ack, making that artist wait (deepcanvas-bench load: ack p99
// with 8 painters).
bool CanvasService::Impl::StrokeThread::epoch_too_soon() const {
  return config.min_epoch_interval.count() > 0 && strokes.size() <= 1 &&
         Clock::now() < last_epoch_at + config.min_epoch_interval;
}

void CanvasService::Impl::StrokeThread::maybe_stage(bool stop_now, bool first_step_ran) {
  if (!quiesce_waiting.empty() && strokes.empty() && !painter_busy) force_epoch = true;
  sched::StagingState st;
  st.force_epoch = force_epoch;
  st.replies_first = config.replies_first;
  st.replies_pending = answers_waiting();
  st.compress_backlog = m.compress_backlog.load();
  st.max_backlog = max_backlog;
  st.idle = idle();
  st.stopping = stop_now;
  st.too_soon = epoch_too_soon();
  if (!sched::stage_now(st)) return;
  if (force_epoch && !quiesce_waiting.empty()) add_quiesce_replies();
  const bool had =
      answers_waiting() || !m.tree->dirty_blocks().empty() || force_epoch || interiors_due();
  if (had) {
    metrics.live_cells.set(static_cast<std::int64_t>(m.tree->stats().live_cells));
    end_epoch(force_epoch, first_step_ran);
  }
  force_epoch = false;
}

// The waiting quiesce requests are answered with the next epoch: the canvas's hashes as it is.
void CanvasService::Impl::StrokeThread::add_quiesce_replies() {
  Octree& tree = *m.tree;
  Quiescent q;
  q.epoch = epoch + 1;
  tree.refresh_interior_colours();  // what this epoch will send
  q.pool_hash = tree.pool_hash();
  q.canvas_hash = tree.canvas_hash();
  {
    protocol::PoolHasher h;
    const std::uint64_t groups = tree.high_water_cells() / 8;
    h.add(groups);
    h.add_bytes(tree.group_link_pool().data(), groups * 6 * 4);
    q.links_hash = h.finish();
  }
  q.strokes = completed;
  q.live_cells = tree.stats().live_cells;
  for (auto& p : quiesce_waiting) after_publish.push_back([p, q] { p->set_value(q); });
  quiesce_waiting.clear();
}

// Stages the dirty blocks as the next epoch, with the replies and receipts it carries.
// `inline_ok`: the epoch may be encoded and published right here when the compress thread is idle
// (a stroke's first epoch: a thread hand-off costs more than encoding its few blocks).
void CanvasService::Impl::StrokeThread::end_epoch(bool force, bool inline_ok) {
  const auto t0 = Clock::now();
  // Interior values may lag (octree.hpp) while strokes are open, for at most
  // interior_refresh_interval between exact takes. Once no stroke is open the next epoch is
  // exact, but not one carrying replies: the last stroke's ack would wait for those blocks.
  const bool exact = (strokes.empty() && !answers_waiting()) ||
                     t0 >= last_exact_interiors_at + config.interior_refresh_interval;
  auto dirty = m.tree->take_dirty_blocks(exact ? Octree::InteriorRefresh::exact
                                               : Octree::InteriorRefresh::zeros_exact);
  if (exact) last_exact_interiors_at = t0;
  if (dirty.empty() && !answers_waiting() && !force) return;
  StagedEpoch se;
  se.epoch = ++epoch;
  last_epoch_at = t0;
  se.steps = epoch_painting_steps  ? StagedEpoch::Steps::painting
             : epoch_merging_steps ? StagedEpoch::Steps::merging_only
                                   : StagedEpoch::Steps::none;
  epoch_painting_steps = epoch_merging_steps = false;
  // The replies need the epoch's number only: they go out before its blocks are copied, so an
  // artist's ack does not wait for the staging of every block dirtied with it (a large epoch
  // takes milliseconds to copy on a loaded machine; deepcanvas-bench load, ack p99 with 8).
  send_replies();
  std::sort(dirty.begin(), dirty.end());
  se.blocks.reserve(dirty.size());
  for (BlockId b : dirty) se.blocks.push_back(stage_block(*m.tree, b));
  metrics.blocks_staged.add(se.blocks.size());
  se.receipts = std::move(receipts);
  receipts.clear();
  se.after_publish = std::move(after_publish);
  after_publish.clear();
  se.staged_at = Clock::now();
  metrics.stage_seconds.observe_seconds(seconds_between(t0, se.staged_at));
  for (const auto& t : se.receipts)
    metrics.stroke_to_stage_seconds.observe_seconds(seconds_between(t, se.staged_at));
  if (sched::publish_inline(inline_ok, se.blocks.size(), m.compress_backlog.load())) {
    metrics.inline_epochs.add();
    m.encode_and_publish(se);
    for (auto& fn : se.after_publish) fn();
    // Give the network threads just woken by the publish a chance at a core before this thread
    // goes on painting (a scheduling hint, not a wait: nothing here depends on them).
    std::this_thread::yield();
    return;
  }
  {
    std::lock_guard lock(m.cmutex);
    m.staged.push_back(std::move(se));
    ++m.compress_backlog;
    metrics.compress_queue.set(m.compress_backlog.load());
  }
  m.ccv.notify_one();
}

// The answers the next epoch carries go out as soon as it is numbered, not once its blocks are
// copied or the compress thread has encoded them for the viewers: an artist's ack then waits for
// its own stroke, not for the staging and encoding of every other artist's blocks (deepcanvas-bench
// load: ack p99 with 8 painters). The ack names the epoch, which its client applies whenever it
// comes (PROTOCOL.md 2.1, item 5).
void CanvasService::Impl::StrokeThread::send_replies() {
  auto now = std::move(replies);
  replies.clear();
  for (auto& fn : now) fn();
}

// ------------------------------------------------------------------------------------ replies

// Answers the pick-ups, in arrival order, once the input of the strokes ordered before each has
// all been painted (a stroke held open does not hold a pick-up up: what it sent so far counts).
void CanvasService::Impl::StrokeThread::answer_picks() {
  auto earlier_input_waiting = [&](std::uint64_t limit) {
    if (painter_busy && active != 0 && active <= limit) return true;
    for (const auto& [id, s] : strokes) {
      if (id > limit) break;
      if (has_turn_input(s)) return true;
    }
    return false;
  };
  while (!picks_waiting.empty() && !earlier_input_waiting(picks_waiting.front().after_stroke)) {
    Job j = std::move(picks_waiting.front());
    picks_waiting.pop_front();
    if (j.playback_done) {
      run_playback(j);
      continue;
    }
    if (j.copy_done) {
      // The tree as it stands, through the checkpoint's own save and restore.
      std::vector<std::vector<std::uint8_t>> blocks(m.tree->block_count());
      for (BlockId b = 0; b < blocks.size(); ++b) blocks[b] = m.tree->save_block(b);
      auto copy = Octree::restore(m.tree->config(), m.tree->save_allocator(),
                                  [&](BlockId b) { return std::span<const std::uint8_t>(blocks[b]); });
      if (copy)
        j.copy_done(std::shared_ptr<const Octree>(std::move(*copy)));
      else
        j.copy_done(std::move(copy).error());
      continue;
    }
    if (!painter) {
      j.reply(make_error(Errc::internal, "no painter"));
      continue;
    }
    auto p = painter->pick(Vec3d{j.pick.position[0], j.pick.position[1], j.pick.position[2]});
    if (!p) {
      j.reply(std::move(p).error());
      continue;
    }
    protocol::PickUpReply r;
    r.request_id = j.pick.request_id;
    for (int c = 0; c < 3; ++c) r.colour[c] = p->rgb[c];
    r.density = p->alpha;
    r.depth = p->depth;
    j.reply(r);
  }
}

// Strokes still waiting will not be painted: tell their senders; pick-ups get the canvas as it
// is; quiesce requests get the stopping error. The last replies go out with a final epoch.
void CanvasService::Impl::StrokeThread::shut_down() {
  refuse_strokes(stopping_error());
  for (auto& j : picks_waiting)
    if (j.copy_done) {
      j.copy_done(stopping_error());
      j.copy_done = nullptr;
    } else if (j.playback_done) {
      j.playback_done(stopping_error());
      j.playback_done = nullptr;
    }
  std::erase_if(picks_waiting, [](const Job& j) { return !j.reply; });
  answer_picks();
  for (auto& p : quiesce_waiting) p->set_value(stopping_error());
  quiesce_waiting.clear();
  end_epoch(answers_waiting());
  // A last checkpoint of what was painted, so that a restart replays nothing (the strokes
  // stopped above stay as they are: begun, not ended).
  if (config.journal && painter && !painter_busy && painter->open_strokes() == 0 &&
      last_seq > checkpoint_seq)
    checkpoint_step(true);
}

}  // namespace deepcanvas::server_core
