// libFuzzer: control message decoding. Beyond "no crash, no UB": whatever decodes must encode
// to text that decodes again to the same encoding (the round trip is a fixed point).
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "deepcanvas/protocol/messages.hpp"

namespace dp = deepcanvas::protocol;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  dp::MessageRef about;
  auto m = dp::decode_message(text, {}, &about);
  if (!m.ok()) {
    if (m.error().message.empty()) __builtin_trap();
    // The error frame a server would send must itself decode.
    if (!dp::decode_message(dp::encode_message(dp::to_error_message(m.error(), about))).ok())
      __builtin_trap();
    return 0;
  }
  const std::string once = dp::encode_message(*m);
  auto again = dp::decode_message(once);
  if (!again.ok() || again->index() != m->index()) __builtin_trap();
  if (dp::encode_message(*again) != once) __builtin_trap();
  return 0;
}
