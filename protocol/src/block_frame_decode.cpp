// Block frame decoding (PROTOCOL.md 4.1 to 4.3) and delta resolution (4.7). Every input is
// untrusted: see block_frame.hpp.
#include <zstd.h>

#include <algorithm>
#include <string>

#include "block_frame_format.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/version.hpp"

namespace deepcanvas::protocol {

using namespace frame_format;

Result<void> frame_format::check_block_header(BlockHeader& r, std::uint32_t base_distance,
                                              const BlockDecodeLimits& limits) {
  if (r.flags & ~kKnownFlags) return make_error(Errc::unsupported, "block frame: unknown flags");
  if (!(r.flags & kFlagDelta) && base_distance != 0)
    return malformed("base distance is not zero in a frame that is not a delta");
  if (r.fields & ~kFieldAll) return make_error(Errc::unsupported, "block frame: unknown fields");
  if (r.fields == 0) return malformed("no field present");
  if (r.flags & kFlagDelta) {
    if (base_distance == 0 || base_distance > r.version)
      return malformed("delta frame with base distance " + std::to_string(base_distance) +
                       " from version " + std::to_string(r.version));
    r.base_version = r.version - base_distance;
  }
  if (r.cell_count == 0 || r.cell_count % 8 || r.first_cell % 8)
    return malformed("first_cell and cell_count must be multiples of 8, cell_count > 0");
  const std::uint64_t end = std::uint64_t{r.first_cell} + r.cell_count;
  if (end > (std::uint64_t{1} << 32)) return malformed("cell range passes 2^32");
  if (r.cell_count > limits.max_cells)
    return make_error(Errc::limit_exceeded, "block frame: " + std::to_string(r.cell_count) +
                                                " cells exceed the limit of " +
                                                std::to_string(limits.max_cells));
  if (limits.block_cells) {
    const std::uint64_t lo = std::uint64_t{r.block_id} * limits.block_cells;
    if (r.first_cell < lo || end > lo + limits.block_cells)
      return malformed("cell range lies outside block " + std::to_string(r.block_id));
  }
  if (r.flags & kFlagDelta) {
    // The changed cells are counted once the bitmaps are read (decode()); here, the bounds: none
    // changed, or all.
    const std::size_t least = delta_payload_size(r.cell_count, r.fields, 0, 0);
    const std::size_t most =
        least + block_payload_size(r.cell_count,
                                   static_cast<std::uint16_t>(r.fields & ~kFieldNeighbourMask));
    if (r.raw_size < least || r.raw_size > most)
      return malformed("raw size " + std::to_string(r.raw_size) +
                       " of a delta frame is not within " + std::to_string(least) + ".." +
                       std::to_string(most));
  } else if (r.raw_size != block_payload_size(r.cell_count, r.fields)) {
    return malformed("raw size " + std::to_string(r.raw_size) + " does not match the fields");
  }
  return {};
}

Result<BlockHeader> parse_block_header(std::span<const std::uint8_t> frame,
                                       const BlockDecodeLimits& limits) {
  if (frame.size() < 8)
    return malformed("truncated header (" + std::to_string(frame.size()) + " bytes)");
  const std::uint8_t* h = frame.data();
  if (get<std::uint32_t>(h + kOffMagic) != kBlockFrameMagic) return malformed("bad magic");
  BlockHeader r;
  r.format_version = get<std::uint16_t>(h + kOffFormat);
  if (r.format_version != kBlockFrameVersion)
    return make_error(Errc::unsupported, "block frame: format version " +
                                             std::to_string(r.format_version) +
                                             " is not supported (this side speaks " +
                                             std::to_string(kBlockFrameVersion) + ")");
  if (frame.size() < kBlockHeaderSize)
    return malformed("truncated header (" + std::to_string(frame.size()) + " bytes)");
  if (get<std::uint32_t>(h + kOffHeaderCrc) != crc32({h, kOffHeaderCrc}))
    return malformed("header checksum mismatch");
  if (get<std::uint16_t>(h + kOffHeaderSize) != kBlockHeaderSize)
    return malformed("header size is not 64");
  r.flags = get<std::uint16_t>(h + kOffFlags);
  r.fields = get<std::uint16_t>(h + kOffFields);
  const std::uint32_t base_distance = get<std::uint32_t>(h + kOffBaseDistance);
  r.block_id = get<std::uint32_t>(h + kOffBlockId);
  r.version = get<std::uint64_t>(h + kOffVersion);
  r.epoch = get<std::uint64_t>(h + kOffEpoch);
  r.first_cell = get<std::uint32_t>(h + kOffFirstCell);
  r.cell_count = get<std::uint32_t>(h + kOffCellCount);
  r.stored_size = get<std::uint32_t>(h + kOffStored);
  r.raw_size = get<std::uint32_t>(h + kOffRaw);
  r.payload_crc = get<std::uint32_t>(h + kOffPayloadCrc);
  r.stored_crc = get<std::uint32_t>(h + kOffStoredCrc);
  if (auto c = check_block_header(r, base_distance, limits); !c) return std::move(c).error();
  if (r.stored_size != frame.size() - kBlockHeaderSize)
    return malformed("stored size " + std::to_string(r.stored_size) + " but " +
                     std::to_string(frame.size() - kBlockHeaderSize) + " payload bytes present");
  if (!(r.flags & kFlagCompressed) && r.stored_size != r.raw_size)
    return malformed("uncompressed payload size differs from raw size");
  return r;
}

Result<void> frame_format::decompress_exact(ZSTD_DCtx*& dctx, std::span<const std::uint8_t> stored,
                                            std::size_t raw_size, std::vector<std::uint8_t>& out,
                                            const char* what) {
  const auto bad = [&](const std::string& why) {
    return make_error(Errc::malformed, std::string("block frame: ") + what + " " + why);
  };
  const unsigned long long content = ZSTD_getFrameContentSize(stored.data(), stored.size());
  if (content == ZSTD_CONTENTSIZE_ERROR || content == ZSTD_CONTENTSIZE_UNKNOWN)
    return bad("is not a zstd frame with a declared size");
  if (content != raw_size) return bad("has a zstd frame size that differs from its raw size");
  const std::size_t frame_len = ZSTD_findFrameCompressedSize(stored.data(), stored.size());
  if (ZSTD_isError(frame_len) || frame_len != stored.size())
    return bad("is not exactly one zstd frame");
  if (!dctx) {
    dctx = ZSTD_createDCtx();
    if (!dctx) return make_error(Errc::out_of_memory, "block frame: no zstd context");
    ZSTD_DCtx_setParameter(dctx, ZSTD_d_windowLogMax, kMaxWindowLog);
  }
  out.resize(raw_size);
  const std::size_t n =
      ZSTD_decompressDCtx(dctx, out.data(), out.size(), stored.data(), stored.size());
  if (ZSTD_isError(n)) return bad(std::string("zstd: ") + ZSTD_getErrorName(n));
  if (n != raw_size) return bad("decompressed to another size than its raw size");
  return {};
}

Result<void> frame_format::decode_block_payload(const BlockHeader& hd,
                                                std::span<const std::uint8_t> payload,
                                                BlockFrame& out) {
  if (payload.size() != hd.raw_size)
    return malformed("payload of " + std::to_string(payload.size()) + " bytes, raw size " +
                     std::to_string(hd.raw_size));
  // Split into fields, undoing the transform. A delta frame starts with its bitmaps, which say
  // how many values each pool holds.
  const std::uint32_t cells = hd.cell_count, groups = cells / 8;
  const bool tr = hd.flags & kFlagTransformed;
  const bool delta = hd.flags & kFlagDelta;
  const std::uint8_t* p = payload.data();
  std::size_t cell_values = cells, group_values = groups;
  out.changed_cells.clear();
  out.changed_groups.clear();
  if (delta) {
    const auto read_bitmap = [&](std::vector<std::uint64_t>& words, std::size_t n) {
      const std::size_t bytes = (n + 7) / 8;
      if (n % 8 && (p[bytes - 1] >> (n % 8)) != 0) return false;
      words.assign((n + 63) / 64, 0);
      std::memcpy(words.data(), p, bytes);
      p += bytes;
      return true;
    };
    if (hd.fields & kCellFields) {
      read_bitmap(out.changed_cells, cells);  // cells % 8 == 0: no padding bits
      cell_values = count_bits(out.changed_cells, cells);
    }
    if (hd.fields & kGroupFields) {
      if (!read_bitmap(out.changed_groups, groups))
        return malformed("changed-group bitmap padding bits are not zero");
      group_values = count_bits(out.changed_groups, groups);
    }
    if (delta_payload_size(cells, hd.fields, cell_values, group_values) != hd.raw_size)
      return malformed("raw size " + std::to_string(hd.raw_size) + " does not match the delta's " +
                       std::to_string(cell_values) + " changed cells and " +
                       std::to_string(group_values) + " changed groups");
  }
  // stride 0: the colour pool (alpha split off); otherwise an index pool with that prediction.
  const auto read32 = [&](std::vector<std::uint32_t>& v, std::size_t n, bool present,
                          std::uint32_t stride) {
    if (!present) {
      v.clear();
      return;
    }
    v.resize(n);
    if (tr && stride == 0) {
      join_alpha(p, n, v.data());
    } else if (tr) {
      unshuffle32(p, n, v.data());
      delta_decode(v.data(), n, stride);
    } else if (n > 0) {
      std::memcpy(v.data(), p, 4 * n);
    }
    p += 4 * n;
  };
  read32(out.first_child, cell_values, hd.fields & kFieldFirstChild, 8);
  read32(out.colour, cell_values, hd.fields & kFieldColour, 0);
  read32(out.group_parent, group_values, hd.fields & kFieldGroupParent, 1);
  if (hd.fields & kFieldDepthFlags) {
    out.depth_flags.assign(p, p + group_values);
    p += group_values;
  } else {
    out.depth_flags.clear();
  }
  out.neighbour_mask.clear();
  if (hd.fields & kFieldNeighbourMask) {
    const std::size_t mb = mask_bytes(groups);
    if (groups % 8 && (p[mb - 1] >> (groups % 8)) != 0)
      return malformed("neighbour mask padding bits are not zero");
    out.neighbour_mask.assign((groups + 63) / 64, 0);
    std::memcpy(out.neighbour_mask.data(), p, mb);
    p += mb;
  }

  // The checksum covers the untransformed payload: recompute it from the decoded fields. A
  // delta's payload_crc covers the resolved block: apply_block_delta checks it (the changed
  // values here have no checksum of their own beyond stored_crc).
  out.header = hd;
  if (!delta && block_payload_crc(view_of(out), hd.fields) != hd.payload_crc)
    return malformed("payload checksum mismatch");
  return {};
}

struct BlockDecoder::Impl {
  ZSTD_DCtx* dctx = nullptr;
  std::vector<std::uint8_t> buf;
  ~Impl() { ZSTD_freeDCtx(dctx); }
};

BlockDecoder::BlockDecoder() : impl_(std::make_unique<Impl>()) {}
BlockDecoder::~BlockDecoder() = default;
BlockDecoder::BlockDecoder(BlockDecoder&&) noexcept = default;
BlockDecoder& BlockDecoder::operator=(BlockDecoder&&) noexcept = default;

Result<void> BlockDecoder::decode(std::span<const std::uint8_t> frame, BlockFrame& out,
                                  const BlockDecodeLimits& limits) {
  auto hr = parse_block_header(frame, limits);
  if (!hr) return std::move(hr).error();
  const BlockHeader& hd = *hr;
  const auto stored = frame.subspan(kBlockHeaderSize);
  Impl& im = *impl_;
  // Every stored byte is covered, so any corruption is caught here, before decompressing (a
  // changed zstd stream may still decode to the same bytes: harmless, but not what we sent).
  if (crc32(stored) != hd.stored_crc) return malformed("stored payload checksum mismatch");

  // The payload bytes, decompressed into a buffer of exactly raw_size (bounded by the limits
  // through parse_block_header) when compressed.
  std::span<const std::uint8_t> payload = stored;
  if (hd.flags & kFlagCompressed) {
    if (auto r = decompress_exact(im.dctx, stored, hd.raw_size, im.buf, "payload"); !r) return r;
    payload = im.buf;
  }

  return decode_block_payload(hd, payload, out);
}

namespace {

// Expands the values of the set bits of `changed` (the first n bits) in place to n values, the
// others taken from `base` (0 past its end). In place from the top down: the k-th set bit is at
// an index >= k, so a value is moved before its slot is overwritten.
template <class T>
void expand(std::vector<T>& values, std::span<const std::uint64_t> changed, std::span<const T> base,
            std::size_t n) {
  std::size_t k = values.size();
  values.resize(n);
  for (std::size_t w = (n + 63) / 64; w-- > 0;) {
    const std::size_t i0 = w * 64, end = std::min(n, i0 + 64);
    if (changed[w] == 0 && end <= base.size()) {  // no changed cell here
      std::copy(base.begin() + static_cast<std::ptrdiff_t>(i0),
                base.begin() + static_cast<std::ptrdiff_t>(end),
                values.begin() + static_cast<std::ptrdiff_t>(i0));
      continue;
    }
    for (std::size_t i = end; i-- > i0;)
      values[i] = bit(changed, i) ? values[--k] : (i < base.size() ? base[i] : T{0});
  }
}
}  // namespace

Result<void> apply_block_delta(BlockFrame& f, const BlockView& base) {
  const BlockHeader& hd = f.header;
  const auto no_base = [&](const std::string& why) {
    return make_error(Errc::invalid_argument,
                      "delta frame for block " + std::to_string(hd.block_id) + " version " +
                          std::to_string(hd.version) + " needs base version " +
                          std::to_string(hd.base_version) +
                          ", but the receiver does not hold it: " + why);
  };
  if (!f.is_delta()) return make_error(Errc::invalid_argument, "not a delta frame");
  if (base.block_id != hd.block_id) return no_base("the base is another block");
  if (base.version != hd.base_version)
    return no_base("it holds version " + std::to_string(base.version));
  // The base covers a prefix of the frame's range (the block may have grown since).
  if (base.first_cell != hd.first_cell || base.cell_count > hd.cell_count || base.cell_count == 0 ||
      base.cell_count % 8)
    return no_base("it holds another cell range");
  const std::uint32_t cells = hd.cell_count, groups = cells / 8;
  const std::uint32_t bcells = base.cell_count, bgroups = bcells / 8;
  const auto in_base = [](bool present, std::size_t have, std::size_t want) {
    return !present || have == want;
  };
  if (!in_base(f.has(kFieldFirstChild), base.first_child.size(), bcells) ||
      !in_base(f.has(kFieldColour), base.colour.size(), bcells) ||
      !in_base(f.has(kFieldGroupParent), base.group_parent.size(), bgroups) ||
      !in_base(f.has(kFieldDepthFlags), base.depth_flags.size(), bgroups))
    return no_base("a pool the delta carries is missing from the base");
  // The bitmaps and the values as decode() leaves them (checked again: `f` may be any frame).
  const bool per_cell = hd.fields & kCellFields, per_group = hd.fields & kGroupFields;
  if (f.changed_cells.size() != (per_cell ? (cells + 63) / 64 : 0) ||
      f.changed_groups.size() != (per_group ? (groups + 63) / 64 : 0))
    return malformed("delta frame bitmaps do not fit its cell range");
  const std::size_t nc = per_cell ? count_bits(f.changed_cells, cells) : 0;
  const std::size_t ng = per_group ? count_bits(f.changed_groups, groups) : 0;
  const auto holds = [](bool present, std::size_t have, std::size_t want) {
    return present ? have == want : have == 0;
  };
  if (!holds(f.has(kFieldFirstChild), f.first_child.size(), nc) ||
      !holds(f.has(kFieldColour), f.colour.size(), nc) ||
      !holds(f.has(kFieldGroupParent), f.group_parent.size(), ng) ||
      !holds(f.has(kFieldDepthFlags), f.depth_flags.size(), ng))
    return malformed("delta frame values do not match its changed-cell bitmaps");
  if (f.has(kFieldFirstChild)) expand(f.first_child, f.changed_cells, base.first_child, cells);
  if (f.has(kFieldColour)) expand(f.colour, f.changed_cells, base.colour, cells);
  if (f.has(kFieldGroupParent)) expand(f.group_parent, f.changed_groups, base.group_parent, groups);
  if (f.has(kFieldDepthFlags)) expand(f.depth_flags, f.changed_groups, base.depth_flags, groups);
  if (block_payload_crc(view_of(f), hd.fields) != hd.payload_crc)
    return malformed("payload checksum mismatch after applying the delta to base version " +
                     std::to_string(hd.base_version));
  f.header.flags = static_cast<std::uint16_t>(f.header.flags & ~kFlagDelta);
  f.header.base_version = 0;
  f.changed_cells.clear();
  f.changed_groups.clear();
  return {};
}

}  // namespace deepcanvas::protocol
