// Private state of CanvasService, shared by canvas_service.cpp (stroke + compress threads) and
// canvas_publish.cpp (publish state and subscriptions).
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <thread>
#include <unordered_map>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/server_core/canvas_service.hpp"

namespace deepcanvas::server_core {

// The publish state: the newest frame of every block, the published epoch and the subscribers,
// all under one mutex so that a take() sees one consistent epoch.
struct CanvasService::Shared {
  std::mutex mutex;
  std::uint64_t epoch = 0;
  // False until the compress thread has published epoch 0 (the fresh tree's blocks): until then
  // a snapshot would be empty, so take() waits for it (publish() notifies every subscriber).
  bool published_any = false;
  std::condition_variable published_cv;  // signalled when published_any becomes true
  std::vector<std::shared_ptr<const PublishedFrame>> latest;  // by block id
  // By block id: the delta frames of its last published versions, each against the one before
  // (a chain), at most kMaxDeltaChain. A delta subscriber that skipped versions gets the chain
  // from the version it holds instead of the full frame, when that is smaller.
  struct DeltaLink {
    std::uint64_t version = 0, base_version = 0;
    std::shared_ptr<const std::vector<std::uint8_t>> delta;
    std::uint64_t payload_bytes = 0;  // raw payload size (compression ratio metrics)
  };
  std::vector<std::deque<DeltaLink>> delta_chain;
  std::vector<Subscription*> subs;
  std::deque<std::pair<std::uint64_t, Clock::time_point>> receipts_log;  // (epoch, received)
  CanvasMetrics* metrics = nullptr;
  int zstd_level = protocol::kDefaultZstdLevel;  // CanvasServiceConfig::zstd_level
  // The bundles (PROTOCOL.md 4.12) last made for a live batch, and the frames they hold:
  // subscribers in step take the same frames at every epoch, so one encoding serves them all.
  // The key holds the frames themselves (compared by pointer, else by bytes). Guarded by
  // bundle_mutex.
  std::mutex bundle_mutex;
  std::vector<FramePtr> bundle_key;
  std::vector<FramePtr> bundle_value;

  void publish(std::uint64_t new_epoch, std::vector<std::shared_ptr<const PublishedFrame>> frames,
               const std::vector<Clock::time_point>& receipts);
};

// A block copied out of the tree at an epoch boundary (immutable once made).
struct StagedBlock {
  BlockId block = 0;
  std::uint64_t version = 0;
  std::uint32_t first_cell = 0;
  std::uint32_t cell_count = 0;
  std::vector<std::uint32_t> first_child, colour, group_parent;
  std::vector<std::uint8_t> depth_flags;
  std::vector<std::uint64_t> mask;
  // Where it sits in a snapshot's order (PublishedFrame::min_depth, shallow_box).
  std::uint8_t min_depth = 255;
  Aabb shallow_box{};
};

// How many of a block's shallowest groups its shallow_box is made from, spread over the block:
// enough to place a block whose groups lie together, cheap enough for the stroke thread to do
// for every block it stages (one parent walk each).
inline constexpr std::size_t kShallowBoxSamples = 16;

// Copies block `b` out of the tree (and clears its neighbour mask): canvas_service.cpp.
StagedBlock stage_block(Octree& tree, BlockId b);

inline Error stopping_error() {
  return make_error(Errc::refused, "the canvas is shutting down");
}

// A full frame's expected size, from the block's last full frame encoded here (scaled by its
// cell count): a delta no larger than that is sent without encoding the full frame at publish.
struct FullFrameSize {
  std::uint32_t bytes = 0;
  std::uint32_t cells = 0;
};
// A deferred full frame is encoded by the idle compress thread once its version has been the
// newest for this long: a block that strokes keep painting is then never full-encoded between
// its versions, and one that has settled is ready for the next snapshot.
inline constexpr auto kFullFillDelay = std::chrono::milliseconds(200);

// The longest chain of delta frames sent in place of one full frame (Shared::delta_chain).
inline constexpr std::size_t kMaxDeltaChain = 16;

// A full frame was encoded (at publish, by an idle fill or on demand): the encoder counters.
inline void count_full_frame(CanvasMetrics& m, std::uint32_t cell_count, std::size_t bytes) {
  m.bytes_raw.add(protocol::block_payload_size(cell_count, protocol::kFieldAll));
  m.bytes_compressed.add(bytes);
}

// The encoder's view of a staged block at `epoch`.
inline protocol::BlockView view_of(const StagedBlock& b, std::uint64_t epoch) {
  protocol::BlockView v;
  v.block_id = b.block;
  v.version = b.version;
  v.epoch = epoch;
  v.first_cell = b.first_cell;
  v.cell_count = b.cell_count;
  v.first_child = b.first_child;
  v.colour = b.colour;
  v.group_parent = b.group_parent;
  v.depth_flags = b.depth_flags;
  const std::size_t words = (b.cell_count / 8 + 63) / 64;
  v.neighbour_mask = std::span<const std::uint64_t>(b.mask.data(), words);
  return v;
}

struct StagedEpoch {
  std::uint64_t epoch = 0;
  // What the painter steps since the previous epoch did (CanvasMetrics::epoch_bytes_*).
  enum class Steps : std::uint8_t { none, painting, merging_only } steps = Steps::none;
  std::vector<StagedBlock> blocks;
  std::vector<Clock::time_point> receipts;           // strokes first visible in this epoch
  std::vector<std::function<void()>> after_publish;  // quiesce replies, playback positions
  Clock::time_point staged_at;
};

struct Job {
  enum class Kind { stroke, begin, samples, end, pick_up, quiesce, undo, paste } kind = Kind::stroke;
  std::uint64_t id = 0;                           // stroke id (stroke, begin, samples, end)
  std::uint64_t artist = 0;                       // who sent it (stroke, begin)
  std::uint64_t handle = 0;                       // the sender's handle (stroke, begin; 0: none)
  std::optional<protocol::ValidatedBrush> brush;  // stroke, begin
  protocol::ValidatedSamples samples;             // stroke, begin, samples
  Clock::time_point received;
  AckFn done;
  bool cut = false;   // end: EndedBy::server (the sender's connection closed)
  bool redo = false;  // undo
  std::uint64_t undo_stroke = 0;  // undo: that stroke, not the artist's latest (0)
  UndoFn undo_done;   // undo
  std::shared_ptr<const CellPaste> paste;  // paste
  ImportFn import_done;                    // paste
  protocol::PickUp pick;
  PickUpFn reply;
  TreeCopyFn copy_done;  // pick_up with this set: a tree copy instead of a pick
  PlaybackFn playback_done;  // pick_up with this set: a playback step instead of a pick
  std::uint64_t playback_operations = 0;
  double playback_seconds = 0;
  // pick_up: the last stroke id ordered before it; it is answered once that stroke and every
  // earlier one has completed (painted and adjusted), on the stroke thread.
  std::uint64_t after_stroke = 0;
  std::shared_ptr<std::promise<Result<CanvasService::Quiescent>>> quiesce;
};

struct CanvasService::Impl {
  CanvasService* self = nullptr;
  std::shared_ptr<Shared> shared = std::make_shared<Shared>();
  std::unique_ptr<Octree> tree;  // touched only by the stroke thread after create()
  // Where a restored canvas's history stands (CanvasService::RestoredCanvas); read by the
  // stroke thread when it starts.
  std::uint64_t restored_last_seq = 0;
  std::uint64_t restored_checkpoint_seq = 0;
  std::vector<std::uint64_t> restored_checkpoint_versions;
  std::unique_ptr<UndoHistory> restored_undo_history;

  // Job queue (network threads -> stroke thread).
  std::mutex qmutex;
  std::condition_variable qcv;
  std::deque<Job> jobs;
  std::uint64_t next_stroke_id = 1;
  bool stopping = false;
  // Streamed strokes begun and not yet ended (by their end, the idle timeout or an error), with
  // the box of their samples so far (StrokeLimits::max_extent_m): a piece or an end for any
  // other key is answered at once with an error instead of being queued and dropped.
  std::unordered_map<std::uint64_t, protocol::SampleBox> open_streams;
  // Why the latest strokes the server ended itself were ended (the idle timeout, an error),
  // oldest first, at most kServerEndedRemembered: named in the error a late piece gets.
  std::deque<std::pair<std::uint64_t, std::string>> server_ended;
  static constexpr std::size_t kServerEndedRemembered = 4096;

  // Staged epochs (stroke thread -> compress thread).
  std::mutex cmutex;
  std::condition_variable ccv;
  std::deque<StagedEpoch> staged;
  bool compress_stop = false;
  bool deferred_added = false;  // deferred full frames were queued: the compress thread re-arms
  std::atomic<int> compress_backlog{0};  // staged epochs not yet published

  std::thread stroke_thread;
  std::thread compress_thread;
  std::atomic<bool> stopped{false};

  // Encoder state, used by one thread at a time (encode_and_publish): the compress thread, or
  // the stroke thread for a stroke's first epoch while the compress thread is idle.
  std::mutex encode_mutex;
  protocol::BlockEncoder encoder;
  // The last published version of every block (by id), the base of its next delta frame. About
  // one copy of the canvas's transferred pools (shared with the frames whose full frame is
  // still to be encoded).
  std::vector<std::shared_ptr<const StagedBlock>> previous;
  std::vector<FullFrameSize> last_full;  // by block id (encodes at publish and idle fills)
  // Published frames whose full frame was deferred, oldest first, with their publish time: the
  // compress thread encodes those still newest once they are kFullFillDelay old and it is idle.
  std::deque<std::pair<Clock::time_point, std::weak_ptr<const PublishedFrame>>> deferred_full;

  // The stroke thread's state and steps (stroke_thread.hpp); stroke_main runs its loop.
  struct StrokeThread;
  void stroke_main();
  void compress_main();
  void encode_and_publish(StagedEpoch& se);
  // Encodes the full frame of the oldest deferred frame if it is due (compress thread, idle);
  // returns the time the next one is due, or nullopt when none is waiting.
  std::optional<Clock::time_point> fill_deferred_full(Clock::time_point now);
  // The one way into the stroke thread's queue: refused while stopping; limit_exceeded past
  // max_queued_jobs unless `always` (stroke ends and quiesce must never be lost). Assigns the
  // stroke id of stroke/begin jobs (returned) and a pick-up's after_stroke under the lock.
  enum class Admission { bounded, always };
  Result<std::uint64_t> enqueue(Job job, Admission admission);
  // Under qmutex: a streamed stroke's piece or end is for an open stroke (and a piece keeps it
  // within max_extent_m); a begin opens its stroke. Errors: not_found (never begun or ended by
  // its sender), refused (ended by the server: the reason), limit_exceeded (extent).
  Result<void> admit_stream_job(Job& job);
  // The stroke thread ends open streamed stroke `key` itself for `reason`. With `only_if_idle`
  // it does not when a piece or the end of it is queued (input arrived: it is not idle) and
  // returns false. Later pieces and ends of it get `reason` in their error. False also when
  // the stroke is not open (its end was queued).
  bool end_stream_by_server(std::uint64_t key, const std::string& reason, bool only_if_idle);
};

}  // namespace deepcanvas::server_core
