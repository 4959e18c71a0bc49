#include "deepcanvas/server_net/tokens.hpp"

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>

namespace deepcanvas::server_net {

using protocol::is_valid_canvas_name;
using protocol::is_valid_token;
using protocol::parse_role;
using protocol::Role;

namespace {

bool is_blank(char c) {
  return c == ' ' || c == '\t';
}

// Splits on runs of spaces/tabs.
std::vector<std::string_view> fields_of(std::string_view line) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_blank(line[i])) ++i;
    const std::size_t start = i;
    while (i < line.size() && !is_blank(line[i])) ++i;
    if (i > start) out.push_back(line.substr(start, i - start));
  }
  return out;
}

// Equal iff same bytes; the time depends on the lengths only.
bool same_secret(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  unsigned char diff = 0;
  for (std::size_t i = 0; i < a.size(); ++i) diff |= static_cast<unsigned char>(a[i] ^ b[i]);
  return diff == 0;
}

}  // namespace

Result<TokenTable> TokenTable::parse(std::string_view text) {
  if (text.size() > kMaxFileBytes)
    return make_error(Errc::limit_exceeded,
                      "tokens file larger than " + std::to_string(kMaxFileBytes) + " bytes");
  TokenTable table;
  std::size_t line_no = 0;
  std::size_t pos = 0;
  while (pos <= text.size()) {
    const std::size_t nl = text.find('\n', pos);
    std::string_view line = text.substr(pos, nl == std::string_view::npos ? text.npos : nl - pos);
    pos = nl == std::string_view::npos ? text.size() + 1 : nl + 1;
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    const auto at = [line_no](const std::string& what) {
      return make_error(Errc::malformed, "tokens line " + std::to_string(line_no) + ": " + what);
    };
    std::size_t first = 0;
    while (first < line.size() && is_blank(line[first])) ++first;
    if (first == line.size() || line[first] == '#') continue;
    for (char c : line)
      if (!is_blank(c) && (c < 0x21 || c > 0x7E))
        return at("contains a control or non-ASCII character");
    const auto f = fields_of(line);
    if (f.size() != 3)
      return at("expected 'canvas role token', found " + std::to_string(f.size()) + " fields");
    if (!is_valid_canvas_name(f[0])) return at("canvas name must be 1..64 of [A-Za-z0-9._-]");
    auto role = parse_role(f[1]);
    if (!role) return at("role must be painter or viewer");
    if (!is_valid_token(f[2])) return at("token must be 1..256 printable characters");
    for (const auto& e : table.data_->entries)
      if (e.canvas == f[0] && e.token == f[2]) return at("duplicate token for canvas " + e.canvas);
    table.data_->entries.push_back({std::string(f[0]), *role, std::string(f[2])});
  }
  return table;
}

Result<TokenTable> TokenTable::load(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in)
    return make_error(errno == ENOENT ? Errc::not_found : Errc::io_error,
                      "tokens file '" + path + "': " + std::strerror(errno));
  std::string text;
  char buf[4096];
  while (in.read(buf, sizeof buf) || in.gcount() > 0) {
    text.append(buf, static_cast<std::size_t>(in.gcount()));
    if (text.size() > kMaxFileBytes)
      return make_error(Errc::limit_exceeded, "tokens file '" + path + "' larger than " +
                                                  std::to_string(kMaxFileBytes) + " bytes");
  }
  if (in.bad()) return make_error(Errc::io_error, "tokens file '" + path + "': read failed");
  auto t = parse(text);
  if (!t) return make_error(t.error().code, "'" + path + "': " + t.error().message);
  return t;
}

Result<Role> TokenTable::authorize(std::string_view canvas, std::string_view token,
                                   Role requested) const {
  // Scan every entry of the canvas without stopping early, so timing reveals nothing about
  // which entry (if any) matched.
  bool found = false;
  Role role = Role::viewer;
  std::lock_guard lock(data_->mutex);
  for (const auto& e : data_->entries) {
    if (e.canvas != canvas) continue;
    const bool match = same_secret(e.token, token);
    if (match) role = e.role;
    found = found || match;
  }
  if (!found)
    return make_error(Errc::unauthorized, "no such token for canvas '" + std::string(canvas) + "'");
  if (requested == Role::painter && role != Role::painter)
    return make_error(Errc::unauthorized,
                      "this token may only view canvas '" + std::string(canvas) + "'");
  return requested;
}

std::vector<TokenEntry> TokenTable::entries() const {
  std::lock_guard lock(data_->mutex);
  return data_->entries;
}

void TokenTable::replace(const TokenTable& other) {
  auto copy = other.entries();
  std::lock_guard lock(data_->mutex);
  data_->entries = std::move(copy);
}

std::vector<std::string> TokenTable::canvases() const {
  std::vector<std::string> out;
  for (const auto& e : entries())
    if (std::find(out.begin(), out.end(), e.canvas) == out.end()) out.push_back(e.canvas);
  return out;
}

}  // namespace deepcanvas::server_net
