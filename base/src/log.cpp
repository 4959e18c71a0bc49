#include "deepcanvas/base/log.hpp"

#include <spdlog/logger.h>
#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <mutex>
#include <unordered_map>

#include "deepcanvas/base/utf8.hpp"

namespace deepcanvas::base {

namespace {

constexpr std::string_view kNames[] = {"debug", "info", "warn", "error", "off"};

std::atomic<int> g_level{static_cast<int>(LogLevel::info)};
std::atomic<int> g_format{static_cast<int>(LogFormat::text)};

// The rate limit and the logger, under one mutex: a line's decision and its sink are consistent.
struct EventWindow {
  std::chrono::steady_clock::time_point start{};
  unsigned written = 0;
  unsigned long long suppressed = 0;
};

struct State {
  std::mutex mutex;
  unsigned per_second = 20;
  std::unordered_map<std::string, EventWindow> windows;
  std::shared_ptr<spdlog::logger> logger;
};

std::shared_ptr<spdlog::logger> make_logger(std::shared_ptr<spdlog::sinks::sink> sink) {
  if (!sink) sink = std::make_shared<spdlog::sinks::stderr_sink_mt>();
  // Not registered with spdlog's global registry: the line is formatted here, the pattern only
  // appends the newline, and spdlog's own level filter stays open (ours decides).
  auto logger = std::make_shared<spdlog::logger>("deepcanvas", std::move(sink));
  logger->set_pattern("%v");
  logger->set_level(spdlog::level::trace);
  logger->flush_on(spdlog::level::trace);
  return logger;
}

State& state() {
  static State s{.mutex = {}, .per_second = 20, .windows = {}, .logger = make_logger(nullptr)};
  return s;
}

void append_hex_escape(std::string& out, unsigned char c, const char* prefix) {
  char buf[12];
  std::snprintf(buf, sizeof buf, "%s%02x", prefix, static_cast<unsigned>(c));
  out += buf;
}

// How a quoted value escapes what may not appear raw in a log line. Both formats escape quotes,
// backslashes, \n \r \t, the other C0 controls, DEL and the C1 controls (U+0080..U+009F, which
// act on terminals like ESC does); they differ in the spelling of an escaped code point and of a
// byte that is not valid UTF-8 (a JSON string must stay valid UTF-8, so it gets the text \xNN).
// Text escapes bytes (\xNN), so unescaping gives back the original bytes, C1 controls included.
struct EscapeStyle {
  const char* code_point;    // prefix of two hex digits for a control code point
  const char* invalid_byte;  // prefix of two hex digits for a byte that is not valid UTF-8
  bool c1_as_bytes;          // a C1 control as its two UTF-8 bytes, else as its code point
};
constexpr EscapeStyle kTextEscapes{"\\x", "\\x", true};
constexpr EscapeStyle kJsonEscapes{"\\u00", "\\\\x", false};

void append_quoted(std::string& out, std::string_view v, const EscapeStyle& style) {
  out += '"';
  for (std::size_t i = 0; i < v.size();) {
    const auto c = static_cast<unsigned char>(v[i]);
    std::size_t n = 1;
    if (c == '"' || c == '\\') {
      out += '\\';
      out += static_cast<char>(c);
    } else if (c == '\n') {
      out += "\\n";
    } else if (c == '\r') {
      out += "\\r";
    } else if (c == '\t') {
      out += "\\t";
    } else if (c < 0x20 || c == 0x7f) {
      append_hex_escape(out, c, style.code_point);
    } else if (c < 0x80) {
      out += static_cast<char>(c);
    } else if ((n = utf8_sequence_length(v, i)) == 0) {
      append_hex_escape(out, c, style.invalid_byte);
      n = 1;
    } else if (n == 2 && c == 0xc2 && static_cast<unsigned char>(v[i + 1]) < 0xa0) {
      // A C1 control, c2 80..c2 9f.
      if (style.c1_as_bytes) append_hex_escape(out, c, style.invalid_byte);
      append_hex_escape(out, static_cast<unsigned char>(v[i + 1]),
                        style.c1_as_bytes ? style.invalid_byte : style.code_point);
    } else {
      out.append(v.substr(i, n));
    }
    i += n;
  }
  out += '"';
}

// Text: plain when the value is a simple token, else quoted with every unsafe byte escaped.
void append_text_value(std::string& out, std::string_view v) {
  bool quote = v.empty();
  for (std::size_t i = 0; i < v.size() && !quote; ++i) {
    const auto c = static_cast<unsigned char>(v[i]);
    quote = c <= 0x20 || c == 0x7f || c == '"' || c == '=' || c == '\\' || c >= 0x80;
  }
  if (quote)
    append_quoted(out, v, kTextEscapes);
  else
    out += v;
}

void append_json_string(std::string& out, std::string_view v) {
  append_quoted(out, v, kJsonEscapes);
}

// std::to_string of an integer or a finite double; nan and inf are not JSON numbers.
bool is_json_number(std::string_view v) {
  if (v.empty()) return false;
  for (char c : v)
    if (!((c >= '0' && c <= '9') || c == '-' || c == '.')) return false;
  return true;
}

std::string timestamp() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  std::tm tm{};
  gmtime_r(&t, &tm);
  char ts[48];
  std::snprintf(ts, sizeof ts, "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ", tm.tm_year + 1900,
                tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, static_cast<int>(ms));
  return ts;
}

std::string format_text(LogLevel level, std::string_view event,
                        std::initializer_list<LogField> fields, unsigned long long suppressed) {
  std::string line = "ts=" + timestamp();
  line += " level=";
  line += kNames[static_cast<int>(level)];
  line += " event=";
  append_text_value(line, event);
  for (const LogField& f : fields) {
    line += ' ';
    append_text_value(line, f.key);
    line += '=';
    append_text_value(line, f.value);
  }
  if (suppressed > 0) line += " suppressed=" + std::to_string(suppressed);
  return line;
}

std::string format_json(LogLevel level, std::string_view event,
                        std::initializer_list<LogField> fields, unsigned long long suppressed) {
  std::string line = "{\"ts\":\"" + timestamp() + "\",\"level\":\"";
  line += kNames[static_cast<int>(level)];
  line += "\",\"event\":";
  append_json_string(line, event);
  for (const LogField& f : fields) {
    line += ',';
    append_json_string(line, f.key);
    line += ':';
    if (f.number && is_json_number(f.value))
      line += f.value;
    else
      append_json_string(line, f.value);
  }
  if (suppressed > 0) line += ",\"suppressed\":" + std::to_string(suppressed);
  line += '}';
  return line;
}

}  // namespace

void set_log_level(LogLevel level) noexcept {
  g_level.store(static_cast<int>(level));
}
LogLevel log_level() noexcept {
  return static_cast<LogLevel>(g_level.load());
}

bool parse_log_level(std::string_view name, LogLevel& out) noexcept {
  for (int i = 0; i < 5; ++i)
    if (kNames[i] == name) {
      out = static_cast<LogLevel>(i);
      return true;
    }
  return false;
}

void set_log_format(LogFormat format) noexcept {
  g_format.store(static_cast<int>(format));
}
LogFormat log_format() noexcept {
  return static_cast<LogFormat>(g_format.load());
}

bool parse_log_format(std::string_view name, LogFormat& out) noexcept {
  if (name == "text") {
    out = LogFormat::text;
    return true;
  }
  if (name == "json") {
    out = LogFormat::json;
    return true;
  }
  return false;
}

void set_log_rate_limit(unsigned lines_per_second) {
  State& s = state();
  std::lock_guard lock(s.mutex);
  s.per_second = lines_per_second;
  s.windows.clear();
}

void set_log_sink(std::shared_ptr<spdlog::sinks::sink> sink) {
  auto logger = make_logger(std::move(sink));
  State& s = state();
  std::lock_guard lock(s.mutex);
  s.logger = std::move(logger);
}

void log_event(LogLevel level, std::string_view event, std::initializer_list<LogField> fields) {
  if (level == LogLevel::off) return;
  if (static_cast<int>(level) < g_level.load(std::memory_order_relaxed)) return;
  State& s = state();
  unsigned long long suppressed = 0;
  std::shared_ptr<spdlog::logger> logger;
  {
    std::lock_guard lock(s.mutex);
    if (s.per_second > 0) {
      const auto now = std::chrono::steady_clock::now();
      auto it = s.windows.find(std::string(event));
      if (it == s.windows.end()) it = s.windows.emplace(std::string(event), EventWindow{}).first;
      EventWindow& w = it->second;
      if (w.written == 0 || now - w.start >= std::chrono::seconds(1)) {
        w.start = now;
        w.written = 0;
      }
      if (w.written >= s.per_second) {
        ++w.suppressed;
        return;
      }
      ++w.written;
      suppressed = w.suppressed;
      w.suppressed = 0;
    }
    logger = s.logger;
  }
  const std::string line = static_cast<LogFormat>(g_format.load()) == LogFormat::json
                               ? format_json(level, event, fields, suppressed)
                               : format_text(level, event, fields, suppressed);
  static constexpr spdlog::level::level_enum kSpd[] = {spdlog::level::debug, spdlog::level::info,
                                                       spdlog::level::warn, spdlog::level::err};
  logger->log(kSpd[static_cast<int>(level)], spdlog::string_view_t(line.data(), line.size()));
}

}  // namespace deepcanvas::base
