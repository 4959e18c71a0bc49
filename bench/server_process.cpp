// See server_process.hpp. The pipe protocol: the parent writes one Command, the child answers
// one Reply, both fixed-size structs of plain values (the two processes are the same binary).
#include "server_process.hpp"

#include <signal.h>
#include <sys/prctl.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <thread>

#include "child_pipe.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_net/server.hpp"

namespace deepcanvas::bench {
namespace {

struct Command {
  char op = 0;  // 's' start, 'q' quiesce, 'm' memory, 'x' stop and exit
  ServerProcessSettings settings;
  char canvas[72] = {};
  std::uint32_t timeout_s = 0;
};

struct Reply {
  std::int32_t ok = 0;
  std::uint64_t a = 0, b = 0, c = 0, d = 0, e = 0;
  char message[480] = {};
};

// "VmHWM:   123 kB" -> bytes; 0 if absent.
std::uint64_t status_bytes(const char* key) {
  std::ifstream in("/proc/self/status");
  const std::size_t klen = std::strlen(key);
  for (std::string line; std::getline(in, line);)
    if (line.compare(0, klen, key) == 0) return std::strtoull(line.c_str() + klen, nullptr, 10) * 1024;
  return 0;
}

void set_message(Reply& r, const std::string& m) {
  std::snprintf(r.message, sizeof r.message, "%s", m.c_str());
}

Reply start_server(std::unique_ptr<server_net::Server>& server, server_core::CanvasService*& canvas,
                   const Command& c) {
  Reply r;
  server_net::ServerConfig cfg;
  cfg.port = 0;
  cfg.network_threads = static_cast<int>(c.settings.network_threads);
  cfg.max_sessions = c.settings.max_sessions;
  server_core::CanvasServiceConfig cc;
  cc.name = c.canvas;
  cc.octree.max_cells = c.settings.max_cells;
  if (c.settings.turn_seconds >= 0) cc.turn_seconds = c.settings.turn_seconds;
  cfg.canvases.push_back(cc);
  auto s = server_net::Server::create(cfg);
  if (!s) {
    set_message(r, s.error().message);
    return r;
  }
  if (auto st = (*s)->start(); !st) {
    set_message(r, st.error().message);
    return r;
  }
  server = std::move(*s);
  canvas = server->canvas(c.canvas);
  r.ok = 1;
  r.a = server->port();
  return r;
}

Reply quiesce(const server_net::Server* server, server_core::CanvasService* canvas,
              const Command& c) {
  Reply r;
  if (!canvas) {
    set_message(r, "no server started");
    return r;
  }
  auto q = canvas->quiesce(std::chrono::seconds(c.timeout_s));
  if (!q) {
    set_message(r, q.error().message);
    return r;
  }
  r.ok = 1;
  r.a = q->epoch;
  r.b = q->pool_hash;
  r.c = static_cast<std::uint64_t>(canvas->metrics().live_cells.value());
  const double p99 = canvas->metrics().end_to_painted_seconds.quantile_seconds(0.99);
  r.d = std::isfinite(p99) ? static_cast<std::uint64_t>(p99 * 1e6) : ~std::uint64_t{0};
  const double wait99 = server->metrics().answer_wait_seconds.quantile_seconds(0.99);
  r.e = std::isfinite(wait99) ? static_cast<std::uint64_t>(wait99 * 1e6) : ~std::uint64_t{0};
  return r;
}

[[noreturn]] void child_main(int in, int out) {
  // The child ends with the parent, whatever way the parent ends.
  prctl(PR_SET_PDEATHSIG, SIGKILL);
  // Errors only: the hostile phase makes the server log a refusal per connection (rate-limited,
  // still many lines), which would bury the benchmark's own output.
  base::set_log_level(base::LogLevel::error);
  std::unique_ptr<server_net::Server> server;
  server_core::CanvasService* canvas = nullptr;
  Command c;
  while (read_all(in, &c, sizeof c)) {
    Reply r;
    if (c.op == 's') {
      r = server ? Reply{} : start_server(server, canvas, c);
      if (!r.ok && !r.message[0]) set_message(r, "already started");
    } else if (c.op == 'q') {
      r = quiesce(server.get(), canvas, c);
    } else if (c.op == 'm' || c.op == 'x') {
      if (c.op == 'x' && server) server->stop();
      r.ok = 1;
      r.a = status_bytes("VmHWM:");
      r.b = status_bytes("VmRSS:");
      timespec cpu{};
      clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &cpu);
      r.c = static_cast<std::uint64_t>(cpu.tv_sec) * 1000000000u +
            static_cast<std::uint64_t>(cpu.tv_nsec);
    } else {
      set_message(r, "unknown command");
    }
    if (!write_all(out, &r, sizeof r) || c.op == 'x') break;
  }
  if (server) server->stop();
  // _exit: the parent's atexit handlers and static destructors belong to the parent.
  _exit(0);
}

}  // namespace

Result<std::unique_ptr<ServerProcess>> ServerProcess::fork_idle() {
  auto c = fork_child(child_main);
  if (!c) return std::move(c).error();
  std::unique_ptr<ServerProcess> p(new ServerProcess());
  p->child_ = *c;
  return p;
}

// EOF on its pipe: the child stops its server and exits.
ServerProcess::~ServerProcess() { end_child(child_, std::chrono::seconds(30)); }

Result<void> ServerProcess::send(const void* command, std::size_t size) {
  if (child_.to_child < 0 || !write_all(child_.to_child, command, size))
    return make_error(Errc::io_error, "the server process is gone");
  return {};
}

Result<void> ServerProcess::receive(void* reply, std::size_t size, std::chrono::seconds timeout) {
  if (!wait_readable(child_.from_child, timeout))
    return make_error(Errc::io_error, "the server process did not answer in time");
  if (!read_all(child_.from_child, reply, size))
    return make_error(Errc::io_error, "the server process is gone");
  return {};
}

Result<std::uint16_t> ServerProcess::start(const ServerProcessSettings& settings,
                                           const std::string& canvas) {
  Command c;
  c.op = 's';
  c.settings = settings;
  std::snprintf(c.canvas, sizeof c.canvas, "%s", canvas.c_str());
  if (auto r = send(&c, sizeof c); !r) return std::move(r).error();
  Reply r;
  if (auto rr = receive(&r, sizeof r, std::chrono::seconds(60)); !rr) return std::move(rr).error();
  if (!r.ok) return make_error(Errc::io_error, std::string("server start: ") + r.message);
  return static_cast<std::uint16_t>(r.a);
}

Result<ServerQuiet> ServerProcess::quiesce(std::chrono::seconds timeout) {
  Command c;
  c.op = 'q';
  c.timeout_s = static_cast<std::uint32_t>(timeout.count());
  if (auto r = send(&c, sizeof c); !r) return std::move(r).error();
  Reply r;
  if (auto rr = receive(&r, sizeof r, timeout + std::chrono::seconds(10)); !rr)
    return std::move(rr).error();
  if (!r.ok) return make_error(Errc::io_error, std::string("quiesce: ") + r.message);
  return ServerQuiet{r.a, r.b, r.c, static_cast<double>(r.d) * 1e-3,
                     static_cast<double>(r.e) * 1e-3};
}

Result<ServerMemory> ServerProcess::memory() {
  Command c;
  c.op = 'm';
  if (auto r = send(&c, sizeof c); !r) return std::move(r).error();
  Reply r;
  if (auto rr = receive(&r, sizeof r, std::chrono::seconds(30)); !rr) return std::move(rr).error();
  return ServerMemory{r.a, r.b, static_cast<double>(r.c) * 1e-9};
}

ThreadTimesByName ServerProcess::thread_times() const {
  ThreadTimesByName out;
  if (child_.pid <= 0) return out;
  std::error_code ec;
  const std::filesystem::path tasks = "/proc/" + std::to_string(child_.pid) + "/task";
  for (const auto& e : std::filesystem::directory_iterator(tasks, ec)) {
    std::ifstream comm(e.path() / "comm"), sched(e.path() / "schedstat");
    std::string name;
    double run_ns = 0, wait_ns = 0;
    // A thread that ended meanwhile has no files: skipped.
    if (!std::getline(comm, name) || !(sched >> run_ns >> wait_ns)) continue;
    out[name].run_s += run_ns * 1e-9;
    out[name].wait_s += wait_ns * 1e-9;
  }
  return out;
}

Result<ServerMemory> ServerProcess::stop() {
  Command c;
  c.op = 'x';
  if (auto r = send(&c, sizeof c); !r) return std::move(r).error();
  Reply r;
  if (auto rr = receive(&r, sizeof r, std::chrono::seconds(60)); !rr) return std::move(rr).error();
  return ServerMemory{r.a, r.b, static_cast<double>(r.c) * 1e-9};
}

}  // namespace deepcanvas::bench
