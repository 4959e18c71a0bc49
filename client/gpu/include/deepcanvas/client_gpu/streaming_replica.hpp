// StreamingReplica: the GPU replica kept up to date while frames are rendered from it.
//
// Data path. The client's I/O thread decodes (decompresses) block frames and commits whole
// epochs to its CPU Replica (client_core). An epoch listener (Client::set_epoch_listener) then
// captures the epoch: capture_epoch() copies the texture rows covering the ranges the epoch's
// frames carried, plus the list of groups whose links the neighbour masks mark, into an
// EpochUpload, and push() queues it (a memcpy of the changed rows; the I/O thread never waits
// for the GPU). The upload thread, owned here, takes queued epochs in order, applies their rows
// to a CPU mirror of exactly what the textures will hold, copies those rows into the textures
// through GpuReplica's persistent host-visible staging buffer (one submission for all the rows
// of a batch, whatever their number) and recomputes G3 on the GPU for the masked groups only
// (links.comp, one dispatch per depth; never on the CPU).
//
// Consistency (the invariant: a frame never renders a state with a reachable cell whose data has
// not arrived). Epochs are the unit: the server publishes only consistent states, and a batch (one
// or more whole epochs, merged; the rows of the last write win, so the result is the last epoch's
// state) is applied to the mirror and to the textures, links included, while the GPU lock is held;
// epochs queued while a batch waited for the lock join it there (late joiners: their content step
// and mirror writes follow the batch's, under the lock, so they do not wait for the next band). The
// render loop renders a frame as row bands, each band under the same lock (GpuLock, FIFO so that
// bands and batches alternate when both wait): it reads the resident epoch and locates the camera
// on the mirror, records, submits and waits for the band. A band therefore always sees whole
// epochs, never part of one, and each band knows the epoch it shows (frames record the epoch range
// of their bands); freed and reused slots are harmless because no band can observe the textures
// between the write of a reused group and the write of its new parent. The order of rows inside a
// batch does not matter, which is what the adversarial test exercises (random batching, delays,
// bands, and submissions split at random under the lock), validating every band against a reference
// render of the CPU state at its epoch.
//
// Queues. lavapipe exposes one queue (Context::transfer_queue() == compute_queue() there), and
// the batches are serialised with the bands anyway (the textures must not change under a band:
// a write-after-read hazard across queues would need a semaphore in each direction and would
// still have to wait for the band), so uploads and G3 go to the compute queue, in order with the
// bands. A device with a separate transfer queue gains nothing here since texture copies are
// short next to a band; what matters is that the CPU side of streaming (decompression on the I/O
// thread, row capture, batching, budget waits) runs off the render thread.
//
// The batch policy (which epochs form a batch, when it starts, late joiners, growth stepping) is
// its own unit, UploadBatchPolicy (upload_batch_policy.hpp); the upload thread waits, moves the
// epochs and does the GPU work it decides. The reasons for its rules follow.
//
// Growth. The textures grow by doubling, by at most GpuReplicaConfig::max_growth_cells at a time
// (cell indices never change). Past half full (large textures: with less than half a growth
// left), a batch starts an incremental growth (GpuReplica::begin_growth): the old rows are
// copied into the taller textures by steps of about 2 ms (growth_step, under the GPU lock, in
// the gaps between a paced loop's frames, one after each batch and more while no epoch is
// queued; past 3/4 full, or with less than a quarter of a growth left, the remaining steps at
// once, each its own turn under the lock); the rows it adds are left unwritten until a batch
// writes them (GpuReplica's header); rows that batches write in the meantime are copied again
// by the last step, which switches the textures; the raycaster
// re-writes its descriptors on the next band (generation()). Epochs that need more rows than
// the current textures have wait: the growth (begun then if none is under way) completes in
// steps, each its own turn under the lock, and the epochs that fit go first (make_room()).
// Only an epoch that outgrows even the textures of that growth completes a growth at once
// (ResidentBatch::grew). Why: a growth is a copy of every row, milliseconds of GPU lock on a
// canvas of a million cells; done inside one batch it would hold a frame up by as long (a frame
// hitch at every doubling), and a burst of epochs queued during one frame (a large stroke's
// painter steps) that crosses the textures' size would do it inside one long batch. The test
// StreamingReplica.BurstPastTheTexturesGrowsInStepsNotAtOnce pins this; deepcanvas-bench render
// reports growth steps, growths at once and the longest batch lock.
//
// Budget. UploadBudget can cap bytes per second (token bucket), epochs per batch, and batches
// per rendered frame (the paper's "one block per frame"); the default is none of them: every
// pending epoch goes in the next batch, and batches alternate with bands through the FIFO lock.
// Why: a stroke stream's peaks exceed any rate worth setting, so a rate or per-frame cap builds
// a backlog and only adds latency, while a batch stays short without one because it holds only
// the changed rows (deepcanvas-bench e2e --budget-mbps X, --epochs-per-batch N and
// --batches-per-frame N measure each cap). How long a batch waits for the queue is bounded by
// the render loop's band target instead (RenderLoopOptions::band_target_ms: shorter bands mean
// shorter waits and more submission overhead per frame; e2e --band-ms). The budget in time that
// is used is the frame gap: with a paced render loop, batches go between frames (see
// frame_started()), which is the paper's per-frame slot with whatever the gap holds instead of
// one block.
//
// Content box (the render loop's content cull, client_core::RenderOptions::content_bounds).
// Invariant: whenever the GPU lock is free, ResidentState::content_bounds contains every leaf
// with non-zero alpha of the resident epoch (painted_bounds(pools) lies inside it), or is
// nullopt when that epoch has no such leaf. It is updated in the same critical section as the
// mirror and the textures, so a band never sees a box older than its epoch. A box that missed
// paint would cut resident paint out of frames, so it errs on the large side:
//  * Growth (every batch, O(changed cells), computed from the batch's rows laid over the mirror
//    before the batch takes the lock, swapped in with the mirror under it): the rows are
//    compared with the mirror; each leaf whose colour or first_child changed and that is painted
//    afterwards is added, located by its group_parent chain (checked against first_child at
//    every step, memoised per group, box arithmetic in double as painted_bounds does); a cell
//    whose first_child changed to a child group gets its whole subtree walked (a subtree can
//    be attached by one pointer, e.g. a reused slot whose cells kept their values). Why that
//    suffices: a painted leaf whose path from its root (first_child of every ancestor, its own
//    first_child and colour) did not change was the same painted leaf at the same place before
//    the batch, so the previous box holds it; otherwise the deepest changed cell on its path is
//    one of the two cases above. Scratch kept between batches: ~4.3 bytes per cell.
//  * Anything that is not a tree (a live group its parent does not point to, a freed group
//    still pointed to, a group still pointed to by its previous parent, a depth that does not
//    match, a bad index) makes that batch recompute the box exactly with painted_bounds under
//    the lock; pools painted_bounds refuses give the whole canvas.
//  * Shrinking: erasing leaves the box loose, never too small. When paint was removed where it
//    touched the box's faces (the removed leaves are located in the state before the batch,
//    outside the lock), the upload thread recomputes the exact box (painted_bounds, O(cells),
//    on the mirror outside the lock: only this thread writes it) once no epoch is queued and
//    at least 0.5 s after the previous recompute (at the latest after 5 s), then swaps it in
//    under the lock.
// The first batch sets the box with painted_bounds. Hence, for the resident epoch E:
// painted_bounds(E) <= content_bounds <= the hull of painted_bounds over the epochs up to E.
//
// Threading: push() and the accessors are thread-safe. with_gpu() runs `fn` under the GPU lock
// (the render loop's bands; tests). The GpuReplica must be used only inside with_gpu(). The
// Context must outlive this object; the destructor stops the upload thread (pending epochs are
// dropped).
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <thread>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_core/content_boxes.hpp"
#include "deepcanvas/client_core/pool_array.hpp"
#include "deepcanvas/client_core/pool_view.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/epoch_upload.hpp"
#include "deepcanvas/client_gpu/replica_gpu.hpp"
#include "deepcanvas/client_gpu/upload_batch_policy.hpp"

namespace deepcanvas::client_gpu {
namespace detail {
class ContentTracker;  // streaming_replica_content.hpp
struct ContentStep;
}  // namespace detail

// Test hooks: an adversarial upload schedule. Off by default.
struct UploadChaos {
  std::uint64_t seed = 0;              // 0 = off
  std::uint32_t max_delay_us = 2000;   // random sleep before a batch (outside the lock)
  std::uint32_t max_epochs_batch = 4;  // random batch size 1..this
  bool split_submissions = true;       // rows in random chunks, one submission each
  // Non-zero: incremental growth steps of this many rows (many steps, batches between them).
  std::uint32_t growth_rows_per_step = 0;
  // BROKEN on purpose, for the test's negative control only: releases the GPU lock between
  // the chunks, so bands can see part of an epoch. The test must then find bad bands.
  bool break_atomicity = false;
  // BROKEN on purpose, for the content-box test's negative control only: the n-th batch
  // (1-based; 0 = off) does not grow the content box, and no exact recompute repairs it.
  std::uint64_t skip_content_growth_batch = 0;
};

// One batch, when it became resident (its submissions and G3 done).
struct ResidentBatch {
  std::uint64_t first_epoch = 0, last_epoch = 0;
  SteadyTime committed_at{};  // of its first epoch
  SteadyTime taken_at{};      // when the upload thread took it off the queue (after any gap wait)
  SteadyTime resident_at{};
  std::uint64_t bytes = 0;
  double lock_wait_ms = 0;  // waiting for the GPU lock (a band of a frame in progress)
  // Epochs committed while the batch waited for the GPU lock, taken along (late joiners).
  std::uint64_t late_epochs = 0;
  double gpu_lock_ms = 0;  // time the batch held the GPU lock, of which:
  double mirror_ms = 0, grow_ms = 0, upload_ms = 0, links_ms = 0;
  double stage_ms = 0;  // before the lock: the rows into the staging buffer
  // Before the lock too: the mirror's rows this batch writes first set to the never-used values
  // (prepare_mirror_rows), and before the batch was taken (in taken_at), the textures grown to
  // hold it.
  double mirror_prepare_ms = 0, room_ms = 0;
  std::uint64_t rows = 0, link_groups = 0;
  bool grew = false;  // had to complete a growth at once (the textures were too small)
  // Paced render loop only (see frame_started()): the batch waited for a gap between frames
  // this long; it went mid-frame (between bands) because its oldest epoch had waited too long.
  double gap_wait_ms = 0;
  bool in_gap = false;  // scheduled in a gap between frames
  bool partial = false;  // its last epoch is part of a snapshot (EpochUpload::partial)
  bool mid_frame = false;
  // The content box: its growth, computed before the batch takes the lock (not in
  // gpu_lock_ms), over this many changed cells; an exact recompute under the lock (the first
  // batch; fallbacks), included in gpu_lock_ms.
  double content_ms = 0, content_exact_ms = 0;
  std::uint64_t changed_cells = 0;
  std::vector<std::pair<std::uint64_t, SteadyTime>> commits;  // (epoch, committed_at) each
};

struct StreamingStats {
  // growths: texture growths completed (incremental or at once); growth_steps: incremental
  // steps run; max_growth_ms: the longest batch that had to grow at once (0: none did).
  std::uint64_t epochs = 0, batches = 0, bytes = 0, growths = 0, growth_steps = 0;
  std::uint64_t late_epochs = 0;  // of `epochs`, joined a batch while it waited for the lock
  double max_batch_lock_ms = 0, max_growth_ms = 0, max_growth_step_ms = 0;
  // Content box: exact recomputes (first batch, shrinking after erases, fallbacks), of which
  // fallbacks (pools that are not a tree, see "Content box"); the longest exact recompute.
  std::uint64_t content_exact = 0, content_fallbacks = 0;
  double max_content_exact_ms = 0;
};

// A FIFO lock: waiters are served in arrival order, so a band waiting behind a batch (and a
// batch behind a band) waits for one turn at most.
class GpuLock {
 public:
  void lock();
  bool try_lock();  // takes it only when it is free and nobody waits
  void unlock();

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::uint64_t next_ = 0, serving_ = 0;
};

// What a band sees under the lock.
struct ResidentState {
  bool any = false;             // at least one epoch resident, or part of the first
  std::uint64_t epoch = 0;      // the resident epoch (valid when any)
  // Part of the snapshot of `epoch` (a progressive join): the subtrees still missing show as
  // their parents' filtered values; `epoch` itself is not resident yet.
  bool partial = false;
  client_core::PoolView pools;  // the mirror: exactly the textures' contents (links not kept)
  GpuReplica& replica;
  // Contains every painted leaf of `pools` (see "Content box"); nullopt: nothing painted.
  std::optional<client_core::DAabb> content_bounds;
  // `ro` culled to this epoch's content: its box, or content_empty where nothing is painted (the
  // one place a render of the resident epoch turns the box into RenderOptions).
  void cull(client_core::RenderOptions& ro) const {
    ro.content_bounds = content_bounds;
    ro.content_empty = !content_bounds;
    ro.content_boxes.reset();
  }
  // cull(), refined for one camera: the content boxes of what it can see
  // (client_core::content_boxes_for_view on the mirror). Per view: another camera needs its own.
  void cull_for_view(client_core::RenderOptions& ro, const client_core::Camera& camera) const {
    cull(ro);
    if (content_bounds)
      ro.content_boxes = client_core::content_boxes_for_view(pools, camera, *content_bounds);
  }
};

class StreamingReplica {
 public:
  static Result<std::unique_ptr<StreamingReplica>> create(const Context& ctx,
                                                          const GpuReplicaConfig& cfg,
                                                          const UploadBudget& budget = {},
                                                          const UploadChaos& chaos = {});
  ~StreamingReplica();
  StreamingReplica(const StreamingReplica&) = delete;
  StreamingReplica& operator=(const StreamingReplica&) = delete;

  // Queues an epoch (epochs must arrive in increasing order; an older one is dropped). Never
  // blocks on the GPU.
  void push(EpochUpload upload);
  // Runs `fn` under the GPU lock with the resident state.
  Result<void> with_gpu(const std::function<Result<void>(const ResidentState&)>& fn);
  // Blocks until `epoch` is resident (true) or the timeout passes / the upload thread failed.
  // Part of a snapshot (EpochUpload::partial) does not count.
  bool wait_resident(std::uint64_t epoch, std::chrono::milliseconds timeout);
  // Blocks until anything can be shown (an epoch or part of the first snapshot is resident).
  bool wait_any_resident(std::chrono::milliseconds timeout);
  std::uint64_t resident_epoch() const;  // the newest epoch resident whole
  bool any_resident() const;  // anything can be shown (part of the first snapshot included)
  // The batches made resident since the last call.
  std::vector<ResidentBatch> take_resident_log();
  StreamingStats stats() const;
  // The first error of the upload thread (it stops uploading after one), or success.
  Result<void> status() const;
  std::uint32_t width_log2() const noexcept { return width_log2_; }
  // Render loops report their frames (UploadBudget::max_batches_per_frame; frame gaps).
  //
  // Frame gaps. A paced loop (RenderLoopOptions::max_fps) leaves a gap after each frame and
  // passes `gap_wait_ms` > 0: the upload thread then starts a batch (its CPU work and its turn
  // under the GPU lock) only between frames, when the batch is expected to end before the
  // next frame is due (`next_frame_due`, from frame_finished(); the estimate follows recent
  // batches), so uploads and frames do not share the CPUs lavapipe renders on. A batch whose
  // oldest epoch has waited `gap_wait_ms` since its commit goes in the next gap, or at once
  // (between two bands of the frame in progress, as with an unpaced loop) when that gap has
  // already passed (a late loop starts its next frame right away, often before this thread is
  // scheduled) or no frame ends within another gap_wait: gaps shape when uploads happen, never
  // whether. A batch longer than a whole gap goes in the first gap it finds (waiting for
  // another would not make it fit). gap_wait_ms == 0 (an unpaced loop, frames back to back):
  // no gap logic.
  void attach_frames(bool attached);
  void frame_started(double gap_wait_ms = 0);
  void frame_finished(SteadyTime next_frame_due);

 private:
  StreamingReplica();
  void upload_thread();
  // What the upload thread does next (waits while there is nothing to do).
  enum class Work { stop, growth_step, batch };
  Work wait_for_work();
  // The byte budget and the batches-per-frame budget; false: stopping.
  bool wait_for_budget();
  // Records a batch made resident (or its error) in the stats and the log.
  void record_batch(const Result<void>& r, const ResidentBatch& rb, std::size_t epochs,
                    std::uint64_t bytes);
  // After a batch: the growth steps it calls for, and the content box shrink when due.
  void after_batch();
  struct GapWait {
    bool scheduled = false;  // a paced loop with gaps was attached: the wait applied
    double waited_ms = 0;
    bool mid_frame = false;  // went while a frame was in progress (no gap came in time)
    bool stop = false;
  };
  // Frame gaps (see frame_started()): waits, with `l` (mutex_) held, while
  // UploadBatchPolicy::decide_gap says so for work of about `estimate_ms` whose oldest epoch
  // was committed at `since`. Returns at once without a paced loop.
  GapWait wait_for_gap(std::unique_lock<std::mutex>& l, SteadyTime since, double estimate_ms);
  // Growth without a stall (see "Growth"): before `batch` (taken off the queue, `bytes` in
  // all) is applied, a first epoch the textures cannot hold waits while the growth completes in
  // steps; epochs after it that the textures cannot hold go back to the queue's front, and
  // `max_epochs` then keeps late joiners out.
  void make_room(std::vector<EpochUpload>& batch, std::uint32_t& max_epochs, std::uint64_t& bytes);
  // One step of the incremental texture growth (GpuReplica::growth_step) under the GPU lock, in
  // a gap between frames (`urgent`: at once, the textures are nearly full).
  void growth_step_in_gap(bool urgent = false);
  // Makes `batch` resident; epochs queued while it waited for the GPU lock join it (up to
  // `max_epochs` in all, 0: no limit) and are appended to `batch`.
  Result<void> apply_batch(std::vector<EpochUpload>& batch, std::uint32_t max_epochs,
                           ResidentBatch& out);
  // Under the GPU lock, after `batch` is in the mirror: the late joiners' content step and
  // mirror writes; they are appended to `batch`, their rows and groups merged into `rows` and
  // `groups`, and their rows alone returned in `late_rows` (uploaded after the staged batch).
  Result<void> apply_late_joiners(std::vector<EpochUpload>& batch, std::vector<EpochUpload>& late,
                                  std::vector<std::uint32_t>& rows,
                                  std::vector<std::uint32_t>& groups,
                                  std::vector<std::uint32_t>& late_rows, ResidentBatch& out);
  // Upload thread: sets the mirror's `rows` that no batch wrote yet to the never-used values
  // (leaf, empty, free group, no link), so that every row a batch writes held them before.
  // Outside the GPU lock for a batch's rows: bands read only cells reachable from the roots,
  // never such a row. Returns the milliseconds it took.
  double prepare_mirror_rows(std::span<const std::uint32_t> rows);
  // Under the GPU lock: writes the batch's rows (each prepared) into the mirror.
  void apply_to_mirror(const std::vector<EpochUpload>& batch);
  client_core::PoolView mirror_view() const noexcept;
  // Under the GPU lock: the box := exact_content_bounds() (no longer loose).
  void set_exact_content();
  // Under the GPU lock, once the step's epochs are in the mirror: the box := the step's box, or
  // exactly (set_exact_content) where the step fell back or `exact` (no box to grow yet).
  void take_content_step(const detail::ContentStep& step, bool exact, ResidentBatch& out);
  // The exact box of the mirror (painted_bounds; the whole canvas for pools it refuses).
  std::optional<client_core::DAabb> exact_content_bounds() const;
  // Upload thread, outside the GPU lock: recomputes the loose box when it is due.
  void maybe_shrink_content(bool queue_empty);

  std::unique_ptr<GpuReplica> replica_;
  std::uint32_t width_log2_ = 12;
  UploadBatchPolicy policy_;  // upload thread only
  UploadChaos chaos_;
  GpuLock gpu_lock_;

  // Mirror of the textures (guarded by gpu_lock_): m_cells_ cells, of the rows the textures'
  // uploads wrote (the rows no batch wrote read as zero and are never read: see
  // GpuReplica's header). The arrays are reserved for 2^28 cells when made, and sized so (their
  // size never changes: bands may take spans of them while the upload thread prepares rows); a
  // page takes memory when a row on it is first prepared, so growing costs nothing and a large
  // canvas's first part shows without writing its whole index range first.
  client_core::PoolArray<std::uint32_t> m_first_child_, m_colour_, m_group_parent_, m_links_;
  client_core::PoolArray<std::uint8_t> m_depth_flags_;
  std::vector<std::uint8_t> m_row_prepared_;  // per texture row; upload thread only
  std::uint64_t m_cells_ = 0;
  std::uint32_t roots_per_axis_ = 4;
  double edge_m_ = 20000.0;
  bool m_any_ = false;
  std::uint64_t m_epoch_ = 0;
  bool m_partial_ = false;
  std::optional<client_core::DAabb> m_content_;      // see "Content box"
  std::unique_ptr<detail::ContentTracker> content_;  // upload thread only
  // Upload thread only: the box may be larger than the exact one, and when it was last exact.
  bool content_loose_ = false;
  SteadyTime content_exact_at_{};
  std::uint64_t batch_number_ = 0;
  bool content_broken_ = false;  // UploadChaos::skip_content_growth_batch happened
  std::uint64_t content_exact_ = 0, content_fallbacks_ = 0;
  double max_content_exact_ms_ = 0;

  mutable std::mutex mutex_;  // queue, log, stats, status, frames_
  std::condition_variable cv_;
  std::deque<EpochUpload> queue_;
  std::uint64_t last_pushed_ = 0;
  bool pushed_any_ = false;
  bool stop_ = false;
  bool any_resident_ = false;    // anything, part of a snapshot included
  bool whole_resident_ = false;  // a whole epoch
  std::uint64_t resident_epoch_ = 0;
  std::vector<ResidentBatch> log_;
  StreamingStats stats_;
  FrameSchedule frames_;  // what the render loops report
  Result<void> status_;
  std::thread thread_;
};

// The upload for one of a client's commits (its changed ranges and cells, its masked groups;
// `partial` as the commit's), for textures of width 2^width_log2. Call it in the epoch listener:
// the commit's replica is valid only there.
EpochUpload capture_commit(const client_core::EpochCommit& commit, std::uint32_t width_log2);

// Feeds `client`'s committed epochs into `replica` (Client::set_epoch_listener: the current
// state at once, then every commit). Both must outlive the connection, or call
// client.set_epoch_listener({}) first.
void stream_client_into(client_core::Client& client, StreamingReplica& replica);

}  // namespace deepcanvas::client_gpu
