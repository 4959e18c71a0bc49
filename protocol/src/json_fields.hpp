// Reading JSON control messages field by field (messages.cpp and messages_files.cpp): every
// error names the field's path. Private to the protocol target.
#pragma once

#include <array>
#include <cmath>
#include <nlohmann/json.hpp>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/messages.hpp"

namespace deepcanvas::protocol::detail {

using nlohmann::json;

inline Error malformed(std::string what) {
  return make_error(Errc::malformed, std::move(what));
}
inline Error out_of_range(std::string what) {
  return make_error(Errc::invalid_argument, std::move(what));
}

// Field access with the field's path in every error. Never throws: each get<> below is preceded
// by the JSON type check that makes it valid.
class Obj {
 public:
  Obj(const json& j, std::string path) : j_(j), path_(std::move(path)) {}

  std::string name(std::string_view key) const {
    return path_.empty() ? std::string(key) : path_ + "." + std::string(key);
  }

  Result<const json*> field(std::string_view key) const {
    const auto it = j_.find(key);
    if (it == j_.end()) return malformed("missing field '" + name(key) + "'");
    return &*it;
  }
  bool has(std::string_view key) const { return j_.find(key) != j_.end(); }

  Result<std::uint64_t> uint(std::string_view key, std::uint64_t max = kMaxJsonInteger) const {
    auto f = field(key);
    if (!f) return std::move(f).error();
    return uint_value(**f, name(key), max);
  }

  Result<double> number(std::string_view key, double lo, double hi) const {
    auto f = field(key);
    if (!f) return std::move(f).error();
    return number_value(**f, name(key), lo, hi);
  }

  Result<bool> boolean(std::string_view key) const {
    auto f = field(key);
    if (!f) return std::move(f).error();
    if (!(*f)->is_boolean()) return malformed("field '" + name(key) + "' must be true or false");
    return (*f)->get<bool>();
  }

  Result<std::string> string(std::string_view key, std::size_t max_len) const {
    auto f = field(key);
    if (!f) return std::move(f).error();
    if (!(*f)->is_string()) return malformed("field '" + name(key) + "' must be a string");
    const auto& s = (*f)->get_ref<const std::string&>();
    if (s.size() > max_len)
      return out_of_range("field '" + name(key) + "' is longer than " + std::to_string(max_len) +
                          " bytes");
    return s;
  }

  Result<Obj> object(std::string_view key) const {
    auto f = field(key);
    if (!f) return std::move(f).error();
    if (!(*f)->is_object()) return malformed("field '" + name(key) + "' must be an object");
    return Obj(**f, name(key));
  }

  Result<const json*> array(std::string_view key) const {
    auto f = field(key);
    if (!f) return std::move(f).error();
    if (!(*f)->is_array()) return malformed("field '" + name(key) + "' must be an array");
    return *f;
  }

  static Result<std::uint64_t> uint_value(const json& v, const std::string& what,
                                          std::uint64_t max) {
    std::uint64_t x = 0;
    if (v.is_number_unsigned()) {
      x = v.get<std::uint64_t>();
    } else if (v.is_number_integer()) {
      const auto s = v.get<std::int64_t>();
      if (s < 0) return out_of_range("field '" + what + "' must not be negative");
      x = static_cast<std::uint64_t>(s);
    } else {
      return malformed("field '" + what + "' must be an integer");
    }
    if (x > max)
      return out_of_range("field '" + what + "' exceeds its maximum " + std::to_string(max));
    return x;
  }

  static Result<double> number_value(const json& v, const std::string& what, double lo, double hi) {
    if (!v.is_number()) return malformed("field '" + what + "' must be a number");
    const double d = v.get<double>();
    if (!std::isfinite(d)) return out_of_range("field '" + what + "' must be finite");
    if (d < lo || d > hi)
      return out_of_range("field '" + what + "' must be within [" + std::to_string(lo) + ", " +
                          std::to_string(hi) + "]");
    return d;
  }

 private:
  const json& j_;
  std::string path_;
};

// A box of the canvas, field `key`: six numbers x0 y0 z0 x1 y1 z1, each within the canvas of edge
// `edge_m` (centred on the origin), the minimum corner first.
inline Result<std::array<double, 6>> read_box(const Obj& o, std::string_view key, double edge_m) {
  auto f = o.array(key);
  if (!f) return std::move(f).error();
  const json& box = **f;
  const std::string name = o.name(key);
  if (box.size() != 6) return malformed("field '" + name + "' must hold 6 numbers");
  std::array<double, 6> b{};
  for (std::size_t i = 0; i < 6; ++i) {
    auto v = Obj::number_value(box[i], name + "[" + std::to_string(i) + "]", -edge_m / 2, edge_m / 2);
    if (!v) return std::move(v).error();
    b[i] = *v;
  }
  if (b[0] > b[3] || b[1] > b[4] || b[2] > b[5])
    return out_of_range("field '" + name + "': the minimum corner must not pass the maximum");
  return b;
}

#define DC_TRY(var, expr)                          \
  auto var##_r = (expr);                           \
  if (!var##_r) return std::move(var##_r).error(); \
  auto var = std::move(var##_r).value()

// Import and export messages (messages_files.cpp).
json import_json(const Import& m);
json import_reply_json(const ImportReply& m);
Result<Message> read_import(const Obj& o, const DecodeOptions& opt, MessageRef* about);
Result<Message> read_import_reply(const Obj& o, MessageRef* about);
json export_json(const ExportRequest& m);
json export_reply_json(const ExportReply& m);
Result<Message> read_export(const Obj& o, const DecodeOptions& opt, MessageRef* about);
Result<Message> read_export_reply(const Obj& o, const DecodeOptions& opt, MessageRef* about);

// History playback messages (messages_playback.cpp).
json playback_step_json(const PlaybackStep& m);
json playback_position_json(const PlaybackPosition& m);
Result<Message> read_playback_step(const Obj& o, MessageRef* about);
Result<Message> read_playback_position(const Obj& o, const DecodeOptions& opt, MessageRef* about);

// Base64 (RFC 4648, with padding). decode: malformed for any other character, bad padding or a
// length that is not a multiple of 4.
std::string base64_encode(std::span<const std::uint8_t> bytes);
Result<std::vector<std::uint8_t>> base64_decode(std::string_view text);

}  // namespace deepcanvas::protocol::detail
