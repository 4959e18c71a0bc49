#include "server_test_util.hpp"

#include <gtest/gtest.h>

#include <boost/asio.hpp>
#include <boost/beast.hpp>

#include "deepcanvas/base/log.hpp"

namespace deepcanvas::test {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;

server_core::CanvasServiceConfig small_canvas(const std::string& name) {
  server_core::CanvasServiceConfig c;
  c.name = name;
  c.octree.edge_m = 8.0;
  c.octree.max_depth = 12;
  c.octree.block_cells = 4096;
  c.octree.max_cells = 1u << 24;
  c.max_cells_per_step = 4096;  // several steps per stroke: epochs between steps get exercised
  return c;
}

TestServer start_server(std::vector<std::string> canvases, std::string tokens_text,
                        protocol::SessionLimits limits, int send_buffer_bytes,
                        const std::function<void(server_net::ServerConfig&)>& tweak) {
  if (!std::getenv("DEEPCANVAS_TEST_LOG")) base::set_log_level(base::LogLevel::warn);
  server_net::ServerConfig cfg;
  cfg.listen_address = "127.0.0.1";
  cfg.port = 0;
  cfg.limits = limits;
  cfg.socket_send_buffer_bytes = send_buffer_bytes;
  for (const auto& n : canvases) cfg.canvases.push_back(small_canvas(n));
  if (!tokens_text.empty()) {
    auto t = server_net::TokenTable::parse(tokens_text);
    if (!t) {
      ADD_FAILURE() << t.error().message;
      return {};
    }
    cfg.tokens = std::move(*t);
  }
  if (tweak) tweak(cfg);
  TestServer s;
  auto server = server_net::Server::create(std::move(cfg));
  if (!server) {
    ADD_FAILURE() << server.error().message;
    return {};
  }
  if (auto r = (*server)->start(); !r) {
    ADD_FAILURE() << r.error().message;
    return {};
  }
  s.server = std::move(*server);
  s.url = "ws://127.0.0.1:" + std::to_string(s.server->port()) + "/";
  return s;
}

client_core::ClientOptions client_options(const TestServer& s, const std::string& canvas,
                                          protocol::Role role, const std::string& token) {
  client_core::ClientOptions o;
  o.url = s.url;
  o.canvas = canvas;
  o.role = role;
  o.token = token;
  return o;
}

protocol::Stroke random_stroke(std::mt19937_64& rng, int n, protocol::BrushMode mode) {
  std::uniform_real_distribution<double> pos(-1.0, 1.0), step(-0.08, 0.08);
  std::uniform_real_distribution<float> rad(0.02f, 0.12f), col(0.0f, 1.0f);
  protocol::Stroke s;
  s.brush.mode = mode;
  s.brush.colour[0] = col(rng);
  s.brush.colour[1] = col(rng);
  s.brush.colour[2] = col(rng);
  s.brush.colour[3] = 0.5f + col(rng) / 2;
  s.brush.opacity = 0.5f + col(rng) / 2;
  s.brush.hardness = col(rng);
  double x = pos(rng), y = pos(rng), z = pos(rng);
  for (int i = 0; i < n; ++i) {
    protocol::StrokeSample p;
    p.x = x;
    p.y = y;
    p.z = z;
    p.radius = rad(rng);
    p.pressure = 0.5f + col(rng) / 2;
    p.t_ms = static_cast<std::uint32_t>(i * 10);
    s.samples.push_back(p);
    x += step(rng);
    y += step(rng);
    z += step(rng);
  }
  return s;
}

server_core::CanvasService::Quiescent expect_converged(server_core::CanvasService& canvas,
                                                       std::vector<client_core::Client*> clients,
                                                       std::chrono::milliseconds timeout) {
  auto q = canvas.quiesce(timeout);
  EXPECT_TRUE(q.ok()) << (q ? "" : q.error().message);
  if (!q) return {};
  for (std::size_t i = 0; i < clients.size(); ++i) {
    auto e = clients[i]->wait_for_epoch(q->epoch, timeout);
    EXPECT_TRUE(e.ok()) << "client " << i << ": " << (e ? "" : e.error().message);
    EXPECT_EQ(clients[i]->pool_hash(), q->pool_hash) << "client " << i << " pools differ";
    EXPECT_EQ(clients[i]->links_hash(), q->links_hash) << "client " << i << " links differ";
  }
  return *q;
}

// ---------------------------------------------------------------------------------- RawWs

struct RawWs::Impl {
  net::io_context ioc;
  websocket::stream<beast::tcp_stream> ws{ioc};
  beast::flat_buffer buf;
  bool ended = false;
  int close_code = 0;

  // Runs one async operation to completion or timeout.
  template <class Start>
  beast::error_code run(Start start, std::chrono::milliseconds timeout) {
    beast::error_code result = net::error::timed_out;
    bool done = false;
    start([&](beast::error_code ec, std::size_t = 0) {
      result = ec;
      done = true;
    });
    ioc.restart();
    ioc.run_for(timeout);
    if (!done) {
      beast::get_lowest_layer(ws).cancel();
      ioc.restart();
      ioc.run_for(std::chrono::seconds(1));
    }
    return result;
  }
};

std::unique_ptr<RawWs> RawWs::connect(const TestServer& s, const std::string& from,
                                      int* refused_status, int receive_buffer_bytes) {
  auto r = std::unique_ptr<RawWs>(new RawWs());
  r->impl_ = std::make_unique<Impl>();
  beast::error_code ec;
  auto& sock = beast::get_lowest_layer(r->impl_->ws).socket();
  if (!from.empty() || receive_buffer_bytes > 0) {
    sock.open(tcp::v4(), ec);
    if (!ec && !from.empty()) sock.bind(tcp::endpoint(net::ip::make_address(from), 0), ec);
    if (!ec && receive_buffer_bytes > 0)
      sock.set_option(net::socket_base::receive_buffer_size(receive_buffer_bytes), ec);
    if (ec) return nullptr;
  }
  sock.connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), s.server->port()), ec);
  if (ec) return nullptr;
  websocket::response_type res;
  beast::get_lowest_layer(r->impl_->ws).expires_after(std::chrono::seconds(10));
  r->impl_->ws.handshake(res, "127.0.0.1", "/", ec);
  beast::get_lowest_layer(r->impl_->ws).expires_never();
  if (ec) {
    if (refused_status) *refused_status = static_cast<int>(res.result_int());
    return nullptr;
  }
  r->impl_->ws.read_message_max(64u << 20);
  return r;
}

RawWs::~RawWs() {
  beast::error_code ec;
  beast::get_lowest_layer(impl_->ws).socket().close(ec);
}

bool RawWs::send_text(const std::string& text) {
  impl_->ws.text(true);
  auto ec = impl_->run([&](auto h) { impl_->ws.async_write(net::buffer(text), h); },
                       std::chrono::seconds(10));
  return !ec;
}

bool RawWs::send_partial(const std::string& text) {
  impl_->ws.text(true);
  auto ec = impl_->run(
      [&](auto h) { impl_->ws.async_write_some(false, net::buffer(text), h); },
      std::chrono::seconds(10));
  return !ec;
}

bool RawWs::send_fragmented(const std::string& text, std::size_t piece) {
  impl_->ws.text(true);
  for (std::size_t at = 0; at < text.size(); at += piece) {
    const std::size_t n = std::min(piece, text.size() - at);
    const bool last = at + n == text.size();
    auto ec = impl_->run(
        [&](auto h) { impl_->ws.async_write_some(last, net::buffer(text.data() + at, n), h); },
        std::chrono::seconds(10));
    if (ec) return false;
    if (!last) {
      ec = impl_->run([&](auto h) { impl_->ws.async_ping({}, h); }, std::chrono::seconds(10));
      if (ec) return false;
    }
  }
  return true;
}

bool RawWs::send_binary(const std::vector<std::uint8_t>& bytes) {
  impl_->ws.binary(true);
  auto ec = impl_->run([&](auto h) { impl_->ws.async_write(net::buffer(bytes), h); },
                       std::chrono::seconds(10));
  return !ec;
}

std::optional<RawWs::Message> RawWs::read_message(std::chrono::milliseconds timeout) {
  if (impl_->ended) return std::nullopt;
  impl_->buf.consume(impl_->buf.size());
  auto ec = impl_->run([&](auto h) { impl_->ws.async_read(impl_->buf, h); }, timeout);
  if (ec) {
    impl_->ended = true;
    if (ec == websocket::error::closed) impl_->close_code = impl_->ws.reason().code;
    return std::nullopt;
  }
  return Message{impl_->ws.got_text(), beast::buffers_to_string(impl_->buf.data())};
}

std::optional<std::string> RawWs::read_text(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!impl_->ended && std::chrono::steady_clock::now() < deadline) {
    auto m = read_message(std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now()));
    if (m && m->text) return std::move(m->data);
  }
  return std::nullopt;
}

int RawWs::read_until_closed(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!impl_->ended && std::chrono::steady_clock::now() < deadline) read_text(timeout);
  return impl_->close_code;
}

std::pair<int, std::string> http_get(const TestServer& s, const std::string& target) {
  net::io_context ioc;
  beast::tcp_stream stream(ioc);
  beast::error_code ec;
  stream.connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), s.server->port()), ec);
  if (ec) return {0, ec.message()};
  http::request<http::empty_body> req{http::verb::get, target, 11};
  req.set(http::field::host, "127.0.0.1");
  http::write(stream, req, ec);
  if (ec) return {0, ec.message()};
  beast::flat_buffer buf;
  http::response<http::string_body> res;
  http::read(stream, buf, res, ec);
  if (ec) return {0, ec.message()};
  return {static_cast<int>(res.result_int()), res.body()};
}

}  // namespace deepcanvas::test
