// See load_run.hpp. Streaming at the recorded pace follows bench/e2e_run.cpp: stroke_begin with
// the first sample, stroke_samples with the samples due at each wake-up, stroke_end right after
// the last one ("sent"); a one-sample stroke is sent whole.
#include "load_run.hpp"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>

#include "deepcanvas/client_core/client.hpp"
#include "load_clients.hpp"

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

// Each viewer's latency per acked stroke: stroke_end sent -> the viewer's replica first held the
// ack's epoch (never: not counted).
void collect_viewer_latency(const LoadClientsReport& clients, PhaseResult& out) {
  for (const auto& strokes : out.painters)
    for (const StrokeOutcome& s : strokes) {
      if (!s.acked) continue;
      for (const auto& commits : clients.commits) {
        auto it = std::lower_bound(commits.begin(), commits.end(), s.epoch,
                                   [](const auto& c, std::uint64_t e) { return c.first < e; });
        if (it != commits.end()) out.viewer_epoch_ms.push_back(ms_between(s.end_sent, it->second));
      }
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

Result<PhaseResult> run_phase(ServerProcess& server, LoadClientsProcess& others,
                              const PhaseSpec& spec) {
  auto port = server.start(spec.server, "load");
  if (!port) return std::move(port).error();
  const auto server_cpu0 = server.memory();
  PhaseResult out;
  out.name = spec.name;
  // The viewers and the hostile mix stand in for other machines: their own process, at the
  // priorities PhaseSpec gives (load_clients.hpp). The painters, whose latency is measured,
  // keep this process's priority.
  LoadClientsSpec cs;
  cs.port = *port;
  cs.viewers = static_cast<std::uint32_t>(spec.viewers);
  cs.viewer_nice = spec.viewer_nice;
  cs.viewer_idle_class = spec.viewer_idle_class ? 1 : 0;
  cs.hostile = spec.hostile;
  cs.unauthenticated = static_cast<std::uint32_t>(spec.unauthenticated);
  cs.stalled_readers = static_cast<std::uint32_t>(spec.stalled_readers);
  cs.hostile_nice = spec.hostile_nice;
  if (auto r = others.connect(cs); !r) return std::move(r).error();
  std::vector<std::unique_ptr<Painter>> painters;
  for (const PaintingSlice* slice : spec.painters) {
    auto c = client_core::Client::connect(
        load_client_options(*port, protocol::Role::painter, "load-painter"));
    if (!c) return make_error(c.error().code, "painter: " + c.error().message);
    painters.push_back(std::make_unique<Painter>(std::move(*c), *slice));
  }
  const auto t0 = Clock::now() + std::chrono::milliseconds(200);
  const double cpu0 = process_cpu_seconds();
  const ThreadTimesByName threads0 = server.thread_times();
  for (auto& p : painters) p->start(t0);
  // The holder keeps its stroke open until the last regular stroke has been sent.
  while (!std::all_of(painters.begin(), painters.end(),
                      [](const auto& p) { return p->done_sending(); }))
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  if (spec.hostile)
    if (auto r = others.release_holder(); !r) return std::move(r).error();
  for (auto& p : painters) p->join();
  if (spec.hostile) {
    auto h = others.finish_hostile();
    if (!h) return std::move(h).error();
    out.hostile = std::move(*h);
  }
  out.wall_s = std::chrono::duration<double>(Clock::now() - t0).count();
  out.clients_cpu_s = process_cpu_seconds() - cpu0;
  out.server_threads = server.thread_times();
  for (auto& [name, t] : out.server_threads) {
    if (auto it = threads0.find(name); it != threads0.end()) {
      t.run_s -= it->second.run_s;
      t.wait_s -= it->second.wait_s;
    }
  }
  for (const auto& p : painters) out.painters.push_back(p->outcomes());
  // Every job done on the server, then each viewer at the last epoch with the server's pool
  // hash.
  auto quiet = server.quiesce(std::chrono::seconds(120));
  std::uint64_t epoch = 0, hash = 0;
  if (quiet) {
    out.quiet = *quiet;
    epoch = quiet->epoch;
    hash = quiet->pool_hash;
  }
  auto report = others.finish(epoch, hash, std::chrono::seconds(120));
  if (!report) return std::move(report).error();
  out.viewers = report->viewers;
  out.clients_cpu_s += report->cpu_s;
  if (!quiet) {
    out.replica_check_error = quiet.error().message;
    out.viewers_differing = out.viewers;
  } else {
    out.replica_check_error = report->replica_check_error;
    out.viewers_differing = report->viewers_differing;
  }
  collect_viewer_latency(*report, out);
  if (auto m = server.stop(); m) {
    out.memory = *m;
    if (server_cpu0) out.memory.cpu_seconds -= server_cpu0->cpu_seconds;
  }
  return out;
}

}  // namespace deepcanvas::bench
