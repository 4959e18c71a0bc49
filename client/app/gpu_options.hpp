// The options the commands that render on the GPU (render, watch) share: --device, --no-cull
// and --quiet.
#pragma once

#include <CLI/CLI.hpp>

#include <string>

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

}  // namespace deepcanvas::client_app
