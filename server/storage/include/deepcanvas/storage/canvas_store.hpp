// CanvasStore: a canvas's durable storage, one SQLite database per canvas (DIR/NAME.canvas),
// implementing server_core::CanvasJournal (canvas_journal.hpp states the contract with the
// stroke thread: append, when_durable, accepting, wants_checkpoint, checkpoint, note_artist).
//
// File format (format version 1; SQLite 3, journal_mode=WAL)
// ----------------------------------------------------------
//   meta(key TEXT PRIMARY KEY, value)
//     format_version  1 (a file with another or an unreadable version: Errc::unsupported)
//     canvas          the canvas name
//     created_ms      unix ms of creation
//     roots_per_axis, edge_m, max_depth, block_cells, max_cells: the canvas's OctreeConfig,
//                     fixed at creation (on open of an existing file the stored one wins)
//   artists(artist INTEGER PRIMARY KEY, role TEXT, name TEXT, first_seen_ms INTEGER)
//   events(seq INTEGER PRIMARY KEY, stroke INTEGER NOT NULL, kind INTEGER NOT NULL,
//          artist INTEGER NOT NULL, time_ms INTEGER NOT NULL, record BLOB NOT NULL)
//     seq        1, 2, ... across the canvas's whole history, no gaps
//     time_ms    wall clock (unix ms) when the stroke thread appended it
//     record     exactly server_core::encode_stroke_event(event): u32 length, u64 FNV-1a-64,
//                payload (stroke_log.hpp, version 2), so every row checks itself; stroke and
//                kind repeat the payload's for queries and must agree with it
//   checkpoints(id INTEGER PRIMARY KEY, event_seq INTEGER NOT NULL, next_stroke INTEGER NOT
//               NULL, block_count INTEGER NOT NULL, created_ms INTEGER, allocator BLOB NOT NULL,
//               allocator_checksum INTEGER NOT NULL, blocks_written INTEGER)
//     allocator           Octree::save_allocator() bytes, uncompressed
//     allocator_checksum  fnv1a64 of them (as the signed int64 with the same bits)
//   checkpoint_blocks(checkpoint INTEGER NOT NULL, block INTEGER NOT NULL, version INTEGER NOT
//                     NULL, data BLOB NOT NULL, checksum INTEGER NOT NULL,
//                     PRIMARY KEY(checkpoint, block))
//     data      one zstd frame (with its content size) of Octree::save_block(block)
//     checksum  fnv1a64 of the uncompressed bytes (signed int64 bit pattern)
//   checkpoint_undo(checkpoint INTEGER PRIMARY KEY, data BLOB NOT NULL, checksum INTEGER NOT NULL)
//     data      server_core::UndoHistory::save() at the checkpoint (its layout: undo_history.hpp)
//     checksum  fnv1a64 of data; a damaged one is skipped with a note (undo starts empty)
//   stroke_names(stroke INTEGER PRIMARY KEY, artist INTEGER NOT NULL, handle INTEGER NOT NULL,
//                ended INTEGER NOT NULL)
//     a stroke its sender named (a begin with StrokeEvent::handle, from a client id's artist),
//     written with its begin event; ended 1 once its sender's end event is written, 2 for the
//     end of a stroke a limit stopped (EndedBy::stopped: its sender was answered with
//     limit_exceeded, and a resend after a restart is too); an end the server cut short (a
//     closed connection, the idle timeout, the restart's for a stroke the stop cut off)
//     leaves it 0, and a salvage that drops an end event sets it back to 0. Added to files of
//     format version 1 on open (older builds ignore it, and read 2 as neither ended nor
//     unended); a file without it names no strokes.
//   Checkpoints are incremental: checkpoint k holds only the blocks handed over with it; the
//   tree at checkpoint k is, for every block b < block_count(k), the row of b with the largest
//   checkpoint <= k. Each checkpoint (row + blocks) is written in one transaction, which also
//   prunes: only checkpoint k and the one before it (the fallback) are kept, with the block rows
//   they need (index checkpoint_blocks_by_block). The first
//   checkpoint, and any after blocks were never saved, must therefore hold every block below
//   block_count; the writer refuses (logs and drops) one that would leave a block with no row.
//
// Untrusted input: a database file is untrusted. Every blob is size-checked before use and
// checksummed (records: their own FNV; allocator and blocks: the stored fnv1a64 of the
// uncompressed bytes; decompressed sizes are bounded by the block layout), and the tree is
// rebuilt only through Octree::restore, which validates structure. A bad checkpoint is skipped
// (LoadedCanvas::notes) and deleted with the checkpoints after it, so that the incremental rule
// above never picks a bad row again; events are the history and are never deleted except by an
// explicit salvage.
//
// Threading and ownership: the store owns one SQLite connection. open() and load() run on the
// caller's thread before start(); start() starts the one writer thread, which then owns the
// connection until close(). The CanvasJournal members are thread-safe per canvas_journal.hpp
// (one mutex; the disk is only touched on the writer thread). when_durable callbacks run on the
// writer thread (or the caller's, when already durable), outside the store's lock; they must not
// call close(). close() (also the destructor) writes what is queued, retrying for a short while
// if writes fail, joins the writer, and then calls the callbacks still waiting with an io_error.
//
// Writes: group commit. The writer takes everything queued (events, artists) and writes it in
// one transaction (BEGIN IMMEDIATE, prepared INSERTs, COMMIT: one WAL sync per batch), then
// advances durable_seq and calls the callbacks it satisfies, in seq order (calls for the same
// seq in call order). A failed write (disk full, I/O error, StoreOptions::before_write) is
// rolled back and its batch kept queued (never dropped) and retried every 200 ms; meanwhile
// accepting() returns the error (log event storage_write_failed, once; storage_write_recovered
// when a write succeeds again).
//
// Checkpoints: checkpoint() queues the data; the writer commits the events queued before it,
// compresses the blocks in chunks (committing newly queued events between chunks, so acks are
// not held for the whole compression) and writes the checkpoint in one transaction. A failed
// checkpoint write is not lost: the store keeps its blocks and merges the next checkpoint's
// over them (by block id, newer wins; blocks at or past the newer block_count are dropped), so
// the next checkpoint written holds the union. The caller therefore only ever hands over the
// blocks changed since the checkpoint it handed over last, whether or not that one was written.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/server_core/canvas_journal.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"

namespace deepcanvas::storage {

inline constexpr std::uint32_t kStoreFormatVersion = 1;
// What a load returns of stroke_names: the newest strokes only, as a client resends what it
// sent just before the server went away.
inline constexpr std::uint64_t kMaxLoadedStrokeNames = 65536;
inline constexpr const char* kCanvasFileSuffix = ".canvas";

struct StoreOptions {
  bool sync = true;  // synchronous=FULL; false (synchronous=OFF) for benchmarks only
  std::uint64_t checkpoint_every_events = 20000;
  std::chrono::milliseconds checkpoint_every{30000};
  int zstd_level = 1;  // 1..3
  std::chrono::milliseconds busy_timeout{5000};
  // Called by the writer before each write transaction; an error fails that write as a disk
  // error would (tests inject "disk full" with it).
  std::function<Result<void>()> before_write;
};

struct LoadedCanvas {
  std::unique_ptr<server_core::Octree> tree;
  server_core::OctreeConfig config;     // the canvas's (as stored in the file)
  std::uint64_t checkpoint_id = 0;      // 0: none (a fresh tree)
  std::uint64_t checkpoint_event_seq = 0;
  std::vector<server_core::StrokeEvent> events_after;  // seq checkpoint_event_seq+1 .. last_seq
  std::vector<std::uint8_t> undo_history;  // the checkpoint's UndoHistory::save() (may be empty)
  std::uint64_t last_seq = 0;
  std::uint64_t next_stroke_id = 1;
  std::vector<std::string> notes;  // checkpoints skipped, events dropped by salvage
  // The names of ended strokes (stroke_names ended 1 or 2: StrokeName::stopped), newest first,
  // at most kMaxLoadedStrokeNames.
  std::vector<server_core::StrokeName> stroke_names;
  // The names of strokes whose sender's end is not written, the newest kMaxLoadedStrokeNames,
  // oldest first: strokes the stop left open (their begin in events_after, no end) and strokes
  // the server cut short before (EndedBy::server). A client id may resend them.
  std::vector<server_core::StrokeName> unended_names;
};

class CanvasStore final : public server_core::CanvasJournal {
 public:
  // Opens DIR/NAME.canvas (creating DIR and the file if missing; a new file stores
  // `config_for_new`). invalid_argument for a name that is not a plain file name; io_error when
  // the file cannot be opened or written; malformed when it is not a canvas database;
  // unsupported for another format version.
  static Result<std::unique_ptr<CanvasStore>> open(const std::string& dir, const std::string& name,
                                                   const server_core::OctreeConfig& config_for_new,
                                                   const StoreOptions& options = {});
  ~CanvasStore() override;
  CanvasStore(const CanvasStore&) = delete;
  CanvasStore& operator=(const CanvasStore&) = delete;

  // Once, before start(): the tree at the newest usable checkpoint and the events after it
  // (see the top comment). malformed (naming canvas, file and seq) for an event that does not
  // decode, unless `salvage`: then that event and all after it are deleted (one transaction)
  // and a note says how many. Call it before start() even when the caller does not need the
  // tree: it also tells the writer which blocks the kept checkpoints cover (without it the next
  // checkpoint must hold every block). internal when called after start() or after a success.
  Result<LoadedCanvas> load(bool salvage = false);
  void start();
  void close();

  // ---- CanvasJournal ----
  std::uint64_t append(const server_core::StrokeEvent& event, std::uint64_t artist,
                       server_core::EndedBy ended_by = server_core::EndedBy::sender) override;
  void when_durable(std::uint64_t seq, std::function<void(Result<void>)> done) override;
  Result<void> accepting() const override;
  bool wants_checkpoint() override;
  void checkpoint(server_core::CheckpointData data) override;
  void note_artist(const server_core::ArtistInfo& artist) override;

  // ---- introspection ----
  const std::string& name() const noexcept;
  const std::string& path() const noexcept;
  const server_core::OctreeConfig& config() const noexcept;  // the stored one
  bool created() const noexcept;                              // open() made the file
  std::uint64_t last_seq() const;
  std::uint64_t durable_seq() const;
  std::uint64_t commits() const noexcept;              // event transactions committed
  std::uint64_t checkpoints_written() const noexcept;  // this session
  std::uint64_t checkpoints_failed() const noexcept;   // this session (their blocks are kept)

  struct Impl;

 private:
  explicit CanvasStore(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// ---- data directory ----

// Names (without the suffix) of the DIR/*.canvas files, sorted; empty when DIR is missing.
std::vector<std::string> list_canvases(const std::string& dir);

// One server per data directory: an exclusive flock on DIR/lock, which holds the owner's pid.
class DataDirLock {
 public:
  // Creates DIR if missing. refused: "data directory DIR is in use by another server (pid N)".
  static Result<DataDirLock> acquire(const std::string& dir);
  DataDirLock() = default;
  DataDirLock(DataDirLock&& other) noexcept;
  DataDirLock& operator=(DataDirLock&& other) noexcept;
  DataDirLock(const DataDirLock&) = delete;
  DataDirLock& operator=(const DataDirLock&) = delete;
  ~DataDirLock();
  bool held() const noexcept { return fd_ >= 0; }
  const std::string& dir() const noexcept { return dir_; }

 private:
  int fd_ = -1;
  std::string dir_;
};

// ---- statistics for tools (read-only) ----

struct AuthorSummary {
  std::uint64_t artist = 0;
  std::string role;
  std::string name;
  std::uint64_t strokes = 0;  // distinct strokes with an end event
  std::uint64_t undos = 0;    // undo and redo events
  std::uint64_t imports = 0;  // paste events (imports)
  std::uint64_t events = 0;
};

struct CheckpointSummary {
  std::uint64_t id = 0;
  std::uint64_t event_seq = 0;
  std::uint64_t next_stroke = 0;
  std::uint64_t block_count = 0;
  std::uint64_t blocks_written = 0;  // rows of this checkpoint
  std::uint64_t bytes = 0;           // allocator + compressed blocks
  std::int64_t created_ms = 0;
};

struct StoreSummary {
  std::string path;
  std::uint32_t format_version = 0;
  std::string canvas;
  std::int64_t created_ms = 0;
  server_core::OctreeConfig config;
  std::uint64_t events = 0;
  std::uint64_t last_seq = 0;
  std::uint64_t strokes = 0;  // distinct strokes with an end event
  std::int64_t first_ms = 0, last_ms = 0;  // of the events (0 when none)
  std::vector<AuthorSummary> authors;      // by artist id
  std::vector<CheckpointSummary> checkpoints;  // by id
  std::uint64_t db_bytes = 0, wal_bytes = 0;
  std::string integrity;  // PRAGMA integrity_check's answer ("ok" when sound)
};

// Opens the database read-only. not_found, malformed (not a canvas database), unsupported.
Result<StoreSummary> summarize(const std::string& db_path);

// The canvas's shape and its history, events 1 .. until_seq (0: all), read-only, every record
// checked: malformed naming the event for one that does not decode or is missing (and for a
// file that is not a canvas database), unsupported for another format version.
struct StoredHistory {
  server_core::OctreeConfig config;
  std::vector<server_core::StrokeEvent> events;
};
Result<StoredHistory> read_history(const std::string& db_path, std::uint64_t until_seq = 0);

}  // namespace deepcanvas::storage
