// deepcanvas-server serve: serve canvases over WebSocket until SIGINT/SIGTERM.
#include <pthread.h>
#include <signal.h>

#include <cstdio>
#include <string>
#include <string_view>
#include <vector>

#include "commands.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/server_core/log.hpp"
#include "deepcanvas/server_net/server.hpp"
#include "cli_options.hpp"

namespace deepcanvas::server_app {
namespace {

namespace cli = deepcanvas::base::cli;
using server_net::Server;
using server_net::ServerConfig;

constexpr const char* kDescription =
    "Serves canvases over WebSocket: clients send a hello (protocol version, role, token,\n"
    "canvas), then strokes; every client receives the canvas's blocks (a snapshot, then live\n"
    "updates grouped by epoch). HTTP on the same port answers GET /metrics (Prometheus text)\n"
    "and GET /healthz. Log lines (key=value) go to stderr. SIGINT/SIGTERM stop it cleanly.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-server serve\n"
    "      one canvas 'default' on ws://127.0.0.1:7878/default\n"
    "  deepcanvas-server serve --listen 127.0.0.1:0 --canvas main --canvas scratch\n"
    "      two canvases on a free port (the 'listening' log line names it)\n"
    "  deepcanvas-server serve --listen 0.0.0.0:7878 --tokens tokens.txt\n"
    "      every interface; tokens.txt holds lines '<canvas> <role> <token>'\n";

// "HOST:PORT" or "[V6]:PORT", port 0..65535.
bool parse_listen(std::string_view v, std::string& host, std::uint16_t& port) {
  const auto colon = v.rfind(':');
  if (colon == std::string_view::npos) return false;
  const auto p = parse_whole(v.substr(colon + 1));
  if (!p || *p > 65535) return false;
  host = std::string(v.substr(0, colon));
  if (host.size() > 2 && host.front() == '[' && host.back() == ']')
    host = host.substr(1, host.size() - 2);
  if (host.empty()) return false;
  port = static_cast<std::uint16_t>(*p);
  return true;
}

int serve_main(int argc, char** argv) {
  ServerConfig cfg;
  server_core::CanvasServiceConfig canvas;
  std::vector<std::string> names;
  std::string listen = "127.0.0.1:7878", tokens_path, log_level = "info";

  CLI::App app{kDescription, "deepcanvas-server serve"};
  cli::standard(app, kExamples);
  app.add_option("--listen", listen,
                 "address to listen on (default 127.0.0.1:7878; port 0 picks a free port, "
                 "printed in the 'listening' log line)")
      ->type_name("HOST:PORT")
      ->check(CLI::Validator(
          [](std::string& v) -> std::string {
            std::string host;
            std::uint16_t port = 0;
            return parse_listen(v, host, port) ? std::string()
                                               : "expected HOST:PORT, got '" + v + "'";
          },
          ""));
  app.add_option("--canvas", names,
                 "serve a canvas with this name; repeat for several canvases, each with its own "
                 "tree and threads (default: the canvases named in --tokens, or one canvas "
                 "'default')")
      ->type_name("NAME")
      ->allow_extra_args(false);
  app.add_option("--tokens", tokens_path,
                 "access tokens: lines '<canvas> <role> <token>', role painter or viewer ('#' "
                 "comments). Without it every client gets the role it asks for, and only a "
                 "loopback address may be used")
      ->type_name("FILE");
  app.add_option("--threads", cfg.network_threads, "network threads (default 2)")
      ->type_name("N")
      ->transform(whole(1, 64));
  app.add_option("--edge", canvas.octree.edge_m, "canvas edge in metres (default 20000)")
      ->type_name("METRES")
      ->transform(positive());
  app.add_option("--roots", canvas.octree.roots_per_axis, "roots per axis, even (default 4)")
      ->type_name("N")
      ->transform(whole(2, 64));
  app.add_option("--max-depth", canvas.octree.max_depth, "deepest level (default 24)")
      ->type_name("D")
      ->transform(whole(1, 24));
  app.add_option("--block-cells", canvas.octree.block_cells,
                 "cells per block, a power of two (default 4096)")
      ->type_name("N")
      ->transform(whole(0, 1u << 20));
  app.add_option("--max-cells", canvas.octree.max_cells,
                 "cell capacity per canvas (default 268435456)")
      ->type_name("N")
      ->transform(whole(0));
  app.add_option("--max-cells-per-step", canvas.max_cells_per_step,
                 "painter step bound in work units (default 8192)")
      ->type_name("N")
      ->transform(whole(1));
  app.add_option("--zstd-level", canvas.zstd_level, "block compression level (default 3)")
      ->type_name("L")
      ->transform(whole(1, 19));
  app.add_option("--max-frame-bytes", cfg.limits.max_frame_bytes,
                 "largest message a client may send (default 16777216)")
      ->type_name("N")
      ->transform(whole(0));
  app.add_option("--max-samples", cfg.limits.max_samples_per_stroke,
                 "samples per stroke (default 100000)")
      ->type_name("N")
      ->transform(whole(1, 0xFFFFFFFFu));
  app.add_option("--max-strokes-per-second", cfg.limits.max_strokes_per_second,
                 "strokes per second per session (default 100)")
      ->type_name("N")
      ->transform(whole(0, 0xFFFFFFFFu));
  app.add_option("--max-open-strokes", cfg.limits.max_open_strokes,
                 "streamed strokes open at once per session (default 16)")
      ->type_name("N")
      ->transform(whole(1, 0xFFFFFFFFu));
  app.add_option("--max-sessions", cfg.max_sessions, "open WebSocket sessions (default 1024)")
      ->type_name("N")
      ->transform(whole(1));
  app.add_option("--send-buffer-bytes", cfg.socket_send_buffer_bytes,
                 "SO_SNDBUF per client socket (default: the OS's autotuning); smaller makes slow "
                 "clients coalesce sooner")
      ->type_name("N")
      ->transform(whole(0, 1u << 30));
  app.add_option("--log-level", log_level, "debug | info | warn | error | off (default info)")
      ->type_name("LEVEL")
      ->check(CLI::Validator(
          [](std::string& v) -> std::string {
            server_core::LogLevel level;
            return server_core::parse_log_level(v, level)
                       ? std::string()
                       : "expected debug, info, warn, error or off, got '" + v + "'";
          },
          ""));
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;

  parse_listen(listen, cfg.listen_address, cfg.port);
  server_core::LogLevel level;
  server_core::parse_log_level(log_level, level);
  server_core::set_log_level(level);
  if (!tokens_path.empty()) {
    auto t = server_net::TokenTable::load(tokens_path);
    if (!t) return cli::fail(app, "--tokens: " + t.error().message);
    if (names.empty()) names = t->canvases();
    cfg.tokens = std::move(*t);
  }
  if (names.empty()) names.push_back("default");
  for (const auto& n : names) {
    auto c = canvas;
    c.name = n;
    cfg.canvases.push_back(std::move(c));
  }

  // Block the stop signals in every thread (threads inherit the mask); this thread waits for
  // them with sigwait, so no async-signal-safety concerns arise.
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
  // A client that vanishes mid-write must not kill the server.
  signal(SIGPIPE, SIG_IGN);

  // invalid_argument: the server refuses the configuration the options made (a bad canvas
  // name, an odd --roots, a public address without --tokens), a usage error; anything else
  // (the port is taken) is a runtime failure.
  auto refused = [&](const Error& e) {
    return e.code == Errc::invalid_argument ? usage_error(app, e.message)
                                            : cli::fail(app, e.message);
  };
  auto server = Server::create(std::move(cfg));
  if (!server) return refused(server.error());
  if (auto r = (*server)->start(); !r) return refused(r.error());
  int sig = 0;
  sigwait(&set, &sig);
  server_core::log_event(server_core::LogLevel::info, "signal",
                         {{"signal", sig == SIGINT ? "SIGINT" : "SIGTERM"}});
  (*server)->stop();
  return 0;
}

}  // namespace

DEEPCANVAS_SERVER_COMMAND("serve", "serve canvases over WebSocket", serve_main);

}  // namespace deepcanvas::server_app
