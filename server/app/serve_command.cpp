// deepcanvas-server serve: serve canvases over WebSocket until SIGINT/SIGTERM.
#include <pthread.h>
#include <signal.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <string_view>

#include "commands.hpp"
#include "deepcanvas/server_core/log.hpp"
#include "deepcanvas/server_net/server.hpp"

namespace {

using deepcanvas::server_net::Server;
using deepcanvas::server_net::ServerConfig;

void usage(FILE* out) {
  std::fprintf(
      out,
      "usage: deepcanvas-server serve [options]\n\n"
      "Serves canvases over WebSocket: clients send a hello (protocol version, role, token,\n"
      "canvas), then strokes; every client receives the canvas's blocks (a snapshot, then live\n"
      "updates grouped by epoch). HTTP on the same port answers GET /metrics (Prometheus text)\n"
      "and GET /healthz. Log lines (key=value) go to stderr. SIGINT/SIGTERM stop it cleanly.\n\n"
      "options:\n"
      "  --listen HOST:PORT          address to listen on (default 127.0.0.1:7878; port 0 picks\n"
      "                              a free port, printed in the 'listening' log line)\n"
      "  --canvas NAME               serve a canvas with this name; repeat for several canvases,\n"
      "                              each with its own tree and threads (default: the canvases\n"
      "                              named in --tokens, or one canvas 'default')\n"
      "  --tokens FILE               access tokens: lines '<canvas> <role> <token>', role painter\n"
      "                              or viewer ('#' comments). Without it every client gets the\n"
      "                              role it asks for, and only a loopback address may be used\n"
      "  --threads N                 network threads (default 2)\n"
      "  --edge METRES               canvas edge (default 20000)\n"
      "  --roots N                   roots per axis, even (default 4)\n"
      "  --max-depth D               deepest level, 1..24 (default 24)\n"
      "  --block-cells N             cells per block, a power of two (default 4096)\n"
      "  --max-cells N               cell capacity per canvas (default 268435456)\n"
      "  --max-cells-per-step N      painter step bound in work units (default 8192)\n"
      "  --zstd-level L              block compression level (default 3)\n"
      "  --max-frame-bytes N         largest message a client may send (default 16777216)\n"
      "  --max-samples N             samples per stroke (default 100000)\n"
      "  --max-strokes-per-second N  per session (default 100)\n"
      "  --max-open-strokes N        streamed strokes open at once per session (default 16)\n"
      "  --max-sessions N            open WebSocket sessions (default 1024)\n"
      "  --send-buffer-bytes N       SO_SNDBUF per client socket (default: the OS's autotuning);\n"
      "                              smaller makes slow clients coalesce sooner\n"
      "  --log-level LEVEL           debug | info | warn | error | off (default info)\n"
      "  --help                      this text\n");
}

bool parse_u64(std::string_view s, std::uint64_t& out) {
  if (s.empty()) return false;
  char* end = nullptr;
  const std::string str(s);
  errno = 0;
  const unsigned long long v = std::strtoull(str.c_str(), &end, 10);
  if (errno || *end || str[0] == '-') return false;
  out = v;
  return true;
}

bool parse_double(std::string_view s, double& out) {
  const std::string str(s);
  char* end = nullptr;
  out = std::strtod(str.c_str(), &end);
  return !str.empty() && !*end && std::isfinite(out);
}

int serve_main(int argc, char** argv) {
  ServerConfig cfg;
  deepcanvas::server_core::CanvasServiceConfig canvas;
  std::vector<std::string> names;
  std::string tokens_path;
  auto fail = [](const std::string& msg) {
    std::fprintf(stderr, "deepcanvas-server serve: %s\n(see deepcanvas-server serve --help)\n",
                 msg.c_str());
    return 2;
  };
  for (int i = 1; i < argc; ++i) {
    const std::string_view a = argv[i];
    if (a == "--help" || a == "-h") {
      usage(stdout);
      return 0;
    }
    if (i + 1 >= argc) return fail("unknown option or missing value: " + std::string(a));
    const std::string_view v = argv[++i];
    std::uint64_t u = 0;
    double d = 0;
    if (a == "--listen") {
      const auto colon = v.rfind(':');
      if (colon == std::string_view::npos || !parse_u64(v.substr(colon + 1), u) || u > 65535)
        return fail("--listen wants HOST:PORT");
      std::string host(v.substr(0, colon));
      if (host.size() > 2 && host.front() == '[' && host.back() == ']')
        host = host.substr(1, host.size() - 2);
      cfg.listen_address = host;
      cfg.port = static_cast<std::uint16_t>(u);
    } else if (a == "--canvas") {
      names.emplace_back(v);
    } else if (a == "--tokens") {
      tokens_path = v;
    } else if (a == "--threads" && parse_u64(v, u) && u >= 1 && u <= 64) {
      cfg.network_threads = static_cast<int>(u);
    } else if (a == "--edge" && parse_double(v, d) && d > 0) {
      canvas.octree.edge_m = d;
    } else if (a == "--roots" && parse_u64(v, u) && u <= 64) {
      canvas.octree.roots_per_axis = static_cast<std::uint32_t>(u);
    } else if (a == "--max-depth" && parse_u64(v, u) && u <= 24) {
      canvas.octree.max_depth = static_cast<int>(u);
    } else if (a == "--block-cells" && parse_u64(v, u) && u <= (1u << 20)) {
      canvas.octree.block_cells = static_cast<std::uint32_t>(u);
    } else if (a == "--max-cells" && parse_u64(v, u)) {
      canvas.octree.max_cells = u;
    } else if (a == "--max-cells-per-step" && parse_u64(v, u) && u > 0) {
      canvas.max_cells_per_step = u;
    } else if (a == "--zstd-level" && parse_u64(v, u) && u >= 1 && u <= 19) {
      canvas.zstd_level = static_cast<int>(u);
    } else if (a == "--max-frame-bytes" && parse_u64(v, u)) {
      cfg.limits.max_frame_bytes = u;
    } else if (a == "--max-samples" && parse_u64(v, u) && u > 0 && u <= 0xFFFFFFFFu) {
      cfg.limits.max_samples_per_stroke = static_cast<std::uint32_t>(u);
    } else if (a == "--max-strokes-per-second" && parse_u64(v, u) && u <= 0xFFFFFFFFu) {
      cfg.limits.max_strokes_per_second = static_cast<std::uint32_t>(u);
    } else if (a == "--max-open-strokes" && parse_u64(v, u) && u > 0 && u <= 0xFFFFFFFFu) {
      cfg.limits.max_open_strokes = static_cast<std::uint32_t>(u);
    } else if (a == "--send-buffer-bytes" && parse_u64(v, u) && u <= (1u << 30)) {
      cfg.socket_send_buffer_bytes = static_cast<int>(u);
    } else if (a == "--max-sessions" && parse_u64(v, u) && u > 0) {
      cfg.max_sessions = u;
    } else if (a == "--log-level") {
      deepcanvas::server_core::LogLevel level;
      if (!deepcanvas::server_core::parse_log_level(v, level))
        return fail("--log-level wants debug, info, warn, error or off");
      deepcanvas::server_core::set_log_level(level);
    } else {
      return fail("bad option or value: " + std::string(a) + " " + std::string(v));
    }
  }
  if (!tokens_path.empty()) {
    auto t = deepcanvas::protocol::TokenTable::load(tokens_path);
    if (!t) return fail("--tokens " + tokens_path + ": " + t.error().message);
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

  auto server = Server::create(std::move(cfg));
  if (!server) return fail(server.error().message);
  if (auto r = (*server)->start(); !r) {
    std::fprintf(stderr, "deepcanvas-server serve: %s\n", r.error().message.c_str());
    return 1;
  }
  int sig = 0;
  sigwait(&set, &sig);
  deepcanvas::server_core::log_event(deepcanvas::server_core::LogLevel::info, "signal",
                                     {{"signal", sig == SIGINT ? "SIGINT" : "SIGTERM"}});
  (*server)->stop();
  return 0;
}

}  // namespace

DEEPCANVAS_SERVER_COMMAND("serve", serve_main);
