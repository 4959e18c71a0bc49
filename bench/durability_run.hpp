// Helpers of `deepcanvas-bench durability` (bench/durability_bench.cpp says what it measures):
// painters over the wire (recorded pace or as fast as acks come back), the real
// `deepcanvas-server serve` as a child process (for kill -9), synthetic strokes that grow a
// canvas quickly, and read-only queries of a canvas database.
//
// Threading: each DurablePainter runs its own threads; the other helpers are called from the
// suite's one thread.
#pragma once

#include <sys/types.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"
#include "deepcanvas/server_core/canvas_service.hpp"
#include "load_run.hpp"

namespace deepcanvas::bench::durability {

using Clock = std::chrono::steady_clock;

// What one painter got.
struct PainterResult {
  std::vector<double> ack_ms;              // stroke_end sent -> ack read, per acked stroke
  std::vector<std::uint64_t> acked_ids;    // the canvas stroke ids the acks named
  std::size_t sent = 0, failed = 0;        // failed: sent and answered with an error
  std::string first_error;
  double wall_s = 0;                       // first send -> last answer
};

// One painter on ws://127.0.0.1:PORT/, canvas `canvas`.
//   paced: streams `slice` at its recorded pace (stroke_begin, stroke_samples as samples fall
//          due, stroke_end), as bench/load_run.cpp does; ends after the slice.
//   fast:  sends the slice's strokes whole, over and over, with at most `window` unanswered,
//          until stop() or `fast_for` has passed or the connection closes.
class DurablePainter {
 public:
  struct Spec {
    std::uint16_t port = 0;
    std::string canvas;
    const PaintingSlice* slice = nullptr;
    bool paced = true;
    std::size_t window = 8;
    std::chrono::milliseconds fast_for{0};  // 0: until stop()
    std::string client_name = "durability-painter";
  };
  static Result<std::unique_ptr<DurablePainter>> connect(const Spec& spec);
  ~DurablePainter();
  DurablePainter(const DurablePainter&) = delete;
  DurablePainter& operator=(const DurablePainter&) = delete;

  void start(Clock::time_point t0);
  void stop() { stop_ = true; }
  void join();
  // After join().
  const PainterResult& result() const { return result_; }

 private:
  struct Impl;
  DurablePainter() = default;
  void run(Clock::time_point t0);
  std::unique_ptr<Impl> impl_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
  PainterResult result_;
};

// The real `deepcanvas-server serve` as a child process, its stderr read by a thread.
class ChildServer {
 public:
  // The binary: $DEEPCANVAS_SERVER, else ../server/deepcanvas-server next to this program's
  // folder (the build tree's layout). not_found when neither exists.
  static Result<std::string> find_binary();
  // Starts `binary serve --listen LISTEN ARGS...` and waits for its listening line. The child
  // is in the calling thread's network namespace.
  static Result<std::unique_ptr<ChildServer>> start(const std::string& binary,
                                                   std::vector<std::string> args,
                                                   std::chrono::seconds timeout,
                                                   const std::string& listen = "127.0.0.1:0");
  ~ChildServer();  // SIGKILL if still running, reaped
  ChildServer(const ChildServer&) = delete;
  ChildServer& operator=(const ChildServer&) = delete;
  std::uint16_t port() const { return port_; }
  pid_t pid() const { return pid_; }
  void kill9();                                      // SIGKILL and reap
  int terminate(std::chrono::seconds timeout);       // SIGTERM; exit status (-1: timed out)
  std::string log() const;

 private:
  ChildServer() = default;
  pid_t pid_ = -1;
  bool reaped_ = false;
  std::uint16_t port_ = 0;
  std::thread reader_;
  mutable std::mutex mutex_;
  std::string log_;
};

// Synthetic strokes for growing a canvas: `samples` samples on a random walk inside a cube of
// `extent_m` around the canvas centre, radius `radius_m`, random colour.
protocol::Stroke synthetic_stroke(std::mt19937_64& rng, int samples, double radius_m,
                                  double extent_m);

// Submits synthetic strokes from 4 artists (at most 16 unanswered) until the canvas has
// at least `target_cells` live cells (CanvasMetrics::live_cells after a quiesce), or `max_s`
// passed. Returns the strokes acked.
Result<std::uint64_t> grow_canvas(server_core::CanvasService& svc, std::mt19937_64& rng,
                                  std::uint64_t target_cells, double radius_m, double max_s);

// Submits `n` synthetic strokes of `samples` samples (artists round robin, at most `window`
// unanswered) and waits for their acks; per-stroke submit -> ack ms appended to `ack_ms` when
// given.
Result<std::uint64_t> paint_strokes(server_core::CanvasService& svc, std::mt19937_64& rng,
                                    std::uint64_t n, double radius_m, std::size_t window,
                                    std::vector<double>* ack_ms = nullptr, int samples = 24);

// Read-only queries of a canvas database (DIR/NAME.canvas).
struct EventStats {
  std::uint64_t events = 0;
  std::uint64_t record_bytes = 0;  // sum(length(record)) over the events
  std::uint64_t ended_strokes = 0;
  std::set<std::uint64_t> ended_ids;  // stroke ids with an end event (kind 3)
};
Result<EventStats> event_stats(const std::string& db_path, bool want_ids);

// The size of a file (0 when missing).
std::uint64_t file_bytes(const std::string& path);

}  // namespace deepcanvas::bench::durability
