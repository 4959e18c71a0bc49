// deepcanvas-server: the authoritative canvas server. Subcommands register themselves
// (commands.hpp); main() hands argv to the one named, and answers --help, --version and unknown
// commands itself.
#include "commands.hpp"

int main(int argc, char** argv) {
  return deepcanvas::base::cli::run_commands(
      argc, argv, "deepcanvas-server",
      "The deepcanvas server owns the authoritative voxel octree of each canvas and "
      "streams it to clients over WebSocket.\n",
      "Examples:\n"
      "  deepcanvas-server serve --listen 127.0.0.1:7878 --canvas main\n"
      "  deepcanvas-server replay painting.apa\n"
      "  deepcanvas-server COMMAND --help      the options of one command\n");
}
