// The clients of `deepcanvas-bench load` that stand in for other machines: the 32 viewers that
// keep replicas and, in the hostile phase, the hostile mix (load_hostile.hpp). They run in a
// child process of the benchmark, away from the painters whose latency is measured.
//
// Why a process of their own, not threads beside the painters: the viewers run in the
// SCHED_IDLE class (or at nice 19) so that on a machine of few cores they do not take the
// server's CPU, and threads of one process share its allocator's locks (glibc malloc arenas,
// one per two threads at most on two cores).
// A viewer thread preempted while it held an arena left a painter's thread waiting on it for up
// to 200 ms, and those waits, not the server, were the tail of the painters' ack latency
// (traced stroke by stroke: stroke_end sent -> written by the client took up to 198 ms). Other
// machines share no locks with the painters; a process of their own shares none either.
//
// Use: fork_idle() while the benchmark is still one thread (as ServerProcess::fork_idle), one
// per phase; then connect(), release_holder() and finish_hostile() (hostile phases), and
// finish(), after which the child exits. Not thread-safe: one thread drives a process.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <utility>
#include <vector>

#include "child_pipe.hpp"
#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/protocol/messages.hpp"

namespace deepcanvas::bench {

// The options every client of the load benchmark connects with (canvas "load" on loopback).
// Painters only paint, as `deepcanvas-client paint` does: no replica, no block frames.
client_core::ClientOptions load_client_options(std::uint16_t port, protocol::Role role,
                                               const char* name);

// This process's CPU time so far, all its threads.
double process_cpu_seconds();

// What the child connects (plain values: they cross the pipe as bytes).
struct LoadClientsSpec {
  std::uint16_t port = 0;
  std::uint32_t viewers = 32;
  std::int32_t viewer_nice = 19;  // each viewer's threads
  std::int32_t viewer_idle_class = 0;  // nonzero: the viewers' threads in SCHED_IDLE instead
  bool hostile = false;
  std::uint32_t unauthenticated = 1000;  // hostile: connections that never say hello
  std::uint32_t stalled_readers = 4;     // hostile: viewers that never read
  std::int32_t hostile_nice = 10;        // the hostile mix's threads
};

struct LoadClientsReport {
  std::size_t viewers = 0, viewers_differing = 0;
  std::string replica_check_error;  // non-empty: a viewer did not reach the epoch in time
  // Per viewer, ascending: (epoch, steady_clock time its replica first held it). The child's
  // steady_clock is the parent's (CLOCK_MONOTONIC), so the times compare with the painters'.
  std::vector<std::vector<std::pair<std::uint64_t, std::chrono::steady_clock::time_point>>>
      commits;
  double cpu_s = 0;  // the child's CPU time from connect() to the end of the painting
};

class LoadClientsProcess {
 public:
  // Forks a child that waits for connect(). io_error when fork or pipe fail.
  static Result<std::unique_ptr<LoadClientsProcess>> fork_idle();
  ~LoadClientsProcess();  // ends the child if it still runs (SIGKILL after a grace period)
  LoadClientsProcess(const LoadClientsProcess&) = delete;
  LoadClientsProcess& operator=(const LoadClientsProcess&) = delete;

  // Connects the viewers (each at its snapshot of epoch 0 when this returns) and, if
  // spec.hostile, starts the hostile mix. Errors: a viewer cannot connect, the child is gone.
  Result<void> connect(const LoadClientsSpec& spec);
  // Hostile phases: the holder ends its stroke (at its next sample).
  Result<void> release_holder();
  // Hostile phases, once the painters are done: waits for each hostile part's end and returns
  // what each got (load_hostile.hpp).
  Result<nlohmann::json> finish_hostile();
  // Ends the phase: each viewer waits for `epoch` (the quiesced server's) and compares its
  // replica's pool hash with `pool_hash`; the child then disconnects and exits.
  Result<LoadClientsReport> finish(std::uint64_t epoch, std::uint64_t pool_hash,
                                   std::chrono::seconds timeout);

 private:
  LoadClientsProcess() = default;
  Result<std::string> exchange(const void* command, std::size_t size,
                               std::chrono::seconds timeout);
  ForkedChild child_;
};

}  // namespace deepcanvas::bench
