// Helpers for the server tests: a server on a free loopback port, random strokes, and a raw
// WebSocket connection for hand-made (bad) input.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/protocol/stroke.hpp"
#include "deepcanvas/server_net/server.hpp"

namespace deepcanvas::test {

using namespace std::chrono_literals;

// A small canvas so that strokes adjust in few steps: 8 m edge, depth <= 12.
server_core::CanvasServiceConfig small_canvas(const std::string& name);

struct TestServer {
  std::unique_ptr<server_net::Server> server;
  std::string url;
  server_core::CanvasService* canvas(const std::string& name = "c") const {
    return server->canvas(name);
  }
};

// Starts a server on 127.0.0.1:0 with the canvases named (small_canvas each) and `tokens_text`
// as its tokens file (empty: open access). Fails the test (ADD_FAILURE) and returns an empty
// server when it cannot start.
// `tweak`, if given, edits the configuration last (deadlines, caps).
TestServer start_server(std::vector<std::string> canvases = {"c"}, std::string tokens_text = "",
                        protocol::SessionLimits limits = {}, int send_buffer_bytes = 0,
                        const std::function<void(server_net::ServerConfig&)>& tweak = {});

// The tokens every test server with auth uses.
inline constexpr const char* kTokens =
    "c painter paint-token\n"
    "c viewer view-token\n"
    "d painter paint-d\n";

client_core::ClientOptions client_options(const TestServer& s, const std::string& canvas = "c",
                                          protocol::Role role = protocol::Role::painter,
                                          const std::string& token = "paint-token");

// A stroke of `n` samples inside the central 2 m of the canvas, radius 2..12 cm.
protocol::Stroke random_stroke(std::mt19937_64& rng, int n = 6,
                               protocol::BrushMode mode = protocol::BrushMode::paint);

// Quiesces the canvas and checks that `client`'s replica reaches the published state
// byte-identically (pool hash and links). Returns the quiescent state.
server_core::CanvasService::Quiescent expect_converged(server_core::CanvasService& canvas,
                                                       std::vector<client_core::Client*> clients,
                                                       std::chrono::milliseconds timeout = 30s);

// A bare synchronous WebSocket connection (no hello sent) for hand-made messages.
class RawWs {
 public:
  // `from`: the local address to connect from (any of 127.0.0.0/8 on Linux; empty: the
  // system's choice), so that tests can be several client addresses. When the upgrade is
  // refused, `*refused_status` (if given) is the HTTP status of the answer (0: no answer).
  // `receive_buffer_bytes` > 0: the socket's SO_RCVBUF, set before connecting (a small one makes
  // the server's writes stop within a few frames while the test does not read).
  static std::unique_ptr<RawWs> connect(const TestServer& s, const std::string& from = "",
                                        int* refused_status = nullptr,
                                        int receive_buffer_bytes = 0);
  ~RawWs();
  bool send_text(const std::string& text);
  // The first frame of a text message that is never finished (FIN clear).
  bool send_partial(const std::string& text);
  bool send_binary(const std::vector<std::uint8_t>& bytes);
  // One text message in frames of `piece` bytes (a ping between each two).
  bool send_fragmented(const std::string& text, std::size_t piece);
  // The next text message (skipping binary frames), or nullopt when the connection ended.
  std::optional<std::string> read_text(std::chrono::milliseconds timeout = 10s);
  // The next message, text or binary (its bytes in `data`), or nullopt when the connection
  // ended or nothing came within `timeout`.
  struct Message {
    bool text = false;
    std::string data;
  };
  std::optional<Message> read_message(std::chrono::milliseconds timeout = 10s);
  // Reads until the connection ends; returns the close code (0 if none).
  int read_until_closed(std::chrono::milliseconds timeout = 10s);
  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

// Plain HTTP GET on the server's port; returns status and body.
std::pair<int, std::string> http_get(const TestServer& s, const std::string& target);

}  // namespace deepcanvas::test
