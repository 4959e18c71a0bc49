// libFuzzer: tokens file parsing. Accepted tables hold only valid entries, and every entry
// authorizes (as a viewer at least) on its own canvas.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "deepcanvas/server_net/tokens.hpp"

namespace dp = deepcanvas::protocol;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto t = deepcanvas::server_net::TokenTable::parse(text);
  if (!t.ok()) {
    if (t.error().message.empty()) __builtin_trap();
    return 0;
  }
  for (const auto& e : t->entries()) {
    if (!dp::is_valid_canvas_name(e.canvas) || !dp::is_valid_token(e.token)) __builtin_trap();
    if (!t->authorize(e.canvas, e.token, dp::Role::viewer).ok()) __builtin_trap();
    if (t->authorize(e.canvas, e.token, dp::Role::painter).ok() != (e.role == dp::Role::painter))
      __builtin_trap();
  }
  return 0;
}
