// CRC-32 of block frames through ISA-L (libisal, Debian's libisal-dev): crc32_gzip_refl is the
// zlib/gzip CRC-32 (reflected polynomial 0xEDB88320, inverted in and out), with a carry-less
// multiplication (PCLMULQDQ / VPCLMULQDQ) path chosen at run time where the CPU has one and a
// table path elsewhere. A frame's CRC is on the hot path of every encode and decode, so its speed
// is a figure of `deepcanvas-bench protocol` (crc32_gb_per_s).
#include <isa-l/crc.h>

#include "deepcanvas/protocol/block_frame.hpp"

namespace deepcanvas::protocol {

std::uint32_t crc32(std::span<const std::uint8_t> bytes, std::uint32_t crc) noexcept {
  // ISA-L takes a 64-bit length: one call covers any span.
  return crc32_gzip_refl(crc, bytes.data(), bytes.size());
}

}  // namespace deepcanvas::protocol
