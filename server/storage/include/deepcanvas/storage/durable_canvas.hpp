// A durable canvas: a CanvasService whose history lives in a CanvasStore (canvas_store.hpp).
// Opening one restores the canvas exactly as it was: the newest usable checkpoint, then the
// events after it replayed in order (server_core::replay_stroke_events), so its canvas_hash and
// pool_hash are those the canvas had after its last durable event. Strokes the history leaves
// open (the server stopped or crashed while they were painted) are ended at once with the
// samples that were durable, and those ends are appended to the history, so that the history
// still replays to the canvas served. Those a client id sent are named in the report
// (cut_stroke_names): their sender never had the ack and resends them whole after reconnecting;
// the resend withdraws what was kept (CanvasService::undo of that stroke), so it shows once.
//
// Threading: open_durable_canvas runs on the caller's thread (start-up) and returns a service
// whose stroke thread feeds the store; the service holds the store (CanvasServiceConfig::
// journal) and closes it when the last reference goes.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/server_core/canvas_service.hpp"
#include "deepcanvas/server_core/event_replay.hpp"
#include "deepcanvas/storage/canvas_store.hpp"

namespace deepcanvas::storage {

struct RestoreReport {
  std::string path;                   // the database file
  bool created = false;               // a new canvas
  std::uint64_t checkpoint_id = 0;    // 0: none, the whole history was replayed
  std::uint64_t checkpoint_event_seq = 0;
  std::uint64_t events_replayed = 0;
  std::uint64_t strokes_ended = 0;    // open strokes ended at restart
  std::uint64_t last_seq = 0;
  double seconds = 0;                 // load + replay
  std::vector<std::string> notes;     // checkpoints skipped, salvage, a stored shape that differs
  // The newest strokes their senders named and ended (LoadedCanvas::stroke_names): the server
  // seeds its receipts with them, so that a resend after the restart paints nothing.
  std::vector<server_core::StrokeName> stroke_names;
  // The strokes a client id sent that the server cut short (artist key, handle, stroke id),
  // oldest first: ended at this restart (the stop cut them off), or before it (a closed
  // connection, the idle timeout; EndedBy::server). The server seeds its receipts with them, so
  // that a resend withdraws the stroke first.
  std::vector<server_core::StrokeName> cut_stroke_names;
};

// Opens (or creates) DIR/NAME.canvas for `config` (the stored canvas shape wins over config's
// octree), restores it and starts its service. Errors name the canvas and the file.
Result<std::unique_ptr<server_core::CanvasService>> open_durable_canvas(
    const std::string& dir, server_core::CanvasServiceConfig config, const StoreOptions& options,
    bool salvage, RestoreReport* report = nullptr);

// The canvas as it was after event `until_seq` (0: the whole history), rebuilt headless from a
// database file by replaying its events from nothing (no checkpoint is used): what
// `deepcanvas-server replay DIR/NAME.canvas --until SEQ` reports. `config` gives the painter
// (stroke limits, stamps, step budgets) the live canvas had; the canvas shape is the file's.
struct HistoryReplay {
  std::unique_ptr<server_core::Octree> tree;
  server_core::EventReplayTotals totals;
  std::uint64_t last_seq = 0;  // the last event replayed
};
Result<HistoryReplay> replay_history(const std::string& db_path,
                                     server_core::CanvasServiceConfig config,
                                     std::uint64_t until_seq = 0);

}  // namespace deepcanvas::storage
