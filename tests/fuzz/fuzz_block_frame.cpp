// libFuzzer: block frame decoding. Input = one mode byte + a frame. Mode bit 0 set: the header
// and stored-payload checksums are recomputed first, so mutations reach the zstd, transform and
// field-splitting code instead of dying at the checksums. Whatever decodes must re-encode (same
// flags) to a frame that decodes to the same pools. A delta frame is also resolved against a
// base made from the input (apply_block_delta on untrusted bytes); when that succeeds, the result
// must be the brute-force expansion of its bitmaps over that base, and the delta re-encoded
// against the same base must resolve to the same pools. Mode bit 2: the decoded
// payload_crc is replaced by the checksum the result would have with that base (as if the sender
// had used it), so the success path is reached, not only the checksum failure.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <type_traits>
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
    // A base made from the input: a range of up to the frame's cells (a byte of the input picks
    // how much shorter), every value derived from another byte, so that both a matching and a
    // failing checksum are reachable.
    const std::uint32_t salt = size > 1 ? data[1] : 0;
    const std::uint32_t cells = f.header.cell_count;
    const std::uint32_t shorter = size > 2 ? 8u * (data[2] % 4) : 0;
    const std::uint32_t bcells = cells > shorter ? cells - shorter : cells;
    std::vector<std::uint32_t> bfc, bcol, bgp;
    std::vector<std::uint8_t> bdf;
    if (f.has(dp::kFieldFirstChild)) bfc.assign(bcells, salt * 0x01010101u);
    if (f.has(dp::kFieldColour)) bcol.assign(bcells, salt << 8);
    if (f.has(dp::kFieldGroupParent)) bgp.assign(bcells / 8, salt);
    if (f.has(dp::kFieldDepthFlags)) bdf.assign(bcells / 8, static_cast<std::uint8_t>(salt));
    dp::BlockView bv;
    bv.block_id = f.header.block_id;
    bv.version = f.header.base_version;
    bv.first_cell = f.header.first_cell;
    bv.cell_count = bcells;
    bv.first_child = bfc;
    bv.colour = bcol;
    bv.group_parent = bgp;
    bv.depth_flags = bdf;
    // The block the delta stands for, expanded by brute force (the reference for the result).
    // A field the frame carries spans the whole block even where none of its values changed
    // (then `values` is empty); a field it does not carry stays empty.
    const auto expand = [](bool present, const auto& values,
                           const std::vector<std::uint64_t>& changed, const auto& base,
                           std::size_t n) {
      std::remove_cvref_t<decltype(values)> out(present ? n : 0);
      std::size_t k = 0;
      for (std::size_t i = 0; i < out.size(); ++i)
        out[i] = (changed[i / 64] >> (i % 64)) & 1 ? values[k++] : (i < base.size() ? base[i] : 0);
      return out;
    };
    dp::BlockFrame want = f;
    want.first_child =
        expand(f.has(dp::kFieldFirstChild), f.first_child, f.changed_cells, bfc, cells);
    want.colour =
        expand(f.has(dp::kFieldColour), f.colour, f.changed_cells, bcol, cells);
    want.group_parent =
        expand(f.has(dp::kFieldGroupParent), f.group_parent, f.changed_groups, bgp, cells / 8);
    want.depth_flags =
        expand(f.has(dp::kFieldDepthFlags), f.depth_flags, f.changed_groups, bdf, cells / 8);
    dp::BlockFrame resolved = f;
    if (mode & 4) {
      std::uint32_t crc = 0;
      const auto feed = [&crc](const auto& v, std::size_t bytes) {
        crc = dp::crc32({reinterpret_cast<const std::uint8_t*>(v.data()), bytes}, crc);
      };
      feed(want.first_child, want.first_child.size() * 4);
      feed(want.colour, want.colour.size() * 4);
      feed(want.group_parent, want.group_parent.size() * 4);
      feed(want.depth_flags, want.depth_flags.size());
      if (want.has(dp::kFieldNeighbourMask))
        feed(want.neighbour_mask, (want.header.cell_count / 8 + 7) / 8);
      resolved.header.payload_crc = crc;
    }
    if (!dp::apply_block_delta(resolved, bv).ok()) return 0;
    if (resolved.is_delta() || resolved.first_child != want.first_child ||
        resolved.colour != want.colour || resolved.group_parent != want.group_parent ||
        resolved.depth_flags != want.depth_flags)
      __builtin_trap();
    const dp::BlockView nv = view_of(resolved);
    dp::BlockEncoder enc({1, (f.header.flags & dp::kFlagTransformed) != 0,
                          (f.header.flags & dp::kFlagCompressed) != 0});
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
