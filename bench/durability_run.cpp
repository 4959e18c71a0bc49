// See durability_run.hpp.
#include "durability_run.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <condition_variable>
#include <cstdlib>
#include <deque>
#include <filesystem>
#include <functional>
#include <map>

#include "deepcanvas/client_core/client.hpp"

namespace deepcanvas::bench::durability {

namespace {

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

Clock::time_point at_ms(Clock::time_point t0, double ms) {
  return t0 + std::chrono::microseconds(static_cast<std::int64_t>(ms * 1000));
}

}  // namespace

// ------------------------------------------------------------------------------ painter

struct DurablePainter::Impl {
  Spec spec;
  std::unique_ptr<client_core::Client> client;
  std::mutex mutex;
  std::condition_variable cv;
  std::deque<std::pair<std::uint64_t, Clock::time_point>> waiting;  // handle, end sent
  bool sending_done = false;
  std::thread collector;
  std::map<std::uint64_t, std::string> failed;  // collector only
};

Result<std::unique_ptr<DurablePainter>> DurablePainter::connect(const Spec& spec) {
  client_core::ClientOptions o;
  o.url = "ws://127.0.0.1:" + std::to_string(spec.port) + "/";
  o.canvas = spec.canvas;
  o.role = protocol::Role::painter;
  o.client_name = spec.client_name;
  o.connect_timeout = std::chrono::seconds(30);
  o.keep_replica = false;
  o.block_frames = false;
  auto c = client_core::Client::connect(o);
  if (!c) return std::move(c).error();
  std::unique_ptr<DurablePainter> p(new DurablePainter());
  p->impl_ = std::make_unique<Impl>();
  p->impl_->spec = spec;
  p->impl_->client = std::move(*c);
  return p;
}

DurablePainter::~DurablePainter() {
  stop();
  join();
}

void DurablePainter::join() {
  if (thread_.joinable()) thread_.join();
  if (impl_ && impl_->collector.joinable()) impl_->collector.join();
}

void DurablePainter::start(Clock::time_point t0) {
  Impl& m = *impl_;
  m.collector = std::thread([this, &m, t0] {
    const auto note_error = [&](const std::string& e) {
      ++result_.failed;
      if (result_.first_error.empty()) result_.first_error = e;
    };
    Clock::time_point last = t0;
    for (;;) {
      std::pair<std::uint64_t, Clock::time_point> next;
      {
        std::unique_lock lock(m.mutex);
        m.cv.wait(lock, [&] { return !m.waiting.empty() || m.sending_done; });
        if (m.waiting.empty()) break;
        next = m.waiting.front();
      }
      const auto deadline = next.second + std::chrono::seconds(120);
      for (;;) {
        if (auto a = m.client->wait_for_ack(next.first, std::chrono::milliseconds(20))) {
          last = Clock::now();
          result_.ack_ms.push_back(ms_between(next.second, last));
          result_.acked_ids.push_back(a->stroke_id);
          break;
        }
        while (auto e = m.client->wait_for_error(std::chrono::milliseconds(0)))
          if (e->handle && e->in_reply_to != "stroke_samples")
            m.failed.emplace(*e->handle, std::string(errc_name(e->code)) + ": " + e->message);
        if (auto it = m.failed.find(next.first); it != m.failed.end()) {
          note_error(it->second);
          break;
        }
        if (!m.client->is_open() || Clock::now() > deadline) {
          note_error(m.client->is_open() ? "no answer within 120 s" : "connection closed");
          break;
        }
      }
      std::lock_guard lock(m.mutex);
      m.waiting.pop_front();
      m.cv.notify_all();
    }
    result_.wall_s = std::chrono::duration<double>(last - t0).count();
  });
  thread_ = std::thread([this, t0] { run(t0); });
}

void DurablePainter::run(Clock::time_point t0) {
  Impl& m = *impl_;
  const PaintingSlice& slice = *m.spec.slice;
  const auto queue = [&](std::uint64_t handle, Clock::time_point sent) {
    std::lock_guard lock(m.mutex);
    m.waiting.emplace_back(handle, sent);
    ++result_.sent;
    m.cv.notify_all();
  };
  std::this_thread::sleep_until(t0);
  if (m.spec.paced) {
    for (std::size_t i = 0; i < slice.strokes.size() && !stop_; ++i) {
      const protocol::Stroke& s = slice.strokes[i];
      const auto& due = slice.due_ms[i];
      std::this_thread::sleep_until(at_ms(t0, due[0]));
      if (s.samples.size() < 2) {
        const auto sent = Clock::now();
        auto h = m.client->send_stroke(s);
        if (!h) break;
        queue(*h, sent);
        continue;
      }
      auto h = m.client->begin_stroke(s.brush, {s.samples[0]});
      if (!h) break;
      std::size_t k = 1;
      bool ok = true;
      while (k < s.samples.size() && ok) {
        std::this_thread::sleep_until(at_ms(t0, due[k]));
        std::vector<protocol::StrokeSample> chunk{s.samples[k++]};
        const double now_ms = ms_between(t0, Clock::now()) + 1.0;
        while (k < s.samples.size() && due[k] <= now_ms) chunk.push_back(s.samples[k++]);
        ok = m.client->add_samples(*h, std::move(chunk)).ok();
      }
      const auto sent = Clock::now();
      if (!ok || !m.client->end_stroke(*h)) break;
      queue(*h, sent);
    }
  } else {
    const auto until = t0 + m.spec.fast_for;
    for (std::size_t i = 0; !stop_ && !slice.strokes.empty(); ++i) {
      if (m.spec.fast_for.count() > 0 && Clock::now() >= until) break;
      {
        std::unique_lock lock(m.mutex);
        m.cv.wait(lock, [&] { return m.waiting.size() < m.spec.window || stop_; });
      }
      if (stop_ || !m.client->is_open()) break;
      const auto sent = Clock::now();
      auto h = m.client->send_stroke(slice.strokes[i % slice.strokes.size()]);
      if (!h) break;
      queue(*h, sent);
    }
  }
  std::lock_guard lock(m.mutex);
  m.sending_done = true;
  m.cv.notify_all();
}

// ------------------------------------------------------------------------------ child server

Result<std::string> ChildServer::find_binary() {
  namespace fs = std::filesystem;
  if (const char* e = std::getenv("DEEPCANVAS_SERVER"); e && *e) {
    if (!fs::exists(e))
      return make_error(Errc::not_found, std::string("DEEPCANVAS_SERVER=") + e + " does not exist");
    return std::string(e);
  }
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    const fs::path p = self.parent_path().parent_path() / "server" / "deepcanvas-server";
    if (fs::exists(p)) return p.string();
  }
  return make_error(Errc::not_found,
                    "no deepcanvas-server: set DEEPCANVAS_SERVER to the binary (or build it next "
                    "to this one, build/server/deepcanvas-server)");
}

Result<std::unique_ptr<ChildServer>> ChildServer::start(const std::string& binary,
                                                        std::vector<std::string> args,
                                                        std::chrono::seconds timeout,
                                                        const std::string& listen) {
  args.insert(args.begin(), {binary, "serve", "--listen", listen});
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  int fds[2];
  if (pipe2(fds, O_CLOEXEC) != 0) return make_error(Errc::io_error, "pipe failed");
  std::unique_ptr<ChildServer> s(new ChildServer());
  s->pid_ = fork();
  if (s->pid_ < 0) {
    close(fds[0]);
    close(fds[1]);
    return make_error(Errc::io_error, "fork failed");
  }
  if (s->pid_ == 0) {  // async-signal-safe calls only until exec
    dup2(fds[1], 2);
    execv(argv[0], argv.data());
    _exit(127);
  }
  close(fds[1]);
  ChildServer* raw = s.get();
  s->reader_ = std::thread([raw, fd = fds[0]] {
    char buf[4096];
    for (;;) {
      const ssize_t n = read(fd, buf, sizeof buf);
      if (n <= 0) break;
      std::lock_guard lock(raw->mutex_);
      raw->log_.append(buf, static_cast<std::size_t>(n));
    }
    close(fd);
  });
  const auto deadline = Clock::now() + timeout;
  while (Clock::now() < deadline) {
    const std::string text = s->log();
    const auto at = text.find("event=listening");
    if (at != std::string::npos) {
      const auto p = text.find("port=", at);
      if (p != std::string::npos) {
        s->port_ = static_cast<std::uint16_t>(std::atoi(text.c_str() + p + 5));
        return s;
      }
    }
    int status = 0;
    if (waitpid(s->pid_, &status, WNOHANG) == s->pid_) {
      s->reaped_ = true;
      return make_error(Errc::io_error, "deepcanvas-server exited at start: " + s->log());
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return make_error(Errc::io_error, "deepcanvas-server did not listen in time: " + s->log());
}

ChildServer::~ChildServer() {
  if (pid_ > 0 && !reaped_) kill9();
  if (reader_.joinable()) reader_.join();
}

void ChildServer::kill9() {
  if (pid_ <= 0 || reaped_) return;
  ::kill(pid_, SIGKILL);
  waitpid(pid_, nullptr, 0);
  reaped_ = true;
}

int ChildServer::terminate(std::chrono::seconds timeout) {
  if (pid_ <= 0 || reaped_) return -1;
  ::kill(pid_, SIGTERM);
  const auto deadline = Clock::now() + timeout;
  while (Clock::now() < deadline) {
    int status = 0;
    if (waitpid(pid_, &status, WNOHANG) == pid_) {
      reaped_ = true;
      return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return -1;
}

std::string ChildServer::log() const {
  std::lock_guard lock(mutex_);
  return log_;
}

// ------------------------------------------------------------------------------ canvases

protocol::Stroke synthetic_stroke(std::mt19937_64& rng, int samples, double radius_m,
                                  double extent_m) {
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  std::uniform_real_distribution<float> c(0.05f, 1.0f);
  protocol::Stroke s;
  s.brush.colour[0] = c(rng);
  s.brush.colour[1] = c(rng);
  s.brush.colour[2] = c(rng);
  s.brush.hardness = 0.8f;
  // A random walk with steps of about the radius inside the cube (the canvas centre is 0).
  double p[3] = {u(rng) * extent_m, u(rng) * extent_m, u(rng) * extent_m};
  for (int i = 0; i < samples; ++i) {
    protocol::StrokeSample smp;
    for (double& v : p) {
      v += u(rng) * radius_m * 2;
      v = std::clamp(v, -extent_m / 2, extent_m / 2);
    }
    smp.x = p[0];
    smp.y = p[1];
    smp.z = p[2];
    smp.radius = static_cast<float>(radius_m);
    smp.t_ms = static_cast<std::uint32_t>(i * 10);
    s.samples.push_back(smp);
  }
  return s;
}

namespace {

// Submits strokes made by `make`, at most `window` unanswered, until `more` says stop.
template <class Make, class More>
Result<std::uint64_t> submit_loop(server_core::CanvasService& svc, Make make, More more,
                                  std::size_t window, std::vector<double>* ack_ms) {
  std::mutex mutex;
  std::condition_variable cv;
  std::size_t in_flight = 0;
  std::uint64_t acked = 0, i = 0;
  std::string error;
  for (; more(i, acked); ++i) {
    {
      std::unique_lock lock(mutex);
      cv.wait(lock, [&] { return in_flight < window; });
      if (!error.empty()) break;
      ++in_flight;
    }
    auto v = protocol::ValidatedStroke::make(make(), svc.stroke_rules());
    if (!v) {
      std::lock_guard lock(mutex);
      --in_flight;
      error = "synthetic stroke: " + v.error().message;
      break;
    }
    const auto t = server_core::Clock::now();
    auto r = svc.submit_stroke(
        std::move(*v), t,
        [&, t](Result<server_core::StrokeDone> d) {
          std::lock_guard lock(mutex);
          if (d) {
            ++acked;
            if (ack_ms) ack_ms->push_back(ms_between(t, server_core::Clock::now()));
          } else if (error.empty()) {
            error = d.error().message;
          }
          --in_flight;
          cv.notify_all();
        },
        i % 4);
    if (!r) {
      std::lock_guard lock(mutex);
      --in_flight;
      if (r.error().code != Errc::limit_exceeded) {
        error = r.error().message;
        break;
      }
    }
  }
  std::unique_lock lock(mutex);
  if (!cv.wait_for(lock, std::chrono::seconds(300), [&] { return in_flight == 0; }))
    return make_error(Errc::io_error, "strokes unanswered after 300 s");
  if (!error.empty()) return make_error(Errc::io_error, "stroke failed: " + error);
  return acked;
}

}  // namespace

Result<std::uint64_t> grow_canvas(server_core::CanvasService& svc, std::mt19937_64& rng,
                                  std::uint64_t target_cells, double radius_m, double max_s) {
  const auto t0 = Clock::now();
  std::uint64_t total = 0;
  for (;;) {
    const auto live = static_cast<std::uint64_t>(svc.metrics().live_cells.value());
    if (live >= target_cells) return total;
    if (std::chrono::duration<double>(Clock::now() - t0).count() > max_s)
      return make_error(Errc::limit_exceeded,
                        "canvas reached only " + std::to_string(live) + " of " +
                            std::to_string(target_cells) + " cells in " +
                            std::to_string(static_cast<int>(max_s)) + " s");
    // Batches of up to 64 strokes (each adds some 30,000 cells), fewer near the target so as
    // not to overshoot it much; then a quiesce and a look at the canvas again.
    const std::uint64_t batch = std::min<std::uint64_t>(64, (target_cells - live) / 50000 + 1);
    auto n = submit_loop(
        svc, [&] { return synthetic_stroke(rng, 64, radius_m, 80.0); },
        [batch](std::uint64_t i, std::uint64_t) { return i < batch; }, 16, nullptr);
    if (!n) return std::move(n).error();
    total += *n;
    if (auto q = svc.quiesce(); !q) return std::move(q).error();
  }
}

Result<std::uint64_t> paint_strokes(server_core::CanvasService& svc, std::mt19937_64& rng,
                                    std::uint64_t n, double radius_m, std::size_t window,
                                    std::vector<double>* ack_ms, int samples) {
  return submit_loop(
      svc, [&] { return synthetic_stroke(rng, samples, radius_m, 40.0); },
      [n](std::uint64_t i, std::uint64_t) { return i < n; }, window, ack_ms);
}

// ------------------------------------------------------------------------------ database

Result<EventStats> event_stats(const std::string& db_path, bool want_ids) {
  sqlite3* db = nullptr;
  if (sqlite3_open_v2(db_path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) != SQLITE_OK) {
    std::string m = db ? sqlite3_errmsg(db) : "out of memory";
    sqlite3_close(db);
    return make_error(Errc::io_error, db_path + ": " + m);
  }
  sqlite3_busy_timeout(db, 5000);
  EventStats out;
  std::string error;
  const auto query = [&](const char* sql, const std::function<void(sqlite3_stmt*)>& row) {
    sqlite3_stmt* st = nullptr;
    if (sqlite3_prepare_v2(db, sql, -1, &st, nullptr) != SQLITE_OK) {
      error = sqlite3_errmsg(db);
      return;
    }
    int rc = 0;
    while ((rc = sqlite3_step(st)) == SQLITE_ROW) row(st);
    if (rc != SQLITE_DONE && error.empty()) error = sqlite3_errmsg(db);
    sqlite3_finalize(st);
  };
  query("SELECT count(*), coalesce(sum(length(record)), 0) FROM events", [&](sqlite3_stmt* st) {
    out.events = static_cast<std::uint64_t>(sqlite3_column_int64(st, 0));
    out.record_bytes = static_cast<std::uint64_t>(sqlite3_column_int64(st, 1));
  });
  query("SELECT count(DISTINCT stroke) FROM events WHERE kind = 3", [&](sqlite3_stmt* st) {
    out.ended_strokes = static_cast<std::uint64_t>(sqlite3_column_int64(st, 0));
  });
  if (want_ids)
    query("SELECT stroke FROM events WHERE kind = 3", [&](sqlite3_stmt* st) {
      out.ended_ids.insert(static_cast<std::uint64_t>(sqlite3_column_int64(st, 0)));
    });
  sqlite3_close(db);
  if (!error.empty()) return make_error(Errc::io_error, db_path + ": " + error);
  return out;
}

std::uint64_t file_bytes(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0 ? static_cast<std::uint64_t>(st.st_size) : 0;
}

}  // namespace deepcanvas::bench::durability
