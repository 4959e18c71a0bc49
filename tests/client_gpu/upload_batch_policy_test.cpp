// UploadBatchPolicy (label unit, no device): StreamingReplica's batch rules on synthetic epochs and
// clocks. The streaming GPU tests (tests/render_gpu) check the same rules end to end on a device.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <deque>
#include <vector>

#include "deepcanvas/client_gpu/upload_batch_policy.hpp"

namespace deepcanvas::client_gpu {
namespace {

using Action = GapDecision::Action;
using std::chrono::milliseconds;

const SteadyTime kT0 = SteadyTime{} + std::chrono::hours(1);

double seconds(std::chrono::duration<double> d) {
  return d.count();
}

EpochUpload epoch(std::uint64_t n, std::uint64_t cells) {
  EpochUpload e;
  e.epoch = n;
  e.cell_count = cells;
  return e;
}

TEST(UploadBatchPolicy, ByteBudgetIsATokenBucketWithA50MsBurst) {
  UploadBatchPolicy p({.bytes_per_second = 1e6}, kT0);
  EXPECT_FALSE(p.byte_budget_wait(kT0)) << "an empty bucket is not in debt";
  p.spend_bytes(100000);  // 0.1 s worth
  auto w = p.byte_budget_wait(kT0);
  ASSERT_TRUE(w);
  EXPECT_NEAR(seconds(*w), 0.1, 1e-9);
  w = p.byte_budget_wait(kT0 + milliseconds(50));
  ASSERT_TRUE(w);
  EXPECT_NEAR(seconds(*w), 0.05, 1e-9) << "refilled for the 50 ms since the last call";
  EXPECT_FALSE(p.byte_budget_wait(kT0 + milliseconds(100)));
  // A long idle time fills the bucket to 50 ms worth, no more.
  EXPECT_FALSE(p.byte_budget_wait(kT0 + std::chrono::seconds(10)));
  p.spend_bytes(150000);
  w = p.byte_budget_wait(kT0 + std::chrono::seconds(10));
  ASSERT_TRUE(w);
  EXPECT_NEAR(seconds(*w), 0.1, 1e-9);

  UploadBatchPolicy unlimited({}, kT0);
  unlimited.spend_bytes(1u << 30);
  EXPECT_FALSE(unlimited.byte_budget_wait(kT0)) << "no rate: never waits";
}

TEST(UploadBatchPolicy, BatchesPerFrameAreCountedPerStartedFrameWhileALoopIsAttached) {
  UploadBatchPolicy p({.max_batches_per_frame = 2}, kT0);
  FrameSchedule f;
  EXPECT_FALSE(p.frame_budget_spent(f)) << "no loop attached";
  p.batch_done();
  p.batch_done();
  EXPECT_FALSE(p.frame_budget_spent(f)) << "no loop attached";
  f.attach(true);
  f.frame_started(0);
  EXPECT_FALSE(p.frame_budget_spent(f)) << "a new frame starts a new count";
  p.batch_done();
  EXPECT_FALSE(p.frame_budget_spent(f));
  p.batch_done();
  EXPECT_TRUE(p.frame_budget_spent(f));
  EXPECT_TRUE(p.frame_budget_spent(f)) << "until the next frame starts";
  f.frame_started(0);
  EXPECT_FALSE(p.frame_budget_spent(f));
  p.batch_done();
  p.batch_done();
  EXPECT_TRUE(p.frame_budget_spent(f));
  p.frame_budget_restart(f);  // after waiting a second for a frame that did not come
  EXPECT_FALSE(p.frame_budget_spent(f));
  f.attach(false);
  p.batch_done();
  p.batch_done();
  EXPECT_FALSE(p.frame_budget_spent(f)) << "the loop detached";

  UploadBatchPolicy uncapped({}, kT0);
  for (int i = 0; i < 100; ++i) uncapped.batch_done();
  EXPECT_FALSE(uncapped.frame_budget_spent(f));
}

TEST(UploadBatchPolicy, FrameScheduleFollowsTheLoops) {
  FrameSchedule f;
  EXPECT_FALSE(f.gaps_apply());
  f.attach(true);
  f.frame_started(0);
  EXPECT_FALSE(f.gaps_apply()) << "an unpaced loop (gap_wait 0): no gap logic";
  f.frame_started(8.0);
  EXPECT_TRUE(f.gaps_apply());
  EXPECT_TRUE(f.frame_in_progress);
  EXPECT_EQ(f.frames_started, 2u);
  f.frame_finished(kT0, kT0 + milliseconds(10));
  EXPECT_FALSE(f.frame_in_progress);
  EXPECT_EQ(f.last_frame_end, kT0);
  EXPECT_DOUBLE_EQ(f.gap_ms, 10.0);
  f.frame_started(8.0);
  f.attach(false);
  EXPECT_FALSE(f.gaps_apply());
  EXPECT_FALSE(f.frame_in_progress) << "no loop left: nothing is in progress";
}

// A paced loop: frames end at kT0, the next is due 10 ms later; the batch's oldest epoch was
// committed at kT0 - 2 ms with gap_wait 8 ms, so its deadline is kT0 + 6 ms.
struct PacedLoop {
  FrameSchedule f;
  GapWindow window = UploadBatchPolicy::gap_window(kT0 - milliseconds(2), 8.0);
  PacedLoop() {
    f.attach(true);
    f.frame_started(8.0);
    f.frame_finished(kT0, kT0 + milliseconds(10));
  }
};

TEST(UploadBatchPolicy, InAGapABatchGoesWhenItFitsBeforeTheNextFrame) {
  PacedLoop l;
  EXPECT_EQ(l.window.deadline, kT0 + milliseconds(6));
  EXPECT_EQ(l.window.slack, milliseconds(8));
  EXPECT_EQ(UploadBatchPolicy::decide_gap(l.f, kT0 + milliseconds(1), l.window, 2.0).action,
            Action::go);
  // 5 ms of work with 4.5 ms left before the next frame: wait for the next gap (until the
  // deadline at most).
  const GapDecision d = UploadBatchPolicy::decide_gap(
      l.f, kT0 + std::chrono::microseconds(5500), l.window, 5.0);
  EXPECT_EQ(d.action, Action::wait);
  EXPECT_EQ(d.wait_until, l.window.deadline);
  // Past the deadline it starts a gap at the latest.
  EXPECT_EQ(UploadBatchPolicy::decide_gap(l.f, kT0 + milliseconds(7), l.window, 5.0).action,
            Action::go);
  // Work longer than the whole gap goes in the first gap it finds.
  EXPECT_EQ(UploadBatchPolicy::decide_gap(l.f, kT0 + milliseconds(1), l.window, 10.0).action,
            Action::go);
}

TEST(UploadBatchPolicy, DuringAFrameABatchWaitsThenGoesMidFrameOnceOverdue) {
  PacedLoop l;
  l.f.frame_started(8.0);  // a frame is in progress; the last gap ended at kT0
  // Before the deadline: wait for it (a gap may come first and wake the thread).
  GapDecision d = UploadBatchPolicy::decide_gap(l.f, kT0 + milliseconds(3), l.window, 2.0);
  EXPECT_EQ(d.action, Action::wait);
  EXPECT_EQ(d.wait_until, l.window.deadline);
  // Overdue, but the last gap ended before the deadline: wait one more gap_wait for a gap.
  d = UploadBatchPolicy::decide_gap(l.f, kT0 + milliseconds(7), l.window, 2.0);
  EXPECT_EQ(d.action, Action::wait);
  EXPECT_EQ(d.wait_until, l.window.deadline + l.window.slack);
  // ... then between the bands of the frame in progress.
  EXPECT_EQ(UploadBatchPolicy::decide_gap(l.f, l.window.deadline + l.window.slack, l.window, 2.0)
                .action,
            Action::go_mid_frame);
  // Overdue and the gap after the deadline came and went unused: mid-frame at once.
  l.f.frame_finished(kT0 + milliseconds(7), kT0 + milliseconds(8));
  l.f.frame_started(8.0);
  EXPECT_EQ(UploadBatchPolicy::decide_gap(l.f, kT0 + milliseconds(9), l.window, 2.0).action,
            Action::go_mid_frame);
}

TEST(UploadBatchPolicy, ABatchTakesTheQueueFrontUpToMaxEpochs) {
  EXPECT_EQ(UploadBatchPolicy::epochs_to_take(5, 0), 5u) << "0: every epoch pending";
  EXPECT_EQ(UploadBatchPolicy::epochs_to_take(5, 2), 2u);
  EXPECT_EQ(UploadBatchPolicy::epochs_to_take(1, 3), 1u);
  EXPECT_EQ(UploadBatchPolicy::epochs_to_take(0, 3), 0u);
  EXPECT_EQ(UploadBatchPolicy({.max_epochs_per_batch = 7}, kT0).max_epochs_per_batch(), 7u);
}

TEST(UploadBatchPolicy, EpochsPastTheTexturesWaitForTheNextBatch) {
  const std::uint64_t cap = 1024;
  // A burst crossing the textures' size: the epochs that fit go first, the first that does not
  // and everything after it (in order) wait for the next batch, which grows first.
  std::deque<EpochUpload> queue;
  for (std::uint64_t i = 0; i < 6; ++i) queue.push_back(epoch(i, 600 + 150 * i));
  std::vector<EpochUpload> batch(queue.begin(), queue.end());
  std::size_t fit = UploadBatchPolicy::epochs_that_fit(batch, cap);
  EXPECT_EQ(fit, 3u);  // 600, 750, 900 fit; 1050 does not
  for (std::size_t i = 0; i < fit; ++i) EXPECT_TRUE(UploadBatchPolicy::fits(batch[i], cap));
  // The next batch starts with the epoch that did not fit: it goes (after a growth), and so do
  // those after it that the grown textures hold.
  batch.erase(batch.begin(), batch.begin() + static_cast<std::ptrdiff_t>(fit));
  EXPECT_FALSE(UploadBatchPolicy::fits(batch.front(), cap));
  EXPECT_EQ(UploadBatchPolicy::epochs_that_fit(batch, cap), 1u) << "the first always goes";
  EXPECT_EQ(UploadBatchPolicy::epochs_that_fit(batch, 2 * cap), batch.size());
  // An epoch that fits after one that does not still waits (epochs stay in order).
  const std::vector<EpochUpload> mixed = {epoch(1, 100), epoch(2, 2000), epoch(3, 100)};
  EXPECT_EQ(UploadBatchPolicy::epochs_that_fit(mixed, cap), 1u);
  EXPECT_EQ(UploadBatchPolicy::epochs_that_fit(std::vector<EpochUpload>{epoch(1, 5000)}, cap), 1u);
}

TEST(UploadBatchPolicy, LateJoinersOnlyWithinMaxEpochsTheTexturesTheMirrorAndTheRowLimit) {
  using Room = UploadBatchPolicy::LateRoom;
  const std::uint64_t cap = 1024;
  const Room open{0, cap, cap, 0};
  EXPECT_TRUE(UploadBatchPolicy::may_join_late(epoch(9, 1000), 5, open)) << "no limit";
  EXPECT_TRUE(UploadBatchPolicy::may_join_late(epoch(9, 1024), 2, Room{3, cap, cap, 0}));
  EXPECT_FALSE(UploadBatchPolicy::may_join_late(epoch(9, 1000), 3, Room{3, cap, cap, 0}))
      << "batch full";
  EXPECT_FALSE(UploadBatchPolicy::may_join_late(epoch(9, 1025), 1, Room{0, cap, 2 * cap, 0}))
      << "the textures cannot hold it: it waits for a batch that grows them in steps";
  EXPECT_FALSE(UploadBatchPolicy::may_join_late(epoch(9, 1000), 1, Room{0, cap, 999, 0}))
      << "the mirror would grow under the lock: it waits for a batch that grows it outside";
  EpochUpload e = epoch(9, 1000);
  e.rows.assign(10, 0);
  const std::size_t max_rows = UploadBatchPolicy::kMaxLateRows;
  EXPECT_TRUE(UploadBatchPolicy::may_join_late(e, 1, Room{0, cap, cap, max_rows - 10}));
  EXPECT_FALSE(UploadBatchPolicy::may_join_late(e, 1, Room{0, cap, cap, max_rows - 9}))
      << "its rows would be copied under the lock past the limit";
}

TEST(UploadBatchPolicy, GrowthBeginsPastHalfFullAndHurriesPastThreeQuarters) {
  EXPECT_FALSE(UploadBatchPolicy::begin_growth_ahead(512, 1024));
  EXPECT_TRUE(UploadBatchPolicy::begin_growth_ahead(513, 1024));
  EXPECT_FALSE(UploadBatchPolicy::growth_urgent(768, 1024));
  EXPECT_TRUE(UploadBatchPolicy::growth_urgent(769, 1024));
}

// Against the rule stated in cells: a growth begins past half full, or with less than half a
// growth's cells free, whichever comes later; it hurries past 3/4 full, or with less than a
// quarter of a growth free. Every (cells, capacity, cap) on a small grid, and the 128M-cell case.
TEST(UploadBatchPolicy, LargeTexturesGrowFromTheirFreeRoom) {
  for (std::uint64_t cap = 1; cap <= 96; ++cap) {
    for (std::uint64_t growth = 1; growth <= 130; growth += 3) {
      for (std::uint64_t cells = 0; cells <= 2 * cap; ++cells) {
        const bool full = cells >= cap;
        const double free_cells = full ? 0.0 : static_cast<double>(cap - cells);
        const double limit = static_cast<double>(std::min(cap, growth));
        EXPECT_EQ(UploadBatchPolicy::begin_growth_ahead(cells, cap, growth),
                  full || free_cells < limit / 2)
            << cells << " of " << cap << ", growth " << growth;
        EXPECT_EQ(UploadBatchPolicy::growth_urgent(cells, cap, growth),
                  full || free_cells < limit / 4)
            << cells << " of " << cap << ", growth " << growth;
      }
    }
  }
  constexpr std::uint64_t M = 1u << 20, cap = 128 * M + 16 * M, growth = 16 * M;
  EXPECT_FALSE(UploadBatchPolicy::begin_growth_ahead(128 * M, cap, growth))
      << "a joined 128M-cell canvas with 16M cells of room grows no further";
  EXPECT_TRUE(UploadBatchPolicy::begin_growth_ahead(128 * M, 128 * M + 8 * M - 1, growth));
  EXPECT_FALSE(UploadBatchPolicy::growth_urgent(128 * M, 128 * M + 4 * M, growth));
  EXPECT_TRUE(UploadBatchPolicy::growth_urgent(128 * M, 128 * M + 4 * M - 1, growth));
}

TEST(UploadBatchPolicy, GrowthStepsAreSizedToTheTargetTime) {
  UploadBatchPolicy p({}, kT0);
  EXPECT_EQ(p.growth_rows_per_step(), 16u);
  p.growth_step_took(0.5, false);  // 16 rows in 0.5 ms: 2 ms is 64 rows
  EXPECT_EQ(p.growth_rows_per_step(), 64u);
  p.growth_step_took(0.04, false);  // too short to measure
  EXPECT_EQ(p.growth_rows_per_step(), 64u);
  p.growth_step_took(50.0, true);  // the last step of a growth says nothing about the next
  EXPECT_EQ(p.growth_rows_per_step(), 64u);
  p.growth_step_took(64.0, false);  // 1 ms a row: at least 8 rows a step
  EXPECT_EQ(p.growth_rows_per_step(), 8u);
  p.growth_step_took(0.06, false);  // very fast rows: at most 4096 a step
  EXPECT_EQ(p.growth_rows_per_step(), 266u);
  p.growth_step_took(0.06, false);
  EXPECT_EQ(p.growth_rows_per_step(), 4096u);
}

TEST(UploadBatchPolicy, TheBatchEstimateFollowsRecentBatches) {
  UploadBatchPolicy p({}, kT0);
  EXPECT_DOUBLE_EQ(p.batch_estimate_ms(), 2.0);
  p.batch_took(12.0);
  EXPECT_DOUBLE_EQ(p.batch_estimate_ms(), 4.0);
  for (int i = 0; i < 100; ++i) p.batch_took(1.0);
  EXPECT_NEAR(p.batch_estimate_ms(), 1.0, 1e-6);
}

}  // namespace
}  // namespace deepcanvas::client_gpu
