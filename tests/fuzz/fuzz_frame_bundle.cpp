// libFuzzer: frame bundle decoding (PROTOCOL.md 4.12). Input = one mode byte + a bundle.
// Mode bit 0: the header and stored checksums are recomputed first, so mutations reach the zstd
// frame and the records. Mode bit 1 (with bit 0): the bytes after the header are taken as the
// records themselves and compressed into a valid zstd frame, so mutations reach the record checks
// and the payload decoding directly. Whatever decodes must hand over exactly record_count frames,
// each of which re-encodes (a full frame) to a frame that decodes to the same pools; a bundle that
// fails must have handed over nothing unless a record's payload failed (the structure is checked
// first).
#include <zstd.h>

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/frame_bundle.hpp"

namespace dp = deepcanvas::protocol;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const std::uint8_t mode = data[0];
  std::vector<std::uint8_t> bundle(data + 1, data + size);
  if ((mode & 3) == 3 && bundle.size() >= dp::kBundleHeaderSize) {
    const std::vector<std::uint8_t> records(bundle.begin() + dp::kBundleHeaderSize, bundle.end());
    bundle.resize(dp::kBundleHeaderSize + ZSTD_compressBound(records.size()));
    const std::size_t n =
        ZSTD_compress(bundle.data() + dp::kBundleHeaderSize, bundle.size() - dp::kBundleHeaderSize,
                      records.data(), records.size(), 1);
    if (ZSTD_isError(n)) return 0;
    bundle.resize(dp::kBundleHeaderSize + n);
    const auto raw = static_cast<std::uint32_t>(records.size());
    std::memcpy(bundle.data() + 12, &raw, 4);
  }
  if ((mode & 1) && bundle.size() >= dp::kBundleHeaderSize) {
    const std::uint32_t stored = dp::crc32(std::span(bundle).subspan(dp::kBundleHeaderSize));
    std::memcpy(bundle.data() + 24, &stored, 4);
    const std::uint32_t header = dp::crc32(std::span(bundle).first(28));
    std::memcpy(bundle.data() + 28, &header, 4);
  }
  dp::BundleDecodeLimits limits;
  limits.block.max_cells = 1u << 16;
  if (mode & 4) limits.block.block_cells = 4096;
  static dp::BundleDecoder decoder;  // reused, as receivers do
  static dp::BlockDecoder single;
  static dp::BlockEncoder encoder(dp::BlockEncodeOptions{1, true, true});
  dp::BlockFrame scratch;
  std::size_t handed = 0;
  bool reencoded_ok = true;
  auto r =
      decoder.decode(bundle, limits, scratch, [&](dp::BlockFrame& f) -> deepcanvas::Result<void> {
        ++handed;
        if (f.is_delta()) return {};
        std::vector<std::uint8_t> again;
        dp::BlockFrame back;
        if (!encoder.encode(dp::view_of(f), again) || !single.decode(again, back) ||
            back.first_child != f.first_child || back.colour != f.colour ||
            back.group_parent != f.group_parent || back.depth_flags != f.depth_flags ||
            back.neighbour_mask != f.neighbour_mask)
          reencoded_ok = false;
        return {};
      });
  if (!reencoded_ok) __builtin_trap();
  // The header verdict agrees with the whole decode.
  auto h = dp::parse_bundle_header(bundle, limits);
  if (r.ok() && (!h.ok() || h->record_count != handed || r->record_count != handed))
    __builtin_trap();
  if (!h.ok() && handed != 0) __builtin_trap();
  return 0;
}
