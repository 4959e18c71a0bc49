// Block frame encoding (PROTOCOL.md 4.1 to 4.3, delta frames 4.7).
#include <zstd.h>

#include <algorithm>
#include <string>
#include <type_traits>

#include "block_frame_format.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/version.hpp"

namespace deepcanvas::protocol {

using namespace frame_format;

namespace {

Error encode_error(std::string what) {
  return make_error(Errc::invalid_argument, "block frame encode: " + what);
}

Error delta_encode_error(std::string what) {
  return make_error(Errc::invalid_argument, "block frame delta encode: " + what);
}

// The fields a view carries (a non-empty span is a present field), once its range and span
// lengths are checked.
Result<std::uint16_t> encoded_fields(const BlockView& b) {
  if (b.cell_count == 0 || b.cell_count % 8 || b.first_cell % 8)
    return encode_error("first_cell and cell_count must be multiples of 8, cell_count > 0");
  if (std::uint64_t{b.first_cell} + b.cell_count > (std::uint64_t{1} << 32))
    return encode_error("cell range passes 2^32");
  const std::uint32_t cells = b.cell_count, groups = cells / 8;
  std::uint16_t fields = 0;
  const auto check = [&](std::size_t have, std::size_t want, std::uint16_t bit) {
    if (have != 0) fields |= bit;
    return have == 0 || have == want;
  };
  const bool sizes_ok = check(b.first_child.size(), cells, kFieldFirstChild) &&
                        check(b.colour.size(), cells, kFieldColour) &&
                        check(b.group_parent.size(), groups, kFieldGroupParent) &&
                        check(b.depth_flags.size(), groups, kFieldDepthFlags) &&
                        check(b.neighbour_mask.size(), (groups + 63) / 64, kFieldNeighbourMask);
  if (!sizes_ok)
    return encode_error("a field span has the wrong length for " + std::to_string(cells) +
                        " cells");
  if (fields == 0) return encode_error("no field present");
  return fields;
}

// How a pool's values become payload bytes (PROTOCOL.md 4.3).
enum class PoolCoding { raw, transformed };

// An index pool (first_child, group_parent) at `w`; `residuals` is reused scratch.
void write_index_pool(std::span<const std::uint32_t> pool, PoolCoding coding, std::uint32_t stride,
                      std::vector<std::uint32_t>& residuals, std::uint8_t* w) {
  if (coding == PoolCoding::transformed) {
    residuals.resize(pool.size());
    delta_encode(pool, stride, residuals.data());
    shuffle32(residuals.data(), pool.size(), w);
  } else if (!pool.empty()) {
    std::memcpy(w, pool.data(), pool.size_bytes());
  }
}

void write_colour_pool(std::span<const std::uint32_t> pool, PoolCoding coding, std::uint8_t* w) {
  if (coding == PoolCoding::transformed)
    split_alpha(pool.data(), pool.size(), w);
  else if (!pool.empty())
    std::memcpy(w, pool.data(), pool.size_bytes());
}

// The mask's bytes (4.2) at `w`, bits past the last group cleared; returns the byte count.
std::size_t write_mask(std::span<const std::uint64_t> mask, std::uint32_t groups, std::uint8_t* w) {
  const std::size_t mb = mask_bytes(groups);
  std::memcpy(w, mask.data(), mb);
  if (groups % 8) w[mb - 1] &= static_cast<std::uint8_t>((1u << (groups % 8)) - 1);
  return mb;
}

// The raw (or transformed) payload of 4.2 at `payload`, written once.
void write_payload(const BlockView& b, std::uint16_t fields, PoolCoding coding,
                   std::vector<std::uint32_t>& residuals, std::uint8_t* payload) {
  const std::uint32_t cells = b.cell_count, groups = cells / 8;
  std::uint8_t* w = payload;
  if (fields & kFieldFirstChild) {
    write_index_pool(b.first_child, coding, 8, residuals, w);
    w += 4 * std::size_t{cells};
  }
  if (fields & kFieldColour) {
    write_colour_pool(b.colour, coding, w);
    w += 4 * std::size_t{cells};
  }
  if (fields & kFieldGroupParent) {
    write_index_pool(b.group_parent, coding, 1, residuals, w);
    w += 4 * std::size_t{groups};
  }
  if (fields & kFieldDepthFlags) {  // bytes: never transformed
    if (!b.depth_flags.empty()) std::memcpy(w, b.depth_flags.data(), b.depth_flags.size());
    w += groups;
  }
  if (fields & kFieldNeighbourMask) write_mask(b.neighbour_mask, groups, w);
}

// The values of `pool` at the set bits of `changed` (the first pool.size() bits).
template <class T>
void gather(std::span<const T> pool, std::span<const std::uint64_t> changed, std::vector<T>& out) {
  out.clear();
  const std::size_t n = pool.size();
  for (std::size_t w = 0; w * 64 < n; ++w) {
    std::uint64_t bits = changed[w];
    if (n - w * 64 < 64) bits &= (std::uint64_t{1} << (n - w * 64)) - 1;
    for (; bits; bits &= bits - 1)
      out.push_back(pool[w * 64 + static_cast<std::size_t>(std::countr_zero(bits))]);
  }
}

// Bit i of `words` set where element i of a or c differs from that of was_a or was_c (0 past
// their end), a and c of one length or empty (an absent pool), was_a and was_c no longer.
template <class A, class C>
void mark_changes(std::span<const A> a, std::span<const A> was_a, std::span<const C> c,
                  std::span<const C> was_c, std::vector<std::uint64_t>& words) {
  const std::size_t n = std::max(a.size(), c.size());
  const std::size_t old = std::max(was_a.size(), was_c.size());
  words.assign((n + 63) / 64, 0);
  for (std::size_t i0 = 0; i0 < n; i0 += 64) {
    const std::size_t end = std::min(n, i0 + 64);
    std::uint64_t bits = 0;
    if (end <= old) {  // both versions hold these elements: branch-free compares
      for (std::size_t i = i0; i < end; ++i) {
        const bool differs = (!a.empty() && a[i] != was_a[i]) | (!c.empty() && c[i] != was_c[i]);
        bits |= std::uint64_t{differs} << (i - i0);
      }
    } else {
      for (std::size_t i = i0; i < end; ++i) {
        const bool differs = (!a.empty() && a[i] != (i < was_a.size() ? was_a[i] : A{0})) ||
                             (!c.empty() && c[i] != (i < was_c.size() ? was_c[i] : C{0}));
        bits |= std::uint64_t{differs} << (i - i0);
      }
    }
    words[i0 / 64] = bits;
  }
}

// The bitmap of `n` bits at `w` (LSB first), bits past n cleared; returns its bytes.
std::size_t write_bitmap(std::span<const std::uint64_t> words, std::size_t n, std::uint8_t* w) {
  const std::size_t bytes = (n + 7) / 8;
  std::memcpy(w, words.data(), bytes);
  if (n % 8) w[bytes - 1] &= static_cast<std::uint8_t>((1u << (n % 8)) - 1);
  return bytes;
}

// Scratch for gathering the changed values of one delta frame.
struct DeltaScratch {
  std::vector<std::uint32_t> first_child, colour, group_parent, residuals;
  std::vector<std::uint8_t> depth_flags;
};

// The delta payload of 4.7 at `payload` (delta_payload_size bytes), once `s` holds the changed
// values (gather).
void write_delta_payload(const BlockView& b, const BlockChanges& changes, std::uint16_t fields,
                         PoolCoding coding, DeltaScratch& s, std::uint8_t* payload) {
  const std::uint32_t cells = b.cell_count, groups = cells / 8;
  std::uint8_t* w = payload;
  if (fields & kCellFields) w += write_bitmap(changes.cells, cells, w);
  if (fields & kGroupFields) w += write_bitmap(changes.groups, groups, w);
  if (fields & kFieldFirstChild) {
    write_index_pool(s.first_child, coding, 8, s.residuals, w);
    w += 4 * s.first_child.size();
  }
  if (fields & kFieldColour) {
    write_colour_pool(s.colour, coding, w);
    w += 4 * s.colour.size();
  }
  if (fields & kFieldGroupParent) {
    write_index_pool(s.group_parent, coding, 1, s.residuals, w);
    w += 4 * s.group_parent.size();
  }
  if (fields & kFieldDepthFlags) {
    if (!s.depth_flags.empty()) std::memcpy(w, s.depth_flags.data(), s.depth_flags.size());
    w += s.depth_flags.size();
  }
  if (fields & kFieldNeighbourMask) write_mask(b.neighbour_mask, groups, w);
}

}  // namespace

// zstd writes into `scratch` (room for its worst case, reused across calls), and `out` gets
// exactly the frame: a frame is kept for long (a canvas's delta chains hold 16 of every block),
// and one sized for the worst case would keep ~47 KB of capacity for a delta of a few hundred
// bytes.
Result<void> frame_format::compress_payload(ZSTD_CCtx*& cctx, int level,
                                            const std::uint8_t* payload, std::size_t raw_size,
                                            std::vector<std::uint8_t>& scratch,
                                            std::vector<std::uint8_t>& out,
                                            std::size_t header_room) {
  if (!cctx) {
    cctx = ZSTD_createCCtx();
    if (!cctx) return make_error(Errc::out_of_memory, "block frame encode: no zstd context");
  }
  ZSTD_CCtx_reset(cctx, ZSTD_reset_session_and_parameters);
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_compressionLevel, level);
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_contentSizeFlag, 1);
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_checksumFlag, 0);
  const std::size_t bound = ZSTD_compressBound(raw_size);
  if (scratch.size() < bound) scratch.resize(bound);
  const std::size_t n = ZSTD_compress2(cctx, scratch.data(), bound, payload, raw_size);
  if (ZSTD_isError(n))
    return make_error(Errc::internal,
                      std::string("block frame encode: zstd: ") + ZSTD_getErrorName(n));
  if (out.capacity() > 2 * (header_room + n)) std::vector<std::uint8_t>().swap(out);
  out.resize(header_room + n);
  std::memcpy(out.data() + header_room, scratch.data(), n);
  return {};
}

namespace {

// The 64-byte header (4.1) in front of the stored payload that `frame` already holds.
void write_header(const BlockView& b, std::uint16_t flags, std::uint16_t fields,
                  std::size_t raw_size, std::uint32_t payload_crc, std::uint32_t base_distance,
                  std::vector<std::uint8_t>& frame) {
  std::uint8_t* h = frame.data();
  std::memset(h, 0, kBlockHeaderSize);
  put<std::uint32_t>(h + kOffMagic, kBlockFrameMagic);
  put<std::uint16_t>(h + kOffFormat, kBlockFrameVersion);
  put<std::uint16_t>(h + kOffHeaderSize, static_cast<std::uint16_t>(kBlockHeaderSize));
  put<std::uint16_t>(h + kOffFlags, flags);
  put<std::uint16_t>(h + kOffFields, fields);
  put<std::uint32_t>(h + kOffBlockId, b.block_id);
  put<std::uint64_t>(h + kOffVersion, b.version);
  put<std::uint64_t>(h + kOffEpoch, b.epoch);
  put<std::uint32_t>(h + kOffFirstCell, b.first_cell);
  put<std::uint32_t>(h + kOffCellCount, b.cell_count);
  put<std::uint32_t>(h + kOffStored, static_cast<std::uint32_t>(frame.size() - kBlockHeaderSize));
  put<std::uint32_t>(h + kOffRaw, static_cast<std::uint32_t>(raw_size));
  put<std::uint32_t>(h + kOffPayloadCrc, payload_crc);
  put<std::uint32_t>(h + kOffBaseDistance, base_distance);
  put<std::uint32_t>(h + kOffStoredCrc,
                     crc32({frame.data() + kBlockHeaderSize, frame.size() - kBlockHeaderSize}));
  put<std::uint32_t>(h + kOffHeaderCrc, crc32({h, kOffHeaderCrc}));
}

}  // namespace

std::size_t block_payload_size(std::uint32_t cell_count, std::uint16_t fields) noexcept {
  const std::size_t cells = cell_count, groups = cell_count / 8;
  std::size_t n = 0;
  if (fields & kFieldFirstChild) n += 4 * cells;
  if (fields & kFieldColour) n += 4 * cells;
  if (fields & kFieldGroupParent) n += 4 * groups;
  if (fields & kFieldDepthFlags) n += groups;
  if (fields & kFieldNeighbourMask) n += mask_bytes(static_cast<std::uint32_t>(groups));
  return n;
}

// ---------------------------------------------------------------- encoder

struct BlockEncoder::Impl {
  ZSTD_CCtx* cctx = nullptr;
  std::vector<std::uint8_t> staged;                          // the payload zstd reads
  std::vector<std::uint8_t> compressed;                      // zstd's output, copied into the frame
  std::vector<std::uint64_t> changed_cells, changed_groups;  // encode_delta's bitmaps
  DeltaScratch delta;                                        // also the full frame's residuals
  ~Impl() { ZSTD_freeCCtx(cctx); }
};

BlockEncoder::BlockEncoder(BlockEncodeOptions options)
    : options_(options), impl_(std::make_unique<Impl>()) {}
BlockEncoder::~BlockEncoder() = default;
BlockEncoder::BlockEncoder(BlockEncoder&&) noexcept = default;
BlockEncoder& BlockEncoder::operator=(BlockEncoder&&) noexcept = default;

BlockView view_of(const BlockFrame& f) noexcept {
  BlockView v;
  v.block_id = f.header.block_id;
  v.version = f.header.version;
  v.epoch = f.header.epoch;
  v.first_cell = f.header.first_cell;
  v.cell_count = f.header.cell_count;
  v.first_child = f.first_child;
  v.colour = f.colour;
  v.group_parent = f.group_parent;
  v.depth_flags = f.depth_flags;
  v.neighbour_mask = f.neighbour_mask;
  return v;
}

Result<std::vector<std::uint8_t>> BlockEncoder::encode(const BlockView& b) {
  std::vector<std::uint8_t> out;
  if (auto r = encode(b, out); !r) return std::move(r).error();
  return out;
}

std::uint8_t* BlockEncoder::payload_room(std::size_t raw_size, std::vector<std::uint8_t>& out) {
  // The payload is written once: straight into the frame when it is not compressed, else into a
  // staging buffer that zstd reads.
  if (options_.compress) {
    impl_->staged.resize(raw_size);
    return impl_->staged.data();
  }
  out.resize(kBlockHeaderSize + raw_size);
  return out.data() + kBlockHeaderSize;
}

Result<void> BlockEncoder::finish(const BlockView& b, std::uint16_t flags, std::uint16_t fields,
                                  std::size_t raw_size, std::uint32_t payload_crc,
                                  std::uint32_t base_distance, std::vector<std::uint8_t>& out) {
  Impl& im = *impl_;
  if (options_.transform) flags |= kFlagTransformed;
  if (options_.compress) {
    flags |= kFlagCompressed;
    if (auto r = compress_payload(im.cctx, options_.level, im.staged.data(), raw_size,
                                  im.compressed, out, kBlockHeaderSize);
        !r)
      return r;
  }
  write_header(b, flags, fields, raw_size, payload_crc, base_distance, out);
  return {};
}

Result<void> BlockEncoder::encode(const BlockView& b, std::vector<std::uint8_t>& out) {
  auto fields = encoded_fields(b);
  if (!fields) return std::move(fields).error();
  const std::size_t raw_size = block_payload_size(b.cell_count, *fields);
  if (raw_size > 0xFFFFFFFFu) return encode_error("payload too large");
  write_payload(b, *fields, options_.transform ? PoolCoding::transformed : PoolCoding::raw,
                impl_->delta.residuals, payload_room(raw_size, out));
  return finish(b, 0, *fields, raw_size, block_payload_crc(b, *fields), 0, out);
}

Result<void> BlockEncoder::encode_delta(const BlockView& b, const BlockView& base,
                                        std::vector<std::uint8_t>& out) {
  const auto bad = delta_encode_error;
  if (base.block_id != b.block_id || base.first_cell != b.first_cell ||
      base.cell_count > b.cell_count || base.cell_count == 0 || base.cell_count % 8)
    return bad("the base is another block or does not cover a prefix of the cell range");
  const std::size_t bc = base.cell_count, bg = bc / 8;
  const auto same = [](std::size_t have, std::size_t base_have, std::size_t base_want) {
    return have == 0 ? base_have == 0 : base_have == base_want;
  };
  if (!same(b.first_child.size(), base.first_child.size(), bc) ||
      !same(b.colour.size(), base.colour.size(), bc) ||
      !same(b.group_parent.size(), base.group_parent.size(), bg) ||
      !same(b.depth_flags.size(), base.depth_flags.size(), bg))
    return bad("the base must carry the same pools, sized for its own range");
  auto fields = encoded_fields(b);
  if (!fields) return std::move(fields).error();
  // Mark what differs from the base (from 0 past its range).
  Impl& im = *impl_;
  mark_changes(b.first_child, base.first_child, b.colour, base.colour, im.changed_cells);
  mark_changes(b.group_parent, base.group_parent, b.depth_flags, base.depth_flags,
               im.changed_groups);
  return encode_changes(b, {base.version, im.changed_cells, im.changed_groups}, out);
}

Result<void> BlockEncoder::encode_changes(const BlockView& b, const BlockChanges& changes,
                                          std::vector<std::uint8_t>& out) {
  const auto bad = delta_encode_error;
  if (changes.base_version >= b.version || b.version - changes.base_version > 0xFFFFFFFFu)
    return bad("the base version must be older, by less than 2^32");
  auto fields = encoded_fields(b);
  if (!fields) return std::move(fields).error();
  const std::size_t cells = b.cell_count, groups = cells / 8;
  if (((*fields & kCellFields) && changes.cells.size() != (cells + 63) / 64) ||
      ((*fields & kGroupFields) && changes.groups.size() != (groups + 63) / 64))
    return bad("the changed-cell bitmaps have the wrong length for " + std::to_string(cells) +
               " cells");
  DeltaScratch& s = impl_->delta;
  gather(b.first_child, changes.cells, s.first_child);
  gather(b.colour, changes.cells, s.colour);
  gather(b.group_parent, changes.groups, s.group_parent);
  gather(b.depth_flags, changes.groups, s.depth_flags);
  const std::size_t changed = (*fields & kCellFields) ? count_bits(changes.cells, cells) : 0;
  const std::size_t changed_groups =
      (*fields & kGroupFields) ? count_bits(changes.groups, groups) : 0;
  const std::size_t raw_size = delta_payload_size(b.cell_count, *fields, changed, changed_groups);
  if (raw_size > 0xFFFFFFFFu) return bad("payload too large");
  write_delta_payload(b, changes, *fields,
                      options_.transform ? PoolCoding::transformed : PoolCoding::raw, s,
                      payload_room(raw_size, out));
  return finish(b, kFlagDelta, *fields, raw_size, block_payload_crc(b, *fields),
                static_cast<std::uint32_t>(b.version - changes.base_version), out);
}

}  // namespace deepcanvas::protocol
