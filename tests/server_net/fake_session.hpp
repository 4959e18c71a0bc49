// The transport and strand of a SessionHandler, faked for tests without sockets: FakeOutput
// records every text, batch and close the handler asks for; FakeStrand holds what the canvas's
// threads post back (acks, pick-ups, new epochs) until the test runs it, and drops it once the
// session is over, as the real transport's Poster does.
#pragma once

#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include <gtest/gtest.h>

#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/server_net/session_handler.hpp"

namespace deepcanvas::test {

// What the handler asked the transport for, in order.
struct Sent {
  enum class Kind { text, batch, close, presence } kind = Kind::text;
  // The control message, the batch's epoch_end, the close's last message, or the presence update.
  std::string text;
  std::size_t frames = 0;
  server_net::CloseCode code = server_net::CloseCode::policy_error;
  std::string reason;
};

class FakeOutput : public server_net::SessionOutput {
 public:
  bool send_text(std::string text) override {
    if (full) return false;
    sent.push_back({Sent::Kind::text, std::move(text), 0, server_net::CloseCode::policy_error, {}});
    return true;
  }
  void send_batch(server_net::OutgoingBatch batch) override {
    sent.push_back({Sent::Kind::batch,
                    std::move(batch.epoch_end),
                    batch.frames.size(),
                    server_net::CloseCode::policy_error,
                    {}});
  }
  void close(server_net::CloseCode code, std::string_view reason, std::string last_text) override {
    sent.push_back({Sent::Kind::close, std::move(last_text), 0, code, std::string(reason)});
  }
  server_net::TransportCounters counters() const override { return {3, 300, 2}; }
  void send_presence(server_net::PresenceText text) override {
    sent.push_back({Sent::Kind::presence, *text, 0, server_net::CloseCode::policy_error, {}});
  }
  // The timers: the test fires them (fire_timer, fire_batch_timer) when it wants the delay to
  // have passed.
  void run_after(server_net::SessionTimer which, std::chrono::milliseconds delay,
                 std::function<void()> fn) override {
    if (which == server_net::SessionTimer::batch) {
      batch_timer_delay = delay;
      batch_timer = std::move(fn);
      return;
    }
    timer_delay = delay;
    timer = std::move(fn);
  }
  static bool fire(std::function<void()>& t) {
    if (!t) return false;
    auto fn = std::move(t);
    t = nullptr;
    fn();
    return true;
  }
  bool fire_timer() { return fire(timer); }
  bool fire_batch_timer() { return fire(batch_timer); }

  bool full = false;  // the control queue is at its bound
  std::vector<Sent> sent;
  std::function<void()> timer;  // the pending presence run_after, if any
  std::chrono::milliseconds timer_delay{0};
  std::function<void()> batch_timer;  // the pending batch run_after, if any
  std::chrono::milliseconds batch_timer_delay{0};
};

// The session's strand: closures posted from any thread wait here; the test thread runs them.
class FakeStrand {
 public:
  server_net::Poster poster() {
    return [q = queue_](std::function<void()> fn) {
      {
        std::lock_guard lock(q->mutex);
        if (q->dropped) return;  // the session is gone
        q->fns.push_back(std::move(fn));
      }
      q->cv.notify_all();
    };
  }
  // Runs posted closures until `done` holds; false after `timeout` without it.
  bool run_until(const std::function<bool()>& done,
                 std::chrono::milliseconds timeout = std::chrono::seconds(30)) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (!done()) {
      std::function<void()> fn;
      {
        std::unique_lock lock(queue_->mutex);
        if (!queue_->cv.wait_until(lock, deadline, [&] { return !queue_->fns.empty(); }))
          return done();
        fn = std::move(queue_->fns.front());
        queue_->fns.pop_front();
      }
      fn();
    }
    return true;
  }
  // Runs what is queued now, at most `n` closures; returns how many ran.
  std::size_t run_queued(std::size_t n) {
    std::size_t ran = 0;
    while (ran < n) {
      std::function<void()> fn;
      {
        std::lock_guard lock(queue_->mutex);
        if (queue_->fns.empty()) break;
        fn = std::move(queue_->fns.front());
        queue_->fns.pop_front();
      }
      fn();
      ++ran;
    }
    return ran;
  }
  // The session has ended: what is queued and what is posted later is dropped, never run.
  void drop() {
    std::deque<std::function<void()>> gone;
    {
      std::lock_guard lock(queue_->mutex);
      queue_->dropped = true;
      gone.swap(queue_->fns);
    }
  }

 private:
  struct Queue {
    std::mutex mutex;
    std::condition_variable cv;
    std::deque<std::function<void()>> fns;
    bool dropped = false;
  };
  std::shared_ptr<Queue> queue_ = std::make_shared<Queue>();
};

// One connection of a socket-free test: its transport, strand and handler, and the messages
// the handler sent, decoded.
struct FakeConnection {
  FakeOutput out;
  FakeStrand strand;
  std::unique_ptr<server_net::SessionHandler> handler;
  std::uint64_t id = 0;

  void text(const std::string& m) { handler->on_message(true, m); }
  // Runs what the canvas and other sessions posted to this strand.
  void run() { strand.run_queued(1000); }
  // The connection breaks: the handler ends, what is posted to it later is dropped.
  void cut() {
    handler->on_closed({});
    strand.drop();
    handler.reset();
  }
  // The messages sent from the `first`-th on (a close without a last message has none).
  std::vector<protocol::Message> messages(std::size_t first = 0) const {
    std::vector<protocol::Message> v;
    for (std::size_t i = first; i < out.sent.size(); ++i) {
      if (out.sent[i].text.empty()) continue;
      auto m = protocol::decode_message(out.sent[i].text);
      EXPECT_TRUE(m.ok()) << out.sent[i].text;
      if (m) v.push_back(std::move(*m));
    }
    return v;
  }
  template <class T>
  std::vector<T> sent_of() const {
    std::vector<T> v;
    for (auto& m : messages())
      if (auto* x = std::get_if<T>(&m)) v.push_back(*x);
    return v;
  }
  std::vector<protocol::Ack> acks() const { return sent_of<protocol::Ack>(); }
  std::vector<protocol::ErrorMessage> errors() const { return sent_of<protocol::ErrorMessage>(); }
  std::vector<protocol::PresenceUpdate> presence() const {
    return sent_of<protocol::PresenceUpdate>();
  }
};

}  // namespace deepcanvas::test
