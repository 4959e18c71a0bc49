// A binary made of subcommands (deepcanvas-server, deepcanvas-client): each command lives in its
// own <name>_command.cpp and registers itself with DEEPCANVAS_COMMAND(name, summary, fn), so
// adding a command is adding a file. run_commands() is the binary's main(): it hands argv,
// starting at the command's name, to the command named, which parses it with its own CLI::App
// named "<binary> <name>" (cli.hpp) so its messages name the command; and it answers --help
// (listing the commands, sorted), --version, "help COMMAND" and unknown commands itself.
//
// Threading: commands register during static initialisation, before main(); nothing else
// touches the registry.
#pragma once

#include <algorithm>
#include <cstdio>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "deepcanvas/base/cli.hpp"

namespace deepcanvas::base::cli {

struct Command {
  std::string name;
  std::string summary;  // one line for `<binary> --help`
  std::function<int(int argc, char** argv)> run;
};

// The commands of this executable (each binary links only its own).
inline std::vector<Command>& commands() {
  static std::vector<Command> all;
  return all;
}

struct CommandRegistrar {
  CommandRegistrar(std::string name, std::string summary, std::function<int(int, char**)> run) {
    auto& all = commands();
    all.push_back({std::move(name), std::move(summary), std::move(run)});
    std::sort(all.begin(), all.end(),
              [](const Command& a, const Command& b) { return a.name < b.name; });
  }
};

// main() of a binary of subcommands. `description` heads --help; `footer` (environment,
// examples) ends it.
inline int run_commands(int argc, char** argv, const std::string& binary,
                        const std::string& description, const std::string& footer) {
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
    for (const auto& c : commands())
      if (c.name == name) return c.run(argc - 1, argv + 1);
    if (!name.empty() && name.front() != '-') {
      std::string names;
      for (const auto& c : commands()) names += (names.empty() ? "" : ", ") + c.name;
      std::fprintf(stderr,
                   "%s: unknown command '%s' (commands: %s)\nRun '%s --help' for the options.\n",
                   binary.c_str(), argv[1], names.c_str(), binary.c_str());
      return kExitUsage;
    }
  }
  CLI::App app{description, binary};
  standard(app, footer);
  for (const auto& c : commands()) app.add_subcommand(c.name, c.summary);
  app.require_subcommand(1);
  if (auto code = parse(app, argc, argv)) return *code;
  // Every command was dispatched above; a parse that selects one cannot reach here.
  return kExitUsage;
}

}  // namespace deepcanvas::base::cli

#define DEEPCANVAS_COMMAND(name, summary, fn) \
  static ::deepcanvas::base::cli::CommandRegistrar deepcanvas_command_##fn(name, summary, fn)
