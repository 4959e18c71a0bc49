// UTF-8 validation (RFC 3629): overlong forms, surrogates (U+D800..U+DFFF) and code points
// above U+10FFFF are invalid. Pure functions on untrusted bytes; safe on any input.
#pragma once

#include <cstddef>
#include <string_view>

namespace deepcanvas::base {

// Length (1..4) of the valid UTF-8 sequence starting at s[i], or 0 when none starts there
// (including a sequence cut off by the end of s). Requires i < s.size().
std::size_t utf8_sequence_length(std::string_view s, std::size_t i);

// Whether all of s is valid UTF-8.
bool valid_utf8(std::string_view s);

}  // namespace deepcanvas::base
