// deepcanvas-client: the thin Vulkan client. Subcommands register themselves (commands.hpp);
// main() hands argv to the one named, and answers --help, --version and unknown commands itself.
#include <cstdio>
#include <string>
#include <string_view>
#include <vector>

#include "commands.hpp"
#include "deepcanvas/base/cli.hpp"

int main(int argc, char** argv) {
  namespace cli = deepcanvas::base::cli;
  const auto& commands = deepcanvas::client_app::commands();
  // "help [COMMAND]" and "--help COMMAND" read as "COMMAND --help" (or the binary's --help).
  std::vector<char*> args(argv, argv + argc);
  static char help_flag[] = "--help";
  if (argc >= 2 && (std::string_view(argv[1]) == "help" ||
                    (argc == 3 && (std::string_view(argv[1]) == "--help" ||
                                   std::string_view(argv[1]) == "-h")))) {
    if (argc == 2) {
      args[1] = help_flag;
    } else {
      args[1] = argv[2];
      args[2] = help_flag;
    }
  }
  argc = static_cast<int>(args.size());
  argv = args.data();
  if (argc >= 2) {
    const std::string_view name = argv[1];
    for (const auto& c : commands)
      if (c.name == name) return c.run(argc - 1, argv + 1);
    if (!name.empty() && name.front() != '-') {
      std::string names;
      for (const auto& c : commands) names += (names.empty() ? "" : ", ") + c.name;
      std::fprintf(stderr,
                   "deepcanvas-client: unknown command '%s' (commands: %s)\nRun "
                   "'deepcanvas-client --help' for the options.\n",
                   argv[1], names.c_str());
      return cli::kExitUsage;
    }
  }
  CLI::App app{"The deepcanvas client keeps a GPU replica of a canvas and renders it with "
               "Vulkan.\n",
               "deepcanvas-client"};
  cli::standard(app,
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
  for (const auto& c : commands) app.add_subcommand(c.name, c.summary);
  app.require_subcommand(1);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  // Every command was dispatched above; a parse that selects one cannot reach here.
  return cli::kExitUsage;
}
