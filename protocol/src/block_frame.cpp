#include "deepcanvas/protocol/block_frame.hpp"

#include <zstd.h>

#include <bit>
#include <cstring>
#include <string>

#include "deepcanvas/protocol/version.hpp"

namespace deepcanvas::protocol {

static_assert(std::endian::native == std::endian::little,
              "block frames copy pool memory as little-endian bytes");

namespace {

// ---- header byte offsets (PROTOCOL.md "Block frame header") ----
constexpr std::size_t kOffMagic = 0, kOffFormat = 4, kOffHeaderSize = 6, kOffFlags = 8,
                      kOffFields = 10, kOffBlockId = 12, kOffVersion = 16, kOffEpoch = 24,
                      kOffFirstCell = 32, kOffCellCount = 36, kOffStored = 40, kOffRaw = 44,
                      kOffPayloadCrc = 48, kOffStoredCrc = 52, kOffBaseDistance = 56,
                      kOffHeaderCrc = 60;
constexpr std::uint16_t kKnownFlags = kFlagCompressed | kFlagTransformed | kFlagDelta;
// zstd window for a frame: the largest payload (2^20 cells, all fields) is under 2^24 bytes.
constexpr int kMaxWindowLog = 24;

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

Error malformed(std::string what) {
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
void delta_encode(std::span<const std::uint32_t> in, std::uint32_t stride, std::uint32_t* out) {
  std::uint32_t pred = 0;
  for (std::size_t i = 0; i < in.size(); ++i) {
    out[i] = encode_index(in[i], pred);
    if (in[i] != kNoCellWire) pred = in[i] + stride;
  }
}
void delta_decode(std::uint32_t* values, std::size_t n, std::uint32_t stride) {
  std::uint32_t pred = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint32_t v = decode_index(values[i], pred);
    values[i] = v;
    if (v != kNoCellWire) pred = v + stride;
  }
}

void shuffle32(const std::uint32_t* in, std::size_t n, std::uint8_t* out) {
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint32_t v = in[i];
    out[i] = static_cast<std::uint8_t>(v);
    out[n + i] = static_cast<std::uint8_t>(v >> 8);
    out[2 * n + i] = static_cast<std::uint8_t>(v >> 16);
    out[3 * n + i] = static_cast<std::uint8_t>(v >> 24);
  }
}
void unshuffle32(const std::uint8_t* in, std::size_t n, std::uint32_t* out) {
  for (std::size_t i = 0; i < n; ++i)
    out[i] = std::uint32_t{in[i]} | std::uint32_t{in[n + i]} << 8 |
             std::uint32_t{in[2 * n + i]} << 16 | std::uint32_t{in[3 * n + i]} << 24;
}

// Colour RGBA8 -> the cells' RGB bytes interleaved, then all alpha bytes: a stroke paints one RGB
// over many cells with varying density, so the two parts repeat differently and compress better
// apart than raw or as four byte planes (deepcanvas-bench protocol measures the transform as a
// whole, on and off).
void split_alpha(const std::uint32_t* in, std::size_t n, std::uint8_t* out) {
  std::uint8_t* a = out + 3 * n;
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint32_t v = in[i];
    out[3 * i] = static_cast<std::uint8_t>(v);
    out[3 * i + 1] = static_cast<std::uint8_t>(v >> 8);
    out[3 * i + 2] = static_cast<std::uint8_t>(v >> 16);
    a[i] = static_cast<std::uint8_t>(v >> 24);
  }
}
void join_alpha(const std::uint8_t* in, std::size_t n, std::uint32_t* out) {
  const std::uint8_t* a = in + 3 * n;
  for (std::size_t i = 0; i < n; ++i)
    out[i] = std::uint32_t{in[3 * i]} | std::uint32_t{in[3 * i + 1]} << 8 |
             std::uint32_t{in[3 * i + 2]} << 16 | std::uint32_t{a[i]} << 24;
}

std::size_t mask_bytes(std::uint32_t groups) {
  return (groups + 7) / 8;
}

// The checksum of a block's untransformed payload (PROTOCOL.md 4.2), from its decoded pools.
std::uint32_t decoded_payload_crc(const BlockFrame& f, bool has_mask, std::uint32_t groups) {
  std::uint32_t crc = 0;
  const auto feed = [&crc](const auto& v, std::size_t bytes) {
    crc = crc32({reinterpret_cast<const std::uint8_t*>(v.data()), bytes}, crc);
  };
  feed(f.first_child, f.first_child.size() * 4);
  feed(f.colour, f.colour.size() * 4);
  feed(f.group_parent, f.group_parent.size() * 4);
  feed(f.depth_flags, f.depth_flags.size());
  if (has_mask) feed(f.neighbour_mask, mask_bytes(groups));
  return crc;
}

// out = a XOR b element-wise (pool values of two versions of one block); elements of `a` past
// the end of `b` (the block grew) are XOR-ed with 0, i.e. copied.
template <class T>
void xor_into(std::span<const T> a, std::span<const T> b, std::uint8_t* out) {
  for (std::size_t i = 0; i < a.size(); ++i) {
    const T v = i < b.size() ? static_cast<T>(a[i] ^ b[i]) : a[i];
    std::memcpy(out + i * sizeof(T), &v, sizeof(T));
  }
}

Error encode_error(std::string what) {
  return make_error(Errc::invalid_argument, "block frame encode: " + what);
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

template <class T>
std::span<const std::uint8_t> bytes_of(std::span<const T> s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size_bytes()};
}

// How a pool's values become payload bytes (PROTOCOL.md 4.3 and 4.7).
enum class PoolCoding { raw, transformed, delta };

// An index pool (first_child, group_parent) at `w`; `residuals` is reused scratch.
void write_index_pool(std::span<const std::uint32_t> pool, std::span<const std::uint32_t> base,
                      PoolCoding coding, std::uint32_t stride,
                      std::vector<std::uint32_t>& residuals, std::uint8_t* w) {
  if (coding == PoolCoding::delta) {
    xor_into(pool, base, w);
  } else if (coding == PoolCoding::transformed) {
    residuals.resize(pool.size());
    delta_encode(pool, stride, residuals.data());
    shuffle32(residuals.data(), pool.size(), w);
  } else if (!pool.empty()) {
    std::memcpy(w, pool.data(), pool.size_bytes());
  }
}

void write_colour_pool(std::span<const std::uint32_t> pool, std::span<const std::uint32_t> base,
                       PoolCoding coding, std::uint8_t* w) {
  if (coding == PoolCoding::delta)
    xor_into(pool, base, w);
  else if (coding == PoolCoding::transformed)
    split_alpha(pool.data(), pool.size(), w);
  else if (!pool.empty())
    std::memcpy(w, pool.data(), pool.size_bytes());
}

// The raw (or transformed, or XOR-ed) payload of 4.2 at `payload`, written once; returns its
// payload_crc, which runs over the untransformed source spans.
std::uint32_t write_payload(const BlockView& b, const BlockView* base, std::uint16_t fields,
                            PoolCoding coding, std::vector<std::uint32_t>& residuals,
                            std::uint8_t* payload) {
  const std::uint32_t cells = b.cell_count, groups = cells / 8;
  const BlockView none{};
  const BlockView& from = base ? *base : none;
  std::uint32_t payload_crc = 0;
  std::uint8_t* w = payload;
  if (fields & kFieldFirstChild) {
    payload_crc = crc32(bytes_of(b.first_child), payload_crc);
    write_index_pool(b.first_child, from.first_child, coding, 8, residuals, w);
    w += 4 * std::size_t{cells};
  }
  if (fields & kFieldColour) {
    payload_crc = crc32(bytes_of(b.colour), payload_crc);
    write_colour_pool(b.colour, from.colour, coding, w);
    w += 4 * std::size_t{cells};
  }
  if (fields & kFieldGroupParent) {
    payload_crc = crc32(bytes_of(b.group_parent), payload_crc);
    write_index_pool(b.group_parent, from.group_parent, coding, 1, residuals, w);
    w += 4 * std::size_t{groups};
  }
  if (fields & kFieldDepthFlags) {  // bytes: never transformed
    payload_crc = crc32(bytes_of(b.depth_flags), payload_crc);
    if (coding == PoolCoding::delta)
      xor_into(b.depth_flags, from.depth_flags, w);
    else if (!b.depth_flags.empty())
      std::memcpy(w, b.depth_flags.data(), b.depth_flags.size());
    w += groups;
  }
  if (fields & kFieldNeighbourMask) {  // the words' bytes, bits past the last group cleared
    const std::size_t mb = mask_bytes(groups);
    std::memcpy(w, b.neighbour_mask.data(), mb);
    if (groups % 8) w[mb - 1] &= static_cast<std::uint8_t>((1u << (groups % 8)) - 1);
    payload_crc = crc32({w, mb}, payload_crc);
  }
  return payload_crc;
}

// `payload` as one zstd frame declaring its size, after the header room of `out`. zstd writes
// into `scratch` (room for its worst case, reused across calls), and `out` gets exactly the
// frame: a frame is kept for long (a canvas's delta chains hold 16 of every block), and one
// sized for the worst case would keep ~47 KB of capacity for a delta of a few hundred bytes.
Result<void> compress_payload(ZSTD_CCtx*& cctx, int level, const std::uint8_t* payload,
                              std::size_t raw_size, std::vector<std::uint8_t>& scratch,
                              std::vector<std::uint8_t>& out) {
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
  if (out.capacity() > 2 * (kBlockHeaderSize + n)) std::vector<std::uint8_t>().swap(out);
  out.resize(kBlockHeaderSize + n);
  std::memcpy(out.data() + kBlockHeaderSize, scratch.data(), n);
  return {};
}

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
  std::vector<std::uint8_t> raw;     // untransformed payload (for the CRC)
  std::vector<std::uint8_t> staged;  // transformed payload
  std::vector<std::uint8_t> compressed;  // zstd's output, copied into the frame
  std::vector<std::uint32_t> residuals;
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

Result<void> BlockEncoder::encode(const BlockView& b, std::vector<std::uint8_t>& out) {
  return encode_impl(b, nullptr, out);
}

Result<void> BlockEncoder::encode_delta(const BlockView& b, const BlockView& base,
                                        std::vector<std::uint8_t>& out) {
  const auto bad = [](std::string what) {
    return make_error(Errc::invalid_argument, "block frame delta encode: " + what);
  };
  if (base.block_id != b.block_id || base.first_cell != b.first_cell ||
      base.cell_count > b.cell_count || base.cell_count == 0 || base.cell_count % 8)
    return bad("the base is another block or does not cover a prefix of the cell range");
  if (base.version >= b.version || b.version - base.version > 0xFFFFFFFFu)
    return bad("the base version must be older, by less than 2^32");
  const std::size_t bc = base.cell_count, bg = bc / 8;
  const auto same = [](std::size_t have, std::size_t base_have, std::size_t base_want) {
    return have == 0 ? base_have == 0 : base_have == base_want;
  };
  if (!same(b.first_child.size(), base.first_child.size(), bc) ||
      !same(b.colour.size(), base.colour.size(), bc) ||
      !same(b.group_parent.size(), base.group_parent.size(), bg) ||
      !same(b.depth_flags.size(), base.depth_flags.size(), bg))
    return bad("the base must carry the same pools, sized for its own range");
  return encode_impl(b, &base, out);
}

Result<void> BlockEncoder::encode_impl(const BlockView& b, const BlockView* base,
                                       std::vector<std::uint8_t>& out) {
  auto fields = encoded_fields(b);
  if (!fields) return std::move(fields).error();
  Impl& im = *impl_;
  const std::size_t raw_size = block_payload_size(b.cell_count, *fields);
  if (raw_size > 0xFFFFFFFFu) return encode_error("payload too large");

  // The payload is written once: straight into the frame when it is not compressed, else into a
  // staging buffer that zstd reads.
  std::uint8_t* payload = nullptr;
  if (options_.compress) {
    im.staged.resize(raw_size);
    payload = im.staged.data();
  } else {
    out.resize(kBlockHeaderSize + raw_size);
    payload = out.data() + kBlockHeaderSize;
  }
  // A delta is never transformed: the XOR of two versions is mostly zero, which zstd takes as
  // it is; the prediction transform would turn unchanged runs into non-zero codes.
  const PoolCoding coding = base                ? PoolCoding::delta
                            : options_.transform ? PoolCoding::transformed
                                                 : PoolCoding::raw;
  const std::uint32_t payload_crc = write_payload(b, base, *fields, coding, im.residuals, payload);

  std::uint16_t flags = coding == PoolCoding::transformed ? kFlagTransformed : 0;
  if (base) flags |= kFlagDelta;
  if (options_.compress) {
    flags |= kFlagCompressed;
    if (auto r = compress_payload(im.cctx, options_.level, payload, raw_size, im.compressed, out);
        !r)
      return r;
  }
  write_header(b, flags, *fields, raw_size, payload_crc,
               base ? static_cast<std::uint32_t>(b.version - base->version) : 0u, out);
  return {};
}

// ---------------------------------------------------------------- decoder

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
  if (r.flags & ~kKnownFlags) return make_error(Errc::unsupported, "block frame: unknown flags");
  const std::uint32_t base_distance = get<std::uint32_t>(h + kOffBaseDistance);
  if (!(r.flags & kFlagDelta) && base_distance != 0)
    return malformed("base distance is not zero in a frame that is not a delta");
  if (r.fields & ~kFieldAll) return make_error(Errc::unsupported, "block frame: unknown fields");
  if (r.fields == 0) return malformed("no field present");
  r.block_id = get<std::uint32_t>(h + kOffBlockId);
  r.version = get<std::uint64_t>(h + kOffVersion);
  r.epoch = get<std::uint64_t>(h + kOffEpoch);
  r.first_cell = get<std::uint32_t>(h + kOffFirstCell);
  r.cell_count = get<std::uint32_t>(h + kOffCellCount);
  r.stored_size = get<std::uint32_t>(h + kOffStored);
  r.raw_size = get<std::uint32_t>(h + kOffRaw);
  r.payload_crc = get<std::uint32_t>(h + kOffPayloadCrc);
  r.stored_crc = get<std::uint32_t>(h + kOffStoredCrc);
  if (r.flags & kFlagDelta) {
    if (r.flags & kFlagTransformed) return malformed("a delta frame cannot be transformed");
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
  if (r.raw_size != block_payload_size(r.cell_count, r.fields))
    return malformed("raw size " + std::to_string(r.raw_size) + " does not match the fields");
  if (r.stored_size != frame.size() - kBlockHeaderSize)
    return malformed("stored size " + std::to_string(r.stored_size) + " but " +
                     std::to_string(frame.size() - kBlockHeaderSize) + " payload bytes present");
  if (!(r.flags & kFlagCompressed) && r.stored_size != r.raw_size)
    return malformed("uncompressed payload size differs from raw size");
  return r;
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
    const unsigned long long content = ZSTD_getFrameContentSize(stored.data(), stored.size());
    if (content == ZSTD_CONTENTSIZE_ERROR || content == ZSTD_CONTENTSIZE_UNKNOWN)
      return malformed("payload is not a zstd frame with a declared size");
    if (content != hd.raw_size) return malformed("zstd frame size differs from raw size");
    const std::size_t frame_len = ZSTD_findFrameCompressedSize(stored.data(), stored.size());
    if (ZSTD_isError(frame_len) || frame_len != stored.size())
      return malformed("payload is not exactly one zstd frame");
    if (!im.dctx) {
      im.dctx = ZSTD_createDCtx();
      if (!im.dctx) return make_error(Errc::out_of_memory, "block frame: no zstd context");
      ZSTD_DCtx_setParameter(im.dctx, ZSTD_d_windowLogMax, kMaxWindowLog);
    }
    im.buf.resize(hd.raw_size);
    const std::size_t n =
        ZSTD_decompressDCtx(im.dctx, im.buf.data(), im.buf.size(), stored.data(), stored.size());
    if (ZSTD_isError(n)) return malformed(std::string("zstd: ") + ZSTD_getErrorName(n));
    if (n != hd.raw_size) return malformed("decompressed size differs from raw size");
    payload = im.buf;
  }

  // Split into fields, undoing the transform.
  const std::uint32_t cells = hd.cell_count, groups = cells / 8;
  const bool tr = hd.flags & kFlagTransformed;
  const std::uint8_t* p = payload.data();
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
    } else {
      std::memcpy(v.data(), p, 4 * n);
    }
    p += 4 * n;
  };
  read32(out.first_child, cells, hd.fields & kFieldFirstChild, 8);
  read32(out.colour, cells, hd.fields & kFieldColour, 0);
  read32(out.group_parent, groups, hd.fields & kFieldGroupParent, 1);
  if (hd.fields & kFieldDepthFlags) {
    out.depth_flags.assign(p, p + groups);
    p += groups;
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
  // delta's payload_crc covers the resolved block: apply_block_delta checks it (the XOR bytes
  // here have no checksum of their own beyond stored_crc).
  if (!(hd.flags & kFlagDelta) &&
      decoded_payload_crc(out, hd.fields & kFieldNeighbourMask, groups) != hd.payload_crc)
    return malformed("payload checksum mismatch");
  out.header = hd;
  return {};
}

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
  const auto fits = [](bool present, std::size_t have, std::size_t want, std::size_t got,
                       std::size_t got_want) {
    return !present || (have == want && got == got_want);
  };
  if (!fits(f.has(kFieldFirstChild), base.first_child.size(), bcells, f.first_child.size(),
            cells) ||
      !fits(f.has(kFieldColour), base.colour.size(), bcells, f.colour.size(), cells) ||
      !fits(f.has(kFieldGroupParent), base.group_parent.size(), bgroups, f.group_parent.size(),
            groups) ||
      !fits(f.has(kFieldDepthFlags), base.depth_flags.size(), bgroups, f.depth_flags.size(),
            groups))
    return no_base("a pool the delta carries is missing from the base");
  const auto apply = [](auto& values, const auto& base_values) {
    const std::size_t n = values.empty() ? 0 : base_values.size();
    for (std::size_t i = 0; i < n; ++i) values[i] ^= base_values[i];
  };
  apply(f.first_child, base.first_child);
  apply(f.colour, base.colour);
  apply(f.group_parent, base.group_parent);
  apply(f.depth_flags, base.depth_flags);
  if (decoded_payload_crc(f, f.has(kFieldNeighbourMask), groups) != hd.payload_crc)
    return malformed("payload checksum mismatch after applying the delta to base version " +
                     std::to_string(hd.base_version));
  f.header.flags = static_cast<std::uint16_t>(f.header.flags & ~kFlagDelta);
  f.header.base_version = 0;
  return {};
}

}  // namespace deepcanvas::protocol
