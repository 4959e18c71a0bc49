// FanoutGate: how many sessions may take an epoch batch at once on the network threads.
//
// Why: a batch take (server_core::Subscription::take, and the writes it starts) is the largest
// piece of work a network thread does for a viewer, and the network threads run every session's
// handlers first come, first served. Without a bound, every publish queues a take for each
// subscriber, and a painter's ack or stroke read queued behind them waits for all of them:
// with 8 painters and 32 viewers on two cores, `deepcanvas-bench load` measured acks waiting
// 10 ms at p99 (deepcanvas_answer_wait_seconds) against 3 ms with no viewers. Through the gate at
// most `slots` takes are queued or running at a time (the server gives one less than its
// network threads, at least one), so a network thread stays free for replies and reads; the
// other takes wait in the gate, first come, first served, and go to the network threads one
// by one as slots come back. Takes are not made less work, only put behind the replies.
//
// Threading: every member is safe from any thread. A waiter's resume function runs on the
// thread that gave the slot back (inside release), so it should only post work elsewhere.
//
// Lifetime: make it with std::make_shared; every Slot holds a reference to its gate, so slots
// may outlive whoever made the gate (handlers dropped by a stopping io_context).
#pragma once

#include <cstddef>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>

namespace deepcanvas::server_net {

class FanoutGate : public std::enable_shared_from_this<FanoutGate> {
 public:
  // A held slot; destroying it gives the slot back (to the first waiter, if any).
  class Slot {
   public:
    explicit Slot(std::shared_ptr<FanoutGate> gate) : gate_(std::move(gate)) {}
    ~Slot();
    Slot(const Slot&) = delete;
    Slot& operator=(const Slot&) = delete;

   private:
    std::shared_ptr<FanoutGate> gate_;
  };
  using SlotRef = std::shared_ptr<Slot>;
  // Called with the slot once it is this waiter's. Dropping the SlotRef gives it back, so a
  // waiter that is gone (a closed session) loses nothing.
  using Resume = std::function<void(SlotRef)>;

  explicit FanoutGate(std::size_t slots);

  // A slot now, or null when all are held.
  SlotRef try_acquire();
  // A slot now (resume runs at once, on this thread) or, when all are held, once one comes back,
  // after the waiters queued before this one.
  void acquire(Resume resume);

  std::size_t slots() const noexcept { return slots_; }
  std::size_t waiting() const;
  std::size_t free_slots() const;

 private:
  void release();

  const std::size_t slots_;
  mutable std::mutex mutex_;
  std::size_t free_;
  std::deque<Resume> waiters_;
};

}  // namespace deepcanvas::server_net
