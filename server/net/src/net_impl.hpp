// Private types of server_net: the shared server state, the listener and the two session kinds
// (HttpSession, and WsSession: the WebSocket transport of a SessionHandler).
#pragma once

#include <atomic>
#include <boost/asio.hpp>
#include <boost/beast.hpp>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "deepcanvas/server_net/server.hpp"

namespace deepcanvas::server_net {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;

class WsSession;

struct Server::State {
  ServerConfig config;
  std::vector<std::unique_ptr<server_core::CanvasService>> canvases;
  ServerMetrics metrics;
  net::io_context ioc;
  std::unique_ptr<tcp::acceptor> acceptor;
  std::vector<std::thread> threads;
  std::atomic<std::uint16_t> port{0};

  std::mutex sessions_mutex;
  std::unordered_map<std::uint64_t, std::weak_ptr<WsSession>> sessions;
  std::uint64_t next_session_id = 1;

  std::mutex stop_mutex;
  std::condition_variable stop_cv;
  bool started = false;
  bool stop_begun = false;
  bool stop_done = false;

  server_core::CanvasService* canvas(std::string_view name) const noexcept;
  std::string metrics_text() const;
};

// Starts the accept loop on the state's acceptor.
void start_listener(const std::shared_ptr<Server::State>& state);
// Takes over an accepted socket: reads HTTP requests, upgrades WebSockets.
void start_http_session(tcp::socket socket, const std::shared_ptr<Server::State>& state);
// Takes over an upgraded connection.
void start_ws_session(beast::tcp_stream stream, http::request<http::string_body> request,
                      const std::shared_ptr<Server::State>& state);
// Asks a session to close (posted to its strand).
void close_ws_session(const std::shared_ptr<WsSession>& session);

}  // namespace deepcanvas::server_net
