// Subcommands of deepcanvas-client: each lives in its own <name>_command.cpp and registers with
// DEEPCANVAS_CLIENT_COMMAND(name, summary, fn); base/commands.hpp has the registry and main()'s
// dispatch.
#pragma once

#include "deepcanvas/base/commands.hpp"

#define DEEPCANVAS_CLIENT_COMMAND(name, summary, fn) DEEPCANVAS_COMMAND(name, summary, fn)
