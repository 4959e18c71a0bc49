// Progress of long work on stderr: painting a file, replaying, catching up on join, a benchmark.
//
// On a terminal it redraws one bar line (done/total, rate, ETA) at most ten times a second; when
// stderr is a file or a pipe (CI, logs) it writes one plain line every few seconds instead, so
// logs stay readable. finish() writes the closing line. A disabled Progress (--quiet) writes
// nothing at all.
//
// Threading: one thread updates a Progress; it holds no locks and starts no threads. Output goes
// to stderr only, so stdout stays the command's result (JSON, a table) and can be piped.
#pragma once

#include <chrono>
#include <cstdio>
#include <string>

namespace deepcanvas::base {

class Progress {
 public:
  // what: a short label ("paint demo.apa"); total: the units expected, 0 when unknown;
  // unit: their name, plural ("strokes"). enabled=false: silent.
  Progress(std::string what, double total, std::string unit, bool enabled = true);
  ~Progress();  // finishes if finish() was not called
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;

  // Sets the units done so far (never decreasing what is shown) and redraws when due.
  void update(double done);
  void add(double units) { update(done_ + units); }
  void set_total(double total) { total_ = total; }
  // Closing line: units done, elapsed time, rate. A second call does nothing.
  void finish();

  // Seconds between plain lines when stderr is not a terminal (default 5).
  void set_line_interval(double seconds) { line_interval_s_ = seconds; }

  // Writes to `out` instead of stderr, drawing a bar when `terminal` (tests).
  void set_output(std::FILE* out, bool terminal) {
    out_ = out;
    terminal_ = enabled_ && terminal;
  }

  double done() const { return done_; }

 private:
  using Clock = std::chrono::steady_clock;
  void draw(bool final_line);
  double elapsed_s() const;

  std::string what_;
  std::string unit_;
  double total_ = 0;
  double done_ = 0;
  bool enabled_ = true;
  bool terminal_ = false;
  bool finished_ = false;
  bool drew_bar_ = false;
  double line_interval_s_ = 5.0;
  Clock::time_point start_;
  Clock::time_point last_draw_;
  std::FILE* out_ = stderr;
};

// "1:05", "12 s", "2:03:04": a short duration for progress lines.
std::string format_duration(double seconds);

}  // namespace deepcanvas::base
