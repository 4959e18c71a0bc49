// The stroke thread's undo: a finished stroke's change into its artist's history, and an undo's
// or redo's turn (stroke_thread.hpp; PROTOCOL.md 3.10).
#include "stroke_thread.hpp"

namespace deepcanvas::server_core {

using base::log_event;
using base::LogLevel;
using stroke_thread_detail::seconds_between;

// Finished (or stopped) strokes' changes, and undos' and redos' reverted ones, go to the encoder
// (change_encoder.hpp) in that order; at most half the recording budget's worth of diffs waits
// there (canvas_memory_bound_bytes counts it), more first waits for what is in flight.
void CanvasService::Impl::StrokeThread::hand_over_changes(std::size_t at_most) {
  if (!painter) return;
  using Change = ChangeEncoder::Change;
  auto push = [&](Change c) {
    const std::uint64_t in_flight = encoder.bytes_in_flight();
    if (in_flight > 0 &&
        in_flight + ChangeEncoder::bytes_of(c.diff) > config.undo.max_recording_bytes / 2)
      keep_encoded(encoder.wait_all());
    encoder.push(std::move(c));
  };
  const std::size_t strokes_now = std::min(at_most, unkept.size());
  for (std::size_t i = 0; i < strokes_now; ++i) {
    const auto [artist, id] = unkept[i];
    auto d = painter->take_stroke_diff(id);
    if (!d) continue;
    Change c;
    c.kind = d->too_large ? Change::Kind::too_large : Change::Kind::stroke;
    c.artist = artist;
    c.stroke = id;
    c.diff = std::move(*d);
    push(std::move(c));
  }
  unkept.erase(unkept.begin(), unkept.begin() + static_cast<std::ptrdiff_t>(strokes_now));
  const std::size_t reverts_now = std::min(at_most - strokes_now, unkept_reverts.size());
  for (std::size_t i = 0; i < reverts_now; ++i) {
    auto& r = unkept_reverts[i];
    Change c;
    c.kind = r.redo ? Change::Kind::redo : Change::Kind::undo;
    c.artist = r.artist;
    c.stroke = r.stroke;
    c.diff = std::move(r.change);
    push(std::move(c));
  }
  unkept_reverts.erase(unkept_reverts.begin(),
                       unkept_reverts.begin() + static_cast<std::ptrdiff_t>(reverts_now));
}

// Encoded changes into the undo history, in the order they were handed over.
void CanvasService::Impl::StrokeThread::keep_encoded(std::vector<ChangeEncoder::Change> done) {
  using Kind = ChangeEncoder::Change::Kind;
  for (auto& c : done) {
    if (c.kind == Kind::too_large || (c.failed && c.kind == Kind::stroke)) {  // cannot be undone
      metrics.undo_recordings_dropped.add();
      history.stroke_too_large(c.artist, c.stroke);
    } else if (c.kind == Kind::stroke) {
      history.stroke_done(c.artist, c.stroke, std::move(c.bytes));
    } else {
      // An undo's or redo's change that could not be encoded moves with no bytes: taking it
      // back again is then refused as undecodable, which changes nothing.
      if (c.failed) metrics.undo_recordings_dropped.add();
      history.moved(c.artist, c.stroke, c.kind == Kind::redo, std::move(c.bytes));
    }
  }
}

void CanvasService::Impl::StrokeThread::keep_changes() {
  hand_over_changes();
  keep_encoded(encoder.wait_all());
}

// An undo's (redo's) turn: the painter is not busy; strokes of other artists may be open (their
// cells are kept). It is done at once, recorded as an event, and answered with the next epoch.
void CanvasService::Impl::StrokeThread::run_undo(std::uint64_t id) {
  keep_changes();
  PendingStroke& s = strokes.at(id);
  const bool redo = s.op == PendingStroke::Op::redo;
  const std::uint64_t artist = s.artist;
  const std::uint64_t named = s.undo_stroke;
  UndoFn done = std::move(s.undo_done);
  strokes.erase(id);
  auto refuse = [&](Error e) {
    metrics.undos_refused.add();
    if (done) replies.push_back([done = std::move(done), e = std::move(e)] { done(e); });
  };
  // The entry, and the artist whose history holds it: a named stroke's may be another's (a
  // stroke a restart ended is held by artist 0).
  const UndoHistory::Entry* entry = nullptr;
  std::uint64_t holder = artist;
  if (named != 0) {
    const auto found = history.find(named, false);
    if (!found)
      return refuse(make_error(Errc::not_found,
                               "stroke " + std::to_string(named) + " is not in the undo history"));
    if (found->second->too_large)
      return refuse(make_error(Errc::limit_exceeded, "the change of stroke " +
                                                         std::to_string(named) +
                                                         " was too large to keep"));
    holder = found->first;
    entry = found->second;
  } else {
    auto next = history.next(artist, redo);
    if (!next) return refuse(std::move(next).error());
    entry = *next;
  }
  const std::uint64_t target = entry->stroke_id;
  auto diff = decode_cell_diff(entry->diff, m.tree->config());
  if (!diff)
    return refuse(make_error(Errc::internal, "the history's change of stroke " +
                                                 std::to_string(target) +
                                                 " is damaged: " + diff.error().message));
  const auto t0 = Clock::now();
  RevertStats st;
  auto reverted = painter->revert(*diff, &st);
  metrics.undo_seconds.observe_seconds(seconds_between(t0, Clock::now()));
  metrics.cells_changed.add(st.cells_changed);
  if (!reverted) {
    log_event(LogLevel::error, "undo_failed",
              {{"canvas", config.name}, {"stroke", target}, {"error", reverted.error().message}});
    return refuse(std::move(reverted).error());
  }
  unkept_reverts.push_back({holder, target, redo, std::move(*reverted)});
  metrics.undos.add();
  log_event(LogLevel::info, redo ? "stroke_redone" : "stroke_undone",
            {{"canvas", config.name},
             {"stroke", target},
             {"restored", st.restored},
             {"kept", st.kept}});
  std::uint64_t seq = 0;
  if (config.on_stroke_event || config.journal) {
    StrokeEvent e;
    e.kind = redo ? StrokeEvent::Kind::redo : StrokeEvent::Kind::undo;
    e.stroke_id = target;
    e.artist = artist;
    if (config.journal) seq = last_seq = config.journal->append(e, artist);
    if (config.on_stroke_event) config.on_stroke_event(e);
  }
  if (done) answer_when_durable(seq, std::move(done), UndoDone{target, epoch + 1, redo, st});
}

}  // namespace deepcanvas::server_core
