// Subcommands of deepcanvas-client. Each lives in its own <name>_command.cpp and registers with
// DEEPCANVAS_CLIENT_COMMAND(name, summary, fn); run() gets argv starting at the command name and
// parses it with its own CLI::App named "deepcanvas-client <name>" (base/cli.hpp), so its
// messages name the command. main() lists the registered commands (sorted) in --help, so adding
// a command is adding a file.
#pragma once

#include <algorithm>
#include <functional>
#include <string>
#include <vector>

namespace deepcanvas::client_app {

struct Command {
  std::string name;
  std::string summary;  // one line for `deepcanvas-client --help`
  std::function<int(int argc, char** argv)> run;
};

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

}  // namespace deepcanvas::client_app

#define DEEPCANVAS_CLIENT_COMMAND(name, summary, fn)                                              \
  static ::deepcanvas::client_app::CommandRegistrar deepcanvas_client_command_##fn(name, summary, \
                                                                                   fn)
