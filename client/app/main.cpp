// deepcanvas-client: the thin Vulkan client. Subcommands register themselves (commands.hpp).
#include <cstdio>
#include <cstring>
#include <string_view>

#include "commands.hpp"

namespace {

void usage(FILE* out) {
  std::fprintf(out,
               "usage: deepcanvas-client COMMAND [options]\n\n"
               "The deepcanvas client keeps a GPU replica of a canvas and renders it with "
               "Vulkan.\n\ncommands:\n");
  for (const auto& c : deepcanvas::client_app::commands()) {
    std::fprintf(out, "  %-9s %s\n", c.name.c_str(), c.summary.c_str());
  }
  std::fprintf(
      out,
      "\n  COMMAND --help   help for one command\n"
      "  --help           this text\n"
      "  --version\n\n"
      "environment:\n"
      "  DEEPCANVAS_VK_DEVICE=I|NAME   use Vulkan device index I or the first whose name\n"
      "                                contains NAME (like --device)\n"
      "  DEEPCANVAS_VK_VALIDATION=1    enable the Khronos validation layer if installed\n");
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
    std::printf("deepcanvas-client 0.1.0\n");
    return 0;
  }
  for (const auto& c : deepcanvas::client_app::commands()) {
    if (c.name == cmd) return c.run(argc - 1, argv + 1);
  }
  std::fprintf(stderr, "deepcanvas-client: unknown command '%s'\n\n", argv[1]);
  usage(stderr);
  return 2;
}
