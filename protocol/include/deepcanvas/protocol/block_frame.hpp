// Block update frames: the binary WebSocket frames that carry pool bytes from server to client.
// PROTOCOL.md section "Block frames" is the normative byte-by-byte description.
//
// A frame is a fixed 64-byte little-endian header followed by the payload. The payload holds,
// for a range of cells [first_cell, first_cell + cell_count) (cell_count a multiple of 8, so the
// range covers whole groups), the fields the header's field mask names, in this order:
//   first_child  u32 x cells,  colour  u32 x cells,  group_parent  u32 x groups,
//   depth_flags  u8 x groups,  neighbour mask  1 bit per group (LSB first), zero padded to bytes.
// With kFlagTransformed the index pools are delta coded against a prediction and byte-plane
// shuffled, and colour is stored as interleaved RGB then alpha (all size preserving); with
// kFlagCompressed the payload is one zstd frame.
// The header carries CRC-32 checksums of itself, of the stored payload bytes and of the
// untransformed payload (so the whole transform + compression path is verified end to end).
//
// Temporal delta frames (kFlagDelta, PROTOCOL.md 4.7): a newer version of a block that the
// receiver already holds an older version of (base_version, same fields, a range that is a prefix
// of the frame's). The payload names the changed cells and groups in two bitmaps and carries the
// new values of those alone (transformed as a full frame's pools are, when kFlagTransformed);
// every other cell keeps the base's value (0 past the base's range); the neighbour mask is carried
// whole. A stroke changes a few percent of a block's cells, and the new values alone (one brush
// colour, runs of new children) compress far better than the block or the XOR of two versions.
// decode() returns the bitmaps and the changed values; apply_block_delta() expands them over the
// base and then verifies payload_crc, which is always the checksum of the *resulting* block, so a
// wrong base is detected. Deltas compose: a delta from version a to c marks the cells marked in
// a->b or b->c and carries c's values (BlockEncoder::encode_changes).
//
// Untrusted input: BlockDecoder::decode and apply_block_delta accept any bytes. It checks every
// length against the header, bounds the cell count (and so every allocation) by DecodeLimits before
// allocating, requires the zstd frame to declare exactly the expected size, decompresses into a
// buffer of that size only, and verifies both checksums. It never throws for bad input.
//
// Threading: a BlockEncoder / BlockDecoder holds a zstd context: one per thread. Free functions
// are thread-safe. Host byte order must be little-endian (static_assert in the source).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::protocol {

inline constexpr std::uint32_t kBlockFrameMagic = 0x4B424344u;  // bytes "DCBK"
inline constexpr std::size_t kBlockHeaderSize = 64;
inline constexpr std::uint32_t kNoCellWire = 0xFFFFFFFFu;  // server_core::kNoCell

// Header flags.
inline constexpr std::uint16_t kFlagCompressed = 1u << 0;   // payload is a zstd frame
inline constexpr std::uint16_t kFlagTransformed = 1u << 1;  // delta + byte-plane / alpha split
inline constexpr std::uint16_t kFlagDelta = 1u << 2;        // the cells changed since base_version

// Field mask bits.
inline constexpr std::uint16_t kFieldFirstChild = 1u << 0;
inline constexpr std::uint16_t kFieldColour = 1u << 1;
inline constexpr std::uint16_t kFieldGroupParent = 1u << 2;
inline constexpr std::uint16_t kFieldDepthFlags = 1u << 3;
inline constexpr std::uint16_t kFieldNeighbourMask = 1u << 4;
inline constexpr std::uint16_t kFieldAll = 0x1F;

// zstd level chosen by measurement: deepcanvas-bench protocol reports the compression ratio and
// the encode and decode speed of levels 1, 3, 5 and 9 on octree blocks; level 3 compresses a
// little better than 1 at the same speed, and within a few percent of 5 and 9 at half or less of
// their encoding time.
inline constexpr int kDefaultZstdLevel = 3;

// CRC-32 (IEEE 802.3, reflected, as zlib.crc32 / binascii.crc32): continue with crc = previous.
// Computed by ISA-L (crc32.cpp). Thread-safe, any length.
std::uint32_t crc32(std::span<const std::uint8_t> bytes, std::uint32_t crc = 0) noexcept;

// Payload bytes (untransformed, uncompressed) for `cell_count` cells and a field mask.
std::size_t block_payload_size(std::uint32_t cell_count, std::uint16_t fields) noexcept;

// One block's pools as views into the sender's memory (e.g. a staged block). A field is present
// iff its span is non-empty; present spans must have exactly the sizes below.
struct BlockView {
  std::uint32_t block_id = 0;
  std::uint64_t version = 0;
  std::uint64_t epoch = 0;
  std::uint32_t first_cell = 0;                 // multiple of 8
  std::uint32_t cell_count = 0;                 // multiple of 8, > 0
  std::span<const std::uint32_t> first_child;   // cell_count
  std::span<const std::uint32_t> colour;        // cell_count
  std::span<const std::uint32_t> group_parent;  // cell_count / 8
  std::span<const std::uint8_t> depth_flags;    // cell_count / 8
  // Bit g (word g / 64, bit g % 64) is group first_cell / 8 + g; ceil(groups / 64) words. Bits
  // past the last group are ignored.
  std::span<const std::uint64_t> neighbour_mask;
};

struct BlockHeader {
  std::uint16_t format_version = 0;
  std::uint16_t flags = 0;
  std::uint16_t fields = 0;
  std::uint32_t block_id = 0;
  std::uint64_t version = 0;
  std::uint64_t epoch = 0;
  std::uint32_t first_cell = 0;
  std::uint32_t cell_count = 0;
  std::uint32_t stored_size = 0;  // payload bytes following the header
  std::uint32_t raw_size = 0;     // payload bytes before compression
  std::uint32_t payload_crc = 0;  // CRC-32 of the untransformed, uncompressed payload
  std::uint32_t stored_crc = 0;   // CRC-32 of the payload bytes as stored in the frame
  // kFlagDelta only: the block version the delta applies to (< version; 0 for other frames). On the
  // wire it is stored as version - base_version (u32 at byte 56).
  std::uint64_t base_version = 0;
};

// A decoded frame; absent fields are empty vectors. For a delta frame (header.flags & kFlagDelta)
// the pool fields hold the values of the changed cells (groups) alone, in cell order, until
// apply_block_delta() resolves them.
struct BlockFrame {
  BlockHeader header;
  std::vector<std::uint32_t> first_child;
  std::vector<std::uint32_t> colour;
  std::vector<std::uint32_t> group_parent;
  std::vector<std::uint8_t> depth_flags;
  std::vector<std::uint64_t> neighbour_mask;  // ceil(groups / 64) words, unused bits zero
  // Delta frames only (empty otherwise): bit i (word i / 64, bit i % 64) is set when cell
  // first_cell + i (group first_cell / 8 + i) changed; ceil(cells / 64) (ceil(groups / 64))
  // words, unused bits zero; empty when the frame carries no per-cell (per-group) pool.
  std::vector<std::uint64_t> changed_cells;
  std::vector<std::uint64_t> changed_groups;
  bool has(std::uint16_t field) const noexcept { return (header.fields & field) != 0; }
  bool is_delta() const noexcept { return (header.flags & kFlagDelta) != 0; }
};

// A decoded frame as a BlockView: its header's block, range, version and epoch, views of its
// pools and mask (valid while `frame` lives unchanged). E.g. a resolved frame as the base of the
// next delta, or a decoded frame encoded again.
BlockView view_of(const BlockFrame& frame) noexcept;

// Which cells and groups of a block changed since an older version (a delta frame's bitmaps, as
// in BlockFrame::changed_cells / changed_groups): spans of ceil(cells / 64) and ceil(groups / 64)
// words, bits past the range ignored. A bit may be set for a cell that did not change.
struct BlockChanges {
  std::uint64_t base_version = 0;
  std::span<const std::uint64_t> cells;
  std::span<const std::uint64_t> groups;
};

struct BlockEncodeOptions {
  int level = kDefaultZstdLevel;  // zstd level (1..19); ignored without compress
  bool transform = true;          // delta + byte-plane the pools before compressing
  bool compress = true;
};

class BlockEncoder {
 public:
  explicit BlockEncoder(BlockEncodeOptions options = {});
  ~BlockEncoder();
  BlockEncoder(BlockEncoder&&) noexcept;
  BlockEncoder& operator=(BlockEncoder&&) noexcept;

  const BlockEncodeOptions& options() const noexcept { return options_; }

  // Replaces `out` with the frame (capacity is reused across calls). invalid_argument for spans
  // of the wrong size, a bad range or no field; internal if zstd fails.
  Result<void> encode(const BlockView& block, std::vector<std::uint8_t>& out);
  Result<std::vector<std::uint8_t>> encode(const BlockView& block);

  // A delta frame of `block` against `base`, an older version of the same block: same block id,
  // first_cell and fields, base.cell_count <= block.cell_count (pool spans sized for base's own
  // range), base.version < block.version, and the distance below 2^32 (else invalid_argument).
  // The cells whose values differ from base's (from 0 past its range) are marked; transformed
  // and compressed as options() says.
  Result<void> encode_delta(const BlockView& block, const BlockView& base,
                            std::vector<std::uint8_t>& out);
  // A delta frame of `block` with the cells and groups `changes` marks, against a version the
  // caller knows differs from `block` in no other cell (e.g. the union of the bitmaps of a chain
  // of deltas). invalid_argument for bitmaps of the wrong size, or a base version not older by
  // less than 2^32. A cell left unmarked that did change makes a frame whose checksum fails on
  // the receiver, never a wrong block.
  Result<void> encode_changes(const BlockView& block, const BlockChanges& changes,
                              std::vector<std::uint8_t>& out);

 private:
  // The header and the stored payload of a frame whose payload (raw_size bytes) is at `payload`:
  // im.staged when compressing, else already in `out`.
  Result<void> finish(const BlockView& block, std::uint16_t flags, std::uint16_t fields,
                      std::size_t raw_size, std::uint32_t payload_crc, std::uint32_t base_distance,
                      std::vector<std::uint8_t>& out);
  // `out` sized for an uncompressed frame, or im.staged for a compressed one: where the payload
  // of raw_size bytes is to be written.
  std::uint8_t* payload_room(std::size_t raw_size, std::vector<std::uint8_t>& out);
  struct Impl;
  BlockEncodeOptions options_;
  std::unique_ptr<Impl> impl_;
};

struct BlockDecodeLimits {
  std::uint32_t max_cells = 1u << 20;  // cells per frame; a client uses its welcome's block_cells
  // Non-zero: the range must lie inside block `block_id` of this many cells.
  std::uint32_t block_cells = 0;
};

// Parses and checks the header alone (magic, version, header CRC, flags, fields, range, sizes
// against `frame.size()` and the limits). Cheap: lets a receiver route or drop a frame first.
Result<BlockHeader> parse_block_header(std::span<const std::uint8_t> frame,
                                       const BlockDecodeLimits& limits = {});

class BlockDecoder {
 public:
  BlockDecoder();
  ~BlockDecoder();
  BlockDecoder(BlockDecoder&&) noexcept;
  BlockDecoder& operator=(BlockDecoder&&) noexcept;

  // Fills `out` (reusing its vectors' capacity). Errors: malformed (truncated, bad magic, bad
  // checksum, bad zstd data, sizes that disagree), unsupported (another format version or unknown
  // flags/fields), limit_exceeded (more cells than the limits allow). On error `out` is
  // unspecified but valid. A delta frame's payload_crc can only be checked against the resolved
  // block: apply_block_delta() does that.
  Result<void> decode(std::span<const std::uint8_t> frame, BlockFrame& out,
                      const BlockDecodeLimits& limits = {});

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Resolves a decoded delta frame against `base`, the receiver's copy of the block (pool spans
// as in BlockView for base's own range, which must be a prefix of the frame's; the mask span is
// ignored): expands the changed values over the base's (0 past its range), checks payload_crc
// over the result and clears kFlagDelta and the bitmaps, so `frame` becomes the full frame it
// stands for.
// Errors (frame unspecified but valid afterwards): invalid_argument when `frame` is not a delta
// or `base` is not its base (another block, version, range, or a pool the frame carries is
// missing: "the receiver does not hold the base version"); malformed when the bitmaps and the
// values disagree (a frame not made by decode()) or the checksum of the result fails (a corrupt
// delta, or a base whose bytes differ from the sender's).
Result<void> apply_block_delta(BlockFrame& frame, const BlockView& base);

}  // namespace deepcanvas::protocol
