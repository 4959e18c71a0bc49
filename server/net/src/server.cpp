// Server: start-up, the listener, shutdown, and /metrics rendering.
#include <algorithm>
#include <array>

#include "deepcanvas/base/thread_name.hpp"
#include "deepcanvas/base/log.hpp"
#include "net_impl.hpp"

namespace deepcanvas::server_net {

using base::log_event;
using base::LogLevel;

server_core::CanvasService* Server::State::canvas(std::string_view name) const noexcept {
  for (const auto& c : canvases)
    if (c->name() == name) return c.get();
  return nullptr;
}

namespace {

bool is_loopback(const std::string& address) {
  boost::system::error_code ec;
  const auto a = net::ip::make_address(address, ec);
  return !ec && a.is_loopback();
}

// The server's TLS context: TLS 1.2 or later, the certificate chain and key from PEM files.
// OpenSSL checks that the key matches the certificate when the key is loaded.
Result<std::unique_ptr<net::ssl::context>> make_tls_context(const std::string& cert_file,
                                                            const std::string& key_file) {
  auto ctx = std::make_unique<net::ssl::context>(net::ssl::context::tls_server);
  beast::error_code ec;
  ctx->set_options(net::ssl::context::default_workarounds | net::ssl::context::no_sslv2 |
                       net::ssl::context::no_sslv3 | net::ssl::context::no_tlsv1 |
                       net::ssl::context::no_tlsv1_1 | net::ssl::context::single_dh_use,
                   ec);
  if (ec) return make_error(Errc::internal, "cannot set TLS options: " + ec.message());
  ctx->use_certificate_chain_file(cert_file, ec);
  if (ec)
    return make_error(Errc::invalid_argument,
                      "cannot load TLS certificate '" + cert_file + "': " + ec.message());
  ctx->use_private_key_file(key_file, net::ssl::context::pem, ec);
  if (ec)
    return make_error(Errc::invalid_argument, "cannot load TLS key '" + key_file +
                                                  "' (for certificate '" + cert_file +
                                                  "'): " + ec.message());
  return ctx;
}

// ---- listener ----

// A connection past a pre-authentication cap: a short HTTP 503 (so that a client sees why),
// then a lingering close: what the client sent meanwhile is read and dropped (at most 2 s), since
// closing a socket with unread bytes resets it and the client could lose the answer.
void refuse_connection(tcp::socket socket, const char* why) {
  struct Refusal {
    beast::tcp_stream stream;
    http::response<http::string_body> res;
    std::array<char, 1024> sink{};
    explicit Refusal(tcp::socket s) : stream(std::move(s)) {}
    static void drain(const std::shared_ptr<Refusal>& r) {
      r->stream.async_read_some(net::buffer(r->sink), [r](beast::error_code ec, std::size_t) {
        if (!ec) return drain(r);
        beast::error_code ignored;
        r->stream.socket().close(ignored);
      });
    }
  };
  auto r = std::make_shared<Refusal>(std::move(socket));
  r->res.result(http::status::service_unavailable);
  r->res.version(11);
  r->res.set(http::field::server, "deepcanvas-server");
  r->res.set(http::field::content_type, "text/plain");
  r->res.set(http::field::retry_after, "5");
  r->res.keep_alive(false);
  r->res.body() = std::string(why) + "\n";
  r->res.prepare_payload();
  r->stream.expires_after(std::chrono::seconds(2));
  http::async_write(r->stream, r->res, [r](beast::error_code ec, std::size_t) {
    beast::error_code ignored;
    if (ec) {
      r->stream.socket().close(ignored);
      return;
    }
    r->stream.socket().shutdown(tcp::socket::shutdown_send, ignored);
    Refusal::drain(r);
  });
}

class Listener : public std::enable_shared_from_this<Listener> {
 public:
  explicit Listener(std::shared_ptr<Server::State> state)
      : state_(std::move(state)), backoff_timer_(state_->ioc) {}
  void accept() {
    state_->acceptor->async_accept(
        net::make_strand(state_->ioc),
        beast::bind_front_handler(&Listener::on_accept, shared_from_this()));
  }

 private:
  void on_accept(beast::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted || !state_->acceptor->is_open()) return;
    if (ec) {
      // Transient (e.g. out of file descriptors): the connection waits in the backlog, so an
      // immediate retry fails the same way. Wait, 50 ms doubling to 1 s, then try again (the
      // log line is rate-limited by log_event).
      state_->metrics.accept_errors.add();
      backoff_ = std::clamp(backoff_ * 2, std::chrono::milliseconds(50), std::chrono::milliseconds(1000));
      log_event(LogLevel::warn, "accept_failed",
                {{"error", ec.message()}, {"retry_ms", static_cast<long>(backoff_.count())}});
      backoff_timer_.expires_after(backoff_);
      backoff_timer_.async_wait([self = shared_from_this()](beast::error_code tec) {
        if (tec || !self->state_->acceptor->is_open()) return;
        self->accept();
      });
      return;
    }
    backoff_ = std::chrono::milliseconds(0);
    take(std::move(socket));
    accept();
  }

  void take(tcp::socket socket) {
    state_->metrics.connections.add();
    beast::error_code ec;
    const auto remote = socket.remote_endpoint(ec);
    if (ec) return;  // already gone
    const std::string key = PreAuthTable::key_of(remote.address());
    const char* why = "";
    std::function<void()> evicted;
    const std::uint64_t place = state_->pre_auth->try_acquire(key, why, evicted);
    if (evicted) {
      state_->metrics.connections_evicted.add();
      log_event(LogLevel::warn, "connection_evicted",
                {{"reason", "the oldest unauthenticated connection, to admit a new one"}});
      evicted();
    }
    if (place == 0) {
      state_->metrics.connections_refused.add();
      log_event(LogLevel::warn, "connection_refused",
                {{"remote", remote.address().to_string()}, {"reason", why}});
      return refuse_connection(std::move(socket), why);
    }
    PreAuthSlot slot(state_->pre_auth, place);
    socket.set_option(tcp::no_delay(true), ec);  // small control messages go out at once
    if (state_->config.socket_send_buffer_bytes > 0)
      socket.set_option(
          net::socket_base::send_buffer_size(state_->config.socket_send_buffer_bytes), ec);
    start_http_session(std::move(socket), std::move(slot), state_);
  }

  std::shared_ptr<Server::State> state_;
  net::steady_timer backoff_timer_;
  std::chrono::milliseconds backoff_{0};
};

}  // namespace

std::string PreAuthTable::key_of(const net::ip::address& address) {
  if (address.is_v6() && !address.to_v6().is_v4_mapped()) {
    auto bytes = address.to_v6().to_bytes();
    return "6:" + std::string(reinterpret_cast<const char*>(bytes.data()), 8);
  }
  const auto v4 = address.is_v4() ? address.to_v4()
                                  : net::ip::make_address_v4(net::ip::v4_mapped,
                                                             address.to_v6());
  const auto bytes = v4.to_bytes();
  return "4:" + std::string(reinterpret_cast<const char*>(bytes.data()), bytes.size());
}

std::uint64_t PreAuthTable::try_acquire(const std::string& key, const char*& why,
                                        std::function<void()>& evicted) {
  std::lock_guard lock(mutex_);
  auto n = by_key_.find(key);
  if (n != by_key_.end() && n->second >= max_per_address_) {
    why = "too many unauthenticated connections from this address";
    return 0;
  }
  if (total_ >= max_total_) {
    auto oldest = std::find_if(places_.begin(), places_.end(),
                               [](const Place& p) { return static_cast<bool>(p.evictor); });
    if (oldest == places_.end()) {
      why = "too many unauthenticated connections";
      return 0;
    }
    // Its counts go now; the connection itself ends when the evictor has closed it.
    evicted = std::move(oldest->evictor);
    drop_counts(oldest->key);
    by_id_.erase(oldest->id);
    places_.erase(oldest);
  }
  ++by_key_[key];
  ++total_;
  metrics_.unauthenticated.add(1);
  const std::uint64_t id = next_id_++;
  places_.push_back(Place{id, key, {}});
  by_id_.emplace(id, std::prev(places_.end()));
  return id;
}

void PreAuthTable::set_evictor(std::uint64_t id, std::function<void()> evictor) {
  std::lock_guard lock(mutex_);
  auto it = by_id_.find(id);
  if (it != by_id_.end()) it->second->evictor = std::move(evictor);
}

void PreAuthTable::drop_counts(const std::string& key) noexcept {
  auto it = by_key_.find(key);
  if (it == by_key_.end()) return;
  if (--it->second == 0) by_key_.erase(it);
  --total_;
  metrics_.unauthenticated.add(-1);
}

void PreAuthTable::release(std::uint64_t id) noexcept {
  std::lock_guard lock(mutex_);
  auto it = by_id_.find(id);
  if (it == by_id_.end()) return;  // evicted: its counts went then
  drop_counts(it->second->key);
  places_.erase(it->second);
  by_id_.erase(it);
}

void start_listener(const std::shared_ptr<Server::State>& state) {
  std::make_shared<Listener>(state)->accept();
}

Result<std::unique_ptr<Server>> Server::create(ServerConfig config) {
  if (config.canvases.empty()) return make_error(Errc::invalid_argument, "no canvas configured");
  if (!config.tokens && !is_loopback(config.listen_address))
    return make_error(Errc::invalid_argument,
                      "refusing to listen on " + config.listen_address +
                          " without --tokens: only loopback may be served without access control");
  if (config.network_threads < 1 || config.network_threads > 64)
    return make_error(Errc::invalid_argument, "network threads must be 1..64");
  if (config.limits.max_frame_bytes < 1024)
    return make_error(Errc::invalid_argument, "max frame bytes must be at least 1024");
  if (config.pre_auth_frame_bytes < 1024 ||
      config.pre_auth_frame_bytes > config.limits.max_frame_bytes)
    return make_error(Errc::invalid_argument,
                      "pre-authentication frame bytes must be 1024..max frame bytes");
  if (config.max_unauthenticated < 1 || config.max_unauthenticated_per_address < 1)
    return make_error(Errc::invalid_argument, "unauthenticated connection caps must be >= 1");
  if (config.hello_timeout.count() <= 0 || config.message_timeout.count() <= 0)
    return make_error(Errc::invalid_argument, "hello and message timeouts must be positive");
  for (std::size_t i = 0; i < config.canvases.size(); ++i) {
    if (!protocol::is_valid_canvas_name(config.canvases[i].name))
      return make_error(Errc::invalid_argument,
                        "bad canvas name '" + config.canvases[i].name + "'");
    for (std::size_t j = 0; j < i; ++j)
      if (config.canvases[j].name == config.canvases[i].name)
        return make_error(Errc::invalid_argument,
                          "canvas '" + config.canvases[i].name + "' named twice");
  }
  if (config.tls_cert_file.empty() != config.tls_key_file.empty())
    return make_error(Errc::invalid_argument,
                      "TLS needs both a certificate file and a key file (got only the " +
                          std::string(config.tls_cert_file.empty() ? "key" : "certificate") + ")");
  std::unique_ptr<net::ssl::context> tls;
  if (!config.tls_cert_file.empty()) {
    auto t = make_tls_context(config.tls_cert_file, config.tls_key_file);
    if (!t) return std::move(t).error();
    tls = std::move(*t);
  }
  std::unique_ptr<Server> server(new Server());
  auto state = std::make_shared<State>();
  state->tls = std::move(tls);
  if (config.limits.stroke_receipts > 0)
    state->receipts = std::make_unique<StrokeReceipts>(ReceiptLimits{config.limits.stroke_receipts});
  for (auto& cc : config.canvases) {
    cc.stroke_limits.max_samples = config.limits.max_samples_per_stroke;
    cc.stroke_limits.min_radius_m = config.limits.min_radius_m;
    cc.stroke_limits.max_radius_m = config.limits.max_radius_m;
    auto c = config.make_canvas ? config.make_canvas(cc) : server_core::CanvasService::create(cc);
    if (!c) return make_error(c.error().code, "canvas '" + cc.name + "': " + c.error().message);
    if (state->receipts && config.restored_stroke_names) {
      const RestoredStrokeNames names = config.restored_stroke_names(cc.name);
      state->receipts->restore(cc.name, names.ended, (*c)->published_epoch());
      state->receipts->restore_cut(cc.name, names.cut);
    }
    state->canvases.push_back(std::move(*c));
  }
  state->fanout = std::make_shared<FanoutGate>(
      static_cast<std::size_t>(std::max(1, config.network_threads - 1)));
  state->pre_auth = std::make_shared<PreAuthTable>(
      config.max_unauthenticated, config.max_unauthenticated_per_address, state->metrics);
  state->config = std::move(config);
  server->state_ = std::move(state);
  return server;
}

Server::~Server() {
  stop();
}

Result<void> Server::start() {
  State& s = *state_;
  {
    std::lock_guard lock(s.stop_mutex);
    if (s.started) return make_error(Errc::refused, "server already started");
    s.started = true;
  }
  beast::error_code ec;
  const auto address = net::ip::make_address(s.config.listen_address, ec);
  if (ec)
    return make_error(Errc::invalid_argument,
                      "bad listen address '" + s.config.listen_address + "'");
  const tcp::endpoint ep{address, s.config.port};
  s.acceptor = std::make_unique<tcp::acceptor>(s.ioc);
  auto fail = [&](const char* what) {
    return make_error(Errc::io_error, std::string(what) + " " + s.config.listen_address + ":" +
                                          std::to_string(s.config.port) + ": " + ec.message());
  };
  s.acceptor->open(ep.protocol(), ec);
  if (ec) return fail("cannot open");
  s.acceptor->set_option(net::socket_base::reuse_address(true), ec);
  if (ec) return fail("cannot set reuse_address on");
  s.acceptor->bind(ep, ec);
  if (ec) return fail("cannot bind");
  s.acceptor->listen(net::socket_base::max_listen_connections, ec);
  if (ec) return fail("cannot listen on");
  s.port = s.acceptor->local_endpoint().port();
  start_listener(state_);
  for (int i = 0; i < s.config.network_threads; ++i)
    s.threads.emplace_back([st = state_] {
      base::set_thread_name("dc-net");
      // A handler that throws is a bug; log it and keep the network alive.
      for (;;) {
        try {
          st->ioc.run();
          return;
        } catch (const std::exception& e) {
          log_event(LogLevel::error, "network_thread_exception", {{"what", e.what()}});
        }
      }
    });
  std::string names;
  for (const auto& c : s.canvases) names += (names.empty() ? "" : ",") + c->name();
  log_event(LogLevel::info, "listening",
            {{"address", s.config.listen_address},
             {"port", static_cast<unsigned>(s.port.load())},
             {"canvases", names},
             {"auth", s.config.tokens ? "tokens" : "open"},
             {"tls", s.tls ? "on" : "off"},
             {"threads", s.config.network_threads}});
  if (!s.tls && !is_loopback(s.config.listen_address))
    log_event(LogLevel::warn, "listening_without_tls",
              {{"address", s.config.listen_address},
               {"risk", "tokens and strokes cross the network unencrypted: use --tls-cert and "
                        "--tls-key (or a TLS proxy in front), or listen on loopback"}});
  return {};
}

void Server::stop() {
  if (!state_) return;
  State& s = *state_;
  {
    std::unique_lock lock(s.stop_mutex);
    if (s.stop_begun) {
      s.stop_cv.wait(lock, [&] { return s.stop_done; });
      return;
    }
    s.stop_begun = true;
  }
  if (s.acceptor) {
    net::post(s.ioc, [st = state_] {
      beast::error_code ec;
      st->acceptor->close(ec);
    });
  }
  std::vector<std::shared_ptr<WsSessionBase>> live;
  {
    std::lock_guard lock(s.sessions_mutex);
    for (auto& [id, w] : s.sessions)
      if (auto p = w.lock()) live.push_back(std::move(p));
  }
  for (auto& p : live) close_ws_session(p);
  live.clear();
  // Give sessions a moment to finish their close handshakes, then stop the loop.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(2);
  for (;;) {
    bool any = false;
    {
      std::lock_guard lock(s.sessions_mutex);
      for (auto& [id, w] : s.sessions)
        if (!w.expired()) any = true;
    }
    if (!any || std::chrono::steady_clock::now() > deadline || s.threads.empty()) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  // An import still converting is abandoned (its session is closing): nothing of it was pasted.
  s.imports.stop();
  s.imports.join();
  s.ioc.stop();
  for (auto& t : s.threads)
    if (t.joinable()) t.join();
  s.threads.clear();
  // Handlers still queued in the io_context hold shared_ptrs back to the state that owns it
  // (the listener, sessions): a cycle. Close the acceptor and run them out so they release it.
  if (s.acceptor) {
    beast::error_code ignored;
    s.acceptor->close(ignored);
  }
  s.ioc.restart();
  s.ioc.run_for(std::chrono::seconds(1));
  for (auto& c : s.canvases) c->stop();
  log_event(LogLevel::info, "stopped", {});
  {
    std::lock_guard lock(s.stop_mutex);
    s.stop_done = true;
  }
  s.stop_cv.notify_all();
}

std::chrono::milliseconds Server::drain(std::chrono::milliseconds timeout) {
  State& s = *state_;
  const auto t0 = std::chrono::steady_clock::now();
  const auto deadline = t0 + timeout;
  log_event(LogLevel::info, "draining", {{"timeout_ms", static_cast<long>(timeout.count())}});
  if (s.acceptor) {
    net::post(s.ioc, [st = state_] {
      beast::error_code ec;
      st->acceptor->close(ec);
    });
  }
  // Stopping a canvas finishes (or fails) its strokes in flight and joins its threads; a stroke
  // submitted from then on is refused at once, so every stroke read gets an answer.
  std::atomic<bool> canvases_stopped{false};
  std::thread stopper([&s, &canvases_stopped] {
    for (auto& c : s.canvases) c->stop();
    canvases_stopped = true;
  });
  auto last_in = s.metrics.messages_in.value();
  auto quiet_since = std::chrono::steady_clock::now();
  while (std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    const auto now = std::chrono::steady_clock::now();
    if (const auto in = s.metrics.messages_in.value(); in != last_in) {
      last_in = in;
      quiet_since = now;
    }
    if (canvases_stopped && s.control_queued.load() == 0 &&
        now - quiet_since >= std::chrono::milliseconds(300))
      break;
  }
  stop();
  stopper.join();
  const auto took = std::chrono::duration_cast<std::chrono::milliseconds>(
      std::chrono::steady_clock::now() - t0);
  log_event(LogLevel::info, "drained",
            {{"ms", static_cast<long>(took.count())},
             {"timed_out", took >= timeout ? "true" : "false"}});
  return took;
}

Result<void> Server::reload_tokens(const TokenTable& tokens) {
  if (!state_->config.tokens)
    return make_error(Errc::refused, "the server was started without --tokens");
  state_->config.tokens->replace(tokens);
  return {};
}

void Server::wait() {
  std::unique_lock lock(state_->stop_mutex);
  state_->stop_cv.wait(lock, [&] { return state_->stop_done; });
}

std::uint16_t Server::port() const noexcept {
  return state_->port.load();
}

server_core::CanvasService* Server::canvas(std::string_view name) const noexcept {
  return state_->canvas(name);
}

const ServerMetrics& Server::metrics() const noexcept {
  return state_->metrics;
}

std::string Server::metrics_text() const {
  return state_->metrics_text();
}

std::string Server::State::metrics_text() const {
  server_core::PrometheusWriter w;
  const ServerMetrics& m = metrics;
  w.counter("deepcanvas_connections_total", "TCP connections accepted.", "", m.connections.value());
  w.counter("deepcanvas_connections_refused_total",
            "Connections closed at accept: a pre-authentication cap was reached.", "",
            m.connections_refused.value());
  w.counter("deepcanvas_connections_evicted_total",
            "Unauthenticated connections closed to admit a new one at the total cap.", "",
            m.connections_evicted.value());
  w.counter("deepcanvas_accept_errors_total", "accept() failures (e.g. out of file descriptors).",
            "", m.accept_errors.value());
  w.counter("deepcanvas_http_requests_total", "Plain HTTP requests answered.", "",
            m.http_requests.value());
  w.counter("deepcanvas_sessions_opened_total", "WebSocket sessions whose hello was accepted.", "",
            m.sessions_opened.value());
  w.counter("deepcanvas_sessions_refused_total", "Hellos refused (auth, version, canvas).", "",
            m.sessions_refused.value());
  w.counter("deepcanvas_messages_in_total", "Control messages received.", "",
            m.messages_in.value());
  w.counter("deepcanvas_errors_sent_total", "Error messages sent to clients.", "",
            m.errors_sent.value());
  w.counter("deepcanvas_block_frames_sent_total",
            "Binary messages written to clients: block frames and frame bundles.", "",
            m.frames_sent.value());
  w.counter("deepcanvas_block_bytes_sent_total",
            "Bytes of block frames and frame bundles written to clients.", "",
            m.frame_bytes_sent.value());
  w.counter("deepcanvas_block_raw_bytes_sent_total",
            "Raw payload bytes of the block frames queued to clients (for the wire ratio).", "",
            m.frame_raw_bytes_sent.value());
  w.counter("deepcanvas_delta_frames_sent_total", "Temporal delta block frames queued to clients.",
            "", m.delta_frames_sent.value());
  w.counter("deepcanvas_control_bytes_sent_total", "Control message bytes written to clients.", "",
            m.control_bytes_sent.value());
  w.counter("deepcanvas_batches_sent_total", "Epoch batches (frames + epoch_end) written.", "",
            m.batches_sent.value());
  w.counter("deepcanvas_presence_published_total",
            "Presence updates published by painters (after the 50 ms interval; gone included).", "",
            m.presence_published.value());
  w.counter("deepcanvas_presence_held_total",
            "Painters' presences replaced by a newer one within the 50 ms interval.", "",
            m.presence_held.value());
  w.counter("deepcanvas_presence_coalesced_total",
            "Presence updates replaced or dropped before a slow reader took them.", "",
            m.presence_coalesced.value());
  w.counter("deepcanvas_presence_sent_total", "Presence updates queued to clients.", "",
            m.presence_sent.value());
  w.gauge("deepcanvas_sessions", "Open WebSocket sessions.", "",
          static_cast<double>(m.sessions.value()));
  w.gauge("deepcanvas_unauthenticated_connections",
          "Connections whose hello has not been accepted (yet), plain HTTP ones included.", "",
          static_cast<double>(m.unauthenticated.value()));
  w.gauge("deepcanvas_fanout_waiting_sessions",
          "Sessions waiting for a free batch take on the network threads (fanout gate).", "",
          static_cast<double>(fanout ? fanout->waiting() : 0));
  w.gauge("deepcanvas_send_queue_frames", "Block frames queued for writing in all sessions.", "",
          static_cast<double>(m.send_queue_frames.value()));
  w.histogram("deepcanvas_stroke_to_first_block_seconds",
              "Stroke read from the network to the first block frame of it written.", "",
              m.stroke_to_first_block_seconds);
  w.histogram("deepcanvas_stroke_to_take_seconds",
              "Stroke read from the network to the session taking the batch with its first blocks.",
              "", m.stroke_to_take_seconds);
  w.histogram("deepcanvas_batch_write_seconds", "An epoch batch queued to its epoch_end written.",
              "", m.batch_write_seconds);
  w.histogram("deepcanvas_answer_wait_seconds",
              "A stroke's answer (ack or error) given by the canvas to its session's network "
              "thread running it.",
              "", m.answer_wait_seconds);
  for (const auto& c : canvases) c->write_metrics(w);
  return w.text();
}

}  // namespace deepcanvas::server_net
