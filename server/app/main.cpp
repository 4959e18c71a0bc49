// deepcanvas-server: the authoritative canvas server.
#include <cstdio>
#include <cstring>
#include <string_view>

#include "commands.hpp"

namespace {

void usage(FILE* out) {
  std::fprintf(out,
               "usage: deepcanvas-server COMMAND [options]\n\n"
               "The deepcanvas server owns the authoritative voxel octree of each canvas.\n\n"
               "commands:\n"
               "  serve    serve canvases over WebSocket (see serve --help)\n"
               "  replay   apply .apa paintings or stroke logs headless and report the result\n"
               "           (see replay --help)\n\n"
               "  --help   this text\n"
               "  --version\n");
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    usage(stderr);
    return 2;
  }
  const std::string_view cmd = argv[1];
  if (cmd == "--help" || cmd == "-h" || cmd == "help") {
    usage(stdout);
    return 0;
  }
  if (cmd == "--version") {
    std::printf("deepcanvas-server 0.1.0\n");
    return 0;
  }
  for (const auto& c : deepcanvas::server_app::commands()) {
    if (c.name == cmd) return c.run(argc - 1, argv + 1);
  }
  std::fprintf(stderr, "deepcanvas-server: unknown command '%s'\n\n", argv[1]);
  usage(stderr);
  return 2;
}
