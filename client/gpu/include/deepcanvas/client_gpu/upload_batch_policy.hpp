// The upload batch policy of StreamingReplica: which queued epochs go in the next batch and when
// it may start. Pure decisions, no Vulkan, no threads, no clock reads (every time is a
// parameter), so each rule is unit-tested with synthetic epochs and clocks
// (tests/client_gpu/upload_batch_policy_test.cpp). StreamingReplica's upload thread does the
// waiting, the queue moves and the GPU work the policy decides.
//
// The rules (StreamingReplica's header gives the reasons and the benchmarks that show them):
//  * Byte budget (UploadBudget::bytes_per_second): a token bucket with a burst of 50 ms worth;
//    a batch starts once the bucket is not in debt, then spends its bytes.
//  * Batches per frame (UploadBudget::max_batches_per_frame): while a render loop is attached,
//    at most that many batches per started frame; then wait for the next frame (at most 1 s).
//  * Frame gaps (a paced loop, FrameSchedule::gap_wait_ms > 0): a batch starts between frames
//    when it is expected to end before the next frame is due, when no gap is long enough for it,
//    or when its oldest epoch has waited gap_wait since its commit; once that deadline has passed
//    it goes mid-frame (between two bands) if the gap after the deadline went by unused, or
//    after another gap_wait at the latest. Gaps shape when uploads happen, never whether.
//  * Which epochs: the queue's front, up to max_epochs (0: all). An epoch the textures cannot
//    hold (cell_count above their capacity) ends the batch there unless it is the first (which
//    waits while a growth completes in steps); the rest go back to the queue, and no epoch joins
//    late. Late joiners (epochs queued while the batch waited for the GPU lock) join only within
//    max_epochs and within the textures.
//  * Growth: past half full a batch begins an incremental growth ahead of need; past 3/4 full
//    the remaining steps run at once (each its own turn under the GPU lock). Textures larger
//    than twice a growth's cap (GpuReplicaConfig::max_growth_cells) count from their free room
//    instead: a growth begins with less than half a growth's cells left, and is urgent with less
//    than a quarter. Steps aim at about 2 ms, sized from the last step's time per row.
//
// Threading: UploadBatchPolicy is the upload thread's alone (not thread-safe). FrameSchedule is a
// value the owner guards with its own lock.
#pragma once

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>

#include "deepcanvas/client_gpu/epoch_upload.hpp"

namespace deepcanvas::client_gpu {

struct UploadBudget {
  double bytes_per_second = 0;             // token bucket rate; 0 = unlimited
  std::uint32_t max_epochs_per_batch = 0;  // 0 = every epoch pending
  // Non-zero: at most this many batches per rendered frame (the paper's "one block per
  // frame", per batch here), while a render loop is attached.
  std::uint32_t max_batches_per_frame = 0;
};

// What the render loops report (StreamingReplica::attach_frames, frame_started,
// frame_finished): the input of the frame-gap and batches-per-frame rules.
struct FrameSchedule {
  int attached_loops = 0;
  std::uint64_t frames_started = 0;
  bool frame_in_progress = false;
  double gap_wait_ms = 0;        // > 0: a paced loop, the gap rules apply
  SteadyTime next_frame_due{};   // from the last frame_finished()
  SteadyTime last_frame_end{};   // when the last frame_finished() came
  double gap_ms = 0;             // the last gap's length: from its frame's end to next_frame_due

  void attach(bool attached);
  void frame_started(double gap_wait);
  void frame_finished(SteadyTime now, SteadyTime next_due);
  bool gaps_apply() const noexcept { return attached_loops > 0 && gap_wait_ms > 0; }
};

// One step of the wait for a frame gap.
struct GapDecision {
  enum class Action { go, go_mid_frame, wait };
  Action action = Action::go;
  SteadyTime wait_until{};  // Action::wait: wake up then (or when the schedule changes)
};

// The deadline of a gap wait: `since` (the oldest epoch's commit) + gap_wait, and the slack
// after it before the batch goes mid-frame whatever the loop does.
struct GapWindow {
  SteadyTime deadline{};
  SteadyTime::duration slack{};
};

class UploadBatchPolicy {
 public:
  // The growth steps aim at this long under the GPU lock.
  static constexpr double kGrowthStepTargetMs = 2.0;
  // A first epoch the textures cannot hold waits for at most this many growths in steps (a
  // growth under way may be to textures still too small for it); then the batch grows at once.
  static constexpr int kGrowthRoundsBeforeBatch = 2;

  UploadBatchPolicy() = default;  // no budget
  UploadBatchPolicy(const UploadBudget& budget, SteadyTime now);

  // ---- byte budget ----
  // Refills the bucket for the time since the last call; how long to wait before a batch may
  // start, or nullopt to start now (always nullopt without a rate).
  std::optional<std::chrono::duration<double>> byte_budget_wait(SteadyTime now);
  void spend_bytes(std::uint64_t bytes);

  // ---- batches per frame ----
  // True when the frame in progress has had its max_batches_per_frame: wait for the next frame
  // (or 1 s, or the loop detaching), then call frame_budget_restart(). Starts a new count when
  // a new frame has started since the last batch.
  bool frame_budget_spent(const FrameSchedule& frames);
  void frame_budget_restart(const FrameSchedule& frames);
  void batch_done() noexcept { ++batches_in_frame_; }

  // ---- frame gaps ----
  static GapWindow gap_window(SteadyTime since, double gap_wait_ms);
  // `estimate_ms`: what the work about to start is expected to take.
  static GapDecision decide_gap(const FrameSchedule& frames, SteadyTime now,
                                const GapWindow& window, double estimate_ms);
  // What the next batch is expected to take: a running mean of recent batches' content step
  // and GPU lock time (it takes what queued meanwhile, so recent batches predict it).
  double batch_estimate_ms() const noexcept { return batch_estimate_ms_; }
  void batch_took(double ms) noexcept { batch_estimate_ms_ = 0.8 * batch_estimate_ms_ + 0.2 * ms; }

  // ---- which epochs ----
  std::uint32_t max_epochs_per_batch() const noexcept { return budget_.max_epochs_per_batch; }
  // How many of `queued` epochs at the queue's front a batch takes.
  static std::size_t epochs_to_take(std::size_t queued, std::uint32_t max_epochs) noexcept;
  static bool fits(const EpochUpload& e, std::uint64_t capacity_cells) noexcept {
    return e.cell_count <= capacity_cells;
  }
  // Of a batch taken in queue order (not empty), how many go now: the first always, then those
  // before the first the textures cannot hold. The rest go back to the queue's front and the
  // batch's max_epochs becomes this count.
  static std::size_t epochs_that_fit(std::span<const EpochUpload> batch,
                                     std::uint64_t capacity_cells) noexcept;
  // Whether `e`, queued while a batch of `batch_epochs` waited for the GPU lock, joins it. A late
  // joiner's rows are copied under the lock (the batch's were staged before it), so it joins
  // only when the CPU mirror holds it without growing (`mirror_room_cells`) and the late rows
  // so far (`late_rows`) leave room for its rows within kMaxLateRows; otherwise it waits for
  // the next batch, staged outside the lock like this one.
  static constexpr std::size_t kMaxLateRows = 64;
  struct LateRoom {
    std::uint32_t max_epochs = 0;  // 0: no limit
    std::uint64_t capacity_cells = 0;
    std::uint64_t mirror_room_cells = 0;
    std::size_t late_rows = 0;
  };
  static bool may_join_late(const EpochUpload& e, std::size_t batch_epochs,
                            const LateRoom& room) noexcept;

  // ---- growth ----
  // After a batch has reserved its cells: begin an incremental growth ahead of need (past half
  // full, or with less than half of `max_growth_cells` free, whichever comes later).
  static bool begin_growth_ahead(std::uint64_t cells, std::uint64_t capacity_cells,
                                 std::uint64_t max_growth_cells = ~std::uint64_t{0}) noexcept {
    if (cells >= capacity_cells) return true;
    return 2 * (capacity_cells - cells) < std::min(capacity_cells, max_growth_cells);
  }
  // During a growth: run the remaining steps now rather than one per batch or idle turn (past
  // 3/4 full, or with less than a quarter of `max_growth_cells` free, whichever comes later).
  static bool growth_urgent(std::uint64_t cells, std::uint64_t capacity_cells,
                            std::uint64_t max_growth_cells = ~std::uint64_t{0}) noexcept {
    if (cells >= capacity_cells) return true;
    return 4 * (capacity_cells - cells) < std::min(capacity_cells, max_growth_cells);
  }
  std::uint32_t growth_rows_per_step() const noexcept { return growth_rows_per_step_; }
  // A step of growth_rows_per_step() rows took `ms` (`finished`: it completed the growth):
  // the next steps are sized to kGrowthStepTargetMs from its time per row.
  void growth_step_took(double ms, bool finished) noexcept;

 private:
  UploadBudget budget_;
  double tokens_ = 0;
  SteadyTime last_refill_{};
  std::uint64_t frame_of_batches_ = 0;
  std::uint32_t batches_in_frame_ = 0;
  double batch_estimate_ms_ = 2.0;
  std::uint32_t growth_rows_per_step_ = 16;
};

}  // namespace deepcanvas::client_gpu
