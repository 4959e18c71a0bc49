// The hostile mix of `deepcanvas-bench load` (bench/load_bench.cpp), run alongside the painters
// and viewers of its last phase, each part as an attacker or a careless client would behave:
//   - a painter holding a stroke open: one sample every 1.5 s (an artist resting the pen), ended
//     only when the regular painters have sent their last stroke;
//   - an attempted huge stroke: two samples from (10, 10, 10) to (-10000, 10, 10), radius 5 cm
//     (196 bytes on the wire that ask for some 10^9 cells);
//   - unauthenticated connections: raw TCP connections that upgrade to WebSocket and never send
//     a hello, each opened again a second after the server closes or refuses it, from 16
//     loopback addresses (127.0.1.1 to 127.0.1.16: an attacker's hosts, the legitimate clients
//     being on 127.0.0.1);
//   - a viewer joining while those connections are held (does it get in, how fast);
//   - stalled readers: viewers with a small receive buffer that stop reading once connected.
// What each part got is recorded (the holder's and the huge stroke's answers, the connections'
// fate, whether the stalled readers were dropped), never asserted.
//
// Threading: each part runs on its own thread from start() until finish(); finish() joins it.
// Not copyable; one thread drives each object.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "deepcanvas/client_core/client.hpp"

namespace deepcanvas::bench {

// N connections that complete the WebSocket upgrade and then say nothing, kept at N: one the
// server closes (or refuses with an HTTP status) is opened again after `reopen_delay`.
// Connection i comes from 127.0.1.(1 + i % source_addresses).
class UnauthFlood {
 public:
  UnauthFlood(std::uint16_t port, std::size_t connections, std::size_t source_addresses = 16,
              std::chrono::milliseconds reopen_delay = std::chrono::seconds(1));
  ~UnauthFlood();  // finish()
  UnauthFlood(const UnauthFlood&) = delete;
  UnauthFlood& operator=(const UnauthFlood&) = delete;
  // Closes every connection and stops; returns what happened to them.
  nlohmann::json finish();

 private:
  struct Slot;
  void run();
  void open(Slot& s);
  void on_event(Slot& s, short revents);
  void close_slot(Slot& s, bool by_server);

  std::uint16_t port_;
  std::size_t sources_;
  std::chrono::milliseconds reopen_delay_;
  std::vector<Slot> slots_;
  std::atomic<bool> stop_{false};
  // Counters, read after the thread is joined.
  std::uint64_t opened_ = 0, upgraded_ = 0, refused_http_ = 0, closed_by_server_ = 0,
                connect_failed_ = 0, upgraded_now_ = 0, upgraded_max_ = 0;
  std::thread thread_;  // last: starts once the rest is built
};

// The painter that holds one stroke open: connects at construction, then on its thread begins
// the stroke, adds a sample every `interval` until release(), then sends stroke_end; finish()
// waits for its answer.
class StrokeHolder {
 public:
  StrokeHolder(client_core::ClientOptions options,
               std::chrono::milliseconds interval = std::chrono::milliseconds(1500));
  ~StrokeHolder();
  StrokeHolder(const StrokeHolder&) = delete;
  StrokeHolder& operator=(const StrokeHolder&) = delete;
  void release();  // end the stroke at the next wake-up
  nlohmann::json finish();

 private:
  void run();
  std::unique_ptr<client_core::Client> client_;
  std::string connect_error_;
  std::chrono::milliseconds interval_;
  std::atomic<bool> released_{false};
  nlohmann::json result_;
  std::thread thread_;
};

// The huge stroke: sent once at construction from its own painter connection; finish() waits
// (at most `timeout`) for its answer.
class HugeStroke {
 public:
  explicit HugeStroke(client_core::ClientOptions options);
  ~HugeStroke();
  HugeStroke(const HugeStroke&) = delete;
  HugeStroke& operator=(const HugeStroke&) = delete;
  nlohmann::json finish(std::chrono::seconds timeout);

 private:
  std::unique_ptr<client_core::Client> client_;
  std::uint64_t handle_ = 0;
  std::chrono::steady_clock::time_point sent_;
  std::string send_error_;
};

// Viewers that stop reading as soon as their hello is answered.
class StalledReaders {
 public:
  StalledReaders(client_core::ClientOptions options, std::size_t n);
  // How many are still connected (the server may drop a reader that never reads), then closes
  // them.
  nlohmann::json finish();

 private:
  std::vector<std::unique_ptr<client_core::Client>> clients_;
  std::size_t failed_ = 0;
};

// A viewer that connects `delay` after construction (while the flood is on) and waits for its
// snapshot; finish() says whether it got in and how long connect -> snapshot took.
class LateViewer {
 public:
  LateViewer(client_core::ClientOptions options, std::chrono::milliseconds delay);
  ~LateViewer();
  LateViewer(const LateViewer&) = delete;
  LateViewer& operator=(const LateViewer&) = delete;
  nlohmann::json finish();

 private:
  nlohmann::json result_;
  std::thread thread_;
};

// The huge stroke's samples (shared with the report's description).
protocol::Stroke huge_stroke();

}  // namespace deepcanvas::bench
