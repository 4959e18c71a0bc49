// The block frame format's internals shared by the encoder (block_frame_encode.cpp) and the
// decoder (block_frame_decode.cpp): header offsets, the transform of 4.3 and the sizes of a delta
// payload (4.7). PROTOCOL.md section 4 is the normative description; block_frame.hpp the API.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"

struct ZSTD_CCtx_s;
struct ZSTD_DCtx_s;

namespace deepcanvas::protocol::frame_format {

static_assert(std::endian::native == std::endian::little,
              "block frames copy pool memory as little-endian bytes");

// ---- header byte offsets (PROTOCOL.md "Block frame header") ----
inline constexpr std::size_t kOffMagic = 0, kOffFormat = 4, kOffHeaderSize = 6, kOffFlags = 8,
                             kOffFields = 10, kOffBlockId = 12, kOffVersion = 16, kOffEpoch = 24,
                             kOffFirstCell = 32, kOffCellCount = 36, kOffStored = 40, kOffRaw = 44,
                             kOffPayloadCrc = 48, kOffStoredCrc = 52, kOffBaseDistance = 56,
                             kOffHeaderCrc = 60;
inline constexpr std::uint16_t kKnownFlags = kFlagCompressed | kFlagTransformed | kFlagDelta;
// zstd window for a frame: the largest payload (2^20 cells, all fields) is under 2^24 bytes.
inline constexpr int kMaxWindowLog = 24;

template <class T>
void put(std::uint8_t* p, T v) {
  std::memcpy(p, &v, sizeof v);
}
template <class T>
T get(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

inline Error malformed(std::string what) {
  return make_error(Errc::malformed, "block frame: " + what);
}

// ---- transform: prediction residuals with kNoCell as 0, zigzag, byte planes ----
inline std::uint32_t zigzag(std::uint32_t r) {
  return (r << 1) ^ static_cast<std::uint32_t>(static_cast<std::int32_t>(r) >> 31);
}
inline std::uint32_t unzigzag(std::uint32_t f) {
  return (f >> 1) ^ (0u - (f & 1));
}

// Bijection on u32: kNoCell -> 0, otherwise the zigzagged residual against the prediction,
// shifted past the one value (K, the code kNoCell itself would have had) that cannot occur.
inline std::uint32_t encode_index(std::uint32_t v, std::uint32_t pred) {
  if (v == kNoCellWire) return 0;
  const std::uint32_t f = zigzag(v - pred);
  const std::uint32_t k = zigzag(kNoCellWire - pred);
  return f < k ? f + 1 : f;
}
inline std::uint32_t decode_index(std::uint32_t t, std::uint32_t pred) {
  if (t == 0) return kNoCellWire;
  const std::uint32_t k = zigzag(kNoCellWire - pred);
  const std::uint32_t f = t <= k ? t - 1 : t;
  return pred + unzigzag(f);
}

// Index pool -> residual codes. The prediction is the previous non-none value plus `stride`
// (children groups and parents are allocated in runs), starting at 0.
inline void delta_encode(std::span<const std::uint32_t> in, std::uint32_t stride,
                         std::uint32_t* out) {
  std::uint32_t pred = 0;
  for (std::size_t i = 0; i < in.size(); ++i) {
    out[i] = encode_index(in[i], pred);
    if (in[i] != kNoCellWire) pred = in[i] + stride;
  }
}
inline void delta_decode(std::uint32_t* values, std::size_t n, std::uint32_t stride) {
  std::uint32_t pred = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint32_t v = decode_index(values[i], pred);
    values[i] = v;
    if (v != kNoCellWire) pred = v + stride;
  }
}

inline void shuffle32(const std::uint32_t* in, std::size_t n, std::uint8_t* out) {
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint32_t v = in[i];
    out[i] = static_cast<std::uint8_t>(v);
    out[n + i] = static_cast<std::uint8_t>(v >> 8);
    out[2 * n + i] = static_cast<std::uint8_t>(v >> 16);
    out[3 * n + i] = static_cast<std::uint8_t>(v >> 24);
  }
}
inline void unshuffle32(const std::uint8_t* in, std::size_t n, std::uint32_t* out) {
  for (std::size_t i = 0; i < n; ++i)
    out[i] = std::uint32_t{in[i]} | std::uint32_t{in[n + i]} << 8 |
             std::uint32_t{in[2 * n + i]} << 16 | std::uint32_t{in[3 * n + i]} << 24;
}

// Colour RGBA8 -> the cells' RGB bytes interleaved, then all alpha bytes: a stroke paints one RGB
// over many cells with varying density, so the two parts repeat differently and compress better
// apart than raw or as four byte planes (deepcanvas-bench protocol measures the transform as a
// whole, on and off).
inline void split_alpha(const std::uint32_t* in, std::size_t n, std::uint8_t* out) {
  std::uint8_t* a = out + 3 * n;
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint32_t v = in[i];
    out[3 * i] = static_cast<std::uint8_t>(v);
    out[3 * i + 1] = static_cast<std::uint8_t>(v >> 8);
    out[3 * i + 2] = static_cast<std::uint8_t>(v >> 16);
    a[i] = static_cast<std::uint8_t>(v >> 24);
  }
}
inline void join_alpha(const std::uint8_t* in, std::size_t n, std::uint32_t* out) {
  const std::uint8_t* a = in + 3 * n;
  for (std::size_t i = 0; i < n; ++i)
    out[i] = std::uint32_t{in[3 * i]} | std::uint32_t{in[3 * i + 1]} << 8 |
             std::uint32_t{in[3 * i + 2]} << 16 | std::uint32_t{a[i]} << 24;
}

inline std::size_t mask_bytes(std::uint32_t groups) {
  return (groups + 7) / 8;
}

// ---- delta payload (4.7): two bitmaps, then the changed cells' and groups' values ----

inline constexpr std::uint16_t kCellFields = kFieldFirstChild | kFieldColour;
inline constexpr std::uint16_t kGroupFields = kFieldGroupParent | kFieldDepthFlags;

inline bool bit(std::span<const std::uint64_t> words, std::size_t i) {
  return (words[i / 64] >> (i % 64)) & 1;
}

// Set bits among the first n of `words`.
inline std::size_t count_bits(std::span<const std::uint64_t> words, std::size_t n) {
  std::size_t c = 0;
  for (std::size_t w = 0; w < n / 64; ++w) c += static_cast<std::size_t>(std::popcount(words[w]));
  if (n % 64)
    c += static_cast<std::size_t>(
        std::popcount(words[n / 64] & ((std::uint64_t{1} << (n % 64)) - 1)));
  return c;
}

// The bytes of the two bitmaps for these fields.
inline std::size_t delta_bitmap_bytes(std::uint32_t cells, std::uint16_t fields) {
  return ((fields & kCellFields) ? cells / 8 : 0) +
         ((fields & kGroupFields) ? mask_bytes(cells / 8) : 0);
}

// The delta payload size for `changed` cells and `changed_groups` groups.
inline std::size_t delta_payload_size(std::uint32_t cells, std::uint16_t fields,
                                      std::size_t changed, std::size_t changed_groups) {
  std::size_t n = delta_bitmap_bytes(cells, fields);
  if (fields & kFieldFirstChild) n += 4 * changed;
  if (fields & kFieldColour) n += 4 * changed;
  if (fields & kFieldGroupParent) n += 4 * changed_groups;
  if (fields & kFieldDepthFlags) n += changed_groups;
  if (fields & kFieldNeighbourMask) n += mask_bytes(cells / 8);
  return n;
}

template <class T>
std::span<const std::uint8_t> bytes_of(std::span<const T> s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size_bytes()};
}

// payload_crc of a block: the CRC of its untransformed payload (4.2), from its spans (the
// encoder's view, or a decoded frame's view_of).
inline std::uint32_t block_payload_crc(const BlockView& b, std::uint16_t fields) {
  std::uint32_t crc = 0;
  if (fields & kFieldFirstChild) crc = crc32(bytes_of(b.first_child), crc);
  if (fields & kFieldColour) crc = crc32(bytes_of(b.colour), crc);
  if (fields & kFieldGroupParent) crc = crc32(bytes_of(b.group_parent), crc);
  if (fields & kFieldDepthFlags) crc = crc32(bytes_of(b.depth_flags), crc);
  if (fields & kFieldNeighbourMask) {  // bits past the last group count as 0
    const std::uint32_t groups = b.cell_count / 8;
    const auto* m = reinterpret_cast<const std::uint8_t*>(b.neighbour_mask.data());
    const std::size_t mb = mask_bytes(groups);
    if (groups % 8 == 0) {
      crc = crc32({m, mb}, crc);
    } else {
      crc = crc32({m, mb - 1}, crc);
      const auto last = static_cast<std::uint8_t>(m[mb - 1] & ((1u << (groups % 8)) - 1));
      crc = crc32({&last, 1}, crc);
    }
  }
  return crc;
}

// ---- shared by block frames and frame bundles (frame_bundle.cpp) ----

// Completes a header whose fields were read (`base_distance` as read from the wire): checks
// flags, fields, the range against the limits and raw_size against the fields, and sets
// base_version for a delta. Not stored_size (its meaning differs between a frame and a bundle
// record).
Result<void> check_block_header(BlockHeader& header, std::uint32_t base_distance,
                                const BlockDecodeLimits& limits);
// Splits a raw (decompressed) payload of exactly header.raw_size bytes into `out`'s fields,
// undoing the transform, and checks payload_crc for a frame that is not a delta. Untrusted bytes.
Result<void> decode_block_payload(const BlockHeader& header, std::span<const std::uint8_t> payload,
                                  BlockFrame& out);
// `stored` must be exactly one zstd frame declaring `raw_size`; decompresses it into `out`
// (resized to raw_size). `what` names the bytes in the error. The context is made on first use.
Result<void> decompress_exact(ZSTD_DCtx_s*& dctx, std::span<const std::uint8_t> stored,
                              std::size_t raw_size, std::vector<std::uint8_t>& out,
                              const char* what);
// `payload` as one zstd frame declaring its size, written after `header_room` bytes of `out`
// (out's size becomes header_room + the frame's). The context is made on first use.
Result<void> compress_payload(ZSTD_CCtx_s*& cctx, int level, const std::uint8_t* payload,
                              std::size_t raw_size, std::vector<std::uint8_t>& scratch,
                              std::vector<std::uint8_t>& out, std::size_t header_room);

}  // namespace deepcanvas::protocol::frame_format
