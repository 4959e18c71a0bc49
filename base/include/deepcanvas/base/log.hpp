// Structured log lines, one event a line, on spdlog: the one logger of the server and the client.
//
//   log_event(LogLevel::info, "session_open", {{"session", id}, {"role", "painter"}});
//
// Two formats, chosen at start-up (set_log_format):
//   text  ts=2026-11-25T05:18:38.123Z level=info event=session_open session=7 role=painter
//   json  {"ts":"2026-11-25T05:18:38.123Z","level":"info","event":"session_open","session":7,...}
//
// Values are untrusted (a client's name, an error text): they are escaped so that no byte of a
// value can end, forge or corrupt a line. In text, a value holding a space, '=', a quote, a
// backslash, a control byte (< 0x20, 0x7f), a C1 control or invalid UTF-8 is written in quotes
// with \" \\ \n \r \t and \xNN escapes; a text line has no raw control byte and ends with exactly
// one '\n'. In JSON, every line is one valid JSON object: control bytes become \uXXXX, and each
// byte of invalid UTF-8 becomes the four characters \xNN (so valid UTF-8 reads back unchanged).
// Keys and event names are expected to be identifiers written in the code; they are escaped too.
// Tokens and other secrets must never be passed as values.
//
// Rate limit: per event name at most set_log_rate_limit() lines a second (default 20), so a
// failure repeating in a loop (a spinning accept) cannot fill a disk. Lines over the limit are
// counted and the count is reported as `suppressed=K` on the next line of that event written.
//
// Output goes through one spdlog logger whose sink writes whole lines under a mutex, so lines from
// different threads never interleave. Default sink: stderr.
//
// Threading: log_event() is thread-safe. set_log_level(), set_log_format(),
// set_log_rate_limit() and set_log_sink() are meant for start-up and tests; they are safe to call
// concurrently with log_event() but lines in flight may use the old setting.
#pragma once

#include <spdlog/fwd.h>

#include <initializer_list>
#include <memory>
#include <string>
#include <string_view>
#include <type_traits>

namespace deepcanvas::base {

enum class LogLevel : int { debug = 0, info = 1, warn = 2, error = 3, off = 4 };
enum class LogFormat { text, json };

void set_log_level(LogLevel level) noexcept;
LogLevel log_level() noexcept;
// Parses "debug" | "info" | "warn" | "error" | "off"; false (out untouched) for anything else.
bool parse_log_level(std::string_view name, LogLevel& out) noexcept;

void set_log_format(LogFormat format) noexcept;
LogFormat log_format() noexcept;
// Parses "text" | "json".
bool parse_log_format(std::string_view name, LogFormat& out) noexcept;

// Lines a second allowed per event name; 0 lifts the limit. Resets the counts.
void set_log_rate_limit(unsigned lines_per_second);

// Where lines go: nullptr restores stderr. Tests pass an ostream sink to read lines back.
void set_log_sink(std::shared_ptr<spdlog::sinks::sink> sink);

struct LogField {
  std::string_view key;
  std::string value;
  bool number = false;  // written unquoted in JSON (value came from an arithmetic type)
  LogField(std::string_view k, std::string v) : key(k), value(std::move(v)) {}
  LogField(std::string_view k, std::string_view v) : key(k), value(v) {}
  LogField(std::string_view k, const char* v) : key(k), value(v) {}
  LogField(std::string_view k, bool v) : key(k), value(v ? "true" : "false") {}
  template <class T>
  LogField(std::string_view k, T v) requires(std::is_arithmetic_v<T> && !std::is_same_v<T, bool>)
      : key(k), value(std::to_string(v)), number(true) {}
};

// Writes one line if level passes the filter and the event is under its rate limit.
void log_event(LogLevel level, std::string_view event, std::initializer_list<LogField> fields);

}  // namespace deepcanvas::base
