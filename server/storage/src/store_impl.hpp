// CanvasStore's state (internal): shared by canvas_store.cpp (open, queue, writer),
// store_checkpoint.cpp (checkpoint writes) and store_load.cpp (load).
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "deepcanvas/storage/canvas_store.hpp"
#include "sqlite_util.hpp"

namespace deepcanvas::storage {

namespace detail {

// The checkpoint format's config <-> meta conversions (canvas_store.cpp).
Result<server_core::OctreeConfig> config_from_meta(const MetaValues& m, const std::string& where);
std::int64_t now_unix_ms() noexcept;
// "canvas 'x' (/path/x.canvas)"
std::string describe(const std::string& canvas, const std::string& path);

// stroke_names.ended (canvas_store.hpp).
inline constexpr int kNameUnended = 0;
inline constexpr int kNameEnded = 1;
inline constexpr int kNameStopped = 2;

struct PendingEvent {
  std::uint64_t seq = 0;
  std::uint64_t stroke = 0;
  std::uint8_t kind = 0;
  std::uint64_t artist = 0;
  std::uint64_t handle = 0;  // a begin's sender handle (stroke_names); 0: none
  // An end: stroke_names.ended for its name (kNameEnded, kNameStopped), or kNameUnended for one
  // the server cut short (the name stays unended).
  int name_ended = kNameEnded;
  std::int64_t time_ms = 0;
  std::vector<std::uint8_t> record;
};

struct PendingArtist {
  server_core::ArtistInfo info;
  std::int64_t seen_ms = 0;
};

// Newer over older by block id; older blocks at or past newer.block_count are dropped.
server_core::CheckpointData merge_checkpoints(server_core::CheckpointData older,
                                              server_core::CheckpointData newer);

// The events with seq in (after, until] (until 0: to the end), in order, each record decoded and
// checked against its row. Stops at the first bad or missing one: bad_seq and bad_reason say
// which and why (bad_seq 0: none).
struct EventScan {
  std::vector<server_core::StrokeEvent> events;
  std::uint64_t max_stroke_id = 0;
  std::uint64_t bad_seq = 0;
  std::string bad_reason;
};
Result<EventScan> scan_events(sqlite3* db, const std::string& where, std::uint64_t after,
                              std::uint64_t until);

}  // namespace detail

struct CanvasStore::Impl {
  // ---- fixed after open ----
  std::string name, path, where;  // where = describe(name, path)
  server_core::OctreeConfig config;
  StoreOptions options;
  bool created = false;
  detail::Db db;

  // ---- writer-thread state (the connection's statements; load() before start) ----
  detail::Stmt insert_event, upsert_artist, insert_checkpoint, insert_block, insert_undo;
  detail::Stmt insert_name, end_name;
  std::vector<bool> covered;  // blocks that have a checkpoint row (the incremental rule)
  std::optional<server_core::CheckpointData> parked;  // a failed checkpoint's data
  bool loaded = false;

  // ---- shared, under mutex ----
  mutable std::mutex mutex;
  std::condition_variable wake;
  std::deque<detail::PendingEvent> events;
  std::map<std::uint64_t, detail::PendingArtist> artists;
  std::optional<server_core::CheckpointData> checkpoint;
  std::multimap<std::uint64_t, std::function<void(Result<void>)>> waiters;
  std::uint64_t last_seq = 0;
  std::uint64_t durable_seq = 0;
  std::uint64_t checkpoint_seq = 0;  // event_seq of the last checkpoint (handed over or loaded)
  std::chrono::steady_clock::time_point checkpoint_time = std::chrono::steady_clock::now();
  std::optional<Error> write_error;  // set while writes fail
  bool stopping = false;
  bool closed = false;
  std::thread writer;

  std::atomic<std::uint64_t> commits{0};
  std::atomic<std::uint64_t> checkpoints_written{0};
  std::atomic<std::uint64_t> checkpoints_failed{0};

  // ---- writer (canvas_store.cpp) ----
  void run();
  // Writes everything queued (events and artists) in one transaction. true when something
  // was attempted; sets/clears write_error and calls satisfied callbacks.
  bool write_pending();
  Result<void> write_batch(const std::vector<detail::PendingEvent>& batch,
                           const std::vector<detail::PendingArtist>& artists_batch);
  Result<void> prepare_statements();
  void fire_durable(std::uint64_t up_to);

  // ---- checkpoints (store_checkpoint.cpp) ----
  void write_checkpoint(server_core::CheckpointData data);
};

}  // namespace deepcanvas::storage
