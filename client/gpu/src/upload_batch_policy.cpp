// UploadBatchPolicy and FrameSchedule (see upload_batch_policy.hpp).
#include "deepcanvas/client_gpu/upload_batch_policy.hpp"

#include <algorithm>

namespace deepcanvas::client_gpu {

namespace {
using Clock = std::chrono::steady_clock;

Clock::duration from_ms(double ms) {
  return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double, std::milli>(ms));
}
}  // namespace

void FrameSchedule::attach(bool attached) {
  attached_loops += attached ? 1 : -1;
  if (attached_loops == 0) {
    frame_in_progress = false;
    gap_wait_ms = 0;
  }
}

void FrameSchedule::frame_started(double gap_wait) {
  ++frames_started;
  frame_in_progress = true;
  gap_wait_ms = gap_wait;
}

void FrameSchedule::frame_finished(SteadyTime now, SteadyTime next_due) {
  frame_in_progress = false;
  next_frame_due = next_due;
  last_frame_end = now;
  gap_ms = std::chrono::duration<double, std::milli>(next_due - now).count();
}

UploadBatchPolicy::UploadBatchPolicy(const UploadBudget& budget, SteadyTime now)
    : budget_(budget), last_refill_(now) {}

std::optional<std::chrono::duration<double>> UploadBatchPolicy::byte_budget_wait(SteadyTime now) {
  const double rate = budget_.bytes_per_second;
  if (rate <= 0) return std::nullopt;
  tokens_ = std::min(rate * 0.05,
                     tokens_ + rate * std::chrono::duration<double>(now - last_refill_).count());
  last_refill_ = now;
  if (tokens_ >= 0) return std::nullopt;
  return std::chrono::duration<double>(-tokens_ / rate);
}

void UploadBatchPolicy::spend_bytes(std::uint64_t bytes) {
  tokens_ -= static_cast<double>(bytes);
}

bool UploadBatchPolicy::frame_budget_spent(const FrameSchedule& frames) {
  if (budget_.max_batches_per_frame == 0 || frames.attached_loops <= 0) return false;
  if (frames.frames_started != frame_of_batches_) frame_budget_restart(frames);
  return batches_in_frame_ >= budget_.max_batches_per_frame;
}

void UploadBatchPolicy::frame_budget_restart(const FrameSchedule& frames) {
  frame_of_batches_ = frames.frames_started;
  batches_in_frame_ = 0;
}

GapWindow UploadBatchPolicy::gap_window(SteadyTime since, double gap_wait_ms) {
  const Clock::duration gap_wait = from_ms(gap_wait_ms);
  return {since + gap_wait, gap_wait};
}

GapDecision UploadBatchPolicy::decide_gap(const FrameSchedule& frames, SteadyTime now,
                                          const GapWindow& window, double estimate_ms) {
  using Action = GapDecision::Action;
  const SteadyTime deadline = window.deadline;
  if (!frames.frame_in_progress) {
    // In a gap: go when the work is expected to end before the next frame is due, when no gap
    // is long enough for it (waiting would only add latency: it overruns whichever gap it
    // starts in), or when it has already let one gap pass (then it starts a gap at the latest).
    const SteadyTime fits_until = now + from_ms(estimate_ms);
    if (fits_until <= frames.next_frame_due || estimate_ms >= frames.gap_ms || now >= deadline)
      return {Action::go, {}};
  } else if (now >= deadline && frames.last_frame_end >= deadline) {
    // Overdue, and the gap after the deadline came and went before the upload thread ran (the
    // loop started its next frame at once): between this frame's bands, not a frame later.
    return {Action::go_mid_frame, {}};
  } else if (now >= deadline + window.slack) {
    // The loop has rendered a long frame (or stalled): between its bands after all.
    return {Action::go_mid_frame, {}};
  }
  return {Action::wait, now >= deadline ? deadline + window.slack : deadline};
}

std::size_t UploadBatchPolicy::epochs_to_take(std::size_t queued,
                                              std::uint32_t max_epochs) noexcept {
  return max_epochs == 0 ? queued : std::min<std::size_t>(queued, max_epochs);
}

std::size_t UploadBatchPolicy::epochs_that_fit(std::span<const EpochUpload> batch,
                                               std::uint64_t capacity_cells) noexcept {
  std::size_t fit = 1;
  while (fit < batch.size() && fits(batch[fit], capacity_cells)) ++fit;
  return std::min(fit, batch.size());
}

bool UploadBatchPolicy::may_join_late(const EpochUpload& e, std::size_t batch_epochs,
                                      const LateRoom& room) noexcept {
  return (room.max_epochs == 0 || batch_epochs < room.max_epochs) && fits(e, room.capacity_cells) &&
         e.cell_count <= room.mirror_room_cells && room.late_rows + e.rows.size() <= kMaxLateRows;
}

void UploadBatchPolicy::growth_step_took(double ms, bool finished) noexcept {
  if (finished || ms <= 0.05) return;  // too short to measure a time per row
  const double per_row = ms / growth_rows_per_step_;
  growth_rows_per_step_ =
      static_cast<std::uint32_t>(std::clamp(kGrowthStepTargetMs / per_row, 8.0, 4096.0));
}

}  // namespace deepcanvas::client_gpu
