// The command-line helpers the client's commands use: the shared strict values and help wrapping
// of base/cli_values.hpp, and the client's own values (image size, colour, output folders).
#pragma once

#include <unistd.h>

#include <CLI/CLI.hpp>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <cctype>
#include <filesystem>
#include <string>
#include <string_view>

#include "deepcanvas/base/cli_values.hpp"

namespace deepcanvas::client_app {
using namespace ::deepcanvas::base::cli;  // NOLINT: the app's commands share base's helpers

// "WxH", each side 1..8192.
inline bool parse_size(std::string_view s, std::uint32_t& w, std::uint32_t& h) {
  const auto x = s.find('x');
  if (x == std::string_view::npos) return false;
  const auto a = parse_whole(s.substr(0, x)), b = parse_whole(s.substr(x + 1));
  if (!a || !b || *a < 1 || *b < 1 || *a > 8192 || *b > 8192) return false;
  w = static_cast<std::uint32_t>(*a);
  h = static_cast<std::uint32_t>(*b);
  return true;
}

inline CLI::Validator image_size() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        std::uint32_t w = 0, h = 0;
        return parse_size(s, w, h) ? std::string()
                                   : "expected WxH with 1..8192 each, got '" + s + "'";
      },
      "");
}

// "R,G,B", each in 0..1.
inline CLI::Validator rgb() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        const auto t = parse_triple(s);
        const bool ok = t && std::all_of(t->begin(), t->end(),
                                         [](double v) { return v >= 0 && v <= 1; });
        return ok ? std::string() : "expected R,G,B with each in 0..1, got '" + s + "'";
      },
      "");
}

// The folder a file will be written to (the file's parent, "." for a bare name): it must exist
// and be writable, so that a long job does not fail at its very end.
inline CLI::Validator output_file() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        std::filesystem::path dir = std::filesystem::path(s).parent_path();
        if (dir.empty()) dir = ".";
        std::error_code ec;
        if (!std::filesystem::is_directory(dir, ec))
          return "no folder '" + dir.string() + "' to write '" + s + "' into";
        if (::access(dir.c_str(), W_OK) != 0)
          return "cannot write into '" + dir.string() + "': " + std::strerror(errno);
        return {};
      },
      "");
}

// A folder that exists and is writable.
inline CLI::Validator output_folder() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        std::error_code ec;
        if (!std::filesystem::is_directory(s, ec)) return "no folder '" + s + "'";
        if (::access(s.c_str(), W_OK) != 0)
          return "cannot write into '" + s + "': " + std::strerror(errno);
        return {};
      },
      "");
}

// The file format named by `path`'s extension (vdb, gltf, glb, ply; lower-cased), or empty for
// any other (the import and export commands then ask for --format).
inline std::string file_format_of(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  const std::string f = ext.empty() ? "" : ext.substr(1);
  return f == "vdb" || f == "gltf" || f == "glb" || f == "ply" ? f : "";
}

}  // namespace deepcanvas::client_app
