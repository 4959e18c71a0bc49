// Versions of everything that crosses the wire. PROTOCOL.md is the normative description.
//
// kProtocolVersion covers the control messages and the handshake: a server speaks exactly one
// version and answers a hello naming another with error code "unsupported" and closes.
// kBlockFrameVersion is the binary block frame format (byte 4 of every frame).
// kPoolLayoutId / kPoolLayoutVersion name the meaning of the pool bytes a block frame carries
// (shaders/include/pool_layout.h, the one definition of the layout, which owns the version); a
// client that does not know them must not render them.
#pragma once

#include <cstdint>
#include <string_view>

#include "pool_layout.h"

namespace deepcanvas::protocol {

inline constexpr std::uint32_t kProtocolVersion = 1;
inline constexpr std::uint16_t kBlockFrameVersion = 2;
inline constexpr std::string_view kPoolLayoutId = "deepcanvas-soa-g8";
inline constexpr std::uint32_t kPoolLayoutVersion = pool_layout::kLayoutVersion;

// Largest integer every JSON implementation represents exactly (IEEE double): ids, epochs,
// handles and counters in control messages stay at or below it.
inline constexpr std::uint64_t kMaxJsonInteger = (std::uint64_t{1} << 53) - 1;

}  // namespace deepcanvas::protocol
