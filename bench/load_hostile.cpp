// See load_hostile.hpp.
#include "load_hostile.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "deepcanvas/protocol/messages.hpp"

namespace deepcanvas::bench {

using Clock = std::chrono::steady_clock;

namespace {

constexpr char kUpgrade[] =
    "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
    "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n";

double ms_since(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}

nlohmann::json error_json(const protocol::ErrorMessage& e) {
  return {{"code", std::string(errc_name(e.code))},
          {"message", e.message},
          {"in_reply_to", e.in_reply_to}};
}

// A stroke's answer on `client`: its ack, or the error naming its handle, whichever comes first
// (errors for other handles, and for stroke_samples, are noted and waited past).
nlohmann::json wait_answer(client_core::Client& client, std::uint64_t handle,
                           Clock::time_point sent, std::chrono::seconds timeout) {
  const auto deadline = Clock::now() + timeout;
  nlohmann::json piece_errors = nlohmann::json::array();
  while (Clock::now() < deadline) {
    if (auto a = client.wait_for_ack(handle, std::chrono::milliseconds(50)))
      return {{"answer", "ack"}, {"ms", ms_since(sent)}, {"piece_errors", piece_errors}};
    while (auto e = client.wait_for_error(std::chrono::milliseconds(0))) {
      if (e->handle != handle) continue;
      if (e->in_reply_to == "stroke_samples") {
        piece_errors.push_back(error_json(*e));
        continue;
      }
      return {{"answer", "error"},
              {"ms", ms_since(sent)},
              {"error", error_json(*e)},
              {"piece_errors", piece_errors}};
    }
    if (!client.is_open())
      return {{"answer", "connection closed"}, {"ms", ms_since(sent)}};
  }
  return {{"answer", "none within " + std::to_string(timeout.count()) + " s"},
          {"ms", ms_since(sent)}, {"piece_errors", piece_errors}};
}

}  // namespace

// ---- UnauthFlood ----

struct UnauthFlood::Slot {
  enum class State { idle, connecting, requested, upgraded } state = State::idle;
  int fd = -1;
  Clock::time_point retry_at{};
  std::string response;  // the HTTP status line as it arrives
};

UnauthFlood::UnauthFlood(std::uint16_t port, std::size_t connections,
                         std::size_t source_addresses, std::chrono::milliseconds reopen_delay)
    : port_(port),
      sources_(std::max<std::size_t>(1, std::min<std::size_t>(source_addresses, 250))),
      reopen_delay_(reopen_delay),
      slots_(connections),
      thread_([this] { run(); }) {}

UnauthFlood::~UnauthFlood() {
  (void)finish();
}

void UnauthFlood::open(Slot& s) {
  s.response.clear();
  s.fd = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (s.fd < 0) {
    ++connect_failed_;
    s.retry_at = Clock::now() + reopen_delay_;
    return;
  }
  // The whole of 127.0.0.0/8 is the loopback interface: any of it is a source address here.
  sockaddr_in from{};
  from.sin_family = AF_INET;
  const auto index = static_cast<std::size_t>(&s - slots_.data());
  from.sin_addr.s_addr = htonl((127u << 24) | (1u << 8) | static_cast<std::uint32_t>(1 + index % sources_));
  if (::bind(s.fd, reinterpret_cast<const sockaddr*>(&from), sizeof from) != 0) {
    ++connect_failed_;
    ::close(s.fd);
    s.fd = -1;
    s.retry_at = Clock::now() + reopen_delay_;
    return;
  }
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(port_);
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  const int r = ::connect(s.fd, reinterpret_cast<const sockaddr*>(&a), sizeof a);
  if (r != 0 && errno != EINPROGRESS) {
    ++connect_failed_;
    ::close(s.fd);
    s.fd = -1;
    s.retry_at = Clock::now() + reopen_delay_;
    return;
  }
  ++opened_;
  s.state = Slot::State::connecting;
}

void UnauthFlood::close_slot(Slot& s, bool by_server) {
  if (s.state == Slot::State::upgraded) --upgraded_now_;
  if (by_server) ++closed_by_server_;
  ::close(s.fd);
  s.fd = -1;
  s.state = Slot::State::idle;
  s.retry_at = Clock::now() + reopen_delay_;
}

void UnauthFlood::on_event(Slot& s, short revents) {
  if (s.state == Slot::State::connecting) {
    int err = 0;
    socklen_t len = sizeof err;
    getsockopt(s.fd, SOL_SOCKET, SO_ERROR, &err, &len);
    if (err != 0 || (revents & (POLLERR | POLLHUP))) {
      ++connect_failed_;
      return close_slot(s, false);
    }
    if (::send(s.fd, kUpgrade, sizeof kUpgrade - 1, MSG_NOSIGNAL) != sizeof kUpgrade - 1)
      return close_slot(s, true);
    s.state = Slot::State::requested;
    return;
  }
  char buf[4096];
  const ssize_t n = ::recv(s.fd, buf, sizeof buf, 0);
  if (n < 0 && (errno == EAGAIN || errno == EINTR)) return;
  if (n <= 0) return close_slot(s, true);
  if (s.state != Slot::State::requested) return;  // upgraded: whatever the server says is ignored
  s.response.append(buf, static_cast<std::size_t>(std::min<ssize_t>(n, 64)));
  if (s.response.size() < 12) return;
  if (s.response.compare(0, 12, "HTTP/1.1 101") == 0) {
    s.state = Slot::State::upgraded;
    ++upgraded_;
    upgraded_max_ = std::max(upgraded_max_, ++upgraded_now_);
  } else {
    ++refused_http_;  // e.g. 503: the server's cap on such connections
    close_slot(s, false);
  }
}

void UnauthFlood::run() {
  std::vector<pollfd> fds;
  std::vector<Slot*> of;
  while (!stop_.load()) {
    const auto now = Clock::now();
    fds.clear();
    of.clear();
    for (Slot& s : slots_) {
      if (s.state == Slot::State::idle && now >= s.retry_at) open(s);
      if (s.fd < 0) continue;
      fds.push_back({s.fd, static_cast<short>(s.state == Slot::State::connecting ? POLLOUT : POLLIN),
                     0});
      of.push_back(&s);
    }
    const int n = ::poll(fds.data(), fds.size(), 50);
    if (n <= 0) continue;
    for (std::size_t i = 0; i < fds.size(); ++i)
      if (fds[i].revents != 0) on_event(*of[i], fds[i].revents);
  }
}

nlohmann::json UnauthFlood::finish() {
  if (thread_.joinable()) {
    stop_.store(true);
    thread_.join();
    for (Slot& s : slots_)
      if (s.fd >= 0) ::close(s.fd);
  }
  return {{"connections", slots_.size()},
          {"opened", opened_},
          {"upgraded", upgraded_},
          {"upgraded_held_max", upgraded_max_},
          {"refused_by_http_status", refused_http_},
          {"closed_by_server", closed_by_server_},
          {"connect_failed", connect_failed_}};
}

// ---- StrokeHolder ----

StrokeHolder::StrokeHolder(client_core::ClientOptions options, std::chrono::milliseconds interval)
    : interval_(interval) {
  auto c = client_core::Client::connect(options);
  if (c)
    client_ = std::move(*c);
  else
    connect_error_ = c.error().message;
  thread_ = std::thread([this] { run(); });
}

StrokeHolder::~StrokeHolder() {
  release();
  if (thread_.joinable()) thread_.join();
}

void StrokeHolder::release() {
  released_.store(true);
}

void StrokeHolder::run() {
  if (!client_) {
    result_ = {{"answer", "connect failed: " + connect_error_}};
    return;
  }
  client_core::Client* c = client_.get();
  protocol::Brush brush;
  brush.colour[0] = 0.9f;
  protocol::StrokeSample s{0.0, 1.5, 0.0, 0.02f, 1.0f, 0};
  auto h = c->begin_stroke(brush, {s});
  if (!h) {
    result_ = {{"answer", "begin failed: " + h.error().message}};
    return;
  }
  const auto begun = Clock::now();
  std::size_t samples = 1;
  auto next = begun + interval_;
  while (!released_.load()) {
    if (Clock::now() < next) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      continue;
    }
    next += interval_;
    s.x += 0.01;
    s.t_ms += static_cast<std::uint32_t>(interval_.count());
    if (!c->add_samples(*h, {s})) break;
    ++samples;
  }
  const auto ended = Clock::now();
  (void)c->end_stroke(*h);
  result_ = wait_answer(*c, *h, ended, std::chrono::seconds(120));
  result_["held_ms"] = std::chrono::duration<double, std::milli>(ended - begun).count();
  result_["samples"] = samples;
}

nlohmann::json StrokeHolder::finish() {
  release();
  if (thread_.joinable()) thread_.join();
  return result_;
}

// ---- LateViewer ----

LateViewer::LateViewer(client_core::ClientOptions options, std::chrono::milliseconds delay)
    : thread_([this, options = std::move(options), delay] {
        std::this_thread::sleep_for(delay);
        const auto t0 = Clock::now();
        auto c = client_core::Client::connect(options);
        if (!c) {
          result_ = {{"joined", false}, {"error", c.error().message}, {"ms", ms_since(t0)}};
          return;
        }
        auto e = (*c)->wait_for_epoch(0, std::chrono::seconds(60));
        result_ = {{"joined", e.ok()}, {"snapshot_ms", ms_since(t0)}};
        if (!e) result_["error"] = e.error().message;
        (*c)->close();
      }) {}

LateViewer::~LateViewer() {
  if (thread_.joinable()) thread_.join();
}

nlohmann::json LateViewer::finish() {
  if (thread_.joinable()) thread_.join();
  return result_;
}

// ---- HugeStroke ----

protocol::Stroke huge_stroke() {
  protocol::Stroke s;
  s.brush.colour[1] = 0.8f;
  s.samples = {{10.0, 10.0, 10.0, 0.05f, 1.0f, 0}, {-10000.0, 10.0, 10.0, 0.05f, 1.0f, 100}};
  return s;
}

HugeStroke::HugeStroke(client_core::ClientOptions options) {
  auto c = client_core::Client::connect(options);
  if (!c) {
    send_error_ = "connect failed: " + c.error().message;
    return;
  }
  client_ = std::move(*c);
  sent_ = Clock::now();
  auto h = client_->send_stroke(huge_stroke());
  if (!h) {
    send_error_ = "send failed: " + h.error().message;
    return;
  }
  handle_ = *h;
}

HugeStroke::~HugeStroke() = default;

nlohmann::json HugeStroke::finish(std::chrono::seconds timeout) {
  if (!send_error_.empty()) return {{"answer", send_error_}};
  auto out = wait_answer(*client_, handle_, sent_, timeout);
  client_->close();
  return out;
}

// ---- StalledReaders ----

StalledReaders::StalledReaders(client_core::ClientOptions options, std::size_t n) {
  options.receive_buffer_bytes = 4096;
  for (std::size_t i = 0; i < n; ++i) {
    auto c = client_core::Client::connect(options);
    if (!c) {
      ++failed_;
      continue;
    }
    (*c)->pause_reading();
    clients_.push_back(std::move(*c));
  }
}

nlohmann::json StalledReaders::finish() {
  std::size_t open = 0;
  for (const auto& c : clients_) open += c->is_open() ? 1 : 0;
  const std::size_t n = clients_.size();
  // Reading again first: a close handshake needs the server's close frame read.
  for (auto& c : clients_) c->resume_reading();
  for (auto& c : clients_) c->close();
  clients_.clear();
  return {{"readers", n + failed_},
          {"connect_failed", failed_},
          {"still_connected_at_end", open},
          {"dropped_by_server", n - open}};
}

}  // namespace deepcanvas::bench
