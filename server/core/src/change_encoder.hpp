// Encodes finished operations' changes for the undo history (encode_cell_diff) on a thread of
// its own. Encoding a large stroke's change takes 2 to 18 ms; on the stroke thread that time
// came between other artists' turns, and their acks waited for it (deepcanvas-bench load).
// Private to server_core.
//
// Contract: one owner thread (the stroke thread) calls every member; the encoding thread is
// internal. Changes come back in the order they were pushed, so the undo history receives them
// in the same order as when they were encoded in place. A change whose encoding fails (out of
// memory) comes back with `failed` set and no bytes. The destructor finishes what was pushed
// and joins the thread.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <thread>
#include <vector>

#include "deepcanvas/server_core/cell_diff.hpp"

namespace deepcanvas::server_core {

class ChangeEncoder {
 public:
  struct Change {
    enum class Kind { stroke, too_large, undo, redo } kind = Kind::stroke;
    std::uint64_t artist = 0;
    std::uint64_t stroke = 0;
    CellDiff diff;                    // to encode (released once encoded)
    std::vector<std::uint8_t> bytes;  // encode_cell_diff(diff), once it came back
    bool failed = false;              // the encoding failed: no bytes
  };

  ChangeEncoder();
  ~ChangeEncoder();
  ChangeEncoder(const ChangeEncoder&) = delete;
  ChangeEncoder& operator=(const ChangeEncoder&) = delete;

  void push(Change c);
  // The changes encoded so far, in push order (none past the first still being encoded).
  std::vector<Change> take_done();
  // Every change pushed, encoded, in push order.
  std::vector<Change> wait_all();
  // The memory of the diffs pushed and not yet encoded (sizeof(CellChange) a change).
  std::uint64_t bytes_in_flight() const;
  bool empty() const;  // nothing pushed that was not taken back

  static std::uint64_t bytes_of(const CellDiff& d) { return d.size() * sizeof(CellChange); }

 private:
  void run();

  mutable std::mutex mutex_;
  std::condition_variable work_cv_;  // the thread waits for a change or the end
  std::condition_variable done_cv_;  // wait_all waits for the thread
  std::deque<Change> todo_;          // pushed, not yet encoded (the front may be in progress)
  std::deque<Change> done_;          // encoded, in push order
  bool encoding_ = false;            // the thread holds a change taken from todo_
  std::uint64_t bytes_ = 0;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace deepcanvas::server_core
