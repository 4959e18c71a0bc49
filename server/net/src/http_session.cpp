// HttpSession: plain HTTP on the WebSocket port. GET /metrics (Prometheus text), GET /healthz;
// a WebSocket upgrade hands the connection to a WsSession. With TLS (TlsStream) the server-side
// handshake comes first, bounded by ServerConfig::hello_timeout like everything an
// unauthenticated connection does; a failed handshake (a plain ws:// client, a client that does
// not trust the certificate) just drops the connection.
#include "deepcanvas/base/log.hpp"
#include "net_impl.hpp"

namespace deepcanvas::server_net {

namespace {

template <class Stream>
class HttpSession : public std::enable_shared_from_this<HttpSession<Stream>> {
 public:
  HttpSession(Stream stream, PreAuthSlot slot, std::shared_ptr<Server::State> state)
      : stream_(std::move(stream)), state_(std::move(state)), slot_(std::move(slot)) {}

  void run() {
    // Evicted before its hello (PreAuthTable): the connection is closed on its own executor.
    slot_.on_evict([weak = this->weak_from_this()] {
      if (auto self = weak.lock())
        net::post(self->stream_.get_executor(), [self] {
          beast::error_code ec;
          beast::get_lowest_layer(self->stream_).socket().close(ec);
        });
    });
    net::dispatch(stream_.get_executor(),
                  beast::bind_front_handler(&HttpSession::start, this->shared_from_this()));
  }

 private:
  void start() {
    if constexpr (std::is_same_v<Stream, TlsStream>) {
      beast::get_lowest_layer(stream_).expires_after(state_->config.hello_timeout);
      stream_.async_handshake(
          net::ssl::stream_base::server,
          beast::bind_front_handler(&HttpSession::on_handshake, this->shared_from_this()));
    } else {
      read();
    }
  }

  void on_handshake(beast::error_code ec) {
    if (ec) {
      base::log_event(base::LogLevel::debug, "tls_handshake_failed", {{"error", ec.message()}});
      return;
    }
    read();
  }

  void read() {
    parser_.emplace();
    // Requests here are tiny; anything large is not ours.
    parser_->header_limit(16 * 1024);
    parser_->body_limit(16 * 1024);
    beast::get_lowest_layer(stream_).expires_after(std::chrono::seconds(30));
    http::async_read(stream_, buffer_, *parser_,
                     beast::bind_front_handler(&HttpSession::on_read, this->shared_from_this()));
  }

  void on_read(beast::error_code ec, std::size_t) {
    if (ec == http::error::end_of_stream) return close();
    if (ec) return;  // timeout, reset, bad request bytes: just drop the connection
    if (websocket::is_upgrade(parser_->get())) {
      beast::get_lowest_layer(stream_).expires_never();
      // The WsSession takes the stream and the request; this object ends here.
      start_ws_session(std::move(stream_), parser_->release(), std::move(slot_), state_);
      return;
    }
    state_->metrics.http_requests.add();
    const auto& req = parser_->get();
    auto res = std::make_shared<http::response<http::string_body>>();
    res->version(req.version());
    res->keep_alive(req.keep_alive());
    res->set(http::field::server, "deepcanvas-server");
    const std::string_view target(req.target().data(), req.target().size());
    if (req.method() != http::verb::get && req.method() != http::verb::head) {
      res->result(http::status::method_not_allowed);
      res->set(http::field::allow, "GET, HEAD");
      res->set(http::field::content_type, "text/plain");
      res->body() = "method not allowed\n";
    } else if (target == "/metrics") {
      res->result(http::status::ok);
      res->set(http::field::content_type, "text/plain; version=0.0.4; charset=utf-8");
      res->body() = state_->metrics_text();
    } else if (target == "/healthz") {
      res->result(http::status::ok);
      res->set(http::field::content_type, "text/plain");
      res->body() = "ok\n";
    } else {
      res->result(http::status::not_found);
      res->set(http::field::content_type, "text/plain");
      res->body() = "not found: GET /metrics, GET /healthz, or a WebSocket upgrade\n";
    }
    res->prepare_payload();
    if (req.method() == http::verb::head) res->body().clear();
    http::async_write(stream_, *res,
                      [self = this->shared_from_this(), res](beast::error_code wec, std::size_t) {
                        if (wec) return;
                        if (!res->keep_alive()) return self->close();
                        self->read();
                      });
  }

  void close() {
    if constexpr (std::is_same_v<Stream, TlsStream>) {
      // close_notify, then the socket ends with this object (bounded: the peer may not answer).
      beast::get_lowest_layer(stream_).expires_after(std::chrono::seconds(5));
      stream_.async_shutdown([self = this->shared_from_this()](beast::error_code) {});
    } else {
      beast::error_code ec;
      stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
    }
  }

  Stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  std::shared_ptr<Server::State> state_;
  PreAuthSlot slot_;  // plain HTTP is unauthenticated too: it counts until the connection ends
};

}  // namespace

void start_http_session(tcp::socket socket, PreAuthSlot slot,
                        const std::shared_ptr<Server::State>& state) {
  if (state->tls) {
    std::make_shared<HttpSession<TlsStream>>(TlsStream(std::move(socket), *state->tls),
                                             std::move(slot), state)
        ->run();
  } else {
    std::make_shared<HttpSession<PlainStream>>(PlainStream(std::move(socket)), std::move(slot),
                                               state)
        ->run();
  }
}

}  // namespace deepcanvas::server_net
