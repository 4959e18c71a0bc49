// ResumablePaint: a painting sent over connections that may break (resumable_paint.hpp).
#include "resumable_paint.hpp"

#include <algorithm>
#include <cstdio>
#include <random>
#include <thread>

#include "deepcanvas/base/progress.hpp"

namespace deepcanvas::client_app {

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// How one connection ended.
enum class Ended { done, lost };

class Run {
 public:
  Run(const client_core::ClientOptions& options, const std::vector<protocol::Stroke>& strokes,
      const ResumableOptions& run)
      : options_(options), strokes_(strokes), run_(run), acks_(strokes.size()) {}

  Result<PaintOutcome> go(std::unique_ptr<client_core::Client> client) {
    base::Progress progress(run_.progress_label, static_cast<double>(strokes_.size()), "strokes",
                            !run_.quiet);
    progress_ = &progress;
    for (;;) {
      auto ended = paint_on(*client);
      collect_acks(*client);
      if (!ended) return std::move(ended).error();
      if (*ended == Ended::done) break;
      client.reset();
      auto again = reconnect();
      if (!again) return std::move(again).error();
      client = std::move(*again);
      ++outcome_.reconnects;
    }
    progress.finish();
    client->close();
    outcome_.last_ack = *acks_.back();
    return outcome_;
  }

 private:
  std::uint64_t handle(std::size_t i) const { return i + 1; }

  // One connection: resends what has no ack, sends the rest, waits for every ack.
  Result<Ended> paint_on(client_core::Client& c) {
    const auto rate = std::max<std::uint32_t>(1, c.welcome().limits.max_strokes_per_second);
    // Stay a little under the server's rate limit.
    interval_ = std::chrono::microseconds(1'000'000 / rate + 1'000'000 / rate / 10);
    window_ = c.welcome().limits.stroke_receipts;
    next_send_ = Clock::now();
    const std::size_t sent_before = next_;
    for (std::size_t i = oldest_unacked(); i < sent_before; ++i) {
      if (acks_[i]) continue;
      if (!send_whole(c, i)) return Ended::lost;
      ++outcome_.resent;
    }
    while (next_ < strokes_.size()) {
      auto room = wait_for_room(c);
      if (!room) return std::move(room).error();
      if (!*room) return Ended::lost;
      const std::size_t i = next_++;
      const bool sent = run_.recorded_pace ? stream_recorded(c, i) : send_whole(c, i);
      if (auto e = check_errors(c); !e) return std::move(e).error();
      if (!sent) return Ended::lost;
      progress_->update(static_cast<double>(next_));
    }
    return wait_for_all(c);
  }

  // Paced like a first send; false when the connection is gone.
  bool send_whole(client_core::Client& c, std::size_t i) {
    pace();
    return c.send_text(protocol::encode_message(protocol::StrokeMessage{handle(i), strokes_[i]}))
        .ok();
  }

  void pace() {
    std::this_thread::sleep_until(next_send_);
    next_send_ = std::max(next_send_ + interval_, Clock::now());
  }

  // A stroke's samples in chunks of about one controller frame group (~50 ms of recorded
  // time), after the recorded pause since the previous stroke (capped at 2 s).
  bool stream_recorded(client_core::Client& c, std::size_t i) {
    const auto& samples = strokes_[i].samples;
    if (i > 0) {
      const std::int64_t gap =
          std::int64_t(samples.front().t_ms) - strokes_[i - 1].samples.back().t_ms;
      std::this_thread::sleep_for(milliseconds(std::clamp<std::int64_t>(gap, 0, 2000)));
    }
    pace();
    const std::uint64_t h = handle(i);
    const auto send = [&](const protocol::Message& m) {
      return c.send_text(protocol::encode_message(m)).ok();
    };
    if (!send(protocol::StrokeBegin{h, strokes_[i].brush, {samples.front()}})) return false;
    const auto start = Clock::now();
    const std::uint32_t t0 = samples.front().t_ms;
    std::size_t k = 1;
    while (k < samples.size()) {
      const std::uint32_t chunk_end = samples[k].t_ms + 50;
      std::vector<protocol::StrokeSample> chunk;
      while (k < samples.size() && samples[k].t_ms <= chunk_end) chunk.push_back(samples[k++]);
      if (chunk.empty()) chunk.push_back(samples[k++]);  // timestamps going backwards
      std::this_thread::sleep_until(
          start + milliseconds(std::max<std::int64_t>(0, std::int64_t(chunk.back().t_ms) - t0)));
      if (!send(protocol::StrokeSamples{h, std::move(chunk)})) return false;
    }
    return send(protocol::StrokeEnd{h});
  }

  std::size_t oldest_unacked() const {
    std::size_t i = 0;
    while (i < next_ && acks_[i]) ++i;
    return i;
  }

  void collect_acks(client_core::Client& c) {
    for (std::size_t i = oldest_unacked(); i < next_; ++i) {
      if (acks_[i]) continue;
      if (auto a = c.wait_for_ack(handle(i), milliseconds(0))) acks_[i] = *a;
    }
  }

  // The server remembers `window_` strokes per client id: keep the strokes sent since the
  // oldest unacknowledged one below that, so a resend is always recognised. false: lost.
  Result<bool> wait_for_room(client_core::Client& c) {
    for (;;) {
      collect_acks(c);
      if (window_ == 0 || next_ - oldest_unacked() < window_) return true;
      (void)c.wait_for_ack(handle(oldest_unacked()), milliseconds(100));
      if (auto e = check_errors(c); !e) return std::move(e).error();
      if (!c.is_open()) return false;
    }
  }

  // An error about a stroke ends the run; a fatal error closes the connection (a reconnect).
  Result<void> check_errors(client_core::Client& c) {
    while (auto err = c.wait_for_error(milliseconds(0))) {
      if (err->fatal) continue;
      return make_error(err->code, "the server refused a stroke: " + err->message);
    }
    return {};
  }

  Result<Ended> wait_for_all(client_core::Client& c) {
    const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                             std::chrono::duration<double>(run_.ack_timeout_s));
    for (;;) {
      collect_acks(c);
      const std::size_t oldest = oldest_unacked();
      if (oldest == strokes_.size()) return Ended::done;
      (void)c.wait_for_ack(handle(oldest), milliseconds(100));
      if (auto e = check_errors(c); !e) return std::move(e).error();
      if (!c.is_open()) return Ended::lost;
      if (Clock::now() >= deadline)
        return make_error(Errc::io_error, "no ack for stroke handle " +
                                              std::to_string(handle(oldest)) + " after " +
                                              std::to_string(run_.ack_timeout_s) + " s");
    }
  }

  // Connects again: 0.2 s, doubling to 5 s between attempts, for at most reconnect_s.
  Result<std::unique_ptr<client_core::Client>> reconnect() {
    std::size_t unacked = 0;
    for (std::size_t i = 0; i < next_; ++i) unacked += !acks_[i];
    if (run_.reconnect_s <= 0)
      return make_error(Errc::io_error, "the connection was lost with " + std::to_string(unacked) +
                                            " strokes not acknowledged (--reconnect-for 0)");
    const auto start = Clock::now();
    auto delay = milliseconds(200);
    for (int attempt = 1;; ++attempt) {
      note("connection lost with " + std::to_string(unacked) +
           " strokes not acknowledged; reconnecting in " + seconds_text(delay) + " (attempt " +
           std::to_string(attempt) + ")");
      std::this_thread::sleep_for(delay);
      auto c = client_core::Client::connect(options_);
      if (c) {
        if ((*c)->welcome().limits.stroke_receipts == 0 && unacked > 0)
          return make_error(Errc::unsupported,
                            "reconnected, but the server does not remember strokes "
                            "(welcome.limits.stroke_receipts 0): resending could paint some twice");
        note("reconnected after " + seconds_text(Clock::now() - start) + "; resending " +
             std::to_string(unacked) + " strokes");
        return std::move(*c);
      }
      if (c.error().code != Errc::io_error)  // the server refused the hello: not a break
        return make_error(c.error().code, "reconnected, but the server refused: " +
                                              c.error().message);
      if (seconds_since(start) >= run_.reconnect_s)
        return make_error(Errc::io_error, "gave up reconnecting after " +
                                              seconds_text(Clock::now() - start) + " (" +
                                              c.error().message + ")");
      delay = std::min(delay * 2, milliseconds(5000));
    }
  }

  template <class D>
  static std::string seconds_text(D d) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.1f s", std::chrono::duration<double>(d).count());
    return buf;
  }

  void note(const std::string& line) const {
    if (!run_.quiet) std::fprintf(stderr, "paint: %s\n", line.c_str());
  }

  const client_core::ClientOptions& options_;
  const std::vector<protocol::Stroke>& strokes_;
  const ResumableOptions& run_;
  std::vector<std::optional<protocol::Ack>> acks_;  // by stroke index
  std::size_t next_ = 0;                            // the first stroke never sent
  std::uint32_t window_ = 0;
  Clock::duration interval_{};
  Clock::time_point next_send_{};
  base::Progress* progress_ = nullptr;
  PaintOutcome outcome_;
};

}  // namespace

std::string random_client_id() {
  std::random_device rd;
  char buf[40];
  const auto word = [&] { return (std::uint64_t(rd()) << 32) | rd(); };
  std::snprintf(buf, sizeof buf, "%016llx%016llx", static_cast<unsigned long long>(word()),
                static_cast<unsigned long long>(word()));
  return buf;
}

Result<PaintOutcome> paint_resumable(std::unique_ptr<client_core::Client> first,
                                     const client_core::ClientOptions& options,
                                     const std::vector<protocol::Stroke>& strokes,
                                     const ResumableOptions& run) {
  if (strokes.empty()) return make_error(Errc::invalid_argument, "the painting has no strokes");
  return Run(options, strokes, run).go(std::move(first));
}

}  // namespace deepcanvas::client_app
