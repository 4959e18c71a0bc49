// See load_run.hpp. Streaming at the recorded pace follows bench/e2e_run.cpp: stroke_begin with
// the first sample, stroke_samples with the samples due at each wake-up, stroke_end right after
// the last one ("sent"); a one-sample stroke is sent whole.
#include "load_run.hpp"

#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>

#include "deepcanvas/client_core/client.hpp"
#include "load_hostile.hpp"

namespace deepcanvas::bench {

using Clock = std::chrono::steady_clock;

namespace {

constexpr auto kAnswerTimeout = std::chrono::seconds(120);

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

Clock::time_point at_ms(Clock::time_point t0, double ms) {
  return t0 + std::chrono::microseconds(static_cast<std::int64_t>(ms * 1000));
}

// One painter: a sender thread streams the slice at the recorded pace; a collector thread waits
// for each stroke's answer in order (an ack, or an error naming its handle).
class Painter {
 public:
  Painter(std::unique_ptr<client_core::Client> client, const PaintingSlice& slice)
      : client_(std::move(client)), slice_(slice), out_(slice.strokes.size()) {}
  ~Painter() { join(); }
  Painter(const Painter&) = delete;
  Painter& operator=(const Painter&) = delete;

  void start(Clock::time_point t0) {
    collector_ = std::thread([this] { collect(); });
    sender_ = std::thread([this, t0] { send_all(t0); });
  }
  bool done_sending() const {
    std::lock_guard lock(mutex_);
    return sending_done_;
  }
  void join() {
    if (sender_.joinable()) sender_.join();
    if (collector_.joinable()) collector_.join();
  }
  const std::vector<StrokeOutcome>& outcomes() const { return out_; }

 private:
  Result<std::uint64_t> send_one(std::size_t i, Clock::time_point t0) {
    const protocol::Stroke& s = slice_.strokes[i];
    const auto& due = slice_.due_ms[i];
    std::this_thread::sleep_until(at_ms(t0, due[0]));
    if (s.samples.size() < 2) {
      out_[i].end_sent = Clock::now();
      return client_->send_stroke(s);
    }
    auto h = client_->begin_stroke(s.brush, {s.samples[0]});
    if (!h) return h;
    std::size_t k = 1;
    while (k < s.samples.size()) {
      std::this_thread::sleep_until(at_ms(t0, due[k]));
      std::vector<protocol::StrokeSample> chunk{s.samples[k++]};
      const double now_ms = ms_between(t0, Clock::now()) + 1.0;
      while (k < s.samples.size() && due[k] <= now_ms) chunk.push_back(s.samples[k++]);
      if (auto r = client_->add_samples(*h, std::move(chunk)); !r) return std::move(r).error();
    }
    out_[i].end_sent = Clock::now();
    if (auto r = client_->end_stroke(*h); !r) return std::move(r).error();
    return h;
  }

  void send_all(Clock::time_point t0) {
    for (std::size_t i = 0; i < out_.size(); ++i) {
      auto h = send_one(i, t0);
      if (!h) {
        out_[i].error = "send: " + h.error().message;
        break;
      }
      out_[i].sent = true;
      std::lock_guard lock(mutex_);
      queue_.emplace_back(i, *h);
      cv_.notify_one();
    }
    std::lock_guard lock(mutex_);
    sending_done_ = true;
    cv_.notify_one();
  }

  // Errors that end a stroke without an ack (a stroke_samples error leaves it open).
  void drain_errors() {
    while (auto e = client_->wait_for_error(std::chrono::milliseconds(0))) {
      if (!e->handle || e->in_reply_to == "stroke_samples") continue;
      failed_.emplace(*e->handle, std::string(errc_name(e->code)) + ": " + e->message);
    }
  }

  void wait_answer(std::size_t i, std::uint64_t handle) {
    StrokeOutcome& o = out_[i];
    const auto deadline = o.end_sent + kAnswerTimeout;
    for (;;) {
      if (auto a = client_->wait_for_ack(handle, std::chrono::milliseconds(20))) {
        o.acked = true;
        o.ack_ms = ms_between(o.end_sent, Clock::now());
        o.epoch = a->epoch;
        return;
      }
      drain_errors();
      if (auto it = failed_.find(handle); it != failed_.end()) {
        o.error = it->second;
        return;
      }
      if (Clock::now() > deadline) {
        o.error = "no answer within 120 s";
        return;
      }
      if (!client_->is_open()) {
        o.error = "connection closed";
        return;
      }
    }
  }

  void collect() {
    for (;;) {
      std::pair<std::size_t, std::uint64_t> next;
      {
        std::unique_lock lock(mutex_);
        cv_.wait(lock, [&] { return !queue_.empty() || sending_done_; });
        if (queue_.empty()) return;
        next = queue_.front();
        queue_.pop_front();
      }
      wait_answer(next.first, next.second);
    }
  }

  std::unique_ptr<client_core::Client> client_;
  const PaintingSlice& slice_;
  std::vector<StrokeOutcome> out_;
  std::map<std::uint64_t, std::string> failed_;  // collector thread only
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<std::pair<std::size_t, std::uint64_t>> queue_;
  bool sending_done_ = false;
  std::thread sender_, collector_;
};

// A viewer and the time each epoch was committed to its replica (its epoch listener).
struct Viewer {
  std::mutex mutex;
  std::vector<std::pair<std::uint64_t, Clock::time_point>> commits;  // ascending epochs
  // Last: destroyed first, so its I/O thread (which runs the listener) ends before the rest.
  std::unique_ptr<client_core::Client> client;

  // When the replica first held `epoch` or later; nullopt if never.
  std::optional<Clock::time_point> committed(std::uint64_t epoch) {
    std::lock_guard lock(mutex);
    auto it = std::lower_bound(commits.begin(), commits.end(), epoch,
                               [](const auto& c, std::uint64_t e) { return c.first < e; });
    if (it == commits.end()) return std::nullopt;
    return it->second;
  }
};

client_core::ClientOptions options(std::uint16_t port, protocol::Role role, const char* name) {
  client_core::ClientOptions o;
  o.url = "ws://127.0.0.1:" + std::to_string(port) + "/";
  o.canvas = "load";
  o.role = role;
  o.client_name = name;
  o.connect_timeout = std::chrono::seconds(30);
  if (role == protocol::Role::painter) {
    // Painters only paint, as `deepcanvas-client paint` does: the viewers carry the stream.
    o.keep_replica = false;
    o.block_frames = false;
  }
  return o;
}

// Runs `f` on a thread of its own at CPU priority `nice` (that thread's only; the threads it
// makes, such as a client's I/O thread, inherit it) and returns what it returns.
template <class F>
auto with_nice(int nice, F&& f) -> decltype(f()) {
  std::optional<decltype(f())> out;
  std::thread t([&] {
    if (nice != 0) (void)setpriority(PRIO_PROCESS, static_cast<id_t>(::gettid()), nice);
    out.emplace(f());
  });
  t.join();
  return std::move(*out);
}

Result<std::vector<std::unique_ptr<Viewer>>> connect_viewers(std::uint16_t port, std::size_t n) {
  std::vector<std::unique_ptr<Viewer>> viewers;
  for (std::size_t i = 0; i < n; ++i) {
    auto v = std::make_unique<Viewer>();
    auto c = client_core::Client::connect(options(port, protocol::Role::viewer, "load-viewer"));
    if (!c) return make_error(c.error().code, "viewer " + std::to_string(i) + ": " +
                                                  c.error().message);
    v->client = std::move(*c);
    Viewer* raw = v.get();
    v->client->set_epoch_listener([raw](const client_core::EpochCommit& e) {
      if (e.partial) return;  // a part of the snapshot: its epoch is not held yet
      std::lock_guard lock(raw->mutex);
      if (raw->commits.empty() || raw->commits.back().first < e.epoch)
        raw->commits.emplace_back(e.epoch, Clock::now());
    });
    viewers.push_back(std::move(v));
  }
  for (auto& v : viewers)
    if (auto e = v->client->wait_for_epoch(0, std::chrono::seconds(60)); !e)
      return std::move(e).error();
  return viewers;
}

// The hostile parts that run alongside the painters (hostile phases only). The clients that
// must connect do so before the flood starts; the late viewer then tries during it.
struct Hostile {
  std::unique_ptr<StalledReaders> stalled;
  std::unique_ptr<HugeStroke> huge;
  std::unique_ptr<StrokeHolder> holder;
  std::unique_ptr<UnauthFlood> flood;
  std::unique_ptr<LateViewer> late;

  Hostile(std::uint16_t port, const PhaseSpec& spec)
      : stalled(std::make_unique<StalledReaders>(
            options(port, protocol::Role::viewer, "load-stalled"), spec.stalled_readers)),
        huge(std::make_unique<HugeStroke>(options(port, protocol::Role::painter, "load-huge"))),
        holder(std::make_unique<StrokeHolder>(
            options(port, protocol::Role::painter, "load-holder"))),
        flood(std::make_unique<UnauthFlood>(port, spec.unauthenticated)),
        late(std::make_unique<LateViewer>(options(port, protocol::Role::viewer, "load-late"),
                                          std::chrono::seconds(1))) {}

  nlohmann::json finish() {
    nlohmann::json j;
    j["holder"] = holder->finish();
    j["huge_stroke"] = huge->finish(std::chrono::seconds(60));
    j["viewer_joining_during_flood"] = late->finish();
    j["unauthenticated"] = flood->finish();
    j["stalled_readers"] = stalled->finish();
    return j;
  }
};

// After the painters: every job done on the server, then each viewer at the last epoch with
// the server's pool hash.
void check_replicas(ServerProcess& server, std::vector<std::unique_ptr<Viewer>>& viewers,
                    PhaseResult& out) {
  auto quiet = server.quiesce(std::chrono::seconds(120));
  if (!quiet) {
    out.replica_check_error = quiet.error().message;
    out.viewers_differing = viewers.size();
    return;
  }
  out.quiet = *quiet;
  for (auto& v : viewers) {
    const bool at = v->client->wait_for_epoch(quiet->epoch, std::chrono::seconds(120)).ok();
    if (!at || v->client->pool_hash() != quiet->pool_hash) ++out.viewers_differing;
  }
}

void collect_viewer_latency(const std::vector<std::unique_ptr<Viewer>>& viewers,
                            PhaseResult& out) {
  for (const auto& strokes : out.painters)
    for (const StrokeOutcome& s : strokes) {
      if (!s.acked) continue;
      for (const auto& v : viewers)
        if (auto t = v->committed(s.epoch)) out.viewer_epoch_ms.push_back(ms_between(s.end_sent, *t));
    }
}

}  // namespace

PaintingSlice slice_painting(const std::string& name, const paintings::ApaPainting& painting,
                             double seconds, double max_gap_ms) {
  PaintingSlice out;
  out.painting = name;
  double at = 0;
  bool first = true;
  std::uint32_t prev = 0;
  for (const protocol::Stroke& s : painting.strokes) {
    if (s.samples.empty()) continue;
    std::vector<double> due;
    for (const auto& smp : s.samples) {
      if (!first && smp.t_ms >= prev) at += std::min<double>(smp.t_ms - prev, max_gap_ms);
      first = false;
      prev = smp.t_ms;
      due.push_back(at);
    }
    if (due.front() >= seconds * 1000) break;
    out.strokes.push_back(s);
    out.due_ms.push_back(std::move(due));
  }
  return out;
}

double process_cpu_seconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + static_cast<double>(t.tv_nsec) * 1e-9;
}

Result<PhaseResult> run_phase(ServerProcess& server, const PhaseSpec& spec) {
  auto port = server.start(spec.server, "load");
  if (!port) return std::move(port).error();
  const auto server_cpu0 = server.memory();
  PhaseResult out;
  out.name = spec.name;
  // The clients stand in for other machines (PhaseSpec::viewer_nice, hostile_nice); the
  // painters, whose latency is measured, keep this process's priority.
  auto viewers = with_nice(spec.viewer_nice, [&] { return connect_viewers(*port, spec.viewers); });
  if (!viewers) return std::move(viewers).error();
  std::vector<std::unique_ptr<Painter>> painters;
  for (const PaintingSlice* slice : spec.painters) {
    auto c = client_core::Client::connect(options(*port, protocol::Role::painter, "load-painter"));
    if (!c) return make_error(c.error().code, "painter: " + c.error().message);
    painters.push_back(std::make_unique<Painter>(std::move(*c), *slice));
  }
  std::unique_ptr<Hostile> hostile;
  if (spec.hostile)
    hostile = with_nice(spec.hostile_nice, [&] { return std::make_unique<Hostile>(*port, spec); });
  const auto t0 = Clock::now() + std::chrono::milliseconds(200);
  const double cpu0 = process_cpu_seconds();
  for (auto& p : painters) p->start(t0);
  // The holder keeps its stroke open until the last regular stroke has been sent.
  while (!std::all_of(painters.begin(), painters.end(),
                      [](const auto& p) { return p->done_sending(); }))
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  if (hostile) hostile->holder->release();
  for (auto& p : painters) p->join();
  if (hostile) out.hostile = hostile->finish();
  out.wall_s = std::chrono::duration<double>(Clock::now() - t0).count();
  out.clients_cpu_s = process_cpu_seconds() - cpu0;
  for (const auto& p : painters) out.painters.push_back(p->outcomes());
  check_replicas(server, *viewers, out);
  collect_viewer_latency(*viewers, out);
  out.viewers = viewers->size();
  if (auto m = server.stop(); m) {
    out.memory = *m;
    if (server_cpu0) out.memory.cpu_seconds -= server_cpu0->cpu_seconds;
  }
  for (auto& v : *viewers) v->client->set_epoch_listener({});
  return out;
}

}  // namespace deepcanvas::bench
