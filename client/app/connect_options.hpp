// Options every networked client command shares: --connect URL, --token, --canvas, --ca; and
// catching up on join, which every viewing command does first.
// The canvas name may also be the URL's path (ws://127.0.0.1:7878/NAME). wss:// is TLS; --ca
// names the CA certificates to trust instead of the system's.
#pragma once

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cmath>
#include <cstdlib>
#include <optional>
#include <string>
#include <string_view>

#include "cli_options.hpp"
#include "deepcanvas/base/progress.hpp"
#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/client.hpp"

namespace deepcanvas::client_app {

struct ConnectArgs {
  std::string url = "ws://127.0.0.1:7878/default";
  std::string canvas;  // empty: from the URL's path
  std::string token;
  std::string ca_file;  // wss://: PEM CA certificates to trust (empty: the system's store)
  std::uint32_t batch_interval_ms = 0;  // hello "batch_interval_ms" (add_batch_interval_option)
};

// Splits ws[s]://HOST:PORT[/CANVAS] into the server address ("ws://HOST:PORT/", or wss://) and
// the path without slashes at its end; false for anything else.
inline bool split_ws_url(std::string_view url, std::string& server, std::string& path) {
  std::string_view scheme = "ws://";
  if (url.substr(0, 6) == "wss://") scheme = "wss://";
  if (url.substr(0, scheme.size()) != scheme) return false;
  const auto slash = url.find('/', scheme.size());
  const std::string_view host_port = url.substr(scheme.size(), slash - scheme.size());
  const auto colon = host_port.rfind(':');
  if (colon == std::string_view::npos || colon == 0) return false;
  const auto port = parse_whole(host_port.substr(colon + 1));
  if (!port || *port < 1 || *port > 65535) return false;
  server = std::string(url.substr(0, slash)) + "/";
  path = slash == std::string_view::npos ? "" : std::string(url.substr(slash + 1));
  while (!path.empty() && path.back() == '/') path.pop_back();
  return true;
}

inline void add_connect_options(CLI::App& app, ConnectArgs& args) {
  app.add_option("--connect", args.url,
                 "server WebSocket URL (default ws://127.0.0.1:7878/default; the path names the "
                 "canvas; wss:// for TLS)")
      ->type_name("ws[s]://HOST:PORT[/CANVAS]")
      ->check(CLI::Validator(
          [](std::string& s) -> std::string {
            std::string server, path;
            return split_ws_url(s, server, path)
                       ? std::string()
                       : "expected ws://HOST:PORT[/CANVAS] or wss://..., got '" + s + "'";
          },
          ""));
  app.add_option("--canvas", args.canvas, "canvas name (overrides the URL's path)")
      ->type_name("NAME");
  app.add_option("--token", args.token, "access token (default: $DEEPCANVAS_TOKEN, else none)")
      ->type_name("TOKEN");
  app.add_option("--ca", args.ca_file,
                 "wss:// only: trust the CA certificates in this PEM file (a private CA or the "
                 "server's self-signed certificate) instead of the system's store")
      ->type_name("FILE");
}

// --batch-interval-ms, for the commands that watch the canvas stream: the least time between two
// epoch batches the server sends (hello "batch_interval_ms"); fewer bytes on a thin link.
inline void add_batch_interval_option(CLI::App& app, ConnectArgs& args) {
  app.add_option("--batch-interval-ms", args.batch_interval_ms,
                 "ask the server for canvas updates at most every MS milliseconds (0..1000, "
                 "default 0: as they come); the changes in between arrive coalesced, so a thin "
                 "link carries fewer bytes, at up to MS ms more latency")
      ->check(CLI::Range(0u, protocol::kMaxBatchIntervalMs))
      ->type_name("MS");
}

// The client options for `args` (checked when parsed: add_connect_options).
inline client_core::ClientOptions client_options(const ConnectArgs& args, protocol::Role role,
                                                 std::string client_name) {
  client_core::ClientOptions o;
  std::string path;
  split_ws_url(args.url, o.url, path);
  o.canvas = !args.canvas.empty() ? args.canvas : (!path.empty() ? path : "default");
  if (!args.token.empty()) {
    o.token = args.token;
  } else if (const char* env = std::getenv("DEEPCANVAS_TOKEN"); env && *env) {
    o.token = env;
  }
  o.ca_file = args.ca_file;
  o.batch_interval_ms = args.batch_interval_ms;
  o.role = role;
  o.client_name = std::move(client_name);
  return o;
}

// hello "camera" for a client that will look through `c` (ClientOptions::camera): its eye and a
// point one metre ahead; none where the eye lies past what hello allows (1e12 m on an axis).
inline std::optional<protocol::JoinCamera> join_camera(const client_core::Camera& c) {
  const client_core::DVec3 e = c.position(), t = c.position() + c.forward();
  for (int i = 0; i < 3; ++i)
    if (!(std::abs(e[i]) <= 1e11)) return std::nullopt;
  protocol::JoinCamera j{{e.x, e.y, e.z}, {t.x, t.y, t.z}};
  if (j.eye == j.target) return std::nullopt;
  return j;
}

// Waits up to `timeout_s` until `client` has applied the epoch the server was at when it joined,
// with the block frames received so far as progress on stderr (the size of the snapshot is not
// known in advance: a count and a rate, no ETA).
inline Result<void> catch_up(client_core::Client& client, const std::string& canvas,
                             double timeout_s, bool quiet) {
  using Clock = std::chrono::steady_clock;
  const std::uint64_t join_epoch = client.welcome().epoch;
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                           std::chrono::duration<double>(timeout_s));
  base::Progress progress("catching up with canvas '" + canvas + "'", 0, "blocks", !quiet);
  for (;;) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    const auto wait =
        std::clamp(left, std::chrono::milliseconds(0), std::chrono::milliseconds(100));
    const bool done = client.wait_for_epoch(join_epoch, wait).ok();
    progress.update(static_cast<double>(client.stats().frames));
    if (done) return {};
    const std::string at = "epoch " + std::to_string(client.applied_epoch()) + " of " +
                           std::to_string(join_epoch) + " applied";
    if (!client.is_open())
      return make_error(Errc::io_error, "the server closed the connection (" + at + ")");
    if (Clock::now() >= deadline)
      return make_error(Errc::io_error,
                        "not caught up after " + format_number(timeout_s) + " s (" + at + ")");
  }
}

}  // namespace deepcanvas::client_app
