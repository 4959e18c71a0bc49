// A streaming server (server_net::Server, in-process code) run in a child process of the
// benchmark, so that its memory is measured alone: the child's peak resident set (VmHWM) holds
// the server and nothing of the clients, paintings and bookkeeping of the parent, and the
// clients' CPU work is not in the way of reading it. Why a fork and not the deepcanvas-server
// binary: the parent asks the child's canvas for its pool hash after a quiesce (the replicas
// are compared with the server's own), which the wire protocol does not carry.
//
// Use: fork_idle() while the benchmark is still one thread (before anything starts a thread or
// loads paintings: the child starts as a copy of the parent), once per server the run needs;
// each child waits until start() and serves until stop() or until the parent goes away (its
// command pipe closes). Not thread-safe: one thread drives a ServerProcess.
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <string>

#include "child_pipe.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::bench {

// What the child's server is configured with (plain values: they cross the pipe as bytes).
struct ServerProcessSettings {
  std::uint64_t max_cells = 1u << 24;  // the canvas's capacity (OctreeConfig::max_cells)
  std::uint32_t network_threads = 2;
  std::uint32_t max_sessions = 1024;
  double turn_seconds = -1;  // CanvasServiceConfig::turn_seconds; negative: its default
};

struct ServerQuiet {
  std::uint64_t epoch = 0, pool_hash = 0, live_cells = 0;
  // The canvas's stroke_end received -> all its paint in the tree, p99 over every stroke so far
  // (its deepcanvas_end_to_painted_seconds histogram; within the bucket's 19%).
  double end_to_painted_ms_p99 = 0;
  // A stroke's answer given by the canvas -> its session's network thread running it, p99 over
  // every stroke so far (deepcanvas_answer_wait_seconds; within the bucket's 19%).
  double answer_wait_ms_p99 = 0;
};

struct ServerMemory {
  std::uint64_t peak_rss_bytes = 0;  // VmHWM: the child's peak resident set so far
  std::uint64_t rss_bytes = 0;       // VmRSS now
  double cpu_seconds = 0;            // the child's CPU time so far, all threads
};

// A thread name's share of the child's scheduling (summed over the threads of that name, from
// /proc/PID/task/*/schedstat): time on a CPU and time runnable but waiting for one. The wait is
// what a loaded machine adds to the server's latencies.
struct ThreadTimes {
  double run_s = 0, wait_s = 0;
};
using ThreadTimesByName = std::map<std::string, ThreadTimes>;

class ServerProcess {
 public:
  // Forks a child that waits for start(). io_error when fork or pipe fail.
  static Result<std::unique_ptr<ServerProcess>> fork_idle();
  ~ServerProcess();  // stops the child if it still runs (SIGKILL after a grace period) and reaps it
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;

  // Starts the server on 127.0.0.1 with one canvas named `canvas`; returns the port.
  Result<std::uint16_t> start(const ServerProcessSettings& settings, const std::string& canvas);
  // CanvasService::quiesce in the child: every job done, the last epoch published.
  Result<ServerQuiet> quiesce(std::chrono::seconds timeout);
  Result<ServerMemory> memory();
  // The child's threads so far, by name (empty where /proc has no schedstat). Threads that have
  // ended are not counted: read it while the server runs.
  ThreadTimesByName thread_times() const;
  // Stops the server and ends the child; returns its memory just before.
  Result<ServerMemory> stop();

 private:
  ServerProcess() = default;
  Result<void> send(const void* command, std::size_t size);
  Result<void> receive(void* reply, std::size_t size, std::chrono::seconds timeout);
  ForkedChild child_;
};

}  // namespace deepcanvas::bench
