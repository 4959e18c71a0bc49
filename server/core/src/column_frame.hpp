// The zstd frame that cell diffs (cell_diff.cpp) and cell pastes (cell_paste.cpp) are stored
// in: a header (u32 magic, u32 version, u64 count) and little-endian columns, compressed whole.
// Private to server_core.
#pragma once

#include <zstd.h>

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::server_core::detail {

inline void put32(std::uint8_t* p, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
inline std::uint32_t get32(const std::uint8_t* p) {
  return std::uint32_t{p[0]} | (std::uint32_t{p[1]} << 8) | (std::uint32_t{p[2]} << 16) |
         (std::uint32_t{p[3]} << 24);
}

inline constexpr std::size_t kColumnHeader = 16;

// `raw` (header included) compressed at zstd level 3.
inline std::vector<std::uint8_t> compress_columns(const std::vector<std::uint8_t>& raw) {
  std::vector<std::uint8_t> out(ZSTD_compressBound(raw.size()));
  const std::size_t z = ZSTD_compress(out.data(), out.size(), raw.data(), raw.size(), 3);
  if (ZSTD_isError(z)) return {};  // cannot happen with a bound-sized buffer
  out.resize(z);
  return out;
}

// Untrusted bytes: the decompressed frame (header included) when it is one zstd frame of at
// least the header and at most `max_size` bytes (`too_big` otherwise, naming `what`) with the
// magic and version; malformed "WHAT: ..." for anything else. The count's agreement with the
// size is the caller's to check.
inline Result<std::vector<std::uint8_t>> decompress_columns(std::span<const std::uint8_t> bytes,
                                                            unsigned long long max_size,
                                                            std::uint32_t magic,
                                                            std::uint32_t version,
                                                            const std::string& what,
                                                            Errc too_big = Errc::malformed) {
  auto bad = [&](const std::string& why) { return Error{Errc::malformed, what + ": " + why}; };
  const unsigned long long size = ZSTD_getFrameContentSize(bytes.data(), bytes.size());
  if (bytes.empty() || size == ZSTD_CONTENTSIZE_ERROR || size == ZSTD_CONTENTSIZE_UNKNOWN)
    return bad("not a zstd frame");
  if (size < kColumnHeader) return bad("shorter than its header");
  if (size > max_size)
    return Error{too_big, what + ": " + std::to_string(size) + " bytes: more than the limit"};
  std::vector<std::uint8_t> raw(static_cast<std::size_t>(size));
  const std::size_t got = ZSTD_decompress(raw.data(), raw.size(), bytes.data(), bytes.size());
  if (ZSTD_isError(got) || got != raw.size()) return bad("does not decompress");
  if (get32(raw.data()) != magic) return bad("bad magic");
  if (get32(raw.data() + 4) != version)
    return bad("unsupported version " + std::to_string(get32(raw.data() + 4)));
  return raw;
}

}  // namespace deepcanvas::server_core::detail
