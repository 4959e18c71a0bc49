// Access tokens per canvas, from a tokens file. Format (PROTOCOL.md "Tokens file"):
//
//   # comment
//   <canvas> <role> <token>        one entry per line, fields separated by spaces or tabs
//
// canvas: 1..64 of [A-Za-z0-9._-]; role: painter | viewer; token: 1..256 printable ASCII
// characters without spaces. Blank lines and lines starting with '#' are ignored; CRLF endings are
// accepted. The same token twice for one canvas is an error (even with different roles).
//
// Untrusted input: parse() accepts any bytes and reports the first bad line by number; it never
// echoes token text in messages (tokens are secrets). authorize() compares tokens in time that
// does not depend on where they first differ.
//
// Threading: every member is thread-safe. replace() swaps the entries under a lock, so a
// server can reload its tokens file (SIGHUP) while sessions authorize against the same table:
// each authorize() sees the old or the new entries, never a mix. Copies are independent.
#pragma once

#include <cstddef>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::server_net {

struct TokenEntry {
  std::string canvas;
  protocol::Role role = protocol::Role::viewer;
  std::string token;
};

class TokenTable {
 public:
  static constexpr std::size_t kMaxFileBytes = 1u << 20;

  TokenTable() : data_(std::make_unique<Data>()) {}
  TokenTable(const TokenTable& o) : data_(std::make_unique<Data>()) { data_->entries = o.entries(); }
  TokenTable& operator=(const TokenTable& o) {
    if (this != &o) replace(o);
    return *this;
  }
  TokenTable(TokenTable&&) noexcept = default;
  TokenTable& operator=(TokenTable&&) noexcept = default;

  // malformed (naming the line) for a bad line; limit_exceeded past kMaxFileBytes.
  static Result<TokenTable> parse(std::string_view text);
  // io_error / not_found when the file cannot be read, then as parse().
  static Result<TokenTable> load(const std::string& path);

  // The role granted to `token` on `canvas` when asking for `requested`: a painter token may join
  // as a viewer; a viewer token asking for painter, an unknown canvas or token is unauthorized.
  Result<protocol::Role> authorize(std::string_view canvas, std::string_view token, protocol::Role requested) const;

  // A copy of the entries, in file order.
  std::vector<TokenEntry> entries() const;
  // Distinct canvas names, in order of first appearance.
  std::vector<std::string> canvases() const;
  // Takes `other`'s entries (a reloaded file); authorize() calls in flight finish with the old.
  void replace(const TokenTable& other);

 private:
  struct Data {
    mutable std::mutex mutex;
    std::vector<TokenEntry> entries;
  };
  std::unique_ptr<Data> data_;
};

}  // namespace deepcanvas::server_net
