// Frame bundles: the block frames of one live batch as ONE binary WebSocket message, compressed
// together (PROTOCOL.md 4.12 is the normative description).
//
// A stroke's epoch changes a few blocks by a few hundred bytes each. Sent one by one, each delta
// frame pays a 64-byte header (two of its CRCs incompressible) and zstd's per-frame overhead and
// tables, and shares no statistics with its neighbours: a fifth of the bytes of a viewer's
// stream. A bundle holds the same frames as records (a 44-byte header without the CRCs a frame
// needs only alone, then the frame's payload uncompressed), and compresses all of them as one
// zstd frame: about 0.8x of the separate frames' bytes on the real paintings (deepcanvas-bench
// e2e). Every record resolves to exactly the block frame it was made from, so a receiver stages
// them as it stages frames.
//
//   bundle   = header (32 bytes) | zstd frame of raw_size bytes: record_count records
//   header   = magic "DCBN" u32 | format_version u16 (1) | header_size u16 (32) |
//              record_count u32 | raw_size u32 | epoch u64 (the newest record's) |
//              stored_crc u32 (of the zstd frame) | header_crc u32 (of bytes 0..27)
//   record   = flags u16 | fields u16 | block_id u32 | block_version u64 | epoch u64 |
//              first_cell u32 | cell_count u32 | raw_size u32 | payload_crc u32 |
//              base_distance u32 | payload (raw_size bytes, as a frame's before compression)
//
// Untrusted input: decode_bundle accepts any bytes. It bounds raw_size by the limits before
// allocating, requires exactly one zstd frame of the declared size, checks both CRCs, checks every
// record header as a block frame header is checked (BlockDecodeLimits), and never throws for bad
// input. The records' payload_crc is checked as a frame's is (a delta's after resolving it).
//
// Threading: a BundleEncoder / BundleDecoder holds zstd contexts and buffers: one per thread.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/block_frame.hpp"

namespace deepcanvas::protocol {

inline constexpr std::uint32_t kBundleMagic = 0x4E424344u;  // bytes "DCBN"
inline constexpr std::uint16_t kBundleVersion = 1;
inline constexpr std::size_t kBundleHeaderSize = 32;
inline constexpr std::size_t kBundleRecordHeaderSize = 44;

// True when `message` starts with the bundle magic (else it may be a block frame).
bool is_bundle(std::span<const std::uint8_t> message) noexcept;

struct BundleHeader {
  std::uint32_t record_count = 0;
  std::uint32_t raw_size = 0;
  std::uint64_t epoch = 0;
};

struct BundleDecodeLimits {
  BlockDecodeLimits block;                           // for every record
  std::size_t max_raw_bytes = std::size_t{1} << 24;  // 16 MiB: zstd's window for a frame
};

// Parses and checks the header alone (magic, version, header CRC, sizes against the message and
// the limits): a receiver that keeps no replica counts the records from it.
Result<BundleHeader> parse_bundle_header(std::span<const std::uint8_t> message,
                                         const BundleDecodeLimits& limits = {});

class BundleEncoder {
 public:
  explicit BundleEncoder(int level = kDefaultZstdLevel);
  ~BundleEncoder();
  BundleEncoder(BundleEncoder&&) noexcept;
  BundleEncoder& operator=(BundleEncoder&&) noexcept;

  // Appends a block frame (as BlockEncoder made it: full, delta or mask-only, compressed or not)
  // as the next record, decompressing its payload. Errors: the frame's header does not parse, or
  // its payload does not decompress (malformed); nothing is appended then.
  Result<void> add(std::span<const std::uint8_t> frame);
  std::size_t records() const noexcept;
  std::size_t raw_size() const noexcept;  // the records' bytes so far
  // Replaces `out` with the bundle of the records added since the last finish() (at least one,
  // else invalid_argument) and starts an empty one.
  Result<void> finish(std::vector<std::uint8_t>& out);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

class BundleDecoder {
 public:
  BundleDecoder();
  ~BundleDecoder();
  BundleDecoder(BundleDecoder&&) noexcept;
  BundleDecoder& operator=(BundleDecoder&&) noexcept;

  // Decodes every record in order into `frame` (reusing its vectors) and calls `on_frame` with
  // it, as BlockDecoder::decode would have left the frame the record was made from. Stops at the
  // first error, its own or one `on_frame` returns; records before it were handed over. Returns
  // the header. Errors as BlockDecoder::decode's.
  Result<BundleHeader> decode(std::span<const std::uint8_t> message,
                              const BundleDecodeLimits& limits, BlockFrame& frame,
                              const std::function<Result<void>(BlockFrame&)>& on_frame);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace deepcanvas::protocol
