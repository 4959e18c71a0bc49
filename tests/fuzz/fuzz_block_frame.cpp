// libFuzzer: block frame decoding. Input = one mode byte + a frame. Mode bit 0 set: the header
// and stored-payload checksums are recomputed first, so mutations reach the zstd, transform and
// field-splitting code instead of dying at the checksums. Whatever decodes must re-encode (same
// flags) to a frame that decodes to the same pools.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"

namespace dp = deepcanvas::protocol;

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

  dp::BlockView v;
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
