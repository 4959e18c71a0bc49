// Frame bundles (PROTOCOL.md 4.12): block frames of one batch as records of one zstd frame.
// Every input of the decoder is untrusted: see frame_bundle.hpp.
#include "deepcanvas/protocol/frame_bundle.hpp"

#include <zstd.h>

#include <algorithm>
#include <cstring>
#include <string>

#include "block_frame_format.hpp"
#include "deepcanvas/protocol/version.hpp"

namespace deepcanvas::protocol {

using namespace frame_format;

namespace {

// ---- bundle header byte offsets ----
constexpr std::size_t kBOffMagic = 0, kBOffFormat = 4, kBOffHeaderSize = 6, kBOffCount = 8,
                      kBOffRaw = 12, kBOffEpoch = 16, kBOffStoredCrc = 24, kBOffHeaderCrc = 28;
// ---- record header byte offsets ----
constexpr std::size_t kROffFlags = 0, kROffFields = 2, kROffBlockId = 4, kROffVersion = 8,
                      kROffEpoch = 16, kROffFirstCell = 24, kROffCellCount = 28, kROffRaw = 32,
                      kROffPayloadCrc = 36, kROffBaseDistance = 40;
static_assert(kROffBaseDistance + 4 == kBundleRecordHeaderSize);
static_assert(kBOffHeaderCrc + 4 == kBundleHeaderSize);

Error bad_bundle(const std::string& what) {
  return make_error(Errc::malformed, "frame bundle: " + what);
}

}  // namespace

bool is_bundle(std::span<const std::uint8_t> message) noexcept {
  return message.size() >= 4 && get<std::uint32_t>(message.data()) == kBundleMagic;
}

Result<BundleHeader> parse_bundle_header(std::span<const std::uint8_t> m,
                                         const BundleDecodeLimits& limits) {
  if (!is_bundle(m)) return bad_bundle("bad magic");
  if (m.size() < 8) return bad_bundle("truncated header");
  const std::uint8_t* h = m.data();
  if (const auto v = get<std::uint16_t>(h + kBOffFormat); v != kBundleVersion)
    return make_error(Errc::unsupported, "frame bundle: format version " + std::to_string(v) +
                                             " is not supported (this side speaks " +
                                             std::to_string(kBundleVersion) + ")");
  if (m.size() < kBundleHeaderSize) return bad_bundle("truncated header");
  if (get<std::uint32_t>(h + kBOffHeaderCrc) != crc32({h, kBOffHeaderCrc}))
    return bad_bundle("header checksum mismatch");
  if (get<std::uint16_t>(h + kBOffHeaderSize) != kBundleHeaderSize)
    return bad_bundle("header size is not 32");
  BundleHeader r;
  r.record_count = get<std::uint32_t>(h + kBOffCount);
  r.raw_size = get<std::uint32_t>(h + kBOffRaw);
  r.epoch = get<std::uint64_t>(h + kBOffEpoch);
  if (r.record_count == 0) return bad_bundle("no record");
  if (r.raw_size > limits.max_raw_bytes)
    return make_error(Errc::limit_exceeded, "frame bundle: " + std::to_string(r.raw_size) +
                                                " raw bytes exceed the limit of " +
                                                std::to_string(limits.max_raw_bytes));
  if (std::uint64_t{r.record_count} * kBundleRecordHeaderSize > r.raw_size)
    return bad_bundle(std::to_string(r.record_count) + " records cannot fit in " +
                      std::to_string(r.raw_size) + " raw bytes");
  if (get<std::uint32_t>(h + kBOffStoredCrc) != crc32(m.subspan(kBundleHeaderSize)))
    return bad_bundle("stored payload checksum mismatch");
  return r;
}

// ---------------------------------------------------------------------------------- encoder

struct BundleEncoder::Impl {
  int level = kDefaultZstdLevel;
  ZSTD_CCtx* cctx = nullptr;
  ZSTD_DCtx* dctx = nullptr;
  std::vector<std::uint8_t> records, payload, scratch;
  std::uint32_t count = 0;
  std::uint64_t epoch = 0;
  ~Impl() {
    ZSTD_freeCCtx(cctx);
    ZSTD_freeDCtx(dctx);
  }
};

BundleEncoder::BundleEncoder(int level) : impl_(std::make_unique<Impl>()) {
  impl_->level = level;
}
BundleEncoder::~BundleEncoder() = default;
BundleEncoder::BundleEncoder(BundleEncoder&&) noexcept = default;
BundleEncoder& BundleEncoder::operator=(BundleEncoder&&) noexcept = default;

std::size_t BundleEncoder::records() const noexcept {
  return impl_->count;
}
std::size_t BundleEncoder::raw_size() const noexcept {
  return impl_->records.size();
}

Result<void> BundleEncoder::add(std::span<const std::uint8_t> frame) {
  Impl& im = *impl_;
  auto hr = parse_block_header(frame);
  if (!hr) return std::move(hr).error();
  const BlockHeader& hd = *hr;
  std::span<const std::uint8_t> payload = frame.subspan(kBlockHeaderSize);
  if (hd.flags & kFlagCompressed) {
    if (auto r = decompress_exact(im.dctx, payload, hd.raw_size, im.payload, "payload"); !r)
      return r;
    payload = im.payload;
  }
  if (std::uint64_t{im.records.size()} + kBundleRecordHeaderSize + payload.size() > 0xFFFFFFFFu)
    return make_error(Errc::invalid_argument, "frame bundle: more than 4 GiB of records");
  const std::size_t at = im.records.size();
  im.records.resize(at + kBundleRecordHeaderSize + payload.size());
  std::uint8_t* r = im.records.data() + at;
  put<std::uint16_t>(r + kROffFlags, static_cast<std::uint16_t>(hd.flags & ~kFlagCompressed));
  put<std::uint16_t>(r + kROffFields, hd.fields);
  put<std::uint32_t>(r + kROffBlockId, hd.block_id);
  put<std::uint64_t>(r + kROffVersion, hd.version);
  put<std::uint64_t>(r + kROffEpoch, hd.epoch);
  put<std::uint32_t>(r + kROffFirstCell, hd.first_cell);
  put<std::uint32_t>(r + kROffCellCount, hd.cell_count);
  put<std::uint32_t>(r + kROffRaw, hd.raw_size);
  put<std::uint32_t>(r + kROffPayloadCrc, hd.payload_crc);
  put<std::uint32_t>(
      r + kROffBaseDistance,
      (hd.flags & kFlagDelta) ? static_cast<std::uint32_t>(hd.version - hd.base_version) : 0u);
  if (!payload.empty()) std::memcpy(r + kBundleRecordHeaderSize, payload.data(), payload.size());
  ++im.count;
  im.epoch = std::max(im.epoch, hd.epoch);
  return {};
}

Result<void> BundleEncoder::finish(std::vector<std::uint8_t>& out) {
  Impl& im = *impl_;
  if (im.count == 0) return make_error(Errc::invalid_argument, "frame bundle: no record");
  if (auto r = compress_payload(im.cctx, im.level, im.records.data(), im.records.size(), im.scratch,
                                out, kBundleHeaderSize);
      !r)
    return r;
  std::uint8_t* h = out.data();
  put<std::uint32_t>(h + kBOffMagic, kBundleMagic);
  put<std::uint16_t>(h + kBOffFormat, kBundleVersion);
  put<std::uint16_t>(h + kBOffHeaderSize, static_cast<std::uint16_t>(kBundleHeaderSize));
  put<std::uint32_t>(h + kBOffCount, im.count);
  put<std::uint32_t>(h + kBOffRaw, static_cast<std::uint32_t>(im.records.size()));
  put<std::uint64_t>(h + kBOffEpoch, im.epoch);
  put<std::uint32_t>(h + kBOffStoredCrc,
                     crc32({out.data() + kBundleHeaderSize, out.size() - kBundleHeaderSize}));
  put<std::uint32_t>(h + kBOffHeaderCrc, crc32({h, kBOffHeaderCrc}));
  im.records.clear();
  im.count = 0;
  im.epoch = 0;
  return {};
}

// ---------------------------------------------------------------------------------- decoder

struct BundleDecoder::Impl {
  ZSTD_DCtx* dctx = nullptr;
  std::vector<std::uint8_t> raw;
  ~Impl() { ZSTD_freeDCtx(dctx); }
};

BundleDecoder::BundleDecoder() : impl_(std::make_unique<Impl>()) {}
BundleDecoder::~BundleDecoder() = default;
BundleDecoder::BundleDecoder(BundleDecoder&&) noexcept = default;
BundleDecoder& BundleDecoder::operator=(BundleDecoder&&) noexcept = default;

Result<BundleHeader> BundleDecoder::decode(
    std::span<const std::uint8_t> message, const BundleDecodeLimits& limits, BlockFrame& frame,
    const std::function<Result<void>(BlockFrame&)>& on_frame) {
  auto hr = parse_bundle_header(message, limits);
  if (!hr) return std::move(hr).error();
  const BundleHeader bh = *hr;
  Impl& im = *impl_;
  if (auto r = decompress_exact(im.dctx, message.subspan(kBundleHeaderSize), bh.raw_size, im.raw,
                                "bundle");
      !r)
    return std::move(r).error();
  // The records must fill the raw bytes exactly: checked before any is handed over, so a bundle
  // that is cut short or padded changes nothing.
  std::size_t walked = 0;
  for (std::uint32_t i = 0; i < bh.record_count; ++i) {
    if (im.raw.size() - walked < kBundleRecordHeaderSize)
      return bad_bundle("truncated record (record " + std::to_string(i) + ")");
    walked += kBundleRecordHeaderSize;
    const std::uint32_t raw =
        get<std::uint32_t>(im.raw.data() + walked - kBundleRecordHeaderSize + kROffRaw);
    if (im.raw.size() - walked < raw)
      return bad_bundle("truncated record payload (record " + std::to_string(i) + ")");
    walked += raw;
  }
  if (walked != im.raw.size())
    return bad_bundle(std::to_string(im.raw.size() - walked) + " bytes after the records");
  std::span<const std::uint8_t> rest = im.raw;
  for (std::uint32_t i = 0; i < bh.record_count; ++i) {
    const auto at = " (record " + std::to_string(i) + ")";
    const std::uint8_t* r = rest.data();
    BlockHeader hd;
    hd.format_version = kBlockFrameVersion;
    hd.flags = get<std::uint16_t>(r + kROffFlags);
    hd.fields = get<std::uint16_t>(r + kROffFields);
    hd.block_id = get<std::uint32_t>(r + kROffBlockId);
    hd.version = get<std::uint64_t>(r + kROffVersion);
    hd.epoch = get<std::uint64_t>(r + kROffEpoch);
    hd.first_cell = get<std::uint32_t>(r + kROffFirstCell);
    hd.cell_count = get<std::uint32_t>(r + kROffCellCount);
    hd.raw_size = get<std::uint32_t>(r + kROffRaw);
    hd.stored_size = hd.raw_size;
    hd.payload_crc = get<std::uint32_t>(r + kROffPayloadCrc);
    if (hd.flags & kFlagCompressed) return bad_bundle("a record is compressed" + at);
    if (auto c = check_block_header(hd, get<std::uint32_t>(r + kROffBaseDistance), limits.block);
        !c)
      return make_error(c.error().code, c.error().message + at);
    if (hd.epoch > bh.epoch) return bad_bundle("a record is newer than its bundle" + at);
    rest = rest.subspan(kBundleRecordHeaderSize);
    if (auto d = decode_block_payload(hd, rest.first(hd.raw_size), frame); !d)
      return make_error(d.error().code, d.error().message + at);
    rest = rest.subspan(hd.raw_size);
    if (auto c = on_frame(frame); !c) return std::move(c).error();
  }
  return bh;
}

}  // namespace deepcanvas::protocol
