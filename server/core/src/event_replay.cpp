#include "deepcanvas/server_core/event_replay.hpp"

#include <algorithm>
#include <map>
#include <set>

namespace deepcanvas::server_core {

namespace {

bool is_undo(const StrokeEvent& e) {
  return e.kind == StrokeEvent::Kind::undo || e.kind == StrokeEvent::Kind::redo;
}

// An undo or redo event: the named stroke's entry in the history, reverted, moved across.
bool replay_undo(Painter& painter, UndoHistory& history, const StrokeEvent& e) {
  const bool redo = e.kind == StrokeEvent::Kind::redo;
  const auto found = history.find(e.stroke_id, redo);
  if (!found || found->second->too_large) return false;
  auto diff = decode_cell_diff(found->second->diff, painter.octree_config());
  if (!diff) return false;
  auto reverted = painter.revert(*diff);
  if (!reverted) return false;
  history.moved(found->first, e.stroke_id, redo, encode_cell_diff(*reverted));
  return true;
}

}  // namespace

EventReplayTotals replay_stroke_events(Painter& painter, std::span<const StrokeEvent> events,
                                       std::uint64_t first_step_work, UndoHistory* history) {
  using Kind = StrokeEvent::Kind;
  EventReplayTotals t;
  // Undo needs every undone stroke's change: without a history given, one is kept here for the
  // strokes the events' undos and redos name.
  std::optional<UndoHistory> local;
  if (history == nullptr) {
    std::set<std::uint64_t> named;
    for (const StrokeEvent& e : events)
      if (is_undo(e)) named.insert(e.stroke_id);
    if (!named.empty()) {
      local = UndoHistory::without_artists(std::move(named));
      history = &*local;
    }
  }
  // Changes are recorded only where something keeps them: a painter made with record_diffs
  // would otherwise hold every replayed stroke's change until it is destroyed.
  painter.set_record_diffs(history != nullptr);
  std::map<std::uint64_t, std::uint64_t> open;  // stroke id -> its begin event's artist
  std::set<std::uint64_t> dead;  // refused or stopped: their later events are skipped
  // A stroke's change is its sender's, the artist of its begin event: an end the server wrote
  // for it (a restart ending what a stop cut off) may name nobody.
  auto keep_change = [&](std::uint64_t id, std::uint64_t artist) {
    if (auto it = open.find(id); it != open.end() && it->second != 0) artist = it->second;
    if (history == nullptr) return;
    auto d = painter.take_stroke_diff(id);
    if (!d) return;
    if (d->too_large)
      history->stroke_too_large(artist, id);
    else
      history->stroke_done(artist, id, encode_cell_diff(*d));
  };
  for (const StrokeEvent& e : events) {
    ++t.events;
    if (e.kind == Kind::paste) {
      t.max_stroke_id = std::max(t.max_stroke_id, e.stroke_id);
      auto cells = decode_cell_paste(e.paste, painter.octree_config());
      auto change = cells ? painter.paste(*cells) : Result<CellDiff>(cells.error());
      if (!change) {
        ++t.rejected;
        continue;
      }
      ++t.pastes;
      if (history != nullptr) {
        if (change->too_large)
          history->stroke_too_large(e.artist, e.stroke_id);
        else
          history->stroke_done(e.artist, e.stroke_id, encode_cell_diff(*change));
      }
      continue;
    }
    if (is_undo(e)) {
      if (history != nullptr && replay_undo(painter, *history, e))
        ++t.undos;
      else
        ++t.rejected;
      continue;
    }
    t.max_stroke_id = std::max(t.max_stroke_id, e.stroke_id);
    if (dead.count(e.stroke_id)) continue;
    Result<void> r = e.kind == Kind::begin     ? painter.begin_stroke(e.brush, e.stroke_id, e.samples)
                     : e.kind == Kind::samples ? painter.add_samples(e.stroke_id, e.samples)
                                               : painter.end_stroke(e.stroke_id);
    if (!r) {
      ++t.rejected;
      dead.insert(e.stroke_id);
      keep_change(e.stroke_id, e.artist);
      open.erase(e.stroke_id);
      continue;
    }
    if (e.kind == Kind::begin) open.emplace(e.stroke_id, e.artist);
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
      keep_change(e.stroke_id, e.artist);
      open.erase(e.stroke_id);
    } else if (e.kind == Kind::end) {
      ++t.strokes_ended;
      keep_change(e.stroke_id, e.artist);
      open.erase(e.stroke_id);
    }
  }
  for (const auto& [id, artist] : open) t.open.push_back({id, artist});
  return t;
}

}  // namespace deepcanvas::server_core
