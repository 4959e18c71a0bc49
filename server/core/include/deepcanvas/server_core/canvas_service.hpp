// CanvasService: one live canvas of the streaming server, without any networking.
//
// Threads (each canvas has its own):
//   stroke thread   owns the Octree and the painter. It takes jobs (strokes, streamed stroke
//                   pieces, pick-ups) from a bounded queue in arrival order (this order is the
//                   canvas's stroke order; it assigns stroke ids), runs the painter's bounded
//                   adjustment steps, and between steps (a consistent tree) ends an epoch: it
//                   copies every block dirtied since the last epoch, with its neighbour mask,
//                   into an immutable StagedBlock. It never waits on the network or on any
//                   client: when the compress thread is still busy it simply keeps painting and
//                   stages the accumulated dirty blocks at a later step boundary.
//   compress thread encodes each staged block into a temporal delta frame against the block's
//                   previous published version (zstd, shared by every session through
//                   shared_ptr) and into a full frame only where there is no such delta or the
//                   delta compresses poorly (the full frame is otherwise made on demand, see
//                   PublishedFrame::full_bytes), then publishes the epoch
//                   atomically: under one mutex it replaces the latest frame of each changed
//                   block, advances the published epoch and adds the block ids to every
//                   subscription's pending set. Then it wakes the subscriptions (notify).
//
// Latency of a stroke's first blocks: the first step after new samples is small
// (max_cells_first_step), so the epoch it ends has few blocks, and when the compress thread is
// idle the stroke thread encodes and publishes that epoch itself (encode_mutex hands the encoder
// state over; epochs stay in order because it only does so with nothing queued or in progress).
// Why: on a loaded machine waking another thread costs more than encoding a first epoch's few
// blocks (deepcanvas-bench server reports stroke read -> first block written and the share of
// first epochs published inline, inline_first_epochs_per_stroke).
//
// Latency of a stroke's ack: the epoch that completes a stroke's paint carries its ack and is
// staged at once even while the compress thread is busy (CanvasServiceConfig::replies_first),
// so it holds only the last steps' blocks and is encoded as soon as the thread is free.
//
// Staging stays on the stroke thread (not a separate LIFO staging thread): copying an epoch's
// dirty blocks costs a small fraction of a painter step or of compressing the epoch, far less
// than a hand-off to another thread on a loaded machine (histogram deepcanvas_stage_seconds;
// deepcanvas-bench server reports it per epoch, stage_ms_per_epoch_*). The copies are taken at
// step boundaries, so no lock on the tree is needed at all.
//
// Consistency (no replica ever holds a reachable cell whose data it has not received): a
// Subscription::take() runs under the publish mutex, so the frames it returns are exactly the
// newest versions at one published epoch E of every block that changed for this subscriber since
// its previous take. A client that applies a batch atomically at epoch_end(E) therefore moves
// from one consistent published state to another. A slow subscriber's pending set is a set of
// block ids (the newest version wins), so its memory is bounded by the canvas's block count and
// nobody waits for it. Its neighbour-mask bits are OR-ed across the versions it skipped and
// sent as extra mask-only frames, so skipping versions never loses a link recomputation.
// A new subscription starts with every block pending (a snapshot) and full masks.
// Delta frames keep this: a subscription that accepts them remembers the version of every block
// it was given and gets a block's delta frame only when that version is exactly the delta's base,
// or the deltas of the versions it skipped, in order, when they chain up from the version it
// holds and weigh less than the full frame (so a snapshot, an unknown block or a chain no longer
// kept always gets the full frame).
//
// Threading: every public member is thread-safe. Callbacks (AckFn, PickUpFn, notify) run on the
// stroke or compress thread: they must be short and must not call back into this service's
// blocking members (quiesce); post work elsewhere instead.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"
#include "deepcanvas/server_core/canvas_journal.hpp"
#include "deepcanvas/server_core/metrics.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/server_core/playback.hpp"
#include "deepcanvas/server_core/stamp.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"
#include "deepcanvas/server_core/undo_history.hpp"

namespace deepcanvas::server_core {

using Clock = std::chrono::steady_clock;

struct CanvasServiceConfig {
  std::string name = "default";
  OctreeConfig octree;
  protocol::StrokeLimits stroke_limits;
  std::uint32_t texture_width = 16384;
  int zstd_level = protocol::kDefaultZstdLevel;  // see kDefaultZstdLevel
  std::size_t max_queued_jobs = 65536;           // submit fails with limit_exceeded beyond this
  // Painter step cap (work units, painter.hpp): 8192 keeps a step well under a millisecond
  // (histogram deepcanvas_step_seconds; deepcanvas-bench server, step_ms_*), so a stroke's first
  // blocks stay well inside the 5 ms latency budget.
  std::uint64_t max_cells_per_step = 1u << 13;
  // The first step after a stroke's begin (or new streamed samples) does at most this much, so
  // that the epoch it ends is small and the stroke's first blocks are encoded and sent at once.
  std::uint64_t max_cells_first_step = 1u << 10;
  // The stroke thread ends an epoch at a step boundary only while the compress thread has at
  // most this many epochs queued or in progress; otherwise dirty blocks keep accumulating in the
  // tree (coalescing: a block painted again is encoded once, not once per epoch). 0: an epoch
  // is staged only when the compress thread is idle. Why 0: every epoch re-encodes the blocks a
  // stroke keeps painting, so fewer, larger epochs send fewer bytes per stroke and cost less CPU
  // on both sides, and the last epoch of a stroke waits behind at most one (deepcanvas-bench e2e
  // --compress-backlog N measures bytes per stroke and stroke -> resident latency).
  int max_compress_backlog = 0;
  // An epoch that carries replies (a stroke's ack: its paint is complete) is staged at the step
  // boundary where they are ready even while the compress thread is busy, up to
  // max_compress_backlog + 1 epochs queued or in progress. Otherwise it waits for the compress
  // thread like any other epoch, and the steps that follow meanwhile (merging the stroke's
  // uniform children back, the next stroke's paint) add their blocks to the epoch the sender
  // waits for. deepcanvas-bench e2e --replies-wait runs with false: the same bytes per stroke,
  // a later stroke -> committed and stroke -> resident latency.
  bool replies_first = true;
  // The shortest time between two epochs, except an epoch that carries replies (acks: see
  // replies_first), a forced one (quiesce) or the last before stopping. Within it, dirty blocks
  // keep accumulating in the tree, so a block a stroke keeps painting is one version per
  // interval instead of one per painter step: each version costs its delta frame and a 64-byte
  // header on the wire to every subscriber, and most of a streamed stroke's bytes were such
  // versions. A stroke's intermediate progress reaches viewers at most this much later; its
  // acked end does not wait (deepcanvas-bench e2e --epoch-interval-ms measures both). Applies
  // only while at most one stroke is in progress: with several, epochs coalesce behind the busy
  // compress thread anyway, and held-back blocks would be encoded in the epoch carrying the next
  // ack. 0: no interval.
  std::chrono::milliseconds min_epoch_interval{16};
  // While strokes are open, an epoch may leave an interior cell's filtered value lagging its
  // children's as long as it stays nonzero (Octree::InteriorRefresh::zeros_exact): the cells
  // above a stroke are then resent once per interval, not at every epoch (about a fifth of a
  // streamed stroke's bytes; deepcanvas-bench e2e --interior-refresh-ms). An epoch at least this
  // long after the last exact one, and the first once no stroke is open, is exact. Only a
  // progressive join's stand-ins for missing subtrees show the lag. 0: every epoch exact.
  std::chrono::milliseconds interior_refresh_interval{250};
  // Strokes take turns at the painter (stroke_scheduler.hpp): a turn gives it a stroke's begin,
  // at most this many of its samples, or its end. Smaller turns interleave artists more finely.
  std::size_t samples_per_turn = 64;
  // While other strokes are open, a stroke's turn holds only as many samples as its samples have
  // taken this long to paint (at least one): a heavy brush cannot hold the others up for
  // samples_per_turn of its samples (deepcanvas-bench load: a wide brush's turns took up to
  // 414 ms with 64 samples). 0: turns of samples_per_turn always.
  double turn_seconds = 0.016;
  // The most cells one artist's strokes may create per second, on average (stroke_scheduler.hpp:
  // an artist past it gets no turn until its budget refills; the others paint meanwhile).
  // 0: no limit.
  double max_cells_per_second_per_artist = 2e6;
  // A streamed stroke that gets no samples for this long is ended by the server (its paint
  // kept, its ack sent with StrokeDone::idle_ended), so that an artist resting the pen does not
  // keep the stroke open forever.
  std::chrono::milliseconds idle_stroke_timeout{2000};
  // PainterConfig::capacity_reserve: the share of octree.max_cells kept for erase strokes.
  double capacity_reserve = 0.05;
  // PainterConfig::stamps: stamp geometry and the stamps one stroke may have (max_stamps; a
  // stroke past it is refused at its start, or stopped with limit_exceeded when its later
  // samples take it past, keeping what it painted).
  StampParams stamps;
  // Instrumentation and tests: called on the compress thread with a staged epoch's number before
  // it encodes it (not for the epochs the stroke thread publishes itself). Blocking in it holds
  // the compress thread; the stroke thread goes on painting and staging meanwhile.
  std::function<void(std::uint64_t epoch)> before_compress;
  // Called on the stroke thread with each event the painter took, in the order it took them
  // (after the painter accepted it, before the painting it starts): the canvas's stroke order,
  // for a stroke log (stroke_log.hpp). A failing recorder must not throw; it should report
  // itself (log) and go on.
  std::function<void(const StrokeEvent&)> on_stroke_event;
  // Durable storage (canvas_journal.hpp): every stroke event is appended to it, a stroke's ack
  // waits until its events are durable, new strokes are refused while it cannot write, and
  // checkpoints are handed to it. Null: the canvas lives in memory only.
  std::shared_ptr<CanvasJournal> journal;
  // Undo (undo_history.hpp): each artist may undo its last `undo.depth` strokes; a stroke whose
  // encoded change is past undo.max_stroke_bytes cannot be undone. depth 0: no undo (and no
  // change recorded while painting).
  UndoLimits undo;
  // History playback (playback.hpp): the canvas starts empty and paints this history forward as
  // play() asks; it takes no strokes, undos or imports of its own (refused). Null: a canvas
  // artists paint.
  std::shared_ptr<const PlaybackHistory> playback;
};

// The painter a canvas paints with (its stroke limits, stamps and capacity reserve): what a
// replay of its history must use to paint the same strokes.
PainterConfig painter_config(const CanvasServiceConfig& config);

// The most memory one canvas of this configuration should hold, for sizing a machine (the
// process's own, its threads and sessions' buffers come on top; operations.md, "Starting a
// server"): at capacity (octree.max_cells) 47.125 bytes a cell (the tree's pools, 11.625; the
// last published version of every block, about as much again; its encoded and delta frames,
// about a third of that; the painter's per-cell fields, 20), plus with undo the history's
// budget (undo.max_bytes) and 3 times the open strokes' recording budget
// (undo.max_recording_bytes: the recordings themselves, sorting the largest as its stroke ends,
// and up to half of it in sorted changes waiting for the history's encoder thread). An estimate
// from the layouts, checked by measurement (deepcanvas-bench load), not a limit the server
// enforces: --max-cells and the undo options are the limits.
std::uint64_t canvas_memory_bound_bytes(const CanvasServiceConfig& config);

struct StagedBlock;  // a block's pools copied out of the tree (canvas_service_impl.hpp)

// One published block version, shared by every session that sends it; immutable once published
// except that its full frame may be encoded later, once (full_bytes()).
struct PublishedFrame {
  BlockId block = 0;
  std::uint64_t version = 0;
  std::uint64_t epoch = 0;
  // The same version as a temporal delta frame against base_version (the block's previous
  // published version); null when there is none. Sent to a subscriber that accepts deltas and
  // holds base_version, or an older version the recent deltas chain up from (DeltaLink).
  std::shared_ptr<const std::vector<std::uint8_t>> delta;
  // What the full frame is expected to weigh (its size when encoded at publish, else the
  // block's last full frame scaled by cells): a chain of deltas longer than this is not sent.
  std::uint64_t full_size_estimate = 0;
  std::uint64_t base_version = 0;
  std::vector<std::uint64_t> mask;  // its neighbour mask bits (for coalescing)
  std::uint32_t first_cell = 0;
  std::uint32_t cell_count = 0;
  // The depth of the shallowest live group in the block (255: none): a snapshot sends its
  // blocks shallowest first, so that a joining client can show the whole canvas coarse early.
  std::uint8_t min_depth = 255;
  // A box (metres) around a sample of those shallowest groups: of the blocks of one depth, a
  // snapshot sends those nearest the subscriber's camera first (Subscription::set_camera).
  Aabb shallow_box{};

  // The full frame. Encoded at publish when there is no delta frame; otherwise only when some
  // subscriber needs it (a snapshot, a skipped version, a client without delta frames) or, for
  // the newest version of a block that has stopped changing, by the compress thread while it
  // is idle: a block a stroke keeps painting is delta-encoded every epoch but full-encoded once.
  // Thread-safe (the first caller encodes, the others wait for it). Empty if encoding failed
  // (logged). `encoded_now` (optional) is set to whether this call did the encoding.
  const std::vector<std::uint8_t>& full_bytes(bool* encoded_now = nullptr) const;
  bool has_full_bytes() const noexcept { return full_done_.load(std::memory_order_acquire); }
  // Before publishing: the full frame is `bytes`, or is to be encoded from `source` later.
  void set_full_bytes(std::vector<std::uint8_t> bytes);
  void defer_full_bytes(std::shared_ptr<const StagedBlock> source,
                        protocol::BlockEncodeOptions options);

 private:
  mutable std::mutex full_mutex_;
  mutable std::atomic<bool> full_done_{false};
  mutable std::vector<std::uint8_t> full_;
  mutable std::shared_ptr<const StagedBlock> source_;  // until the full frame is encoded
  protocol::BlockEncodeOptions full_options_;
};
using FramePtr = std::shared_ptr<const std::vector<std::uint8_t>>;

struct StrokeDone {
  std::uint64_t stroke_id = 0;
  std::uint64_t epoch = 0;  // the first epoch holding all of its paint (merging may go on after)
  // A streamed stroke the server ended after idle_stroke_timeout without samples: its paint is
  // in the canvas like any acked stroke's, and it is over (its later pieces and its end get a
  // refused error naming the idle end). Why an ack and not an error: the paint is kept, so a
  // client that took an error as "not applied" and resent the stroke would paint it twice; a
  // client that wants to go on drawing begins a new stroke from its last sample.
  bool idle_ended = false;
};
using AckFn = std::function<void(Result<StrokeDone>)>;
// An undo's (redo's) answer: the stroke taken back (restored), and the first epoch holding it.
struct UndoDone {
  std::uint64_t stroke_id = 0;
  std::uint64_t epoch = 0;
  bool redo = false;
  RevertStats stats;
};
using UndoFn = std::function<void(Result<UndoDone>)>;
// An import's answer: its id (an artist's undo takes it back like a stroke), the first epoch
// holding it, and what it changed.
struct ImportDone {
  std::uint64_t stroke_id = 0;
  std::uint64_t epoch = 0;
  PasteStats stats;
};
using ImportFn = std::function<void(Result<ImportDone>)>;
using PickUpFn = std::function<void(Result<protocol::PickUpReply>)>;
// Where a playback canvas stands after a step (CanvasService::play): the first epoch holding
// every event painted so far, how many events and operations are painted, and the painting time
// of the last one painted.
struct PlaybackDone {
  std::uint64_t epoch = 0;
  std::uint64_t events = 0;
  std::uint64_t operations = 0;
  double painting_seconds = 0;
};
using PlaybackFn = std::function<void(Result<PlaybackDone>)>;
// A copy of the canvas's tree (CanvasService::copy_tree), its own: safe to read on any thread.
using TreeCopyFn = std::function<void(Result<std::shared_ptr<const Octree>>)>;

// Canvas-wide counters, readable at any time.
struct CanvasMetrics {
  Counter strokes;        // strokes completed
  Counter samples;        // samples received
  Counter cells_changed;  // cells created + freed + recoloured (painter's count)
  Counter steps;          // painter steps
  Counter epochs;         // epochs published
  Counter inline_epochs;  // of those, encoded and published on the stroke thread
  Counter blocks_staged;
  Counter bytes_raw;             // block payload bytes before compression
  Counter bytes_compressed;      // block frame bytes after compression (full frames)
  Counter bytes_delta;           // delta frame bytes after compression (when one was made)
  // What a subscriber holding every earlier version is sent per epoch (its delta frames where
  // made, else full frames), split by what the epoch's painter steps did: epochs with a step of
  // a stroke not yet painted (acked), and epochs whose steps only merged finished strokes back.
  // Where a stroke's bytes on the wire go (deepcanvas-bench e2e). Epochs without steps (undo,
  // import, quiesce) are in neither.
  Counter epoch_bytes_painting;
  Counter epoch_bytes_merging;
  Counter full_frames_deferred;  // frames published with a delta and no full frame yet
  Counter full_frames_filled;    // of those, full frames the idle compress thread encoded
  // Delta frames made for one subscriber from the held version to the newest, in place of the
  // chain of the versions it skipped (subscribe()'s compose_skipped: hello "batch_interval_ms").
  Counter composed_delta_frames;
  // Frame bundles (hello "frame_bundles"): those encoded, and live batches that took bundles
  // already made for another subscriber in step.
  Counter bundles_encoded;
  Counter bundles_reused;
  // Per live batch taken as bundles: the bytes of its frames as they would go alone, and of the
  // bundles sent instead (the ratio is what bundling saves on the wire).
  Counter bundled_frame_bytes;
  Counter bundle_bytes;
  Counter rejected_jobs;         // queue full
  Counter throttled_turns;       // times an artist's spent cell budget held its input back
  Counter undos;                 // undos and redos done
  Counter undos_refused;         // undos and redos answered with an error
  // Strokes whose recording was dropped (past --undo-max-recording-bytes or the recorder's cap):
  // they cannot be undone.
  Counter undo_recordings_dropped;
  Counter imports;               // imports (cell pastes) applied
  Counter imports_refused;       // imports answered with an error
  Gauge queue_depth;             // jobs waiting for the stroke thread
  Gauge compress_queue;          // staged epochs waiting for the compress thread
  Gauge subscribers;
  Gauge pending_blocks;  // sum over subscriptions (approximate between publishes)
  Gauge live_cells;
  Histogram step_seconds;
  Histogram stage_seconds;               // stroke thread: copying one epoch's dirty blocks
  Histogram compress_seconds;            // per epoch
  Histogram compress_wait_seconds;       // epoch staged -> the compress thread starts on it
  Histogram stroke_to_stage_seconds;     // stroke received -> its first blocks staged
  Histogram stroke_to_publish_seconds;   // stroke received -> its first blocks published
  Histogram end_to_painted_seconds;      // stroke_end received -> all its paint in the tree (ack)
  Histogram painted_to_settled_seconds;  // paint complete -> uniform children merged back
  Histogram undo_seconds;                // one undo's (redo's) revert on the stroke thread
};

class Subscription;

class CanvasService {
 public:
  // Creates the tree, stages and publishes its initial blocks as epoch 0, starts the threads.
  static Result<std::unique_ptr<CanvasService>> create(const CanvasServiceConfig& config);
  // A canvas restored from storage (a checkpoint plus the events after it, replayed): its tree,
  // the id its next stroke gets, the journal's last event and, per block, the version the
  // journal's newest checkpoint holds (so the next checkpoint holds only what changed since).
  struct RestoredCanvas {
    std::unique_ptr<Octree> tree;
    std::uint64_t next_stroke_id = 1;
    std::uint64_t last_seq = 0;
    std::uint64_t checkpoint_seq = 0;  // the last event the newest checkpoint holds
    std::vector<std::uint64_t> checkpoint_versions;
    // The undo history as the checkpoint and the replay after it left it (null: a new one).
    std::unique_ptr<UndoHistory> undo_history;
  };
  static Result<std::unique_ptr<CanvasService>> create(const CanvasServiceConfig& config,
                                                       RestoredCanvas restored);
  ~CanvasService();  // stop() then join
  CanvasService(const CanvasService&) = delete;
  CanvasService& operator=(const CanvasService&) = delete;

  // Stops accepting jobs, finishes the strokes in flight (their acks fire with an error if they
  // cannot complete), publishes the last epoch and joins the threads. Idempotent.
  void stop();

  const CanvasServiceConfig& config() const noexcept { return config_; }
  const std::string& name() const noexcept { return config_.name; }
  // The rules strokes for this canvas are validated with (its bounds and stroke_limits): the
  // network layer decodes with them, code that builds strokes makes them with them.
  protocol::StrokeRules stroke_rules() const noexcept;
  protocol::CanvasGeometry geometry() const noexcept;
  std::uint64_t published_epoch() const;
  const CanvasMetrics& metrics() const noexcept { return metrics_; }
  void write_metrics(PrometheusWriter& out) const;

  // ---- jobs (any thread; never block on the stroke thread) ----
  // Strokes come validated with stroke_rules() (protocol::ValidatedStroke and friends) and are
  // not checked again. `received` is when the network layer read the request (for latency
  // metrics). Errors returned directly (nothing queued, callback never called): limit_exceeded
  // (queue full), refused (stopping).
  //
  // `artist` names who sent the stroke (the network layer: its connection). One artist's strokes
  // are painted one after another in their order; different artists' strokes take turns, so
  // nobody waits for another's stroke to end (stroke_scheduler.hpp). Strokes made in code
  // without one share artist 0.
  //
  // `handle`: the sender's handle for the stroke where its artist is a client id's (0: none).
  // The journal keeps it with the stroke's begin (StrokeEvent::handle), so that after a restart
  // a resend of a stroke whose end is durable is recognised (StrokeName).
  Result<void> submit_stroke(protocol::ValidatedStroke stroke, Clock::time_point received,
                             AckFn done, std::uint64_t artist = 0, std::uint64_t handle = 0);

  // A streamed stroke: begin returns a key; samples append; end completes it (done fires then).
  // The stroke is ordered at begin and painted as its samples arrive. `done` fires exactly once:
  // with the ack when its paint is complete (after its end, or after the server ended it for
  // idleness: StrokeDone::idle_ended), or with the error that stopped it. add_samples and
  // end_stroke answer at once for a stroke that is not open: not_found for a key never begun or
  // already ended by its sender, refused naming the reason for one the server ended (idle
  // timeout, an error). add_samples also refuses, with limit_exceeded, samples that would take
  // the stroke's box past stroke_limits.max_extent_m (the stroke stays open with what it has).
  Result<std::uint64_t> begin_stroke(const protocol::ValidatedBrush& brush,
                                     protocol::ValidatedSamples samples, Clock::time_point received,
                                     AckFn done, std::uint64_t artist = 0,
                                     std::uint64_t handle = 0);
  Result<void> add_samples(std::uint64_t key, protocol::ValidatedSamples samples);
  // `by`: EndedBy::server where the sender's connection closed before its stroke_end: the
  // stroke is ended with what came, and the history keeps it as cut short, so that its resend
  // after a restart takes that part back before it is painted whole.
  Result<void> end_stroke(std::uint64_t key, EndedBy by = EndedBy::sender);

  // Undo (redo) for `artist` (PROTOCOL.md 3.10): takes back its latest stroke not yet undone
  // (restores the latest it undid), cell by cell where nobody painted over it since
  // (Painter::revert). Ordered like a stroke of `artist`: after the strokes it sent before. The
  // change streams to every subscriber like a stroke's, is recorded in the history (an undo
  // event), and `done` fires once it is published and durable, or with the error: not_found
  // (nothing to undo / redo), limit_exceeded (past the history's depth, or a stroke too large
  // to keep), refused (no undo on this canvas). Errors returned directly (nothing queued):
  // limit_exceeded (queue full), refused (stopping).
  // `stroke` (undo only; 0: the artist's latest) names the stroke to take back instead, wherever
  // it is in the history: how a resend withdraws what a restart kept of the stroke it repeats
  // (storage RestoreReport::cut_stroke_names), ordered before the resend by `artist`. not_found
  // when that stroke is not on the undo side.
  Result<void> undo(std::uint64_t artist, bool redo, Clock::time_point received, UndoFn done,
                    std::uint64_t stroke = 0);

  // An import for `artist`: `cells` (normalised: decode_cell_paste / normalise_cell_paste) are
  // pasted as one operation (Painter::paste) in the artist's order, like a stroke. The change
  // streams to every subscriber, is recorded in the history (a paste event) and in the artist's
  // undo history (an undo takes the import back), and `done` fires once it is published and
  // durable, or with the error: out_of_memory (the canvas has no room; nothing changed).
  // Errors returned directly (nothing queued): limit_exceeded (queue full), refused (stopping).
  Result<void> paste(std::uint64_t artist, std::shared_ptr<const CellPaste> cells,
                     Clock::time_point received, ImportFn done);

  // A copy of the canvas as it stands once every stroke ordered before this call has been
  // painted as far as a pick-up would see (exports through a running server, PROTOCOL.md 3.12).
  // Made on the stroke thread (the blocks saved and restored: about as long as a checkpoint's
  // save); `done` fires there, or with the stopping error. limit_exceeded: queue full.
  Result<void> copy_tree(TreeCopyFn done);

  // A playback canvas's next step (config.playback; playback_step_end says how far it goes):
  // painted on the stroke thread event by event as a restart replays them, so the canvas is
  // exactly the history's canvas at the step's last event. `done` fires with the epoch holding
  // it once that is published. operations == 0 and seconds == 0: nothing is painted, the answer
  // says where the playback stands. unsupported: not a playback canvas, or `seconds` for an
  // untimed history; limit_exceeded: queue full; refused: stopping.
  Result<void> play(std::uint64_t operations, double seconds, PlaybackFn done);

  // Colour at a point, read on the stroke thread. Ordered like a stroke: `reply` fires once
  // everything submitted for the strokes ordered before this call has been painted (a whole
  // stroke painted and adjusted; of a streamed stroke still open, the samples it has sent so
  // far: an open stroke does not hold the pick-up up), so a painter that paints and then picks
  // sees its own paint. invalid_argument for a position outside the canvas.
  Result<void> pick_up(const protocol::PickUp& request, PickUpFn reply);

  // Waits until every job submitted before the call is applied, the tree is fully adjusted and
  // its epoch published; returns that epoch and the tree's hashes (read on the stroke thread).
  struct Quiescent {
    std::uint64_t epoch = 0;
    std::uint64_t pool_hash = 0;
    std::uint64_t canvas_hash = 0;
    std::uint64_t links_hash = 0;  // the links pool, hashed as client_core::Replica does
    std::uint64_t strokes = 0;
    std::uint64_t live_cells = 0;
  };
  Result<Quiescent> quiesce(std::chrono::milliseconds timeout = std::chrono::seconds(60));

  // A new subscriber: its first take() is a snapshot of the published state. `notify` is called
  // (from the compress thread, or from this call) whenever take() may return something new.
  // `delta_frames`: the receiver applies temporal delta frames (PROTOCOL.md 4.7), so take()
  // returns a block's delta frame whenever this subscriber was last given exactly its base.
  // `compose_skipped` (with delta_frames): a block whose versions this subscriber skipped goes
  // as one delta from the version it holds, made for it in take() (decoding the chain and the
  // newest full frame, encoding anew: CPU on the taking thread and the newest full frame kept),
  // where that is lighter than the chain and the full frame; for subscribers that skip on
  // purpose (hello "batch_interval_ms"). Without it, the chain or the full frame.
  // `bundles`: the receiver decodes frame bundles (PROTOCOL.md 4.12), so a live batch's frames
  // are taken as bundles (Batch::frames), encoded on the taking thread unless a subscriber in
  // step took the same frames before. A snapshot is never bundled (a progressive join shows its
  // frames as they come), nor a frame of more than 16 KiB raw (a whole block: it goes alone, in
  // its place), nor more than 512 KiB of a batch's records.
  std::shared_ptr<Subscription> subscribe(std::function<void()> notify, bool delta_frames = false,
                                          bool compose_skipped = false, bool bundles = false);

  struct Shared;  // publish state shared with subscriptions (canvas_service.cpp)

 private:
  struct Impl;
  explicit CanvasService(const CanvasServiceConfig& config);
  CanvasServiceConfig config_;
  CanvasMetrics metrics_;
  std::unique_ptr<Impl> impl_;
};

// A session's view of the published stream. take() is cheap and non-blocking.
class Subscription {
 public:
  struct Batch {
    std::uint64_t epoch = 0;       // every frame is the newest version of its block at `epoch`
    bool caught_up = false;        // `epoch` is the newest published epoch right now
    bool snapshot = false;         // the first batch of this subscription
    std::vector<FramePtr> frames;  // block frames, then mask-only frames, in block order
                                   // (a snapshot's block frames: shallowest first, then
                                   // nearest the camera: set_camera); for a bundles
                                   // subscriber, a live batch's frames as bundles
    std::uint32_t block_frames = 0;  // block frames, those in bundles one by one (epoch_end)
    std::uint64_t frame_bytes = 0;
    std::uint64_t raw_bytes = 0;     // the frames' raw payload bytes (compression_ratio)
    std::uint32_t delta_frames = 0;  // how many of the frames are delta frames
    // Receive times of strokes whose first blocks are in this batch (latency metrics).
    std::vector<Clock::time_point> stroke_receipts;
  };

  ~Subscription();  // unsubscribes
  // The next batch, or nullopt when nothing was published since the previous take().
  std::optional<Batch> take();
  // The subscriber's camera (hello "camera"): a snapshot taken from now
  // on sends the blocks of one depth in front of it before those behind, nearest first
  // (PROTOCOL.md 4.4). Without one, in block order. Any thread.
  void set_camera(const protocol::JoinCamera& camera);
  std::size_t pending_blocks() const;
  std::uint64_t sent_epoch() const;

 private:
  friend class CanvasService;
  friend struct CanvasService::Shared;
  Subscription() = default;
  std::shared_ptr<CanvasService::Shared> shared_;
  std::function<void()> notify_;
  // Guarded by Shared::mutex.
  struct Pending;
  std::unique_ptr<Pending> pending_;
};

}  // namespace deepcanvas::server_core
