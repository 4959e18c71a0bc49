#include "deepcanvas/base/progress.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>

namespace deepcanvas::base {

std::string format_duration(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) return "?";
  const long s = std::lround(seconds);
  char buf[32];
  if (seconds < 9.95) {
    std::snprintf(buf, sizeof buf, "%.1f s", seconds);
  } else if (s < 60) {
    std::snprintf(buf, sizeof buf, "%ld s", s);
  } else if (s < 3600) {
    std::snprintf(buf, sizeof buf, "%ld:%02ld", s / 60, s % 60);
  } else {
    std::snprintf(buf, sizeof buf, "%ld:%02ld:%02ld", s / 3600, (s / 60) % 60, s % 60);
  }
  return buf;
}

Progress::Progress(std::string what, double total, std::string unit, bool enabled)
    : what_(std::move(what)),
      unit_(std::move(unit)),
      total_(total),
      enabled_(enabled),
      terminal_(enabled && isatty(fileno(stderr)) == 1),
      start_(Clock::now()),
      last_draw_(start_) {}

Progress::~Progress() { finish(); }

double Progress::elapsed_s() const {
  return std::chrono::duration<double>(Clock::now() - start_).count();
}

void Progress::update(double done) {
  done_ = std::max(done_, done);
  if (!enabled_ || finished_) return;
  const double since = std::chrono::duration<double>(Clock::now() - last_draw_).count();
  if (since >= (terminal_ ? 0.1 : line_interval_s_)) draw(false);
}

void Progress::finish() {
  if (finished_) return;
  finished_ = true;
  if (enabled_) draw(true);
}

void Progress::draw(bool final_line) {
  last_draw_ = Clock::now();
  const double t = elapsed_s();
  const double rate = t > 0 ? done_ / t : 0;
  char counts[96];
  if (total_ > 0) {
    std::snprintf(counts, sizeof counts, "%.0f/%.0f %s", done_, total_, unit_.c_str());
  } else {
    std::snprintf(counts, sizeof counts, "%.0f %s", done_, unit_.c_str());
  }
  if (final_line) {
    std::fprintf(out_, "%s%s: %s in %s (%.1f/s)\n", drew_bar_ ? "\r\033[K" : "", what_.c_str(),
                 counts, format_duration(t).c_str(), rate);
    std::fflush(out_);
    return;
  }
  std::string eta = "?";
  if (total_ > 0 && rate > 0) eta = format_duration(std::max(0.0, total_ - done_) / rate);
  if (terminal_) {
    constexpr int kWidth = 24;
    const double frac = total_ > 0 ? std::clamp(done_ / total_, 0.0, 1.0) : 0.0;
    const int filled = static_cast<int>(frac * kWidth);
    std::string bar(static_cast<std::size_t>(filled), '#');
    bar.append(static_cast<std::size_t>(kWidth - filled), '.');
    std::fprintf(out_, "\r\033[K%s [%s] %s  %.1f/s  ETA %s", what_.c_str(),
                 total_ > 0 ? bar.c_str() : "", counts, rate, eta.c_str());
    drew_bar_ = true;
  } else if (total_ > 0) {
    std::fprintf(out_, "%s: %s (%.0f%%), %.1f/s, ETA %s\n", what_.c_str(), counts,
                 100.0 * std::clamp(done_ / total_, 0.0, 1.0), rate, eta.c_str());
  } else {
    std::fprintf(out_, "%s: %s, %.1f/s, %s elapsed\n", what_.c_str(), counts, rate,
                 format_duration(t).c_str());
  }
  std::fflush(out_);
}

}  // namespace deepcanvas::base
