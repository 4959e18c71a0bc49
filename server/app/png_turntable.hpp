// `deepcanvas-server export --format png`: a turntable of PNG frames of a replayed canvas, made
// by the client's renderer (the server has no Vulkan): the canvas is served on a free loopback
// port from this process, in memory, and `deepcanvas-client render --turntable N` renders it.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::server_app {

struct TurntableOptions {
  std::string out;    // FILE.png: frames FILE_0000.png ...
  std::uint32_t frames = 36;
  std::string size = "1280x720";
  std::string video;  // also encode with ffmpeg (the client's --video)
  bool quiet = false;
};

// The client executable: $DEEPCANVAS_CLIENT, else deepcanvas-client beside this executable (an
// install) or in the build tree's client/ folder, else on PATH. Empty when none is found.
std::string find_client_executable();

// Serves `tree` and runs the client's turntable against it. Returns the exit code: the client's,
// or 1 with a message on stderr when the client cannot be found or the canvas cannot be served.
int export_png_turntable(std::unique_ptr<server_core::Octree> tree, const TurntableOptions& options);

}  // namespace deepcanvas::server_app
