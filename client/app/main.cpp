// deepcanvas-client: the thin Vulkan client. Subcommands register themselves (commands.hpp);
// main() hands argv to the one named, and answers --help, --version and unknown commands itself.
#include "commands.hpp"

int main(int argc, char** argv) {
  return deepcanvas::base::cli::run_commands(
      argc, argv, "deepcanvas-client",
      "The deepcanvas client keeps a GPU replica of a canvas and renders it with "
      "Vulkan.\n",
      "Environment:\n"
      "  DEEPCANVAS_VK_DEVICE=I|NAME   use Vulkan device index I or the first whose\n"
      "                                name contains NAME (like --device)\n"
      "  DEEPCANVAS_VK_VALIDATION=1    enable the Khronos validation layer if installed\n"
      "  DEEPCANVAS_TOKEN=TOKEN        access token (like --token)\n"
      "\n"
      "Examples:\n"
      "  deepcanvas-client devices\n"
      "  deepcanvas-client paint --connect ws://127.0.0.1:7878/main demo.apa\n"
      "  deepcanvas-client render --connect ws://127.0.0.1:7878/main --out main.png\n"
      "  deepcanvas-client COMMAND --help      the options of one command\n");
}
