// CanvasJournal: what a canvas's durable storage offers its stroke thread. The interface lives in
// server_core (which knows no database); deepcanvas::storage implements it over SQLite
// (storage/canvas_store.hpp). A CanvasService without a journal keeps its canvas in memory only.
//
// Contract with the stroke thread (CanvasService):
//   * append() is called with each stroke event in the order the painter takes it (the order
//     a replay needs), before the painting it starts. It returns the event's sequence number
//     (1, 2, ... across the canvas's whole history) and never waits for the disk. An end event
//     says who ended the stroke (EndedBy): a stroke the server cut short (its sender's
//     connection closed, the idle timeout, a stop) keeps its sender's name unended, so that
//     after a restart its resend still takes the cut part back and is painted whole; one a
//     limit stopped is named stopped, so that its resend is answered with the same error.
//   * A stroke's ack is released only through when_durable(seq of its end event): the journal
//     calls `done` once every event up to that one is durable (synced), on its own thread, or
//     at once when it already is. An event that cannot be written yet (disk full) is kept and
//     retried, never dropped, so `done` waits; it gets an error only when the journal closes
//     with the event still not durable.
//   * accepting() is asked before a new stroke is queued: an error (Errc::io_error, e.g. "disk
//     full") refuses the stroke up front while earlier events wait to be written. Viewers are
//     served meanwhile; painting resumes when writes succeed again.
//   * At a step boundary where no stroke is open and the tree is fully adjusted, the stroke
//     thread asks wants_checkpoint(); when it says yes it copies out the blocks whose version
//     changed since the previous checkpoint (Octree::save_block) and the allocator state
//     (Octree::save_allocator) and hands them over with checkpoint(). The journal compresses and
//     writes them on its own thread, atomically.
//
// Threading: append, accepting, wants_checkpoint and checkpoint are called from the stroke
// thread; when_durable from the stroke or compress thread; note_artist from any thread. An
// implementation is thread-safe for that pattern.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"

namespace deepcanvas::server_core {

// One block as a checkpoint holds it: Octree::save_block's bytes (layout in octree.hpp).
struct CheckpointBlock {
  BlockId block = 0;
  std::uint64_t version = 0;
  std::vector<std::uint8_t> bytes;
};

// The tree after every event up to `event_seq` has been painted and adjusted, no stroke open.
struct CheckpointData {
  std::uint64_t event_seq = 0;       // the last event painted into it
  std::uint64_t next_stroke_id = 1;  // the id the canvas gives its next stroke
  std::uint32_t block_count = 0;     // Octree::block_count()
  std::vector<std::uint8_t> allocator;  // Octree::save_allocator()
  std::vector<CheckpointBlock> blocks;  // the blocks changed since the previous checkpoint
  std::vector<std::uint8_t> undo_history;  // UndoHistory::save() at event_seq (may be empty)
};

// Who painted: what a session's hello said (the token's role, the client's display name).
struct ArtistInfo {
  std::uint64_t artist = 0;  // CanvasService's artist key
  std::string role;          // "painter" / "admin"
  std::string name;          // hello's display name, may be empty
};

// Who ended a stroke (append's end events).
enum class EndedBy : std::uint8_t {
  sender,   // its stroke_end or whole stroke: the sender got (or gets) its ack
  server,   // cut short by the server: the sender's connection closed, the idle timeout, a stop
  stopped,  // its sender's end after a limit stopped it (limit_exceeded): the sender got (or
            // gets) that error, and what it painted until then is kept
};

class CanvasJournal {
 public:
  virtual ~CanvasJournal() = default;
  virtual std::uint64_t append(const StrokeEvent& event, std::uint64_t artist,
                               EndedBy ended_by = EndedBy::sender) = 0;
  virtual void when_durable(std::uint64_t seq, std::function<void(Result<void>)> done) = 0;
  virtual Result<void> accepting() const = 0;
  virtual bool wants_checkpoint() = 0;
  virtual void checkpoint(CheckpointData data) = 0;
  virtual void note_artist(const ArtistInfo& artist) = 0;
};

}  // namespace deepcanvas::server_core
