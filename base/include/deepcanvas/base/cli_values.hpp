// Strict option values and readable help, on top of cli.hpp, for every deepcanvas command.
//
// CLI11 on its own reads integers with strtoull in base 0 ("010" is 8, "0x10" is 16, "-1" wraps
// to 2^64-1) and floating point with strtold ("nan", "inf" and hex floats pass). These
// validators accept plain decimal only, refuse NaN and infinities, check the range, and rewrite
// the value in canonical decimal so that CLI11's conversion into the option's variable reads
// exactly what was checked. Attach them with Option::transform().
#pragma once

#include <CLI/CLI.hpp>

#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <optional>
#include <string>
#include <string_view>

#include "deepcanvas/base/cli.hpp"

namespace deepcanvas::base::cli {


// Decimal digits only (no sign, no spaces, no base prefix), at most 2^64-1.
inline std::optional<std::uint64_t> parse_whole(std::string_view s) {
  if (s.empty()) return std::nullopt;
  for (char c : s)
    if (c < '0' || c > '9') return std::nullopt;
  std::uint64_t v = 0;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc{} || ptr != s.data() + s.size()) return std::nullopt;
  return v;
}

// A finite decimal number ("1", "-0.5", "2e3", an optional leading '+'); no NaN, no infinity.
inline std::optional<double> parse_number(std::string_view s) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  if (s.empty() || s.front() == '+') return std::nullopt;
  double v = 0;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc{} || ptr != s.data() + s.size() || !std::isfinite(v)) return std::nullopt;
  return v;
}

// "X,Y,Z": three finite numbers.
inline std::optional<std::array<double, 3>> parse_triple(std::string_view s) {
  std::array<double, 3> out{};
  for (int i = 0; i < 3; ++i) {
    const auto comma = s.find(',');
    if ((i < 2) == (comma == std::string_view::npos)) return std::nullopt;
    auto v = parse_number(s.substr(0, comma));
    if (!v) return std::nullopt;
    out[static_cast<std::size_t>(i)] = *v;
    if (i < 2) s.remove_prefix(comma + 1);
  }
  return out;
}

// "X0,Y0,Z0,X1,Y1,Z1": a box, six finite numbers, the minimum corner first.
inline std::optional<std::array<double, 6>> parse_box(std::string_view s) {
  std::array<double, 6> out{};
  for (int i = 0; i < 6; ++i) {
    const auto comma = s.find(',');
    if ((i < 5) == (comma == std::string_view::npos)) return std::nullopt;
    auto v = parse_number(s.substr(0, comma));
    if (!v) return std::nullopt;
    out[static_cast<std::size_t>(i)] = *v;
    if (i < 5) s.remove_prefix(comma + 1);
  }
  if (out[0] > out[3] || out[1] > out[4] || out[2] > out[5]) return std::nullopt;
  return out;
}

inline std::string format_number(double v) {
  char buf[32];
  const auto [ptr, ec] = std::to_chars(buf, buf + sizeof buf, v);
  return ec == std::errc{} ? std::string(buf, ptr) : std::string("?");
}

// A whole number in [lo, hi]. The help shows the range, or only ">=lo" when hi is merely the
// limit of a 32- or 64-bit variable.
inline CLI::Validator whole(std::uint64_t lo,
                            std::uint64_t hi = std::numeric_limits<std::uint64_t>::max()) {
  const std::string range = std::to_string(lo) + ".." + std::to_string(hi);
  const bool type_limit = hi == std::numeric_limits<std::uint64_t>::max() ||
                          hi == std::numeric_limits<std::uint32_t>::max();
  return CLI::Validator(
      [lo, hi, range](std::string& s) -> std::string {
        const auto v = parse_whole(s);
        if (!v) return "'" + s + "' is not a whole number";
        if (*v < lo || *v > hi) return "must be in " + range + ", got " + s;
        s = std::to_string(*v);
        return {};
      },
      type_limit ? ">=" + std::to_string(lo) : range);
}

// A finite number in [lo, hi], or in (lo, hi] with lo_open.
inline CLI::Validator number(double lo, double hi = std::numeric_limits<double>::max(),
                             bool lo_open = false) {
  std::string range;
  if (hi == std::numeric_limits<double>::max()) {
    range = (lo_open ? ">" : ">=") + format_number(lo);
  } else {
    range = format_number(lo) + ".." + format_number(hi);
    if (lo_open) range = ">" + format_number(lo) + ", <=" + format_number(hi);
  }
  return CLI::Validator(
      [lo, hi, lo_open, range](std::string& s) -> std::string {
        const auto v = parse_number(s);
        if (!v) return "'" + s + "' is not a finite number";
        if ((lo_open ? !(*v > lo) : !(*v >= lo)) || *v > hi)
          return "must be " + std::string(range.find("..") != std::string::npos ? "in " : "") +
                 range + ", got " + s;
        s = format_number(*v);
        return {};
      },
      range);
}

inline CLI::Validator positive() { return number(0, std::numeric_limits<double>::max(), true); }

// "X,Y,Z" (the option stays a string; parse it with parse_triple after parsing).
inline CLI::Validator triple() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        return parse_triple(s) ? std::string() : "expected X,Y,Z (three numbers), got '" + s + "'";
      },
      "");
}

// "X0,Y0,Z0,X1,Y1,Z1" (the option stays a string; parse it with parse_box after parsing).
inline CLI::Validator box_corners() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        return parse_box(s) ? std::string()
                            : "expected X0,Y0,Z0,X1,Y1,Z1 (six numbers, the minimum corner "
                              "first), got '" + s + "'";
      },
      "");
}

// Help text: CLI11 prints an option's description on one line however long it is, and indents
// the lines after a '\n'. Breaks every description of `app` at spaces to fit `width` columns
// (80 on a terminal with the name column of base::cli::standard).
inline std::string wrap(const std::string& text, std::size_t width) {
  std::string out, line;
  std::size_t start = 0;
  while (start <= text.size()) {
    auto end = text.find(' ', start);
    if (end == std::string::npos) end = text.size();
    const std::string word = text.substr(start, end - start);
    if (!line.empty() && line.size() + 1 + word.size() > width) {
      out += line + "\n";
      line.clear();
    }
    line += (line.empty() ? "" : " ") + word;
    start = end + 1;
  }
  return out + line;
}

inline void wrap_help(CLI::App& app, std::size_t width = 46) {
  for (CLI::Option* o : app.get_options()) o->description(wrap(o->get_description(), width));
}

// A usage error found after parsing (options that contradict each other, a configuration the
// command refuses): the same two lines and exit code as base::cli::parse gives.
inline int usage_error(const CLI::App& app, const std::string& message) {
  std::fprintf(stderr, "%s: %s\nRun '%s --help' for the options.\n", app.get_name().c_str(),
               message.c_str(), app.get_name().c_str());
  return kExitUsage;
}

}  // namespace deepcanvas::base::cli
