// Structured log lines on stderr: `ts=... level=info event=session_open key=value ...`.
//
// One line per event, written with a single write() so lines from different threads never
// interleave. Values with spaces, quotes or '=' are quoted. Tokens and other secrets must never
// be passed as values.
//
// Threading: thread-safe. set_log_level() is meant for start-up (and tests that want quiet).
#pragma once

#include <initializer_list>
#include <string>
#include <string_view>
#include <type_traits>

namespace deepcanvas::server_core {

enum class LogLevel : int { debug = 0, info = 1, warn = 2, error = 3, off = 4 };

void set_log_level(LogLevel level) noexcept;
LogLevel log_level() noexcept;
// Parses "debug" | "info" | "warn" | "error" | "off".
bool parse_log_level(std::string_view name, LogLevel& out) noexcept;

struct LogField {
  std::string_view key;
  std::string value;
  LogField(std::string_view k, std::string v) : key(k), value(std::move(v)) {}
  LogField(std::string_view k, std::string_view v) : key(k), value(v) {}
  LogField(std::string_view k, const char* v) : key(k), value(v) {}
  template <class T>
  LogField(std::string_view k, T v) requires std::is_arithmetic_v<T> : key(k),
                                                                       value(std::to_string(v)) {}
};

void log_event(LogLevel level, std::string_view event, std::initializer_list<LogField> fields);

}  // namespace deepcanvas::server_core
