// WsSession: one client's WebSocket connection. Everything here runs on the connection's strand.
//
// Reading: frames are read in chunks so that an oversized message is detected after at most
// max_frame_bytes + one chunk, answered with a limit_exceeded error and a close (1009), without
// buffering the rest. Writing: one write at a time from a deque holding control messages and at
// most one epoch batch (block frames then its epoch_end); the next batch is taken from the
// subscription only when the previous epoch_end has been written, so a slow reader's backlog
// stays in the subscription as a coalescing set of block ids.
#include <variant>

#include "deepcanvas/server_core/log.hpp"
#include "net_impl.hpp"

namespace deepcanvas::server_net {

using server_core::Clock;
using server_core::log_event;
using server_core::LogLevel;

class WsSession : public std::enable_shared_from_this<WsSession> {
 public:
  WsSession(beast::tcp_stream stream, std::shared_ptr<Server::State> state, std::uint64_t id)
      : ws_(std::move(stream)),
        state_(std::move(state)),
        id_(id),
        limiter_(state_->config.limits.max_strokes_per_second,
                 std::max<double>(1.0, state_->config.limits.max_strokes_per_second)),
        hello_timer_(ws_.get_executor()) {}

  ~WsSession() { finish(); }

  void run(http::request<http::string_body> req) {
    remote_ = endpoint_string();
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws_.set_option(websocket::stream_base::decorator(
        [](websocket::response_type& res) { res.set(http::field::server, "deepcanvas-server"); }));
    // Size limits are enforced in on_read (chunked), so that the client gets a JSON error.
    ws_.read_message_max(0);
    ws_.async_accept(req, beast::bind_front_handler(&WsSession::on_accept, shared_from_this()));
  }

  void close_from_server() {
    net::dispatch(ws_.get_executor(), [self = shared_from_this()] {
      if (self->phase_ == Phase::closed || self->close_started_) return;
      self->phase_ = Phase::closing;
      self->start_close(websocket::close_code::going_away);
    });
  }

 private:
  enum class Phase { hello, open, closing, closed };

  struct Out {
    std::shared_ptr<const std::string> text;  // control message, or
    server_core::FramePtr frame;              // block frame
    bool batch_end = false;                   // the epoch_end closing a batch
    bool close_after = false;                 // a fatal error: close once written
    bool counted = false;                     // counts against max_control_queue
    websocket::close_code close_code = websocket::close_code::policy_error;
  };

  std::string endpoint_string() {
    beast::error_code ec;
    const auto ep = beast::get_lowest_layer(ws_).socket().remote_endpoint(ec);
    if (ec) return "?";
    return ep.address().to_string() + ":" + std::to_string(ep.port());
  }

  void on_accept(beast::error_code ec) {
    if (ec) {
      log_event(LogLevel::debug, "ws_accept_failed", {{"session", id_}, {"error", ec.message()}});
      return finish();
    }
    hello_timer_.expires_after(std::chrono::seconds(10));
    hello_timer_.async_wait([self = shared_from_this()](beast::error_code tec) {
      if (tec || self->phase_ != Phase::hello) return;
      self->send_error(make_error(Errc::refused, "no hello within 10 s"), {}, true);
    });
    do_read();
  }

  // ---------------------------------------------------------------- reading

  void do_read() {
    if (phase_ == Phase::closing || phase_ == Phase::closed) return;
    ws_.async_read_some(rbuf_, state_->config.read_chunk_bytes,
                        beast::bind_front_handler(&WsSession::on_read, shared_from_this()));
  }

  void on_read(beast::error_code ec, std::size_t) {
    if (ec) {
      if (ec != websocket::error::closed && ec != net::error::operation_aborted)
        log_event(LogLevel::debug, "ws_read_ended", {{"session", id_}, {"error", ec.message()}});
      return finish();
    }
    if (phase_ == Phase::closing || phase_ == Phase::closed) return;
    const std::uint64_t max = state_->config.limits.max_frame_bytes;
    if (rbuf_.size() > max) {
      rbuf_.consume(rbuf_.size());
      send_error(make_error(Errc::limit_exceeded,
                            "message larger than max_frame_bytes (" + std::to_string(max) + ")"),
                 {}, true, websocket::close_code::too_big);
      return;
    }
    if (!ws_.is_message_done()) return do_read();
    const bool text = ws_.got_text();
    const auto data = rbuf_.cdata();
    const std::string_view msg(static_cast<const char*>(data.data()), data.size());
    handle_message(text, msg);
    rbuf_.consume(rbuf_.size());
    do_read();
  }

  protocol::DecodeOptions decode_options() const {
    protocol::DecodeOptions o;
    o.max_bytes = state_->config.limits.max_frame_bytes;
    if (canvas_) {
      const protocol::StrokeRules rules = canvas_->stroke_rules();
      o.bounds = rules.bounds;
      o.stroke_limits = rules.limits;
    } else {
      o.stroke_limits.max_samples = state_->config.limits.max_samples_per_stroke;
    }
    return o;
  }

  void handle_message(bool text, std::string_view msg) {
    state_->metrics.messages_in.add();
    const bool in_hello = phase_ == Phase::hello;
    if (!text) {
      send_error(make_error(Errc::malformed,
                            "binary frames are not accepted from clients: control messages are "
                            "JSON text frames"),
                 {}, in_hello);
      return;
    }
    protocol::MessageRef about;
    auto decoded = protocol::decode_message(msg, decode_options(), &about);
    if (!decoded) {
      if (in_hello) state_->metrics.sessions_refused.add();
      send_error(decoded.error(), about, in_hello);
      return;
    }
    if (in_hello) {
      if (auto* h = std::get_if<protocol::Hello>(&*decoded)) return on_hello(*h);
      state_->metrics.sessions_refused.add();
      send_error(make_error(Errc::malformed, "the first message must be a hello"), about, true);
      return;
    }
    std::visit(
        [&](auto& m) {
          using T = std::decay_t<decltype(m)>;
          if constexpr (std::is_same_v<T, protocol::DecodedStroke>)
            on_stroke(m);
          else if constexpr (std::is_same_v<T, protocol::DecodedStrokeBegin>)
            on_begin(m);
          else if constexpr (std::is_same_v<T, protocol::DecodedStrokeSamples>)
            on_samples(m);
          else if constexpr (std::is_same_v<T, protocol::StrokeEnd>)
            on_end(m);
          else if constexpr (std::is_same_v<T, protocol::PickUp>)
            on_pick_up(m);
          else if constexpr (std::is_same_v<T, protocol::StatsRequest>)
            on_stats();
          else if constexpr (std::is_same_v<T, protocol::Hello>)
            send_error(make_error(Errc::refused, "hello was already accepted on this connection"),
                       about, false);
          else
            send_error(
                make_error(Errc::malformed, "'" + about.type + "' is a server-to-client message"),
                about, false);
        },
        *decoded);
  }

  void on_hello(const protocol::Hello& h) {
    hello_timer_.cancel();
    if (h.protocol_version != protocol::kProtocolVersion) {
      state_->metrics.sessions_refused.add();
      return send_error(
          make_error(Errc::unsupported, "protocol version " + std::to_string(h.protocol_version) +
                                            " is not supported; this server speaks " +
                                            std::to_string(protocol::kProtocolVersion)),
          {"hello", {}}, true);
    }
    server_core::CanvasService* canvas = state_->canvas(h.canvas);
    if (!canvas) {
      state_->metrics.sessions_refused.add();
      return send_error(make_error(Errc::not_found, "no canvas named '" + h.canvas + "'"),
                        {"hello", {}}, true);
    }
    protocol::Role granted = h.role;
    if (state_->config.tokens) {
      auto r = state_->config.tokens->authorize(h.canvas, h.token, h.role);
      if (!r) {
        state_->metrics.sessions_refused.add();
        log_event(LogLevel::info, "hello_refused",
                  {{"session", id_},
                   {"remote", remote_},
                   {"canvas", h.canvas},
                   {"role", protocol::role_name(h.role)},
                   {"reason", r.error().message}});
        return send_error(r.error(), {"hello", {}}, true);
      }
      granted = *r;
    }
    canvas_ = canvas;
    role_ = granted;
    phase_ = Phase::open;
    state_->metrics.sessions_opened.add();
    protocol::Welcome w;
    w.role = granted;
    w.canvas = canvas->name();
    w.geometry = canvas->geometry();
    w.block_cells = canvas->config().octree.block_cells;
    w.texture_width = canvas->config().texture_width;
    w.epoch = canvas->published_epoch();
    w.limits = state_->config.limits;
    send_control(w);
    // A client that asked for no block frames (hello "block_frames": false, a painter that
    // only paints) gets no subscription: nothing is queued or sent for it.
    std::weak_ptr<WsSession> weak = weak_from_this();
    if (h.block_frames)
      sub_ = canvas->subscribe(
          [weak] {
            auto self = weak.lock();
            if (!self || self->flush_posted_.exchange(true)) return;
            net::post(self->ws_.get_executor(), [self] {
              self->flush_posted_ = false;
              self->maybe_flush();
            });
          },
          h.delta_frames);
    log_event(LogLevel::info, "session_open",
              {{"session", id_},
               {"remote", remote_},
               {"canvas", canvas->name()},
               {"role", protocol::role_name(granted)},
               {"delta_frames", h.delta_frames ? "true" : "false"},
               {"block_frames", h.block_frames ? "true" : "false"},
               {"client", h.client_name}});
  }

  bool may_paint(std::string_view type, std::uint64_t handle) {
    if (role_ != protocol::Role::painter) {
      send_error(make_error(Errc::unauthorized, "viewers may not paint"),
                 {std::string(type), handle}, false);
      return false;
    }
    return true;
  }

  bool within_rate(std::string_view type, std::uint64_t handle) {
    if (limiter_.try_take(Clock::now())) return true;
    send_error(
        make_error(Errc::limit_exceeded,
                   "more than " + std::to_string(state_->config.limits.max_strokes_per_second) +
                       " strokes per second"),
        {std::string(type), handle}, false);
    return false;
  }

  server_core::AckFn ack_fn(std::uint64_t handle) {
    std::weak_ptr<WsSession> weak = weak_from_this();
    return [weak, handle](Result<server_core::StrokeDone> r) {
      auto self = weak.lock();
      if (!self) return;
      net::post(self->ws_.get_executor(), [self, handle, r = std::move(r)] {
        if (self->phase_ != Phase::open) return;
        if (r) {
          self->send_control(protocol::Ack{handle, r->stroke_id, r->epoch});
        } else {
          self->send_error(r.error(), {"stroke", handle}, false);
        }
      });
    };
  }

  void on_stroke(protocol::DecodedStroke& m) {
    if (!may_paint("stroke", m.handle) || !within_rate("stroke", m.handle)) return;
    auto r = canvas_->submit_stroke(std::move(m.stroke), Clock::now(), ack_fn(m.handle));
    if (!r) send_error(r.error(), {"stroke", m.handle}, false);
  }

  void on_begin(protocol::DecodedStrokeBegin& m) {
    if (!may_paint("stroke_begin", m.handle)) return;
    if (open_.count(m.handle))
      return send_error(
          make_error(Errc::invalid_argument,
                     "stroke handle " + std::to_string(m.handle) + " is already open"),
          {"stroke_begin", m.handle}, false);
    if (open_.size() >= state_->config.limits.max_open_strokes)
      return send_error(
          make_error(Errc::limit_exceeded,
                     "more than " + std::to_string(state_->config.limits.max_open_strokes) +
                         " streamed strokes open at once"),
          {"stroke_begin", m.handle}, false);
    if (!within_rate("stroke_begin", m.handle)) return;
    const std::size_t n = m.samples.size();
    auto key = canvas_->begin_stroke(m.brush, std::move(m.samples), Clock::now(), ack_fn(m.handle));
    if (!key) return send_error(key.error(), {"stroke_begin", m.handle}, false);
    open_[m.handle] = OpenStroke{*key, n};
  }

  void on_samples(protocol::DecodedStrokeSamples& m) {
    auto it = open_.find(m.handle);
    if (it == open_.end())
      return send_error(
          make_error(Errc::not_found, "no open stroke with handle " + std::to_string(m.handle)),
          {"stroke_samples", m.handle}, false);
    const std::size_t max = state_->config.limits.max_samples_per_stroke;
    if (it->second.samples + m.samples.size() > max) {
      // These samples are dropped and the stroke ends with what it has.
      const std::uint64_t key = it->second.key;
      open_.erase(it);
      (void)canvas_->end_stroke(key);
      return send_error(make_error(Errc::limit_exceeded,
                                   "stroke longer than " + std::to_string(max) +
                                       " samples: these samples were dropped and the stroke "
                                       "ended"),
                        {"stroke_samples", m.handle}, false);
    }
    it->second.samples += m.samples.size();
    auto r = canvas_->add_samples(it->second.key, std::move(m.samples));
    if (!r) send_error(r.error(), {"stroke_samples", m.handle}, false);
  }

  void on_end(const protocol::StrokeEnd& m) {
    auto it = open_.find(m.handle);
    if (it == open_.end())
      return send_error(
          make_error(Errc::not_found, "no open stroke with handle " + std::to_string(m.handle)),
          {"stroke_end", m.handle}, false);
    const std::uint64_t key = it->second.key;
    open_.erase(it);
    auto r = canvas_->end_stroke(key);
    if (!r) send_error(r.error(), {"stroke_end", m.handle}, false);
  }

  void on_pick_up(const protocol::PickUp& m) {
    std::weak_ptr<WsSession> weak = weak_from_this();
    const std::uint64_t rid = m.request_id;
    auto r = canvas_->pick_up(m, [weak, rid](Result<protocol::PickUpReply> reply) {
      auto self = weak.lock();
      if (!self) return;
      net::post(self->ws_.get_executor(), [self, rid, reply = std::move(reply)] {
        if (self->phase_ != Phase::open) return;
        if (reply)
          self->send_control(*reply);
        else
          self->send_error(reply.error(), {"pick_up", rid}, false);
      });
    });
    if (!r) send_error(r.error(), {"pick_up", rid}, false);
  }

  void on_stats() {
    protocol::Stats s;
    s.epoch = canvas_->published_epoch();
    s.strokes = canvas_->metrics().strokes.value();
    s.live_cells = static_cast<std::uint64_t>(canvas_->metrics().live_cells.value());
    s.clients = static_cast<std::uint64_t>(canvas_->metrics().subscribers.value());
    s.blocks_sent = blocks_sent_;
    s.bytes_sent = bytes_sent_;
    s.queue_blocks = queued_frames_ + (sub_ ? sub_->pending_blocks() : 0);
    send_control(s);
  }

  // ---------------------------------------------------------------- writing

  void send_control(const protocol::Message& m, bool close_after = false,
                    websocket::close_code code = websocket::close_code::policy_error) {
    if (phase_ == Phase::closed || close_started_) return;
    if (queued_control_ >= state_->config.max_control_queue && !close_after) {
      // The client keeps asking but does not read the answers.
      return send_error(
          make_error(Errc::limit_exceeded, "too many unread replies: the client does not read"), {},
          true);
    }
    Out o;
    o.text = std::make_shared<const std::string>(protocol::encode_message(m));
    o.close_after = close_after;
    o.close_code = code;
    o.counted = true;
    ++queued_control_;
    out_.push_back(std::move(o));
    do_write();
  }

  void send_error(const Error& e, const protocol::MessageRef& about, bool fatal,
                  websocket::close_code code = websocket::close_code::policy_error) {
    state_->metrics.errors_sent.add();
    log_event(fatal ? LogLevel::info : LogLevel::debug, "client_error",
              {{"session", id_},
               {"remote", remote_},
               {"code", errc_name(e.code)},
               {"in_reply_to", about.type},
               {"fatal", fatal ? "true" : "false"},
               {"message", e.message}});
    if (fatal) {
      if (phase_ == Phase::closing || phase_ == Phase::closed) return;
      phase_ = Phase::closing;
    }
    send_control(protocol::to_error_message(e, about, fatal), fatal, code);
  }

  void maybe_flush() {
    if (phase_ != Phase::open || batch_in_flight_ || !sub_) return;
    auto batch = sub_->take();
    if (!batch) return;
    for (auto& f : batch->frames) {
      Out o;
      o.frame = std::move(f);
      out_.push_back(std::move(o));
    }
    const auto n = static_cast<std::uint32_t>(batch->frames.size());
    state_->metrics.frame_raw_bytes_sent.add(batch->raw_bytes);
    state_->metrics.delta_frames_sent.add(batch->delta_frames);
    queued_frames_ += n;
    state_->metrics.send_queue_frames.add(n);
    protocol::EpochEnd end;
    end.epoch = batch->epoch;
    end.blocks = n;
    end.caught_up = batch->epoch == canvas_->published_epoch();
    Out o;
    o.text = std::make_shared<const std::string>(protocol::encode_message(end));
    o.batch_end = true;
    out_.push_back(std::move(o));
    batch_in_flight_ = true;
    batch_queued_at_ = Clock::now();
    receipts_ = std::move(batch->stroke_receipts);
    for (const auto& t : receipts_)
      state_->metrics.stroke_to_take_seconds.observe_seconds(
          std::chrono::duration<double>(batch_queued_at_ - t).count());
    do_write();
  }

  void do_write() {
    if (writing_ || out_.empty()) return;
    writing_ = true;
    Out& o = out_.front();
    if (o.frame) {
      ws_.binary(true);
      ws_.async_write(net::buffer(*o.frame),
                      beast::bind_front_handler(&WsSession::on_write, shared_from_this()));
    } else {
      ws_.text(true);
      ws_.async_write(net::buffer(*o.text),
                      beast::bind_front_handler(&WsSession::on_write, shared_from_this()));
    }
  }

  void on_write(beast::error_code ec, std::size_t bytes) {
    writing_ = false;
    if (ec) {
      log_event(LogLevel::debug, "ws_write_failed", {{"session", id_}, {"error", ec.message()}});
      return finish();
    }
    Out o = std::move(out_.front());
    out_.pop_front();
    if (o.frame) {
      --queued_frames_;
      state_->metrics.send_queue_frames.add(-1);
      state_->metrics.frames_sent.add();
      state_->metrics.frame_bytes_sent.add(bytes);
      ++blocks_sent_;
      bytes_sent_ += bytes;
      if (!receipts_.empty()) {
        const auto now = Clock::now();
        for (const auto& t : receipts_)
          state_->metrics.stroke_to_first_block_seconds.observe_seconds(
              std::chrono::duration<double>(now - t).count());
        receipts_.clear();
      }
    } else {
      if (o.counted) --queued_control_;
      state_->metrics.control_bytes_sent.add(bytes);
    }
    if (o.batch_end) {
      batch_in_flight_ = false;
      receipts_.clear();
      state_->metrics.batches_sent.add();
      state_->metrics.batch_write_seconds.observe_seconds(
          std::chrono::duration<double>(Clock::now() - batch_queued_at_).count());
      maybe_flush();
    }
    if (o.close_after) return start_close(o.close_code);
    do_write();
  }

  void start_close(websocket::close_code code) {
    if (close_started_) return;
    close_started_ = true;
    hello_timer_.cancel();
    ws_.async_close(code, [self = shared_from_this()](beast::error_code) { self->finish(); });
  }

  // Releases everything the session holds in shared state. Idempotent; runs on the strand or
  // from the destructor.
  void finish() {
    if (phase_ == Phase::closed) return;
    const bool was_open = phase_ == Phase::open || canvas_ != nullptr;
    phase_ = Phase::closed;
    beast::error_code ec;
    hello_timer_.cancel();
    for (auto& [h, s] : open_) (void)canvas_->end_stroke(s.key);
    open_.clear();
    sub_.reset();
    state_->metrics.send_queue_frames.add(-static_cast<std::int64_t>(queued_frames_));
    queued_frames_ = 0;
    {
      std::lock_guard lock(state_->sessions_mutex);
      state_->sessions.erase(id_);
    }
    state_->metrics.sessions.add(-1);
    if (was_open)
      log_event(LogLevel::info, "session_closed",
                {{"session", id_},
                 {"remote", remote_},
                 {"blocks_sent", blocks_sent_},
                 {"bytes_sent", bytes_sent_}});
  }

  struct OpenStroke {
    std::uint64_t key = 0;
    std::size_t samples = 0;
  };

  websocket::stream<beast::tcp_stream> ws_;
  std::shared_ptr<Server::State> state_;
  std::uint64_t id_;
  std::string remote_;
  beast::flat_buffer rbuf_;
  Phase phase_ = Phase::hello;
  bool close_started_ = false;
  server_core::CanvasService* canvas_ = nullptr;
  protocol::Role role_ = protocol::Role::viewer;
  std::shared_ptr<server_core::Subscription> sub_;
  RateLimiter limiter_;
  net::steady_timer hello_timer_;
  std::unordered_map<std::uint64_t, OpenStroke> open_;

  std::deque<Out> out_;
  bool writing_ = false;
  bool batch_in_flight_ = false;
  std::size_t queued_control_ = 0;
  std::size_t queued_frames_ = 0;
  Clock::time_point batch_queued_at_;
  std::vector<Clock::time_point> receipts_;
  std::atomic<bool> flush_posted_{false};
  std::uint64_t blocks_sent_ = 0;
  std::uint64_t bytes_sent_ = 0;
};

void start_ws_session(beast::tcp_stream stream, http::request<http::string_body> request,
                      const std::shared_ptr<Server::State>& state) {
  std::uint64_t id = 0;
  bool full = false;
  {
    std::lock_guard lock(state->sessions_mutex);
    id = state->next_session_id++;
    full = state->sessions.size() >= state->config.max_sessions;
  }
  if (full) {
    // Not even a WebSocket handshake: answer 503 and drop.
    auto res = std::make_shared<http::response<http::string_body>>(
        http::status::service_unavailable, request.version());
    res->set(http::field::content_type, "text/plain");
    res->body() = "too many sessions\n";
    res->prepare_payload();
    auto s = std::make_shared<beast::tcp_stream>(std::move(stream));
    http::async_write(*s, *res, [s, res](beast::error_code, std::size_t) {
      beast::error_code ec;
      s->socket().shutdown(tcp::socket::shutdown_both, ec);
    });
    return;
  }
  auto session = std::make_shared<WsSession>(std::move(stream), state, id);
  {
    std::lock_guard lock(state->sessions_mutex);
    state->sessions.emplace(id, session);
  }
  state->metrics.sessions.add(1);
  session->run(std::move(request));
}

void close_ws_session(const std::shared_ptr<WsSession>& session) {
  session->close_from_server();
}

}  // namespace deepcanvas::server_net
