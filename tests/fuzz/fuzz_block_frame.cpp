// libFuzzer: block frame decoding. Input = one mode byte + a frame. Mode bit 0 set: the header
// and stored-payload checksums are recomputed first, so mutations reach the zstd, transform and
// field-splitting code instead of dying at the checksums. Whatever decodes must re-encode (same
// flags) to a frame that decodes to the same pools. A delta frame is also resolved against a
// base made from the input (apply_block_delta on untrusted bytes); when that succeeds, the delta
// re-encoded against the same base must resolve to the same pools. Mode bit 2: the decoded
// payload_crc is replaced by the checksum the result would have with that base (as if the sender
// had used it), so the success path is reached, not only the checksum failure.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"

namespace dp = deepcanvas::protocol;

namespace {

using dp::view_of;

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const std::uint8_t mode = data[0];
  std::vector<std::uint8_t> frame(data + 1, data + size);
  if ((mode & 1) && frame.size() >= dp::kBlockHeaderSize) {
    const std::uint32_t stored = dp::crc32(std::span(frame).subspan(dp::kBlockHeaderSize));
    std::memcpy(frame.data() + 52, &stored, 4);
    const std::uint32_t header = dp::crc32(std::span(frame).first(60));
    std::memcpy(frame.data() + 60, &header, 4);
  }
  dp::BlockDecodeLimits limits;
  limits.max_cells = 1u << 16;
  if (mode & 2) limits.block_cells = 4096;
  static dp::BlockDecoder decoder;  // reused, as receivers do
  dp::BlockFrame f;
  auto r = decoder.decode(frame, f, limits);
  // The header verdict is the same through both entry points.
  auto h = dp::parse_block_header(frame, limits);
  if (r.ok() && !h.ok()) __builtin_trap();
  if (!h.ok() && (r.ok() || r.error().message != h.error().message)) __builtin_trap();
  if (!r.ok()) return 0;

  if (f.is_delta()) {
    // Base pools: the XOR values themselves shifted by one byte of the input, so that both a
    // matching and a failing checksum are reachable.
    const std::uint32_t salt = size > 1 ? data[1] : 0;
    dp::BlockFrame base = f;
    for (auto& x : base.first_child) x ^= salt;
    for (auto& x : base.colour) x ^= salt << 8;
    dp::BlockView bv = view_of(base);  // a base carries no epoch and no mask
    bv.version = f.header.base_version;
    bv.epoch = 0;
    bv.neighbour_mask = {};
    dp::BlockFrame resolved = f;
    if (mode & 4) {
      dp::BlockFrame x = f;
      for (std::size_t i = 0; i < x.first_child.size(); ++i)
        x.first_child[i] ^= base.first_child[i];
      for (std::size_t i = 0; i < x.colour.size(); ++i) x.colour[i] ^= base.colour[i];
      for (std::size_t i = 0; i < x.group_parent.size(); ++i)
        x.group_parent[i] ^= base.group_parent[i];
      for (std::size_t i = 0; i < x.depth_flags.size(); ++i)
        x.depth_flags[i] ^= base.depth_flags[i];
      std::uint32_t crc = 0;
      const auto feed = [&crc](const auto& v, std::size_t bytes) {
        crc = dp::crc32({reinterpret_cast<const std::uint8_t*>(v.data()), bytes}, crc);
      };
      feed(x.first_child, x.first_child.size() * 4);
      feed(x.colour, x.colour.size() * 4);
      feed(x.group_parent, x.group_parent.size() * 4);
      feed(x.depth_flags, x.depth_flags.size());
      if (x.has(dp::kFieldNeighbourMask)) feed(x.neighbour_mask, (x.header.cell_count / 8 + 7) / 8);
      resolved.header.payload_crc = crc;
    }
    if (!dp::apply_block_delta(resolved, bv).ok()) return 0;
    if (resolved.is_delta()) __builtin_trap();
    const dp::BlockView nv = view_of(resolved);
    dp::BlockEncoder enc({1, false, (f.header.flags & dp::kFlagCompressed) != 0});
    std::vector<std::uint8_t> again;
    if (!enc.encode_delta(nv, bv, again).ok()) __builtin_trap();
    dp::BlockFrame g;
    if (!decoder.decode(again, g, limits).ok()) __builtin_trap();
    if (!dp::apply_block_delta(g, bv).ok()) __builtin_trap();
    if (g.first_child != resolved.first_child || g.colour != resolved.colour ||
        g.group_parent != resolved.group_parent || g.depth_flags != resolved.depth_flags ||
        g.neighbour_mask != resolved.neighbour_mask)
      __builtin_trap();
    return 0;
  }

  const dp::BlockView v = view_of(f);
  dp::BlockEncoder enc({1, (f.header.flags & dp::kFlagTransformed) != 0,
                        (f.header.flags & dp::kFlagCompressed) != 0});
  auto again = enc.encode(v);
  if (!again.ok()) __builtin_trap();
  dp::BlockFrame g;
  if (!decoder.decode(*again, g, limits).ok()) __builtin_trap();
  if (g.first_child != f.first_child || g.colour != f.colour || g.group_parent != f.group_parent ||
      g.depth_flags != f.depth_flags || g.neighbour_mask != f.neighbour_mask ||
      g.header.fields != f.header.fields || g.header.payload_crc != f.header.payload_crc)
    __builtin_trap();
  return 0;
}
