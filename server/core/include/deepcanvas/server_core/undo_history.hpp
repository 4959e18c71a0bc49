// UndoHistory: each artist's strokes that may be undone and redone (PROTOCOL.md 3.10), with the
// change each made (an encoded CellDiff, cell_diff.hpp). The canvas's stroke thread owns one;
// replays rebuild it from the events (event_replay.hpp); checkpoints hold it (save()/load()), so
// it survives a restart, and it is keyed by artist (CanvasService's artist key: a client id names
// the same artist across reconnects), so it survives a reconnect too.
//
// Per artist: an undo side (its latest strokes, newest last, at most UndoLimits::depth: the
// oldest is dropped past it) and a redo side (strokes it undid, newest last). A new stroke of the
// artist clears its redo side. Undo takes the newest entry of the undo side; the revert's own
// change (what the undo changed) goes with the entry to the redo side, and back on redo.
// A stroke whose encoded change is larger than UndoLimits::max_stroke_bytes is kept as a marker
// without its change: an undo that reaches it is refused (limit_exceeded) and goes no further.
// Memory: at most UndoLimits::max_bytes for the whole canvas (default 128 MiB), whatever the
// number of artists: past it the entries longest in the history (of any artist, either side)
// are dropped first (that artist's undo then stops there with limit_exceeded, as past the
// depth). Within it, at most depth x max_stroke_bytes per artist (default 100 x 2 MiB); a
// stroke's change weighs about 2 to 6 bytes per changed cell (deepcanvas-bench undo,
// history_bytes_per_stroke). While strokes are open the painter records their changes within
// UndoLimits::max_recording_bytes, a budget of its own.
//
// Layout of save() (little-endian), version 1:
//   u32 magic "DCUH", u32 version, u32 depth, u64 max_stroke_bytes, u32 artists, per artist:
//   u64 artist, u8 evicted, u32 undo entries, u32 redo entries, per entry (undo side oldest
//   first, then the redo side oldest first): u64 stroke id, u8 too_large, u32 n, n bytes.
// Untrusted input: load() checks every size against the buffer and returns malformed; the
// changes themselves are checked when used (decode_cell_diff).
//
// Threading: not thread-safe (the stroke thread's).
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <set>
#include <span>
#include <vector>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::server_core {

struct UndoLimits {
  std::uint32_t depth = 100;                      // strokes per artist; 0: no undo
  std::uint64_t max_stroke_bytes = 2u << 20;      // one stroke's encoded change
  // Every artist's changes together (undo and redo sides); the oldest go first past it. Not in
  // save()'s layout: the server's configuration sets it (set_limits) after a load.
  std::uint64_t max_bytes = 128u << 20;
  // The changes the open strokes are recording, together (PainterConfig::max_recording_bytes,
  // about 36 bytes a changed cell): past it the largest recording is dropped and its stroke
  // cannot be undone. Not in save()'s layout either.
  std::uint64_t max_recording_bytes = 64u << 20;
};

class UndoHistory {
 public:
  struct Entry {
    std::uint64_t stroke_id = 0;
    std::vector<std::uint8_t> diff;  // encoded CellDiff; empty when too_large
    bool too_large = false;
    // When it entered its side (at least its stroke id, and growing; load() takes the stroke
    // id): past the byte budget the entry of the smallest goes first, undo or redo, anyone's.
    std::uint64_t seq = 0;
  };

  explicit UndoHistory(UndoLimits limits = {}) : limits_(limits) {}
  // For replaying a history that does not name its artists (a stroke log): one unbounded
  // history for everyone that keeps only the strokes in `named` (those the log's undo and redo
  // events name; empty: every stroke given) and never clears a redo side (the log's redos were
  // valid when made).
  static UndoHistory without_artists(std::set<std::uint64_t> named);

  const UndoLimits& limits() const noexcept { return limits_; }
  // New limits (a restarted server's configuration over a loaded history's): entries past the
  // new depth or byte budget are dropped, oldest first.
  void set_limits(const UndoLimits& limits);

  // `artist`'s stroke finished (or was stopped) with this change.
  void stroke_done(std::uint64_t artist, std::uint64_t stroke_id, std::vector<std::uint8_t> diff);
  // The same for a stroke whose change was too large to record (CellDiff::too_large).
  void stroke_too_large(std::uint64_t artist, std::uint64_t stroke_id);
  // What an undo (redo) by `artist` takes back (restores) now. Errors: not_found (nothing to
  // undo / redo), limit_exceeded (the history's depth was reached, or the stroke's change was
  // too large to keep). The entry stays until moved().
  Result<const Entry*> next(std::uint64_t artist, bool redo) const;
  // Replays: the entry of `stroke_id` on the undo (redo) side of any artist, with that artist.
  std::optional<std::pair<std::uint64_t, const Entry*>> find(std::uint64_t stroke_id,
                                                             bool redo) const;
  // The undo (redo) of `stroke_id` by `artist` is done and changed `revert_diff`: the entry moves
  // to the redo (undo) side with that change.
  void moved(std::uint64_t artist, std::uint64_t stroke_id, bool redo,
             std::vector<std::uint8_t> revert_diff);

  std::uint64_t bytes() const noexcept { return bytes_; }  // encoded changes held
  std::uint64_t entries() const noexcept;

  std::vector<std::uint8_t> save() const;
  static Result<UndoHistory> load(std::span<const std::uint8_t> bytes);

 private:
  struct Artist {
    std::deque<Entry> undo;
    std::vector<Entry> redo;
    bool evicted = false;  // older strokes were dropped past the depth
  };
  void trim(Artist& a);
  void fit_budget();  // drops the entries of smallest seq, any artist or side, past max_bytes
  void push(std::uint64_t artist, Entry e);
  UndoLimits limits_;
  std::uint64_t bytes_ = 0;  // the diffs' sizes, every artist and side
  std::uint64_t next_seq_ = 1;
  std::map<std::uint64_t, Artist> artists_;
  bool merged_ = false;  // without_artists()
  std::set<std::uint64_t> named_;
};

}  // namespace deepcanvas::server_core
