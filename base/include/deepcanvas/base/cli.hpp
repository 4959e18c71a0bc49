// One command-line convention for every deepcanvas binary and subcommand (CLI11).
//
//   CLI::App app{"Serves canvases over WebSocket.", "deepcanvas-server serve"};
//   deepcanvas::base::cli::standard(app, "examples:\n  deepcanvas-server serve --listen ...");
//   app.add_option("--listen", listen, "...");
//   if (auto code = deepcanvas::base::cli::parse(app, argc, argv)) return *code;
//
// Exit codes, the same everywhere: 0 for --help and --version (text on stdout); 2 for a usage
// error (an unknown option, a missing or malformed value), with one line naming the option on
// stderr ("deepcanvas-server serve: --threads: ...") and a pointer to --help; 1 for a runtime
// failure, one clear line on stderr, printed by the command itself (fail() below).
#pragma once

#include <CLI/CLI.hpp>

#include <cstdio>
#include <optional>
#include <string>

namespace deepcanvas::base::cli {

inline constexpr int kExitRuntime = 1;
inline constexpr int kExitUsage = 2;

// The version every binary prints for --version.
inline constexpr const char* kVersion = "0.1.0";

// --version, the examples footer, and help text wide enough to read.
inline void standard(CLI::App& app, const std::string& examples = {}) {
  app.set_version_flag("--version", std::string(app.get_name()) + " " + kVersion);
  if (!examples.empty()) app.footer(examples);
  app.get_formatter()->column_width(34);
}

// Parses argv. Returns the exit code when the command must stop now (help or version printed:
// 0; a usage error printed: 2), nothing when it should run.
inline std::optional<int> parse(CLI::App& app, int argc, const char* const* argv) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp&) {
    std::fputs(app.help().c_str(), stdout);
    return 0;
  } catch (const CLI::CallForAllHelp&) {
    std::fputs(app.help("", CLI::AppFormatMode::All).c_str(), stdout);
    return 0;
  } catch (const CLI::CallForVersion& e) {
    std::printf("%s\n", e.what());
    return 0;
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "%s: %s\nRun '%s --help' for the options.\n", app.get_name().c_str(),
                 e.what(), app.get_name().c_str());
    return kExitUsage;
  }
  return std::nullopt;
}

// A runtime failure: one line "<command>: <message>" on stderr, exit code 1. The message should
// not repeat the command's name.
inline int fail(const CLI::App& app, const std::string& message) {
  std::fprintf(stderr, "%s: %s\n", app.get_name().c_str(), message.c_str());
  return kExitRuntime;
}

}  // namespace deepcanvas::base::cli
