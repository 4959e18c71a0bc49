// One phase of `deepcanvas-bench load` (bench/load_bench.cpp says what the suite measures):
// a server in its own process, viewers that keep replicas and optionally the hostile mix in
// another (load_clients.hpp), and painters in this one replaying slices of real paintings at
// the recorded pace.
//
// Threading: run_phase() is called from one thread; it starts and joins the painters' threads.
#pragma once

#include <chrono>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "load_clients.hpp"
#include "server_process.hpp"

namespace deepcanvas::bench {

// A painter's part: the strokes of a painting begun within its first `seconds` of recorded
// time, each sample due at its recorded time after the phase starts (steps between samples, in
// and between strokes, capped at max_gap_ms: an artist's long pauses are not replayed).
struct PaintingSlice {
  std::string painting;
  std::vector<protocol::Stroke> strokes;
  std::vector<std::vector<double>> due_ms;  // per stroke, per sample
};

PaintingSlice slice_painting(const std::string& name, const paintings::ApaPainting& painting,
                             double seconds, double max_gap_ms);

// What happened to one stroke of a painter.
struct StrokeOutcome {
  bool sent = false, acked = false;
  double ack_ms = 0;  // stroke_end (a whole stroke: the stroke) sent -> its ack read
  std::uint64_t epoch = 0;
  std::chrono::steady_clock::time_point end_sent{};
  std::string error;  // why there is no ack
};

struct PhaseSpec {
  std::string name;
  std::vector<const PaintingSlice*> painters;
  std::size_t viewers = 32;
  bool hostile = false;
  std::size_t unauthenticated = 1000;  // hostile: connections that never say hello
  std::size_t stalled_readers = 4;     // hostile: viewers that never read
  // CPU priorities (nice) of the clients that stand in for other machines: the 32 viewers'
  // threads (each decodes every block frame) at the lowest, so that together they do not
  // outweigh the server's threads on a machine of few cores, and the hostile mix's. The
  // painters keep the benchmark's priority: theirs is the latency measured.
  int viewer_nice = 19;
  bool viewer_idle_class = false;
  int hostile_nice = 10;
  ServerProcessSettings server;
};

struct PhaseResult {
  std::string name;
  std::vector<std::vector<StrokeOutcome>> painters;  // PhaseSpec::painters' order
  std::vector<double> viewer_epoch_ms;  // per (acked stroke, viewer): stroke_end sent -> the
                                        // viewer committed the ack's epoch
  std::size_t viewers = 0, viewers_differing = 0;
  std::string replica_check_error;  // non-empty: the replicas could not be compared
  ServerQuiet quiet;
  ServerMemory memory;
  double wall_s = 0;
  double clients_cpu_s = 0;  // the painters (this process) and the clients' process, over wall_s
  ThreadTimesByName server_threads;  // the server's threads over the paced part of the phase
  nlohmann::json hostile;  // what each hostile part got (null without)
};

// Runs the phase on `server` (forked idle; started here and stopped at the end), with the
// viewers and the hostile mix in `others` (forked idle; it exits at the end). Errors: the
// server does not start, a painter or viewer cannot connect, the clients' process is gone;
// what goes wrong later is in the result.
Result<PhaseResult> run_phase(ServerProcess& server, LoadClientsProcess& others,
                              const PhaseSpec& spec);

}  // namespace deepcanvas::bench
