// What the commands that render on the GPU (render, watch) share: the --device, --no-cull and
// --quiet options, and the GPU replica's shape as a canvas's welcome announces it.
#pragma once

#include <CLI/CLI.hpp>

#include <bit>
#include <cstdint>
#include <string>

#include "deepcanvas/client_gpu/replica_gpu.hpp"
#include "deepcanvas/protocol/messages.hpp"

namespace deepcanvas::client_app {

struct GpuViewArgs {
  std::string device;  // empty: the default device (see `deepcanvas-client devices`)
  bool no_cull = false;
  bool quiet = false;
};

// --device I|NAME.
inline void add_device_option(CLI::App& app, GpuViewArgs& args) {
  app.add_option("--device", args.device,
                 "Vulkan device (default: see `deepcanvas-client devices`)")
      ->type_name("I|NAME");
}
// --no-cull (`cull_help` says what the cull skips, in the command's terms) and --quiet.
inline void add_cull_and_quiet_flags(CLI::App& app, GpuViewArgs& args,
                                     const std::string& cull_help) {
  app.add_flag("--no-cull", args.no_cull, cull_help);
  app.add_flag("--quiet", args.quiet, "no progress on stderr");
}

// The GPU replica matching the canvas the server announced (pool texture width, block size,
// geometry). The welcome was validated by the protocol decoder (powers of two in range).
inline client_gpu::GpuReplicaConfig replica_config(const protocol::Welcome& welcome) {
  client_gpu::GpuReplicaConfig cfg;
  cfg.width_log2 = static_cast<std::uint32_t>(std::countr_zero(welcome.texture_width));
  cfg.block_log2 = static_cast<std::uint32_t>(std::countr_zero(welcome.block_cells));
  cfg.roots_per_axis = welcome.geometry.roots_per_axis;
  cfg.edge_m = welcome.geometry.edge_m;
  cfg.max_depth = welcome.geometry.max_depth;
  return cfg;
}

}  // namespace deepcanvas::client_app
