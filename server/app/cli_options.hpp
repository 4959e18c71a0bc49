// The command-line helpers the server's commands use: the shared strict values and help
// wrapping of base/cli_values.hpp, under the app's namespace.
#pragma once

#include "deepcanvas/base/cli_values.hpp"

namespace deepcanvas::server_app {
using namespace ::deepcanvas::base::cli;  // NOLINT: the app's commands share base's helpers
}  // namespace deepcanvas::server_app
