// Block frames: round trips over random pools (every field subset, every flag combination, index
// values chosen to hit the delta coder's edge cases), every truncated prefix and every corrupted
// byte rejected, declared sizes bounded before allocation, header checks.
#include <gtest/gtest.h>

#include <zstd.h>

#include <algorithm>
#include <cstring>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/version.hpp"
#include "random_blocks.hpp"

namespace dp = deepcanvas::protocol;
using deepcanvas::Errc;

using namespace random_blocks;

namespace {

// Rewrites the header CRC after a test edits header fields on purpose.
void resign(std::vector<std::uint8_t>& frame) {
  const std::uint32_t crc = dp::crc32({frame.data(), 60});
  std::memcpy(frame.data() + 60, &crc, 4);
}
template <class T>
void poke(std::vector<std::uint8_t>& frame, std::size_t off, T v) {
  std::memcpy(frame.data() + off, &v, sizeof v);
  resign(frame);
}

const dp::BlockEncodeOptions kAllOptions[] = {
    {1, true, true}, {3, false, true}, {1, true, false}, {1, false, false}, {9, true, true}};

struct EncodedUnder {
  dp::BlockEncodeOptions options;
  std::vector<std::uint8_t> frame;
};

// One frame of random pools (at most `max_cells` cells) per option set of kAllOptions, the
// input of the tests that damage frames.
std::vector<EncodedUnder> encode_under_every_option(std::mt19937_64& rng, std::uint32_t max_cells) {
  std::vector<EncodedUnder> out;
  for (const auto& opt : kAllOptions) {
    dp::BlockEncoder enc(opt);
    const Pools p = random_pools(rng, max_cells);
    auto frame = enc.encode(p.view());
    EXPECT_TRUE(frame.ok());
    if (frame.ok()) out.push_back({opt, std::move(*frame)});
  }
  return out;
}

}  // namespace

TEST(BlockFrame, Crc32MatchesZlib) {
  const std::string s = "123456789";
  EXPECT_EQ(dp::crc32({reinterpret_cast<const std::uint8_t*>(s.data()), s.size()}), 0xCBF43926u);
  EXPECT_EQ(dp::crc32({}), 0u);
  // Incremental equals one shot, at every split point and every alignment.
  std::vector<std::uint8_t> data(100);
  for (std::size_t i = 0; i < data.size(); ++i) data[i] = static_cast<std::uint8_t>(i * 37 + 1);
  const auto whole = dp::crc32(data);
  for (std::size_t k = 0; k <= data.size(); ++k)
    EXPECT_EQ(dp::crc32(std::span(data).subspan(k), dp::crc32(std::span(data).first(k))), whole);
}

// The CRC-32 definition itself, bit by bit: the brute-force reference for crc32 (ISA-L).
std::uint32_t crc32_bitwise(std::span<const std::uint8_t> bytes, std::uint32_t crc = 0) {
  crc = ~crc;
  for (std::uint8_t b : bytes) {
    crc ^= b;
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
  }
  return ~crc;
}

// crc32 against the bit-by-bit definition: every length up to 600 (the fast path's start, its
// 16-byte steps and its tail), large buffers, odd start addresses, and continued checksums.
TEST(BlockFrame, Crc32EqualsTheBitwiseDefinition) {
  std::mt19937_64 rng(5);
  std::vector<std::uint8_t> data(70000);
  for (auto& b : data) b = static_cast<std::uint8_t>(rng());
  for (std::size_t n = 0; n <= 600; ++n)
    for (std::size_t off : {0, 1, 7}) {
      const auto s = std::span(data).subspan(off, n);
      ASSERT_EQ(dp::crc32(s), crc32_bitwise(s)) << "n " << n << " offset " << off;
    }
  for (int i = 0; i < 200; ++i) {
    const std::size_t off = rng() % 64, n = rng() % (data.size() - 64);
    const std::uint32_t seed = static_cast<std::uint32_t>(rng());
    const auto s = std::span(data).subspan(off, n);
    ASSERT_EQ(dp::crc32(s, seed), crc32_bitwise(s, seed)) << "n " << n;
  }
  // All-zero and all-one buffers (no lucky cancellation by random data).
  const std::vector<std::uint8_t> zeros(4096, 0), ones(4096, 0xFF);
  EXPECT_EQ(dp::crc32(zeros), crc32_bitwise(zeros));
  EXPECT_EQ(dp::crc32(ones), crc32_bitwise(ones));
}

TEST(BlockFrame, RoundTripRandomPoolsAllOptions) {
  std::mt19937_64 rng(11);
  dp::BlockDecoder dec;
  dp::BlockFrame f;
  for (const auto& opt : kAllOptions) {
    dp::BlockEncoder enc(opt);
    std::vector<std::uint8_t> frame;
    for (int iter = 0; iter < 150; ++iter) {
      const Pools p = random_pools(rng);
      ASSERT_TRUE(enc.encode(p.view(), frame).ok());
      auto h = dp::parse_block_header(frame);
      ASSERT_TRUE(h.ok()) << h.error().message;
      EXPECT_EQ(h->flags & dp::kFlagCompressed, opt.compress ? dp::kFlagCompressed : 0);
      EXPECT_EQ(h->flags & dp::kFlagTransformed, opt.transform ? dp::kFlagTransformed : 0);
      EXPECT_EQ(h->raw_size, dp::block_payload_size(p.cell_count, p.fields));
      auto r = dec.decode(frame, f, {4096, 4096});
      ASSERT_TRUE(r.ok()) << r.error().message;
      expect_equal(p, f);
    }
  }
}

TEST(BlockFrame, EncoderIsDeterministicAndReusable) {
  std::mt19937_64 rng(12);
  dp::BlockEncoder reused;
  for (int i = 0; i < 20; ++i) {
    const Pools p = random_pools(rng);
    auto a = reused.encode(p.view());
    dp::BlockEncoder fresh;
    auto b = fresh.encode(p.view());
    ASSERT_TRUE(a.ok() && b.ok());
    EXPECT_EQ(*a, *b);
  }
}

TEST(BlockFrame, RealisticIndexRunsCompressWell) {
  // Children allocated in order and parents in runs: the transform turns them into zeros.
  Pools p;
  p.cell_count = 4096;
  p.first_cell = 4096;
  p.block_id = 1;
  const std::uint32_t groups = 512;
  for (std::uint32_t i = 0; i < p.cell_count; ++i) {
    p.first_child.push_back(i % 3 == 0 ? 10000 + 8 * (i / 3) : dp::kNoCellWire);
    p.colour.push_back(0x80112233u);
  }
  for (std::uint32_t g = 0; g < groups; ++g) {
    p.group_parent.push_back(1000 + g);
    p.depth_flags.push_back(7);
  }
  p.mask.assign(8, 0);
  dp::BlockEncoder with({1, true, true}), without({1, false, true});
  auto a = with.encode(p.view());
  auto b = without.encode(p.view());
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_LT(a->size(), b->size());
  EXPECT_GT(static_cast<double>(dp::block_payload_size(4096, dp::kFieldAll)) / a->size(), 50.0);
}

TEST(BlockFrame, EveryTruncatedPrefixIsRejected) {
  std::mt19937_64 rng(13);
  dp::BlockDecoder dec;
  dp::BlockFrame f;
  auto frames = encode_under_every_option(rng, 512);
  ASSERT_EQ(frames.size(), std::size(kAllOptions));
  for (auto& [opt, frame] : frames) {
    for (std::size_t n = 0; n < frame.size(); ++n) {
      auto r = dec.decode(std::span(frame).first(n), f);
      ASSERT_FALSE(r.ok()) << "prefix " << n << " of " << frame.size() << " accepted";
      EXPECT_EQ(r.error().code, Errc::malformed) << r.error().message;
    }
    // Trailing bytes are no better.
    frame.push_back(0);
    EXPECT_FALSE(dec.decode(frame, f).ok());
  }
}

TEST(BlockFrame, EveryCorruptedByteIsRejected) {
  std::mt19937_64 rng(14);
  dp::BlockDecoder dec;
  dp::BlockFrame f;
  const auto frames = encode_under_every_option(rng, 256);
  ASSERT_EQ(frames.size(), std::size(kAllOptions));
  for (const auto& [opt, frame] : frames) {
    for (std::size_t i = 0; i < frame.size(); ++i) {
      auto bad = frame;
      bad[i] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
      auto r = dec.decode(bad, f);
      ASSERT_FALSE(r.ok()) << "flip at byte " << i << " of " << frame.size() << " accepted; level "
                           << opt.level << " transform " << opt.transform << " compress "
                           << opt.compress << " old " << int(frame[i]) << " new " << int(bad[i]);
    }
  }
}

TEST(BlockFrame, HeaderChecks) {
  std::mt19937_64 rng(15);
  Pools p = random_pools(rng, 64);
  p.cell_count = 64;
  p.first_cell = 4096;
  p.block_id = 1;
  p.fields = dp::kFieldAll;
  p.first_child.resize(64);
  p.colour.resize(64);
  p.group_parent.resize(8);
  p.depth_flags.resize(8);
  p.mask.resize(1);
  dp::BlockEncoder enc;
  auto good = enc.encode(p.view());
  ASSERT_TRUE(good.ok());
  const auto code = [](std::vector<std::uint8_t> frame, dp::BlockDecodeLimits lim = {}) {
    dp::BlockDecoder dec;
    dp::BlockFrame f;
    auto r = dec.decode(frame, f, lim);
    return r.ok() ? Errc::ok : r.error().code;
  };
  EXPECT_EQ(code(*good), Errc::ok);
  EXPECT_EQ(code(*good, {64, 4096}), Errc::ok);
  EXPECT_EQ(code(*good, {32, 0}), Errc::limit_exceeded);
  EXPECT_EQ(code(*good, {4096, 64}), Errc::malformed);  // cells 4096.. lie outside block 1 of 64

  auto f = *good;
  f[0] = 'X';
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint16_t>(f, 4, dp::kBlockFrameVersion + 1);  // format version
  EXPECT_EQ(code(f), Errc::unsupported);
  f = *good;
  f[40] ^= 1;  // any header change without re-signing
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint16_t>(f, 8, 0x8 | dp::kFlagCompressed);  // unknown flag
  EXPECT_EQ(code(f), Errc::unsupported);
  f = *good;
  poke<std::uint16_t>(f, 10, 0x20 | dp::kFieldAll);  // unknown field
  EXPECT_EQ(code(f), Errc::unsupported);
  f = *good;
  poke<std::uint16_t>(f, 10, 0);
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint16_t>(f, 6, 65);  // header size
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint32_t>(f, 56, 1);  // reserved
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint32_t>(f, 52, 0);  // stored checksum
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint32_t>(f, 36, 60);  // cell count not a multiple of 8
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint32_t>(f, 32, 4100);  // first cell not a multiple of 8
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint32_t>(f, 32, 0xFFFFFFF8u);  // range past 2^32
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint32_t>(f, 44, 100);  // raw size disagrees with the fields
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint32_t>(f, 48, 0);  // payload checksum
  EXPECT_EQ(code(f), Errc::malformed);
  f = *good;
  poke<std::uint16_t>(f, 10, dp::kFieldColour);  // fewer fields than the payload holds
  EXPECT_EQ(code(f), Errc::malformed);
}

TEST(BlockFrame, OversizedDeclaredSizesAreRejectedBeforeAllocating) {
  // A header declaring 2^28 cells is refused by the limit before anything is allocated.
  std::vector<std::uint8_t> frame(64, 0);
  poke<std::uint32_t>(frame, 0, dp::kBlockFrameMagic);
  poke<std::uint16_t>(frame, 4, dp::kBlockFrameVersion);
  poke<std::uint16_t>(frame, 6, 64);
  poke<std::uint16_t>(frame, 8, dp::kFlagCompressed);
  poke<std::uint16_t>(frame, 10, dp::kFieldColour);
  poke<std::uint32_t>(frame, 36, 1u << 28);
  poke<std::uint32_t>(frame, 44, 1u << 30);
  dp::BlockDecoder dec;
  dp::BlockFrame out;
  auto r = dec.decode(frame, out);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::limit_exceeded);
  EXPECT_EQ(out.colour.capacity(), 0u);

  // Within the limit, a zstd frame that declares more than raw_size is refused before
  // decompressing, and one that declares less too.
  std::vector<std::uint8_t> big(1u << 20, 0);
  for (const std::size_t declared : {std::size_t{1} << 20, std::size_t{64}}) {
    std::vector<std::uint8_t> z(ZSTD_compressBound(declared));
    const std::size_t n = ZSTD_compress(z.data(), z.size(), big.data(), declared, 1);
    ASSERT_FALSE(ZSTD_isError(n));
    std::vector<std::uint8_t> f(64, 0);
    f.insert(f.end(), z.begin(), z.begin() + static_cast<std::ptrdiff_t>(n));
    poke<std::uint32_t>(f, 0, dp::kBlockFrameMagic);
    poke<std::uint16_t>(f, 4, dp::kBlockFrameVersion);
    poke<std::uint16_t>(f, 6, 64);
    poke<std::uint16_t>(f, 8, dp::kFlagCompressed);
    poke<std::uint16_t>(f, 10, dp::kFieldColour);
    poke<std::uint32_t>(f, 36, 64);
    poke<std::uint32_t>(f, 40, static_cast<std::uint32_t>(n));
    poke<std::uint32_t>(f, 44, 256);
    poke<std::uint32_t>(f, 48, 0);
    poke<std::uint32_t>(f, 52, dp::crc32(std::span(f).subspan(64)));
    auto rr = dec.decode(f, out);
    ASSERT_FALSE(rr.ok());
    EXPECT_EQ(rr.error().code, Errc::malformed);
    EXPECT_NE(rr.error().message.find("zstd frame size"), std::string::npos) << rr.error().message;
  }
}

TEST(BlockFrame, EncoderRejectsBadViews) {
  Pools p;
  p.cell_count = 16;
  p.colour.assign(16, 0);
  p.fields = dp::kFieldColour;
  dp::BlockEncoder enc;
  EXPECT_TRUE(enc.encode(p.view()).ok());
  p.cell_count = 12;
  EXPECT_EQ(enc.encode(p.view()).error().code, Errc::invalid_argument);
  p.cell_count = 24;  // colour span too short
  EXPECT_EQ(enc.encode(p.view()).error().code, Errc::invalid_argument);
  p.cell_count = 16;
  p.first_cell = 4;
  EXPECT_EQ(enc.encode(p.view()).error().code, Errc::invalid_argument);
  p.first_cell = 0;
  p.fields = 0;
  EXPECT_EQ(enc.encode(p.view()).error().code, Errc::invalid_argument);
  p.fields = dp::kFieldColour | dp::kFieldGroupParent;
  p.group_parent.assign(3, 0);  // 16 cells have 2 groups
  EXPECT_EQ(enc.encode(p.view()).error().code, Errc::invalid_argument);
}

// ---------------------------------------------------------------- temporal delta frames

// The cells (groups) whose values differ between `now` and `base`, by brute force: what the
// bitmaps of a delta frame must mark.
std::vector<bool> changed_cells_of(const Pools& now, const Pools& base, bool groups) {
  const std::size_t n = groups ? now.cell_count / 8 : now.cell_count;
  const std::size_t bn = groups ? base.cell_count / 8 : base.cell_count;
  std::vector<bool> out(n, false);
  for (std::size_t i = 0; i < n; ++i) {
    const auto was = [&](const auto& v) -> std::uint64_t {
      return (i < bn && !v.empty()) ? v[i] : 0;
    };
    if (groups)
      out[i] =
          ((now.fields & dp::kFieldGroupParent) && now.group_parent[i] != was(base.group_parent)) ||
          ((now.fields & dp::kFieldDepthFlags) && now.depth_flags[i] != was(base.depth_flags));
    else
      out[i] =
          ((now.fields & dp::kFieldFirstChild) && now.first_child[i] != was(base.first_child)) ||
          ((now.fields & dp::kFieldColour) && now.colour[i] != was(base.colour));
  }
  return out;
}

std::vector<bool> bits_of(const std::vector<std::uint64_t>& words, std::size_t n) {
  std::vector<bool> out(n);  // no bitmap (no such pool): nothing marked
  for (std::size_t i = 0; i < n && !words.empty(); ++i) out[i] = (words[i / 64] >> (i % 64)) & 1;
  return out;
}

TEST(BlockFrameDelta, RoundTripAgainstTheBaseGivesTheNewVersion) {
  std::mt19937_64 rng(21);
  dp::BlockDecoder dec;
  dp::BlockFrame f;
  for (const auto& opt : kAllOptions) {
    dp::BlockEncoder enc(opt);
    std::vector<std::uint8_t> frame;
    for (int iter = 0; iter < 60; ++iter) {
      const Pools base = delta_base(rng);
      const Pools now = next_version(rng, base, rng() % 40);
      ASSERT_TRUE(enc.encode_delta(now.view(), base.view(), frame).ok());
      auto r = dec.decode(frame, f, {4096, 4096});
      ASSERT_TRUE(r.ok()) << r.error().message;
      ASSERT_TRUE(f.is_delta());
      EXPECT_EQ(f.header.base_version, base.version);
      EXPECT_EQ((f.header.flags & dp::kFlagTransformed) != 0, opt.transform);
      EXPECT_EQ((f.header.flags & dp::kFlagCompressed) != 0, opt.compress);
      // The bitmaps mark exactly the cells and groups that differ, and the frame carries their
      // values alone.
      const auto cells = changed_cells_of(now, base, false),
                 groups = changed_cells_of(now, base, true);
      EXPECT_EQ(bits_of(f.changed_cells, now.cell_count), cells);
      EXPECT_EQ(bits_of(f.changed_groups, now.cell_count / 8), groups);
      const auto nc = static_cast<std::size_t>(std::count(cells.begin(), cells.end(), true));
      EXPECT_EQ(f.colour.size(), (now.fields & dp::kFieldColour) ? nc : 0);
      EXPECT_EQ(f.first_child.size(), (now.fields & dp::kFieldFirstChild) ? nc : 0);
      auto a = dp::apply_block_delta(f, base.view());
      ASSERT_TRUE(a.ok()) << a.error().message;
      EXPECT_FALSE(f.is_delta());
      EXPECT_TRUE(f.changed_cells.empty() && f.changed_groups.empty());
      expect_equal(now, f);
      // The same payload checksum as the full frame of that version.
      auto full = enc.encode(now.view());
      ASSERT_TRUE(full.ok());
      EXPECT_EQ(dp::parse_block_header(*full)->payload_crc, f.header.payload_crc);
    }
  }
}

// Deltas compose: the union of the bitmaps of a chain base -> v1 -> ... -> vn with vn's values is
// a delta base -> vn (what the server sends a client that skipped versions), also when the block
// grew on the way; a cell left out of the bitmaps makes a frame the receiver rejects.
TEST(BlockFrameDelta, TheUnionOfAChainsBitmapsIsOneDelta) {
  std::mt19937_64 rng(28);
  dp::BlockEncoder enc;
  dp::BlockDecoder dec;
  for (int iter = 0; iter < 40; ++iter) {
    Pools base = delta_base(rng, 2048);
    base.fields = dp::kFieldAll;
    std::vector<Pools> chain{base};
    for (int k = 0; k < 1 + static_cast<int>(rng() % 5); ++k) {
      Pools next = next_version(rng, chain.back(), rng() % 30);
      if (rng() % 2 && (next.first_cell % 4096) + next.cell_count + 64 <= 4096) {
        for (int c = 0; c < 64; ++c) {  // the block grows: some new cells 0, some not
          next.first_child.push_back(c % 3 ? 0 : static_cast<std::uint32_t>(rng()));
          next.colour.push_back(c % 5 ? 0 : static_cast<std::uint32_t>(rng()));
        }
        for (int g = 0; g < 8; ++g) {
          next.group_parent.push_back(g % 2 ? 0 : static_cast<std::uint32_t>(rng()));
          next.depth_flags.push_back(0);
        }
        next.cell_count += 64;
        next.mask.resize((next.cell_count / 8 + 63) / 64, rng());
      }
      chain.push_back(next);
    }
    const Pools& newest = chain.back();
    std::vector<std::uint64_t> cells((newest.cell_count + 63) / 64, 0),
        groups((newest.cell_count / 8 + 63) / 64, 0);
    for (std::size_t k = 1; k < chain.size(); ++k) {
      std::vector<std::uint8_t> link;
      ASSERT_TRUE(enc.encode_delta(chain[k].view(), chain[k - 1].view(), link).ok());
      dp::BlockFrame lf;
      ASSERT_TRUE(dec.decode(link, lf).ok());
      for (std::size_t w = 0; w < lf.changed_cells.size(); ++w) cells[w] |= lf.changed_cells[w];
      for (std::size_t w = 0; w < lf.changed_groups.size(); ++w) groups[w] |= lf.changed_groups[w];
    }
    std::vector<std::uint8_t> frame;
    ASSERT_TRUE(enc.encode_changes(newest.view(), {base.version, cells, groups}, frame).ok());
    dp::BlockFrame f;
    ASSERT_TRUE(dec.decode(frame, f).ok());
    EXPECT_EQ(f.header.base_version, base.version);
    auto r = dp::apply_block_delta(f, base.view());
    ASSERT_TRUE(r.ok()) << r.error().message;
    expect_equal(newest, f);
    // Leave out one cell that did change: the checksum of the result fails.
    const auto differ = changed_cells_of(newest, base, false);
    const auto it = std::find(differ.begin(), differ.end(), true);
    if (it == differ.end()) continue;
    const std::size_t c = static_cast<std::size_t>(it - differ.begin());
    cells[c / 64] &= ~(std::uint64_t{1} << (c % 64));
    ASSERT_TRUE(enc.encode_changes(newest.view(), {base.version, cells, groups}, frame).ok());
    ASSERT_TRUE(dec.decode(frame, f).ok());
    r = dp::apply_block_delta(f, base.view());
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::malformed);
  }
}

TEST(BlockFrameDelta, EncodeChangesChecksItsBitmaps) {
  std::mt19937_64 rng(29);
  dp::BlockEncoder enc;
  Pools now = delta_base(rng, 512);
  now.fields = dp::kFieldAll;
  std::vector<std::uint64_t> cells((now.cell_count + 63) / 64, ~std::uint64_t{0}),
      groups((now.cell_count / 8 + 63) / 64, ~std::uint64_t{0});
  std::vector<std::uint8_t> out;
  EXPECT_TRUE(enc.encode_changes(now.view(), {now.version - 1, cells, groups}, out).ok());
  auto shorter = cells;
  shorter.pop_back();
  EXPECT_EQ(enc.encode_changes(now.view(), {now.version - 1, shorter, groups}, out).error().code,
            Errc::invalid_argument);
  EXPECT_EQ(enc.encode_changes(now.view(), {now.version, cells, groups}, out).error().code,
            Errc::invalid_argument);
}

// apply_block_delta takes any BlockFrame: values that do not match the bitmaps are refused.
TEST(BlockFrameDelta, ValuesThatDoNotMatchTheBitmapsAreRejected) {
  std::mt19937_64 rng(30);
  dp::BlockEncoder enc;
  dp::BlockDecoder dec;
  Pools base = delta_base(rng, 512);
  base.fields = dp::kFieldAll;
  const Pools now = next_version(rng, base, 6);
  std::vector<std::uint8_t> frame;
  ASSERT_TRUE(enc.encode_delta(now.view(), base.view(), frame).ok());
  dp::BlockFrame good;
  ASSERT_TRUE(dec.decode(frame, good).ok());
  auto f = good;
  f.colour.push_back(1);
  EXPECT_EQ(dp::apply_block_delta(f, base.view()).error().code, Errc::malformed);
  f = good;
  f.changed_groups.clear();
  EXPECT_EQ(dp::apply_block_delta(f, base.view()).error().code, Errc::malformed);
  f = good;
  f.changed_cells[0] ^= 1;  // one more (or one fewer) changed cell than values
  EXPECT_EQ(dp::apply_block_delta(f, base.view()).error().code, Errc::malformed);
  f = good;
  EXPECT_TRUE(dp::apply_block_delta(f, base.view()).ok());
}

TEST(BlockFrameDelta, FewChangesMakeAMuchSmallerFrame) {
  std::mt19937_64 rng(22);
  Pools base = delta_base(rng, 4096);
  base.cell_count = 4096;
  base.first_cell = base.block_id * 4096;
  base.fields = dp::kFieldAll;
  base.first_child.resize(4096);
  base.colour.resize(4096);
  base.group_parent.resize(512);
  base.depth_flags.resize(512);
  base.mask.resize(8);
  // Painted colours are high-entropy: random, as the worst case for full frames.
  for (auto& c : base.colour) c = static_cast<std::uint32_t>(rng());
  const Pools now = next_version(rng, base, 20);
  dp::BlockEncoder enc;
  std::vector<std::uint8_t> full, delta;
  ASSERT_TRUE(enc.encode(now.view(), full).ok());
  ASSERT_TRUE(enc.encode_delta(now.view(), base.view(), delta).ok());
  EXPECT_LT(delta.size() * 10, full.size()) << delta.size() << " vs " << full.size();
}

TEST(BlockFrameDelta, WrongBaseIsRejected) {
  std::mt19937_64 rng(23);
  dp::BlockEncoder enc;
  dp::BlockDecoder dec;
  const Pools base = delta_base(rng, 512);
  const Pools now = next_version(rng, base, 10);
  std::vector<std::uint8_t> frame;
  ASSERT_TRUE(enc.encode_delta(now.view(), base.view(), frame).ok());
  dp::BlockFrame f;
  // Another version of the block: refused before anything is touched.
  Pools other = base;
  other.version = base.version + 1;
  ASSERT_TRUE(dec.decode(frame, f).ok());
  auto r = dp::apply_block_delta(f, other.view());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::invalid_argument);
  EXPECT_NE(r.error().message.find("needs base version"), std::string::npos) << r.error().message;
  // Another block, another range.
  other = base;
  other.block_id = base.block_id + 1;
  EXPECT_EQ(dp::apply_block_delta(f, other.view()).error().code, Errc::invalid_argument);
  other = base;
  other.first_cell += 8;
  EXPECT_EQ(dp::apply_block_delta(f, other.view()).error().code, Errc::invalid_argument);
  // A pool the delta carries is missing from the base.
  other = base;
  other.fields = static_cast<std::uint16_t>(base.fields & ~dp::kFieldColour);
  if (base.fields & dp::kFieldColour) {
    EXPECT_EQ(dp::apply_block_delta(f, other.view()).error().code, Errc::invalid_argument);
  }
  // The right version number but other bytes (a replica that diverged): the checksum says so.
  other = base;
  other.colour[3] ^= 1;
  other.first_child[5] ^= 0x100;
  other.depth_flags[0] ^= 2;
  other.group_parent[1] ^= 4;
  r = dp::apply_block_delta(f, other.view());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::malformed);
  // A full frame is not a delta.
  ASSERT_TRUE(dec.decode(*enc.encode(now.view()), f).ok());
  EXPECT_EQ(dp::apply_block_delta(f, base.view()).error().code, Errc::invalid_argument);
}

TEST(BlockFrameDelta, EncoderRejectsABaseThatIsNotOne) {
  std::mt19937_64 rng(24);
  dp::BlockEncoder enc;
  const Pools base = delta_base(rng, 256);
  Pools now = next_version(rng, base, 3);
  std::vector<std::uint8_t> out;
  Pools b = base;
  b.version = now.version;  // not older
  EXPECT_EQ(enc.encode_delta(now.view(), b.view(), out).error().code, Errc::invalid_argument);
  b = base;
  now.version = b.version + (std::uint64_t{1} << 32);  // too far back for the u32 distance
  EXPECT_EQ(enc.encode_delta(now.view(), b.view(), out).error().code, Errc::invalid_argument);
  now.version = b.version + 1;
  b = base;
  b.block_id += 1;
  EXPECT_EQ(enc.encode_delta(now.view(), b.view(), out).error().code, Errc::invalid_argument);
  b = base;
  b.cell_count = base.cell_count == 8 ? 16 : base.cell_count - 8;
  EXPECT_EQ(enc.encode_delta(now.view(), b.view(), out).error().code, Errc::invalid_argument);
  b = base;
  b.fields = static_cast<std::uint16_t>(base.fields ^ dp::kFieldDepthFlags);
  if (b.fields & ~dp::kFieldNeighbourMask) {
    EXPECT_EQ(enc.encode_delta(now.view(), b.view(), out).error().code, Errc::invalid_argument);
  }
}

TEST(BlockFrameDelta, EveryTruncatedOrCorruptedDeltaIsRejected) {
  std::mt19937_64 rng(25);
  dp::BlockDecoder dec;
  dp::BlockFrame f;
  for (const bool compress : {true, false}) {
    dp::BlockEncoder enc({3, true, compress});
    const Pools base = delta_base(rng, 256);
    const Pools now = next_version(rng, base, 5);
    std::vector<std::uint8_t> frame;
    ASSERT_TRUE(enc.encode_delta(now.view(), base.view(), frame).ok());
    for (std::size_t n = 0; n < frame.size(); ++n) {
      auto r = dec.decode(std::span(frame).first(n), f);
      ASSERT_FALSE(r.ok()) << "prefix " << n << " of " << frame.size() << " accepted";
      EXPECT_EQ(r.error().code, Errc::malformed) << r.error().message;
    }
    for (std::size_t i = 0; i < frame.size(); ++i) {
      auto bad = frame;
      bad[i] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
      // Rejected by the decoder, or else by the checksum of the resolved block.
      const bool decoded = dec.decode(bad, f).ok();
      const bool resolved = decoded && f.is_delta() && dp::apply_block_delta(f, base.view()).ok();
      ASSERT_FALSE(resolved) << "flip at byte " << i << " accepted";
    }
  }
}

TEST(BlockFrameDelta, HeaderChecks) {
  std::mt19937_64 rng(26);
  const Pools base = delta_base(rng, 64);
  const Pools now = next_version(rng, base, 2);
  dp::BlockEncoder enc;
  std::vector<std::uint8_t> good;
  ASSERT_TRUE(enc.encode_delta(now.view(), base.view(), good).ok());
  const auto code = [](std::vector<std::uint8_t> frame) {
    dp::BlockDecoder dec;
    dp::BlockFrame f;
    auto r = dec.decode(frame, f);
    return r.ok() ? Errc::ok : r.error().code;
  };
  EXPECT_EQ(code(good), Errc::ok);
  auto f = good;
  poke<std::uint32_t>(f, 56, 0);  // a delta needs a base distance
  EXPECT_EQ(code(f), Errc::malformed);
  f = good;
  std::uint64_t version = 0;
  std::memcpy(&version, f.data() + 16, 8);
  ASSERT_LT(version, 0xFFFFFFFFu);
  poke<std::uint32_t>(f, 56, static_cast<std::uint32_t>(version) + 1);  // before version 0
  EXPECT_EQ(code(f), Errc::malformed);
  f = good;
  std::uint32_t raw = 0;
  std::memcpy(&raw, f.data() + 44, 4);
  poke<std::uint32_t>(f, 44, raw + 1);  // more values than the bitmaps name
  EXPECT_EQ(code(f), Errc::malformed);
  poke<std::uint32_t>(f, 44, 8);  // less than the bitmaps and the mask
  EXPECT_EQ(code(f), Errc::malformed);
  f = good;
  poke<std::uint16_t>(f, 8, dp::kFlagCompressed);  // a base distance without the delta flag
  EXPECT_EQ(code(f), Errc::malformed);
}

TEST(BlockFrameDelta, ABlockThatGrewIsADeltaAgainstItsPrefix) {
  std::mt19937_64 rng(27);
  dp::BlockEncoder enc;
  dp::BlockDecoder dec;
  for (int iter = 0; iter < 50; ++iter) {
    Pools base = delta_base(rng, 2048);
    base.fields = dp::kFieldAll;
    Pools now = next_version(rng, base, 4);
    // The block gained cells past the base's range.
    const std::uint32_t extra = 8 * (1 + static_cast<std::uint32_t>(rng() % 64));
    const Pools more = random_pools(rng, extra);
    now.cell_count += extra;
    for (std::uint32_t i = 0; i < extra; ++i) {
      now.first_child.push_back(more.first_child[i % more.cell_count]);
      now.colour.push_back(more.colour[i % more.cell_count]);
    }
    for (std::uint32_t g = 0; g < extra / 8; ++g) {
      now.group_parent.push_back(static_cast<std::uint32_t>(rng()));
      now.depth_flags.push_back(static_cast<std::uint8_t>(rng()));
    }
    now.mask.resize((now.cell_count / 8 + 63) / 64, ~std::uint64_t{0});
    if ((now.first_cell % 4096) + now.cell_count > 4096) continue;  // stay inside the block
    std::vector<std::uint8_t> frame;
    ASSERT_TRUE(enc.encode_delta(now.view(), base.view(), frame).ok());
    dp::BlockFrame f;
    ASSERT_TRUE(dec.decode(frame, f, {4096, 4096}).ok());
    auto r = dp::apply_block_delta(f, base.view());
    ASSERT_TRUE(r.ok()) << r.error().message;
    expect_equal(now, f);
    // The other way round (a base longer than the frame) is not a base.
    EXPECT_FALSE(enc.encode_delta(base.view(), now.view(), frame).ok());
  }
}
