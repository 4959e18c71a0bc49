// Subcommands of deepcanvas-server: each lives in its own <name>_command.cpp and registers with
// DEEPCANVAS_SERVER_COMMAND(name, summary, fn); base/commands.hpp has the registry and main()'s
// dispatch.
#pragma once

#include "deepcanvas/base/commands.hpp"

#define DEEPCANVAS_SERVER_COMMAND(name, summary, fn) DEEPCANVAS_COMMAND(name, summary, fn)
