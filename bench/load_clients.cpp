// See load_clients.hpp. The pipe protocol: the parent writes one Command, the child answers one
// Reply (fixed-size structs of plain values: both processes are the same binary), followed by
// Reply::blob_bytes of JSON for the commands that return data.
#include "load_clients.hpp"

#include <sched.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#include <cstdio>
#include <mutex>
#include <optional>
#include <thread>

#include "child_pipe.hpp"
#include "load_hostile.hpp"

namespace deepcanvas::bench {

using Clock = std::chrono::steady_clock;

client_core::ClientOptions load_client_options(std::uint16_t port, protocol::Role role,
                                               const char* name) {
  client_core::ClientOptions o;
  o.url = "ws://127.0.0.1:" + std::to_string(port) + "/";
  o.canvas = "load";
  o.role = role;
  o.client_name = name;
  o.connect_timeout = std::chrono::seconds(30);
  if (role == protocol::Role::painter) {
    o.keep_replica = false;
    o.block_frames = false;
  }
  return o;
}

double process_cpu_seconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + static_cast<double>(t.tv_nsec) * 1e-9;
}

namespace {

struct Command {
  char op = 0;  // 'c' connect, 'r' release the holder, 'h' finish hostile, 'f' finish and exit
  LoadClientsSpec spec;
  std::uint64_t epoch = 0, pool_hash = 0;
  std::uint32_t timeout_s = 0;
};

struct Reply {
  std::int32_t ok = 0;
  std::uint64_t blob_bytes = 0;  // JSON that follows the reply
  char message[480] = {};
};

void set_message(Reply& r, const std::string& m) {
  std::snprintf(r.message, sizeof r.message, "%s", m.c_str());
}

// Runs `f` on a thread of its own at CPU priority `nice`, or in the SCHED_IDLE class when
// `idle_class` (that thread's only; the threads it makes, such as a client's I/O thread,
// inherit it) and returns what it returns. Where SCHED_IDLE is refused, `nice` it is.
template <class F>
auto with_priority(int nice, bool idle_class, F&& f) -> decltype(f()) {
  std::optional<decltype(f())> out;
  std::thread t([&] {
    const sched_param none{};
    const bool idle = idle_class && sched_setscheduler(::gettid(), SCHED_IDLE, &none) == 0;
    if (!idle && nice != 0) (void)setpriority(PRIO_PROCESS, static_cast<id_t>(::gettid()), nice);
    out.emplace(f());
  });
  t.join();
  return std::move(*out);
}

// A viewer and the time each epoch was committed to its replica (its epoch listener).
struct Viewer {
  std::mutex mutex;
  std::vector<std::pair<std::uint64_t, Clock::time_point>> commits;  // ascending epochs
  // Last: destroyed first, so its I/O thread (which runs the listener) ends before the rest.
  std::unique_ptr<client_core::Client> client;
};

Result<std::vector<std::unique_ptr<Viewer>>> connect_viewers(std::uint16_t port, std::size_t n) {
  std::vector<std::unique_ptr<Viewer>> viewers;
  for (std::size_t i = 0; i < n; ++i) {
    auto v = std::make_unique<Viewer>();
    auto c = client_core::Client::connect(
        load_client_options(port, protocol::Role::viewer, "load-viewer"));
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

  explicit Hostile(const LoadClientsSpec& spec)
      : stalled(std::make_unique<StalledReaders>(
            load_client_options(spec.port, protocol::Role::viewer, "load-stalled"),
            spec.stalled_readers)),
        huge(std::make_unique<HugeStroke>(
            load_client_options(spec.port, protocol::Role::painter, "load-huge"))),
        holder(std::make_unique<StrokeHolder>(
            load_client_options(spec.port, protocol::Role::painter, "load-holder"))),
        flood(std::make_unique<UnauthFlood>(spec.port, spec.unauthenticated)),
        late(std::make_unique<LateViewer>(
            load_client_options(spec.port, protocol::Role::viewer, "load-late"),
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

// The child's state between commands.
struct Clients {
  std::vector<std::unique_ptr<Viewer>> viewers;
  std::unique_ptr<Hostile> hostile;
  double cpu_at_connect = 0;
  std::optional<double> cpu_used;  // taken when the painting ends (finish_hostile or finish)

  void painting_ended() {
    if (!cpu_used) cpu_used = process_cpu_seconds() - cpu_at_connect;
  }
};

Reply connect_clients(Clients& cl, const LoadClientsSpec& spec) {
  Reply r;
  if (!cl.viewers.empty()) {
    set_message(r, "already connected");
    return r;
  }
  auto viewers = with_priority(spec.viewer_nice, spec.viewer_idle_class != 0,
                               [&] { return connect_viewers(spec.port, spec.viewers); });
  if (!viewers) {
    set_message(r, viewers.error().message);
    return r;
  }
  cl.viewers = std::move(*viewers);
  if (spec.hostile)
    cl.hostile =
        with_priority(spec.hostile_nice, false, [&] { return std::make_unique<Hostile>(spec); });
  cl.cpu_at_connect = process_cpu_seconds();
  r.ok = 1;
  return r;
}

std::string check_and_report(Clients& cl, const Command& c) {
  cl.painting_ended();
  nlohmann::json j;
  std::size_t differing = 0;
  std::string error;
  for (auto& v : cl.viewers) {
    const bool at =
        v->client->wait_for_epoch(c.epoch, std::chrono::seconds(c.timeout_s)).ok();
    if (!at && error.empty()) error = "a viewer did not reach epoch " + std::to_string(c.epoch);
    if (!at || v->client->pool_hash() != c.pool_hash) ++differing;
  }
  nlohmann::json commits = nlohmann::json::array();
  for (auto& v : cl.viewers) {
    v->client->set_epoch_listener({});
    std::lock_guard lock(v->mutex);
    nlohmann::json one = nlohmann::json::array();
    for (const auto& [e, t] : v->commits)
      one.push_back({e, std::chrono::duration_cast<std::chrono::nanoseconds>(
                            t.time_since_epoch())
                            .count()});
    commits.push_back(std::move(one));
  }
  j["viewers"] = cl.viewers.size();
  j["differing"] = differing;
  j["error"] = error;
  j["commits"] = std::move(commits);
  j["cpu_s"] = *cl.cpu_used;
  return j.dump();
}

[[noreturn]] void child_main(int in, int out) {
  // The child ends with the parent, whatever way the parent ends.
  prctl(PR_SET_PDEATHSIG, SIGKILL);
  Clients cl;
  Command c;
  while (read_all(in, &c, sizeof c)) {
    Reply r;
    std::string blob;
    if (c.op == 'c') {
      r = connect_clients(cl, c.spec);
    } else if (c.op == 'r') {
      if (cl.hostile) cl.hostile->holder->release();
      r.ok = 1;
    } else if (c.op == 'h') {
      cl.painting_ended();
      blob = cl.hostile ? cl.hostile->finish().dump() : "null";
      r.ok = 1;
    } else if (c.op == 'f') {
      blob = check_and_report(cl, c);
      r.ok = 1;
    } else {
      set_message(r, "unknown command");
    }
    r.blob_bytes = blob.size();
    if (!write_all(out, &r, sizeof r) || !write_all(out, blob.data(), blob.size()) ||
        c.op == 'f')
      break;
  }
  // _exit: the parent's atexit handlers and static destructors belong to the parent. The
  // clients' connections close with the process.
  _exit(0);
}

}  // namespace

Result<std::unique_ptr<LoadClientsProcess>> LoadClientsProcess::fork_idle() {
  auto c = fork_child(child_main);
  if (!c) return std::move(c).error();
  std::unique_ptr<LoadClientsProcess> p(new LoadClientsProcess());
  p->child_ = *c;
  return p;
}

// EOF on its pipe: the child exits.
LoadClientsProcess::~LoadClientsProcess() { end_child(child_, std::chrono::seconds(30)); }

Result<std::string> LoadClientsProcess::exchange(const void* command, std::size_t size,
                                                 std::chrono::seconds timeout) {
  if (child_.to_child < 0 || !write_all(child_.to_child, command, size))
    return make_error(Errc::io_error, "the clients' process is gone");
  if (!wait_readable(child_.from_child, timeout))
    return make_error(Errc::io_error, "the clients' process did not answer in time");
  Reply r;
  if (!read_all(child_.from_child, &r, sizeof r))
    return make_error(Errc::io_error, "the clients' process is gone");
  std::string blob(r.blob_bytes, '\0');
  if (!read_all(child_.from_child, blob.data(), blob.size()))
    return make_error(Errc::io_error, "the clients' process is gone");
  if (!r.ok) return make_error(Errc::io_error, r.message);
  return blob;
}

Result<void> LoadClientsProcess::connect(const LoadClientsSpec& spec) {
  Command c;
  c.op = 'c';
  c.spec = spec;
  if (auto r = exchange(&c, sizeof c, std::chrono::seconds(120)); !r)
    return make_error(r.error().code, "clients: " + r.error().message);
  return {};
}

Result<void> LoadClientsProcess::release_holder() {
  Command c;
  c.op = 'r';
  if (auto r = exchange(&c, sizeof c, std::chrono::seconds(30)); !r)
    return std::move(r).error();
  return {};
}

Result<nlohmann::json> LoadClientsProcess::finish_hostile() {
  Command c;
  c.op = 'h';
  auto r = exchange(&c, sizeof c, std::chrono::seconds(180));
  if (!r) return std::move(r).error();
  auto j = nlohmann::json::parse(*r, nullptr, false);
  if (j.is_discarded()) return make_error(Errc::io_error, "clients: unreadable hostile report");
  return j;
}

Result<LoadClientsReport> LoadClientsProcess::finish(std::uint64_t epoch, std::uint64_t pool_hash,
                                                     std::chrono::seconds timeout) {
  Command c;
  c.op = 'f';
  c.epoch = epoch;
  c.pool_hash = pool_hash;
  c.timeout_s = static_cast<std::uint32_t>(timeout.count());
  auto r = exchange(&c, sizeof c, timeout * 2 + std::chrono::seconds(30));
  if (!r) return std::move(r).error();
  auto j = nlohmann::json::parse(*r, nullptr, false);
  if (j.is_discarded() || !j.is_object())
    return make_error(Errc::io_error, "clients: unreadable report");
  LoadClientsReport out;
  out.viewers = j.value("viewers", std::size_t{0});
  out.viewers_differing = j.value("differing", std::size_t{0});
  out.replica_check_error = j.value("error", std::string());
  out.cpu_s = j.value("cpu_s", 0.0);
  for (const auto& one : j["commits"]) {
    auto& v = out.commits.emplace_back();
    for (const auto& ec : one)
      v.emplace_back(ec[0].get<std::uint64_t>(),
                     Clock::time_point(std::chrono::duration_cast<Clock::duration>(
                         std::chrono::nanoseconds(ec[1].get<std::int64_t>()))));
  }
  return out;
}

}  // namespace deepcanvas::bench
