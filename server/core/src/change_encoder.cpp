#include "change_encoder.hpp"

#include <exception>

#include "deepcanvas/base/thread_name.hpp"

namespace deepcanvas::server_core {

ChangeEncoder::ChangeEncoder()
    : thread_([this] {
        base::set_thread_name("dc-undo-encode");
        run();
      }) {}

ChangeEncoder::~ChangeEncoder() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  work_cv_.notify_one();
  thread_.join();
}

void ChangeEncoder::push(Change c) {
  {
    std::lock_guard lock(mutex_);
    bytes_ += bytes_of(c.diff);
    todo_.push_back(std::move(c));
  }
  work_cv_.notify_one();
}

std::vector<ChangeEncoder::Change> ChangeEncoder::take_done() {
  std::vector<Change> out;
  std::lock_guard lock(mutex_);
  out.reserve(done_.size());
  for (auto& c : done_) out.push_back(std::move(c));
  done_.clear();
  return out;
}

std::vector<ChangeEncoder::Change> ChangeEncoder::wait_all() {
  {
    std::unique_lock lock(mutex_);
    done_cv_.wait(lock, [&] { return todo_.empty() && !encoding_; });
  }
  return take_done();
}

std::uint64_t ChangeEncoder::bytes_in_flight() const {
  std::lock_guard lock(mutex_);
  return bytes_;
}

bool ChangeEncoder::empty() const {
  std::lock_guard lock(mutex_);
  return todo_.empty() && !encoding_ && done_.empty();
}

void ChangeEncoder::run() {
  std::unique_lock lock(mutex_);
  for (;;) {
    // The changes pushed before the end are encoded too: the destructor's owner has stopped
    // taking them, so this only drains.
    work_cv_.wait(lock, [&] { return !todo_.empty() || stop_; });
    if (todo_.empty()) return;
    Change c = std::move(todo_.front());
    todo_.pop_front();
    encoding_ = true;
    lock.unlock();
    if (c.kind != Change::Kind::too_large) {
      try {
        c.bytes = encode_cell_diff(c.diff);
      } catch (const std::exception&) {  // out of memory: the change cannot be kept
        c.bytes.clear();
        c.failed = true;
      }
    }
    const std::uint64_t b = bytes_of(c.diff);
    c.diff = CellDiff{};
    lock.lock();
    bytes_ -= b;
    encoding_ = false;
    done_.push_back(std::move(c));
    done_cv_.notify_all();
  }
}

}  // namespace deepcanvas::server_core
