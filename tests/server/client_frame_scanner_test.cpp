// ClientFrameScanner (server/net/src/text_frame_deferral.hpp) against a reference built with
// the frames: random streams of client frames (every length encoding, masked or not, data,
// continuation and control frames) split at random points must come out with exactly the text
// frames' opcodes turned binary, and the kinds of the messages in order.
#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "text_frame_deferral.hpp"

namespace {

using deepcanvas::server_net::ClientFrameScanner;
using Kind = ClientFrameScanner::MessageKind;

struct Stream {
  std::vector<unsigned char> bytes;     // as the client sent them
  std::vector<unsigned char> expected;  // as Beast must see them
  std::vector<Kind> kinds;
};

void add_frame(Stream& s, std::mt19937& rng, unsigned opcode, bool fin) {
  std::uniform_int_distribution<int> pick(0, 9), byte(0, 255);
  std::size_t len;
  switch (pick(rng)) {
    case 0: len = 0; break;
    case 1: len = 126 + static_cast<std::size_t>(byte(rng)) * 7; break;  // 16-bit length
    case 2: len = 65536 + static_cast<std::size_t>(byte(rng)); break;    // 64-bit length
    default: len = static_cast<std::size_t>(byte(rng)) % 126;
  }
  if (opcode >= 8) len %= 126;  // control frames are short
  const bool masked = pick(rng) < 8;
  const std::size_t at = s.bytes.size();
  s.bytes.push_back(static_cast<unsigned char>((fin ? 0x80u : 0u) | (pick(rng) == 0 ? 0x40u : 0u) |
                                               opcode));
  const unsigned char mask_bit = masked ? 0x80 : 0;
  if (len < 126) {
    s.bytes.push_back(static_cast<unsigned char>(mask_bit | len));
  } else if (len < 65536) {
    s.bytes.push_back(mask_bit | 126);
    s.bytes.push_back(static_cast<unsigned char>(len >> 8));
    s.bytes.push_back(static_cast<unsigned char>(len));
  } else {
    s.bytes.push_back(mask_bit | 127);
    for (int k = 7; k >= 0; --k) s.bytes.push_back(static_cast<unsigned char>(len >> (8 * k)));
  }
  if (masked)
    for (int k = 0; k < 4; ++k) s.bytes.push_back(static_cast<unsigned char>(byte(rng)));
  // Payload bytes that look like headers of every kind, to catch a parser that loses its place.
  for (std::size_t k = 0; k < len; ++k) s.bytes.push_back(static_cast<unsigned char>(byte(rng)));
  const std::size_t end = s.bytes.size();
  s.expected.insert(s.expected.end(), s.bytes.begin() + static_cast<std::ptrdiff_t>(at),
                    s.bytes.begin() + static_cast<std::ptrdiff_t>(end));
  if (opcode == 1) {
    s.expected[at] = static_cast<unsigned char>((s.expected[at] & 0xf0u) | 2u);
    s.kinds.push_back(Kind::text);
  } else if (opcode == 2) {
    s.kinds.push_back(Kind::binary);
  }
}

Stream random_stream(std::mt19937& rng) {
  Stream s;
  std::uniform_int_distribution<int> messages(1, 12), fragments(1, 4), pick(0, 5);
  for (int m = messages(rng); m > 0; --m) {
    const unsigned opcode = pick(rng) < 3 ? 1 : 2;
    const int n = fragments(rng);
    for (int f = 0; f < n; ++f) {
      add_frame(s, rng, f == 0 ? opcode : 0, f == n - 1);
      if (pick(rng) == 0) add_frame(s, rng, pick(rng) < 3 ? 9 : 10, true);  // ping or pong
    }
  }
  return s;
}

TEST(ClientFrameScanner, RandomFramesInRandomSplitsMatchTheReference) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 300; ++trial) {
    Stream s = random_stream(rng);
    std::vector<unsigned char> seen = s.bytes;
    ClientFrameScanner scanner;
    std::uniform_int_distribution<std::size_t> chunk(1, trial % 3 == 0 ? 3 : 4000);
    for (std::size_t i = 0; i < seen.size();) {
      const std::size_t n = std::min(chunk(rng), seen.size() - i);
      scanner.scan(seen.data() + i, n);
      i += n;
    }
    ASSERT_EQ(seen, s.expected) << trial;
    for (std::size_t k = 0; k < s.kinds.size(); ++k)
      ASSERT_EQ(scanner.take_message_kind(), s.kinds[k]) << trial << " message " << k;
    EXPECT_EQ(scanner.take_message_kind(), Kind::binary);  // none left
  }
}

}  // namespace
