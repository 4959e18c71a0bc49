// FanoutGate (fanout_gate.hpp): never more slots held than it has, waiters served in order,
// slots of gone waiters passed on without nesting a call per waiter, and the bound kept under
// threads (run under TSan in CI).
#include "deepcanvas/server_net/fanout_gate.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <thread>
#include <vector>

namespace {

using deepcanvas::server_net::FanoutGate;

TEST(FanoutGate, HoldsAtMostItsSlotsAndServesWaitersInOrder) {
  auto gate = std::make_shared<FanoutGate>(2);
  auto a = gate->try_acquire();
  auto b = gate->try_acquire();
  ASSERT_TRUE(a && b);
  EXPECT_FALSE(gate->try_acquire());
  std::vector<int> order;
  std::vector<FanoutGate::SlotRef> kept;
  for (int i = 0; i < 3; ++i)
    gate->acquire([&, i](FanoutGate::SlotRef s) {
      order.push_back(i);
      kept.push_back(std::move(s));
    });
  EXPECT_EQ(gate->waiting(), 3u);
  a.reset();
  EXPECT_EQ(order, (std::vector<int>{0}));
  EXPECT_FALSE(gate->try_acquire()) << "a slot given back goes to a waiter";
  b.reset();
  EXPECT_EQ(order, (std::vector<int>{0, 1}));
  {
    // Both back: the third waiter gets one (into `kept` again), the other is free.
    auto back = std::move(kept);
    kept.clear();
    back.clear();
  }
  EXPECT_EQ(order, (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(gate->free_slots(), 1u);
  EXPECT_EQ(gate->waiting(), 0u);
  kept.clear();
  EXPECT_EQ(gate->free_slots(), 2u);
}

TEST(FanoutGate, AcquireRunsAtOnceWhenASlotIsFree) {
  auto gate = std::make_shared<FanoutGate>(1);
  bool ran = false;
  gate->acquire([&](FanoutGate::SlotRef) {
    ran = true;
    EXPECT_EQ(gate->free_slots(), 0u);
  });
  EXPECT_TRUE(ran);
  EXPECT_EQ(gate->free_slots(), 1u) << "the slot dropped by the resume is back";
}

TEST(FanoutGate, ZeroSlotsMeansOne) {
  auto gate = std::make_shared<FanoutGate>(0);
  EXPECT_EQ(gate->slots(), 1u);
  EXPECT_TRUE(gate->try_acquire());
}

// 100,000 waiters that drop their slot at once (their sessions are gone) in front of one that
// keeps it: the slot reaches the last one, on this thread, without a call nested per waiter (a
// stack of 100,000 frames would overflow under the sanitizers).
TEST(FanoutGate, GoneWaitersPassTheSlotOnWithoutRecursion) {
  auto gate = std::make_shared<FanoutGate>(1);
  auto held = gate->try_acquire();
  constexpr int kGone = 100000;
  int dropped = 0;
  for (int i = 0; i < kGone; ++i) gate->acquire([&](FanoutGate::SlotRef) { ++dropped; });
  FanoutGate::SlotRef last;
  gate->acquire([&](FanoutGate::SlotRef s) { last = std::move(s); });
  held.reset();
  EXPECT_EQ(dropped, kGone);
  EXPECT_TRUE(last);
  EXPECT_EQ(gate->free_slots(), 0u);
  last.reset();
  EXPECT_EQ(gate->free_slots(), 1u);
}

// A slot may outlive whoever made the gate (a handler dropped by a stopping io_context).
TEST(FanoutGate, ASlotKeepsItsGate) {
  auto gate = std::make_shared<FanoutGate>(1);
  auto slot = gate->try_acquire();
  std::weak_ptr<FanoutGate> weak = gate;
  gate.reset();
  EXPECT_FALSE(weak.expired());
  slot.reset();
  EXPECT_TRUE(weak.expired());
}

// Threads taking and giving back slots, each resume holding its slot for a moment: never more
// than `slots` held at once, and every request served.
TEST(FanoutGate, TheBoundHoldsUnderThreads) {
  constexpr std::size_t kSlots = 2;
  auto gate = std::make_shared<FanoutGate>(kSlots);
  std::atomic<int> held{0}, most{0}, served{0};
  constexpr int kThreads = 4, kEach = 2000;
  auto work = [&](FanoutGate::SlotRef) {
    const int now = held.fetch_add(1) + 1;
    int m = most.load();
    while (now > m && !most.compare_exchange_weak(m, now)) {
    }
    std::this_thread::yield();
    held.fetch_sub(1);
    served.fetch_add(1);
  };
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t)
    threads.emplace_back([&] {
      for (int i = 0; i < kEach; ++i) gate->acquire(work);
    });
  for (auto& t : threads) t.join();
  EXPECT_EQ(served.load(), kThreads * kEach);
  EXPECT_LE(most.load(), static_cast<int>(kSlots));
  EXPECT_EQ(gate->free_slots(), kSlots);
  EXPECT_EQ(gate->waiting(), 0u);
}

}  // namespace
