// PNG turntables of a replayed canvas through the client's renderer (png_turntable.hpp).
#include "png_turntable.hpp"

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <vector>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_net/server.hpp"

namespace deepcanvas::server_app {

namespace fs = std::filesystem;

std::string find_client_executable() {
  if (const char* env = std::getenv("DEEPCANVAS_CLIENT"); env && *env) return env;
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    for (const fs::path& p : {self.parent_path() / "deepcanvas-client",
                              self.parent_path().parent_path() / "client" / "deepcanvas-client"})
      if (::access(p.c_str(), X_OK) == 0) return p.string();
  }
  if (const char* path = std::getenv("PATH")) {
    std::string dirs = path;
    std::size_t start = 0;
    while (start <= dirs.size()) {
      const std::size_t colon = dirs.find(':', start);
      const std::string dir = dirs.substr(start, colon == std::string::npos ? std::string::npos : colon - start);
      if (!dir.empty()) {
        const fs::path p = fs::path(dir) / "deepcanvas-client";
        if (::access(p.c_str(), X_OK) == 0) return p.string();
      }
      if (colon == std::string::npos) break;
      start = colon + 1;
    }
  }
  return {};
}

int export_png_turntable(std::unique_ptr<server_core::Octree> tree, const TurntableOptions& o) {
  const std::string client = find_client_executable();
  if (client.empty()) {
    std::fprintf(stderr,
                 "deepcanvas-server export: PNG frames are rendered by deepcanvas-client, which "
                 "was not found (beside this executable, in the build tree or on PATH; or set "
                 "DEEPCANVAS_CLIENT)\n");
    return 1;
  }
  base::set_log_level(base::LogLevel::warn);
  server_net::ServerConfig cfg;
  cfg.listen_address = "127.0.0.1";
  cfg.port = 0;
  server_core::CanvasServiceConfig canvas;
  canvas.name = "default";
  canvas.octree = tree->config();
  cfg.canvases.push_back(canvas);
  auto owned = std::make_shared<std::unique_ptr<server_core::Octree>>(std::move(tree));
  cfg.make_canvas = [owned](const server_core::CanvasServiceConfig& c)
      -> Result<std::unique_ptr<server_core::CanvasService>> {
    server_core::CanvasService::RestoredCanvas restored;
    restored.tree = std::move(*owned);
    return server_core::CanvasService::create(c, std::move(restored));
  };
  auto server = server_net::Server::create(std::move(cfg));
  if (!server) {
    std::fprintf(stderr, "deepcanvas-server export: %s\n", server.error().message.c_str());
    return 1;
  }
  if (auto r = (*server)->start(); !r) {
    std::fprintf(stderr, "deepcanvas-server export: %s\n", r.error().message.c_str());
    return 1;
  }
  const std::string url = "ws://127.0.0.1:" + std::to_string((*server)->port()) + "/default";
  std::vector<std::string> args = {client, "render", "--connect", url, "--out", o.out,
                                   "--turntable", std::to_string(o.frames), "--size", o.size};
  if (!o.video.empty()) args.insert(args.end(), {"--video", o.video});
  if (o.quiet) args.push_back("--quiet");
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  const pid_t pid = ::fork();
  if (pid < 0) {
    std::fprintf(stderr, "deepcanvas-server export: cannot start %s\n", client.c_str());
    return 1;
  }
  if (pid == 0) {
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0) {
  }
  (*server)->stop();
  if (WIFEXITED(status) && WEXITSTATUS(status) == 127) {
    std::fprintf(stderr, "deepcanvas-server export: could not run %s\n", client.c_str());
    return 1;
  }
  return WIFEXITED(status) ? WEXITSTATUS(status) : 1;
}

}  // namespace deepcanvas::server_app
