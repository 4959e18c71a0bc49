// Subcommands of deepcanvas-server. Each lives in its own <name>_command.cpp and registers with
// DEEPCANVAS_SERVER_COMMAND; run() gets argv starting at the command name.
#pragma once

#include <functional>
#include <string>
#include <vector>

namespace deepcanvas::server_app {

struct Command {
  std::string name;
  std::function<int(int argc, char** argv)> run;
};

inline std::vector<Command>& commands() {
  static std::vector<Command> all;
  return all;
}

struct CommandRegistrar {
  CommandRegistrar(std::string name, std::function<int(int, char**)> run) {
    commands().push_back({std::move(name), std::move(run)});
  }
};

}  // namespace deepcanvas::server_app

#define DEEPCANVAS_SERVER_COMMAND(name, fn) \
  static ::deepcanvas::server_app::CommandRegistrar deepcanvas_server_command_##fn(name, fn)
