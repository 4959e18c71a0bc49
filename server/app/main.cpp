// deepcanvas-server: the authoritative canvas server. Subcommands register themselves
// (commands.hpp); main() hands argv to the one named, and answers --help, --version and unknown
// commands itself.
#include <cstdio>
#include <string>
#include <string_view>
#include <vector>

#include "commands.hpp"
#include "deepcanvas/base/cli.hpp"

int main(int argc, char** argv) {
  namespace cli = deepcanvas::base::cli;
  const auto& commands = deepcanvas::server_app::commands();
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
                   "deepcanvas-server: unknown command '%s' (commands: %s)\nRun "
                   "'deepcanvas-server --help' for the options.\n",
                   argv[1], names.c_str());
      return cli::kExitUsage;
    }
  }
  CLI::App app{"The deepcanvas server owns the authoritative voxel octree of each canvas and "
               "streams it to clients over WebSocket.\n",
               "deepcanvas-server"};
  cli::standard(app,
                "Examples:\n"
                "  deepcanvas-server serve --listen 127.0.0.1:7878 --canvas main\n"
                "  deepcanvas-server replay painting.apa\n"
                "  deepcanvas-server COMMAND --help      the options of one command\n");
  for (const auto& c : commands) app.add_subcommand(c.name, c.summary);
  app.require_subcommand(1);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  // Every command was dispatched above; a parse that selects one cannot reach here.
  return cli::kExitUsage;
}
