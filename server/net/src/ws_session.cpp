// WsSession: one client's WebSocket connection, the transport only (as the Boost.Beast examples'
// websocket_session): the stream, the strand, the read loop, the hello timer and one bounded
// write queue. What the messages mean is the SessionHandler's (session_handler.hpp); this file
// tells it what was read and writes what it asks for. Everything here runs on the connection's
// strand.
//
// Reading: Beast sees the client's text frames as binary (TextFrameDeferral), so that invalid
// UTF-8 reaches the handler, which answers it with a `malformed` error before closing 1007.
// Frames are read in chunks no larger than what the limit still allows, so an oversized
// message is detected after at most its limit + 1 bytes and refused without buffering the rest.
// The limit is ServerConfig::pre_auth_frame_bytes until a hello is accepted, then
// SessionLimits::max_frame_bytes.
// Deadlines (transport matters, so enforced here): a hello within ServerConfig::hello_timeout of
// the upgrade, and the end of a started message within message_timeout. Until its hello is
// accepted the session holds a place in the server's pre-authentication caps (PreAuthSlot).
// The stream is a plain TCP stream or a TLS stream over one (WsSession is a template over it);
// with TLS the handshake was done by the HttpSession before the upgrade request was read.
// Writing: one write at a time, from two queues: control messages (replies, errors, presence
// updates, the close) and at most one epoch batch (its frames and its epoch_end; the handler
// takes the next batch only once the previous epoch_end has been written). A control message
// goes out before the batch's frames still queued: an ack or a pick-up reply does not wait for a
// batch, which on a thin link or at a join (a whole canvas) can take seconds; PROTOCOL.md 2.1
// item 4 leaves control messages unordered with the batches. Control messages are bounded by
// max_control_queue, presence updates by the handler (kPresenceInFlight, the rest coalesced in
// its inbox); a fatal error's last message is not.
#include <cstdio>
#include <deque>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_net/session_handler.hpp"
#include "net_impl.hpp"
#include "text_frame_deferral.hpp"

namespace deepcanvas::server_net {

namespace {

// "5", "0.25": a duration in seconds for messages.
std::string seconds_text(std::chrono::milliseconds d) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", static_cast<double>(d.count()) / 1000.0);
  return buf;
}

}  // namespace

using base::log_event;
using base::LogLevel;
using server_core::Clock;

// Stream: PlainStream or TlsStream (net_impl.hpp); instantiated for both at the end of this file.
template <class Stream>
class WsSession final : public WsSessionBase,
                        public std::enable_shared_from_this<WsSession<Stream>>,
                        private SessionOutput {
 public:
  WsSession(Stream stream, std::shared_ptr<Server::State> state, std::uint64_t id, PreAuthSlot slot)
      : ws_(TextFrameDeferral<Stream>(std::move(stream))),
        state_(std::move(state)),
        slot_(std::move(slot)),
        id_(id),
        hello_timer_(ws_.get_executor()),
        message_timer_(ws_.get_executor()),
        presence_timer_(ws_.get_executor()),
        batch_timer_(ws_.get_executor()) {}

  ~WsSession() override { finish(); }

  void run(http::request<http::string_body> req) {
    std::weak_ptr<WsSession> weak = this->weak_from_this();
    // Evicted before its hello (PreAuthTable): the connection is closed on its executor.
    slot_.on_evict([weak] {
      if (auto self = weak.lock())
        net::post(self->ws_.get_executor(), [self] {
          beast::error_code ec;
          beast::get_lowest_layer(self->ws_).socket().close(ec);
        });
    });
    Poster post = [weak](std::function<void()> fn) {
      auto self = weak.lock();
      if (!self) return;
      net::post(self->ws_.get_executor(), [self, fn = std::move(fn)] { fn(); });
    };
    SessionContext ctx;
    ctx.config = &state_->config;
    ctx.metrics = &state_->metrics;
    ctx.find_canvas = [st = state_.get()](std::string_view name) { return st->canvas(name); };
    ctx.receipts = state_->receipts.get();
    ctx.presence = &state_->presence;
    ctx.fanout = state_->fanout;
    ctx.run_import = [st = state_.get()](std::function<void()> job) {
      net::post(st->imports, std::move(job));
    };
    SessionOutput& out = *this;
    remote_ = endpoint_string();
    handler_ = std::make_unique<SessionHandler>(std::move(ctx), out, std::move(post), id_, remote_);
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws_.set_option(websocket::stream_base::decorator(
        [](websocket::response_type& res) { res.set(http::field::server, "deepcanvas-server"); }));
    // Size limits are enforced in on_read (chunked), so that the client gets a JSON error.
    ws_.read_message_max(0);
    ws_.async_accept(req,
                     beast::bind_front_handler(&WsSession::on_accept, this->shared_from_this()));
  }

  // Server shutdown: close with going_away now, without waiting for queued writes.
  void close_from_server() override {
    net::dispatch(ws_.get_executor(), [self = this->shared_from_this()] {
      if (self->finished_ || self->close_started_) return;
      if (self->handler_) self->handler_->on_shutdown();
      self->close_requested_ = true;
      self->start_close(websocket::close_code::going_away, "server shutting down");
    });
  }

 private:
  struct Out {
    std::shared_ptr<const std::string> text;  // control message, or
    server_core::FramePtr frame;              // block frame
    bool batch_end = false;                   // the epoch_end closing a batch
    bool counted = false;                     // counts against max_control_queue
    bool close_after = false;                 // the last message: close once written
    bool presence = false;                    // a presence update (bounded by the handler)
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
    hello_timer_.expires_after(state_->config.hello_timeout);
    hello_timer_.async_wait([self = this->shared_from_this()](beast::error_code tec) {
      if (tec || self->finished_ || !self->handler_->awaiting_hello()) return;
      self->fail_transport(
          Errc::refused,
          "no hello within " + seconds_text(self->state_->config.hello_timeout) + " s",
          CloseCode::policy_error);
    });
    do_read();
  }

  // A fatal error decided by the transport (a deadline, the pre-hello size): the same error
  // message and close a handler's fatal error makes. The handler is told to send nothing more.
  void fail_transport(Errc code, const std::string& message, CloseCode close_code) {
    if (close_requested_ || finished_) return;
    state_->metrics.errors_sent.add();
    if (handler_->awaiting_hello()) state_->metrics.sessions_refused.add();
    log_event(LogLevel::info, "client_error",
              {{"session", id_},
               {"remote", remote_},
               {"code", errc_name(code)},
               {"in_reply_to", ""},
               {"fatal", "true"},
               {"message", message}});
    handler_->on_shutdown();
    close(
        close_code, errc_name(code),
        protocol::encode_message(protocol::to_error_message(make_error(code, message), {}, true)));
  }

  // Arms the message deadline when a message has begun, disarms it when none is open.
  void watch_message(bool open) {
    if (!open) {
      if (message_armed_) message_timer_.cancel();
      message_armed_ = false;
      return;
    }
    if (message_armed_) return;
    message_armed_ = true;
    const std::uint64_t generation = ++message_generation_;
    message_timer_.expires_after(state_->config.message_timeout);
    message_timer_.async_wait([self = this->shared_from_this(), generation](beast::error_code tec) {
      if (tec || self->finished_ || !self->message_armed_ ||
          generation != self->message_generation_)
        return;
      self->fail_transport(Errc::limit_exceeded,
                           "message not finished within " +
                               seconds_text(self->state_->config.message_timeout) + " s",
                           CloseCode::policy_error);
    });
  }

  std::size_t frame_limit() const {
    return handler_->awaiting_hello() ? state_->config.pre_auth_frame_bytes
                                      : state_->config.limits.max_frame_bytes;
  }

  // ---------------------------------------------------------------- reading

  void do_read() {
    if (close_requested_ || finished_) return;
    // Never more than one byte past the limit in the buffer.
    const std::size_t room = frame_limit() + 1 - std::min(rbuf_.size(), frame_limit());
    ws_.async_read_some(rbuf_, std::min(state_->config.read_chunk_bytes, room),
                        beast::bind_front_handler(&WsSession::on_read, this->shared_from_this()));
  }

  void on_read(beast::error_code ec, std::size_t) {
    if (ec) {
      if (ec != websocket::error::closed && ec != net::error::operation_aborted)
        log_event(LogLevel::debug, "ws_read_ended", {{"session", id_}, {"error", ec.message()}});
      return finish();
    }
    if (close_requested_ || finished_) return;
    if (rbuf_.size() > frame_limit()) {
      rbuf_.consume(rbuf_.size());
      watch_message(false);
      if (!handler_->awaiting_hello()) return handler_->on_message_too_big();
      return fail_transport(Errc::limit_exceeded,
                            "message larger than the " +
                                std::to_string(state_->config.pre_auth_frame_bytes) +
                                " bytes allowed before hello",
                            CloseCode::too_big);
    }
    if (!ws_.is_message_done()) {
      watch_message(true);
      return do_read();
    }
    watch_message(false);
    const auto data = rbuf_.cdata();
    // got_text() is always false here: the layer below hands text frames to Beast as binary
    // (text_frame_deferral.hpp) and knows each message's real kind.
    const bool text =
        ws_.next_layer().take_message_kind() == ClientFrameScanner::MessageKind::text;
    handler_->on_message(text,
                         std::string_view(static_cast<const char*>(data.data()), data.size()));
    rbuf_.consume(rbuf_.size());
    if (!handler_->awaiting_hello() && slot_.held()) {
      // Authenticated: the full frame limit from the next read on, and no longer counted
      // against the pre-authentication caps.
      hello_timer_.cancel();
      slot_.release();
    }
    do_read();
  }

  // ---------------------------------------------------------------- SessionOutput

  bool send_text(std::string text) override {
    if (close_requested_ || finished_) return true;  // the session is ending: drop it
    if (queued_control_ >= state_->config.max_control_queue) return false;
    Out o;
    o.text = std::make_shared<const std::string>(std::move(text));
    o.counted = true;
    ++queued_control_;
    state_->control_queued.fetch_add(1);
    control_out_.push_back(std::move(o));
    do_write();
    return true;
  }

  void send_batch(OutgoingBatch batch) override {
    if (close_requested_ || finished_) return;
    const auto n = batch.frames.size();
    for (auto& f : batch.frames) {
      Out o;
      o.frame = std::move(f);
      batch_out_.push_back(std::move(o));
    }
    queued_frames_ += n;
    state_->metrics.send_queue_frames.add(static_cast<std::int64_t>(n));
    Out end;
    end.text = std::make_shared<const std::string>(std::move(batch.epoch_end));
    end.batch_end = true;
    batch_out_.push_back(std::move(end));
    batch_queued_at_ = Clock::now();
    receipts_ = std::move(batch.stroke_receipts);
    do_write();
  }

  void close(CloseCode code, std::string_view reason, std::string last_text) override {
    if (close_requested_ || finished_) return;
    close_requested_ = true;
    close_code_ = static_cast<websocket::close_code>(code);
    close_reason_ = std::string(reason.substr(0, 120));  // a close frame's reason is <= 123 bytes
    Out o;
    o.close_after = true;
    if (!last_text.empty()) o.text = std::make_shared<const std::string>(std::move(last_text));
    control_out_.push_back(std::move(o));
    do_write();
  }

  void send_presence(PresenceText text) override {
    if (close_requested_ || finished_) return;
    Out o;
    o.text = std::move(text);
    o.presence = true;
    control_out_.push_back(std::move(o));
    do_write();
  }

  void run_after(SessionTimer which, std::chrono::milliseconds delay,
                 std::function<void()> fn) override {
    if (close_requested_ || finished_) return;
    net::steady_timer& t = which == SessionTimer::batch ? batch_timer_ : presence_timer_;
    t.expires_after(delay);  // cancels a pending wait: its fn never runs
    t.async_wait([self = this->shared_from_this(), fn = std::move(fn)](beast::error_code ec) {
      if (ec || self->finished_ || self->close_requested_) return;
      fn();
    });
  }

  TransportCounters counters() const override {
    return TransportCounters{frames_sent_, frame_bytes_sent_, queued_frames_};
  }

  // ---------------------------------------------------------------- writing

  // The queue the next write comes from: control messages first (see "Writing" above).
  std::deque<Out>* next_queue() {
    if (!control_out_.empty()) return &control_out_;
    if (!batch_out_.empty()) return &batch_out_;
    return nullptr;
  }

  void do_write() {
    if (writing_ || close_started_) return;
    std::deque<Out>* q = next_queue();
    if (!q) return;
    Out& o = q->front();
    if (!o.frame && !o.text) {  // a close with no last message
      q->pop_front();
      return start_close(close_code_, close_reason_);
    }
    writing_ = true;
    writing_from_ = q;
    ws_.binary(static_cast<bool>(o.frame));
    const auto buffer = o.frame ? net::buffer(*o.frame) : net::buffer(*o.text);
    ws_.async_write(buffer,
                    beast::bind_front_handler(&WsSession::on_write, this->shared_from_this()));
  }

  void on_write(beast::error_code ec, std::size_t bytes) {
    writing_ = false;
    if (ec) {
      log_event(LogLevel::debug, "ws_write_failed", {{"session", id_}, {"error", ec.message()}});
      return finish();
    }
    Out o = std::move(writing_from_->front());
    writing_from_->pop_front();
    if (o.frame)
      count_frame_written(bytes);
    else
      count_control_written(o, bytes);
    if (o.batch_end) {
      receipts_.clear();
      state_->metrics.batches_sent.add();
      state_->metrics.batch_write_seconds.observe_seconds(
          std::chrono::duration<double>(Clock::now() - batch_queued_at_).count());
      handler_->on_batch_written();
    }
    if (o.presence) handler_->on_presence_written();
    if (o.close_after) return start_close(close_code_, close_reason_);
    do_write();
  }

  void count_frame_written(std::size_t bytes) {
    --queued_frames_;
    state_->metrics.send_queue_frames.add(-1);
    state_->metrics.frames_sent.add();
    state_->metrics.frame_bytes_sent.add(bytes);
    ++frames_sent_;
    frame_bytes_sent_ += bytes;
    if (!receipts_.empty()) {
      const auto now = Clock::now();
      for (const auto& t : receipts_)
        state_->metrics.stroke_to_first_block_seconds.observe_seconds(
            std::chrono::duration<double>(now - t).count());
      receipts_.clear();
    }
  }

  void count_control_written(const Out& o, std::size_t bytes) {
    if (o.counted) {
      --queued_control_;
      state_->control_queued.fetch_sub(1);
    }
    state_->metrics.control_bytes_sent.add(bytes);
  }

  void start_close(websocket::close_code code, const std::string& reason) {
    if (close_started_) return;
    close_started_ = true;
    hello_timer_.cancel();
    message_timer_.cancel();
    presence_timer_.cancel();
    batch_timer_.cancel();
    ws_.async_close(websocket::close_reason(code, reason),
                    [self = this->shared_from_this()](beast::error_code) { self->finish(); });
  }

  // Releases everything the session holds in shared state. Idempotent; runs on the strand or
  // from the destructor.
  void finish() {
    if (finished_) return;
    finished_ = true;
    hello_timer_.cancel();
    message_timer_.cancel();
    presence_timer_.cancel();
    batch_timer_.cancel();
    slot_.release();
    if (handler_) handler_->on_closed(counters());
    state_->metrics.send_queue_frames.add(-static_cast<std::int64_t>(queued_frames_));
    queued_frames_ = 0;
    state_->control_queued.fetch_sub(static_cast<std::int64_t>(queued_control_));
    queued_control_ = 0;
    {
      std::lock_guard lock(state_->sessions_mutex);
      state_->sessions.erase(id_);
    }
    state_->metrics.sessions.add(-1);
  }

  websocket::stream<TextFrameDeferral<Stream>> ws_;
  std::shared_ptr<Server::State> state_;
  PreAuthSlot slot_;  // held until the hello is accepted
  std::uint64_t id_;
  std::string remote_;
  beast::flat_buffer rbuf_;
  net::steady_timer hello_timer_;
  net::steady_timer message_timer_;  // a started message must end by then
  net::steady_timer presence_timer_;  // the handler's run_after: its presence interval
  net::steady_timer batch_timer_;     // and the client's least interval between batches
  bool message_armed_ = false;
  std::uint64_t message_generation_ = 0;
  bool close_requested_ = false;  // close() was asked for: read no more, queue no more
  bool close_started_ = false;    // the close handshake has begun
  bool finished_ = false;
  websocket::close_code close_code_ = websocket::close_code::policy_error;
  std::string close_reason_;

  std::deque<Out> control_out_;  // replies, errors, presence, the close
  std::deque<Out> batch_out_;    // the epoch batch's frames and its epoch_end
  bool writing_ = false;
  std::deque<Out>* writing_from_ = nullptr;  // the queue whose front is being written
  std::size_t queued_control_ = 0;
  std::uint64_t queued_frames_ = 0;
  std::uint64_t frames_sent_ = 0;
  std::uint64_t frame_bytes_sent_ = 0;
  Clock::time_point batch_queued_at_;
  std::vector<Clock::time_point> receipts_;

  // Declared last: destroyed first, while the state (and the canvases it owns) still exists.
  std::unique_ptr<SessionHandler> handler_;
};

template <class Stream>
void start_ws_session(Stream stream, http::request<http::string_body> request, PreAuthSlot slot,
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
    auto s = std::make_shared<Stream>(std::move(stream));
    http::async_write(*s, *res, [s, res](beast::error_code, std::size_t) {
      beast::error_code ec;
      beast::get_lowest_layer(*s).socket().shutdown(tcp::socket::shutdown_both, ec);
    });
    return;
  }
  auto session = std::make_shared<WsSession<Stream>>(std::move(stream), state, id, std::move(slot));
  {
    std::lock_guard lock(state->sessions_mutex);
    state->sessions.emplace(id, session);
  }
  state->metrics.sessions.add(1);
  session->run(std::move(request));
}

template void start_ws_session<PlainStream>(PlainStream, http::request<http::string_body>,
                                            PreAuthSlot, const std::shared_ptr<Server::State>&);
template void start_ws_session<TlsStream>(TlsStream, http::request<http::string_body>, PreAuthSlot,
                                          const std::shared_ptr<Server::State>&);

void close_ws_session(const std::shared_ptr<WsSessionBase>& session) {
  session->close_from_server();
}

}  // namespace deepcanvas::server_net
