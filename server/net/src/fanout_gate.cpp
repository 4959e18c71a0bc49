#include "deepcanvas/server_net/fanout_gate.hpp"

#include <algorithm>
#include <utility>

namespace deepcanvas::server_net {
namespace {

// A waiter whose resume drops its slot at once (its session is gone) gives the slot back from
// inside release(): counted here and handed on by the outer release() of this thread, so a long
// run of gone waiters does not nest a call per waiter.
thread_local const FanoutGate* g_releasing = nullptr;
thread_local std::size_t g_deferred = 0;

}  // namespace

FanoutGate::Slot::~Slot() {
  if (gate_) gate_->release();
}

FanoutGate::FanoutGate(std::size_t slots) : slots_(std::max<std::size_t>(1, slots)), free_(slots_) {}

FanoutGate::SlotRef FanoutGate::try_acquire() {
  {
    std::lock_guard lock(mutex_);
    // Waiters go first: a slot given back while they wait is theirs.
    if (free_ == 0 || !waiters_.empty()) return nullptr;
    --free_;
  }
  return std::make_shared<Slot>(shared_from_this());
}

void FanoutGate::acquire(Resume resume) {
  {
    std::lock_guard lock(mutex_);
    if (free_ == 0 || !waiters_.empty()) {
      waiters_.push_back(std::move(resume));
      return;
    }
    --free_;
  }
  resume(std::make_shared<Slot>(shared_from_this()));
}

void FanoutGate::release() {
  if (g_releasing == this) {
    ++g_deferred;
    return;
  }
  const FanoutGate* outer = std::exchange(g_releasing, this);
  const std::size_t outer_deferred = std::exchange(g_deferred, 0);
  std::size_t to_release = 1;
  while (to_release > 0) {
    --to_release;
    Resume next;
    {
      std::lock_guard lock(mutex_);
      if (waiters_.empty()) {
        ++free_;
        continue;
      }
      next = std::move(waiters_.front());
      waiters_.pop_front();
    }
    next(std::make_shared<Slot>(shared_from_this()));
    to_release += std::exchange(g_deferred, 0);
  }
  g_releasing = outer;
  g_deferred = outer_deferred;
}

std::size_t FanoutGate::waiting() const {
  std::lock_guard lock(mutex_);
  return waiters_.size();
}

std::size_t FanoutGate::free_slots() const {
  std::lock_guard lock(mutex_);
  return free_;
}

}  // namespace deepcanvas::server_net
