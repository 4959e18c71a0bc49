// HttpSession: plain HTTP on the WebSocket port. GET /metrics (Prometheus text), GET /healthz;
// a WebSocket upgrade hands the connection to a WsSession.
#include "net_impl.hpp"

namespace deepcanvas::server_net {

namespace {

class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(tcp::socket socket, PreAuthSlot slot, std::shared_ptr<Server::State> state)
      : stream_(std::move(socket)), state_(std::move(state)), slot_(std::move(slot)) {}

  void run() {
    net::dispatch(stream_.get_executor(),
                  beast::bind_front_handler(&HttpSession::read, shared_from_this()));
  }

 private:
  void read() {
    parser_.emplace();
    // Requests here are tiny; anything large is not ours.
    parser_->header_limit(16 * 1024);
    parser_->body_limit(16 * 1024);
    stream_.expires_after(std::chrono::seconds(30));
    http::async_read(stream_, buffer_, *parser_,
                     beast::bind_front_handler(&HttpSession::on_read, shared_from_this()));
  }

  void on_read(beast::error_code ec, std::size_t) {
    if (ec == http::error::end_of_stream) return close();
    if (ec) return;  // timeout, reset, bad request bytes: just drop the connection
    if (websocket::is_upgrade(parser_->get())) {
      stream_.expires_never();
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
                      [self = shared_from_this(), res](beast::error_code wec, std::size_t) {
                        if (wec) return;
                        if (!res->keep_alive()) return self->close();
                        self->read();
                      });
  }

  void close() {
    beast::error_code ec;
    stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
  }

  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  std::shared_ptr<Server::State> state_;
  PreAuthSlot slot_;  // plain HTTP is unauthenticated too: it counts until the connection ends
};

}  // namespace

void start_http_session(tcp::socket socket, PreAuthSlot slot,
                        const std::shared_ptr<Server::State>& state) {
  std::make_shared<HttpSession>(std::move(socket), std::move(slot), state)->run();
}

}  // namespace deepcanvas::server_net
