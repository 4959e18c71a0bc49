// The stroke thread's decisions (server/core/src/stroke_scheduler.hpp): pure functions of named
// inputs, tested without threads or a canvas.
#include <gtest/gtest.h>

#include <vector>

#include "stroke_scheduler.hpp"

namespace deepcanvas::test {
namespace {

namespace sched = server_core::stroke_scheduler;
using sched::QueueWait;

TEST(StrokeScheduler, QueueWaitIdleSleepsForAJob) {
  sched::QueueState s;
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::for_job);
  s.stream_open = true;  // an open streamed stroke: wake to end it if it goes idle
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::idle_stream);
}

TEST(StrokeScheduler, QueueWaitNeverSleepsWithJobsOrWhileStopping) {
  sched::QueueState s;
  s.jobs_queued = true;
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::none);
  s = {};
  s.stopping = true;
  s.stream_open = true;
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::none);
}

TEST(StrokeScheduler, QueueWaitForCompressOnlyWhenOnlyStagingIsLeft) {
  sched::QueueState s;
  s.have_work = true;
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::none);
  s.compress_behind = true;
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::compress);
  s.painter_busy = true;  // steps to run: go on painting
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::none);
  s.painter_busy = false;
  s.jobs_queued = true;  // jobs to take: take them
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::none);
}

TEST(StrokeScheduler, FirstStepIsSmall) {
  EXPECT_EQ(sched::step_budget(true, 1024, 8192), 1024u);
  EXPECT_EQ(sched::step_budget(false, 1024, 8192), 8192u);
  // The first step never exceeds an ordinary one.
  EXPECT_EQ(sched::step_budget(true, 1u << 20, 8192), 8192u);
}

TEST(StrokeScheduler, IdleStreamExpiresAfterTheTimeout) {
  const sched::Clock::time_point t0{};
  const auto at = t0 + sched::kIdleStreamTimeout;
  EXPECT_FALSE(sched::idle_stream_expired(false, t0, at));  // exactly the timeout: not yet
  EXPECT_TRUE(sched::idle_stream_expired(false, t0, at + std::chrono::milliseconds(1)));
  EXPECT_FALSE(sched::idle_stream_expired(true, t0, at + std::chrono::seconds(10)));  // ended
  // A configured timeout (CanvasServiceConfig::idle_stroke_timeout) replaces the default.
  const auto short_timeout = std::chrono::milliseconds(50);
  EXPECT_FALSE(sched::idle_stream_expired(false, t0, t0 + short_timeout, short_timeout));
  EXPECT_TRUE(sched::idle_stream_expired(false, t0, t0 + short_timeout * 2, short_timeout));
}

TEST(StrokeScheduler, IdlePollIsNeverLongerThanTheTimeout) {
  EXPECT_EQ(sched::idle_poll(std::chrono::seconds(2)), sched::kIdleStreamPoll);
  EXPECT_EQ(sched::idle_poll(std::chrono::milliseconds(20)),
            sched::Clock::duration(std::chrono::milliseconds(20)));
}

TEST(StrokeScheduler, AckDueOnceWhenThePaintIsInTheTree) {
  EXPECT_FALSE(sched::ack_due(false, false, false, true));  // stroke not ended yet
  EXPECT_TRUE(sched::ack_due(true, false, false, true));    // painted, merging still to do
  EXPECT_TRUE(sched::ack_due(true, false, true, false));    // finished outright
  EXPECT_FALSE(sched::ack_due(true, false, false, false));  // steps remain
  EXPECT_FALSE(sched::ack_due(true, true, true, true));     // already acked
}

TEST(StrokeScheduler, StagesWithinTheBacklogCap) {
  sched::StagingState s;
  s.max_backlog = 1;
  s.compress_backlog = 1;
  EXPECT_TRUE(sched::stage_now(s));
  s.compress_backlog = 2;
  EXPECT_FALSE(sched::stage_now(s));
  s.force_epoch = true;  // quiesce: always
  EXPECT_TRUE(sched::stage_now(s));
  s.force_epoch = false;
  s.idle = true;
  s.stopping = true;  // the last epoch before stopping
  EXPECT_TRUE(sched::stage_now(s));
}

TEST(StrokeScheduler, RepliesFirstStagesOneEpochBeyondTheCap) {
  sched::StagingState s;
  s.max_backlog = 0;
  s.compress_backlog = 1;
  s.replies_pending = true;
  EXPECT_FALSE(sched::stage_now(s));  // replies_first off
  s.replies_first = true;
  EXPECT_TRUE(sched::stage_now(s));
  s.compress_backlog = 2;  // two beyond: wait
  EXPECT_FALSE(sched::stage_now(s));
  s.compress_backlog = 1;
  s.replies_pending = false;  // nothing to reply: the cap holds
  EXPECT_FALSE(sched::stage_now(s));
}

TEST(StrokeScheduler, AnEpochTooSoonAfterTheLastWaitsUnlessItCarriesRepliesOrIsForced) {
  sched::StagingState s;
  s.too_soon = true;
  EXPECT_FALSE(sched::stage_now(s));  // within the cap, but too soon
  s.replies_first = true;
  s.replies_pending = true;  // an ack: now
  EXPECT_TRUE(sched::stage_now(s));
  s.replies_first = false;  // replies wait like any epoch
  EXPECT_FALSE(sched::stage_now(s));
  s.replies_pending = false;
  s.force_epoch = true;  // quiesce: now
  EXPECT_TRUE(sched::stage_now(s));
  s.force_epoch = false;
  s.idle = true;
  s.stopping = true;  // the last epoch before stopping: now
  EXPECT_TRUE(sched::stage_now(s));
  s = {};
  EXPECT_TRUE(sched::stage_now(s));  // not too soon: as before
}

TEST(StrokeScheduler, QueueWaitsForTheEpochIntervalOnlyWhenOnlyStagingIsLeft) {
  sched::QueueState s;
  s.have_work = true;
  s.epoch_too_soon = true;
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::epoch_interval);
  s.painter_busy = true;  // steps to run: go on painting
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::none);
  s.painter_busy = false;
  s.jobs_queued = true;  // jobs to take: take them
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::none);
  s.jobs_queued = false;
  s.stopping = true;
  EXPECT_EQ(sched::choose_queue_wait(s), QueueWait::none);
}

TEST(StrokeScheduler, InlinePublishOnlyForASmallFirstEpochWithTheCompressThreadIdle) {
  EXPECT_TRUE(sched::publish_inline(true, sched::kMaxInlineBlocks, 0));
  EXPECT_FALSE(sched::publish_inline(false, 1, 0));
  EXPECT_FALSE(sched::publish_inline(true, sched::kMaxInlineBlocks + 1, 0));
  EXPECT_FALSE(sched::publish_inline(true, 1, 1));
}

TEST(StrokeScheduler, TurnsGoRoundRobinInIdOrder) {
  const std::vector<std::uint64_t> ready{3, 5, 9};
  EXPECT_EQ(sched::next_turn(ready, 0), 3u);
  EXPECT_EQ(sched::next_turn(ready, 3), 5u);
  EXPECT_EQ(sched::next_turn(ready, 5), 9u);
  EXPECT_EQ(sched::next_turn(ready, 9), 3u);  // wraps
  EXPECT_EQ(sched::next_turn(ready, 4), 5u);  // the last turn's stroke has finished
  EXPECT_EQ(sched::next_turn(ready, 100), 3u);
  EXPECT_EQ(sched::next_turn(std::vector<std::uint64_t>{7}, 7), 7u);  // alone: its turn again
  EXPECT_FALSE(sched::next_turn({}, 1));
}

// A turn holds what fits turn_seconds of the stroke's measured cost, between 1 and the
// configured samples, and only while others wait.
TEST(StrokeScheduler, TurnsOfAHeavyStrokeShrinkWhileOthersWait) {
  EXPECT_EQ(sched::turn_samples(64, 0.004, 0.0, true), 64u);      // cost not known yet
  EXPECT_EQ(sched::turn_samples(64, 0.004, 0.025, false), 64u);   // alone with input
  EXPECT_EQ(sched::turn_samples(64, 0.0, 0.025, true), 64u);      // sizing off
  EXPECT_EQ(sched::turn_samples(64, 0.004, 0.025, true), 1u);     // 25 ms a sample: one
  EXPECT_EQ(sched::turn_samples(64, 0.004, 0.001, true), 4u);
  EXPECT_EQ(sched::turn_samples(64, 0.004, 0.00001, true), 64u);  // cheap: all it may
  EXPECT_EQ(sched::turn_samples(3, 0.004, 0.0005, true), 3u);
}

// Strokes whose end has come go first, at most kMaxFinishingRun (2) turns in a row: streams
// still get every third turn.
TEST(StrokeScheduler, FinishingStrokesGoFirstAtMostTwiceInARow) {
  const std::vector<std::uint64_t> ready{3, 5, 9, 12};
  const std::vector<std::uint64_t> finishing{9};
  EXPECT_EQ(sched::next_turn(ready, finishing, 3, 0), 9u);   // ahead of 5
  EXPECT_EQ(sched::next_turn(ready, finishing, 9, 1), 9u);   // again, where the caller let it
  EXPECT_EQ(sched::next_turn(ready, finishing, 9, 2), 12u);  // then round robin
  EXPECT_EQ(sched::next_turn(ready, finishing, 12, 0), 9u);
  const std::vector<std::uint64_t> two{5, 12};
  EXPECT_EQ(sched::next_turn(ready, two, 5, 0), 12u);  // round robin among the finishing
  EXPECT_EQ(sched::next_turn(ready, two, 12, 1), 5u);
  EXPECT_EQ(sched::next_turn(ready, two, 5, 2), 9u);   // the run is over: a stream's turn
  EXPECT_EQ(sched::next_turn(ready, {}, 5, 0), 9u);    // none finishing: plain round robin
  EXPECT_EQ(sched::next_turn(ready, {}, 5, 2), 9u);
  EXPECT_FALSE(sched::next_turn({}, {}, 1, 0));
}

TEST(StrokeScheduler, CellBudgetRefillsAtTheRateAndHoldsAnArtistInDebt) {
  const auto t0 = sched::Clock::now();
  sched::CellBudget b{1000, t0};
  EXPECT_TRUE(sched::may_take_turn(b));
  b.tokens -= 3000;  // a turn made 3000 cells
  EXPECT_FALSE(sched::may_take_turn(b));
  EXPECT_EQ(sched::until_turn(b, 1000), std::chrono::seconds(2));
  sched::refill(b, 1000, t0 + std::chrono::seconds(1));
  EXPECT_DOUBLE_EQ(b.tokens, -1000);
  EXPECT_FALSE(sched::may_take_turn(b));
  sched::refill(b, 1000, t0 + std::chrono::seconds(2));
  EXPECT_TRUE(sched::may_take_turn(b));
  sched::refill(b, 1000, t0 + std::chrono::seconds(60));
  EXPECT_DOUBLE_EQ(b.tokens, 1000);  // never more than one second's worth
  sched::refill(b, 1000, t0);        // a clock read out of order adds nothing
  EXPECT_DOUBLE_EQ(b.tokens, 1000);
}

TEST(StrokeScheduler, ChangesWaitWhileAnAckWaitsUpToTheirBound) {
  constexpr std::size_t kMax = sched::kMaxChangesDeferred;
  EXPECT_EQ(sched::changes_to_hand_over(false, 5, false), 5u);  // no ack waits: all, now
  EXPECT_EQ(sched::changes_to_hand_over(false, 0, false), 0u);
  EXPECT_EQ(sched::changes_to_hand_over(true, 1, false), 0u);  // an ack waits: later
  EXPECT_EQ(sched::changes_to_hand_over(true, kMax - 1, false), 0u);
  // Bounded: the oldest over the bound go, not all of them at once.
  EXPECT_EQ(sched::changes_to_hand_over(true, kMax, false), 1u);
  EXPECT_EQ(sched::changes_to_hand_over(true, kMax + 3, false), 4u);
  EXPECT_EQ(sched::changes_to_hand_over(true, 7, true), 7u);  // stopping: all, now
}

}  // namespace
}  // namespace deepcanvas::test
