// Frame bundles (PROTOCOL.md 4.12): a bundle of random frames (full under every option, delta,
// mask-only) decodes to exactly what each frame decodes to alone, in order; every truncated prefix
// and corrupted byte is rejected with no frame handed over; records that do not fill the bundle,
// compressed or too new records, and oversized declared sizes are rejected before allocating.
#include <gtest/gtest.h>

#include <zstd.h>

#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/frame_bundle.hpp"
#include "random_blocks.hpp"

namespace dp = deepcanvas::protocol;
using deepcanvas::Errc;
using namespace random_blocks;

namespace {

// A batch as a server sends it: full frames under every option set, delta frames, and the
// mask-only frame of one of the blocks, in random order.
std::vector<std::vector<std::uint8_t>> random_batch(std::mt19937_64& rng) {
  std::vector<std::vector<std::uint8_t>> frames;
  const dp::BlockEncodeOptions options[] = {
      {3, true, true}, {1, false, true}, {1, true, false}, {1, false, false}};
  const std::size_t n = 1 + rng() % 8;
  for (std::size_t i = 0; i < n; ++i) {
    dp::BlockEncoder enc(options[rng() % std::size(options)]);
    switch (rng() % 3) {
      case 0: {
        frames.push_back(*enc.encode(random_pools(rng, 1024).view()));
        break;
      }
      case 1: {
        Pools base = delta_base(rng, 1024);
        base.fields = dp::kFieldAll;
        const Pools next = next_version(rng, base, 1 + rng() % 20);
        std::vector<std::uint8_t> out;
        EXPECT_TRUE(enc.encode_delta(next.view(), base.view(), out).ok());
        frames.push_back(std::move(out));
        break;
      }
      default: {
        Pools p = random_pools(rng, 1024);
        p.fields = dp::kFieldNeighbourMask;
        dp::BlockEncoder raw({1, false, false});
        frames.push_back(*raw.encode(p.view()));
        break;
      }
    }
  }
  return frames;
}

std::vector<std::uint8_t> bundle_of(const std::vector<std::vector<std::uint8_t>>& frames,
                                    int level = 3) {
  dp::BundleEncoder enc(level);
  for (const auto& f : frames) EXPECT_TRUE(enc.add(f).ok());
  std::vector<std::uint8_t> out;
  EXPECT_TRUE(enc.finish(out).ok());
  return out;
}

// Decodes a bundle, keeping a copy of every frame handed over.
struct Decoded {
  deepcanvas::Result<dp::BundleHeader> result = deepcanvas::Error{};
  std::vector<dp::BlockFrame> frames;
};
Decoded decode_all(std::span<const std::uint8_t> bundle,
                   const dp::BundleDecodeLimits& limits = {}) {
  static dp::BundleDecoder decoder;  // reused, as receivers do
  Decoded d;
  dp::BlockFrame scratch;
  d.result =
      decoder.decode(bundle, limits, scratch, [&](dp::BlockFrame& f) -> deepcanvas::Result<void> {
        d.frames.push_back(f);
        return {};
      });
  return d;
}

void expect_same_frame(const dp::BlockFrame& a, const dp::BlockFrame& b) {
  EXPECT_EQ(a.header.flags & ~dp::kFlagCompressed, b.header.flags & ~dp::kFlagCompressed);
  EXPECT_EQ(a.header.fields, b.header.fields);
  EXPECT_EQ(a.header.block_id, b.header.block_id);
  EXPECT_EQ(a.header.version, b.header.version);
  EXPECT_EQ(a.header.epoch, b.header.epoch);
  EXPECT_EQ(a.header.first_cell, b.header.first_cell);
  EXPECT_EQ(a.header.cell_count, b.header.cell_count);
  EXPECT_EQ(a.header.raw_size, b.header.raw_size);
  EXPECT_EQ(a.header.payload_crc, b.header.payload_crc);
  EXPECT_EQ(a.header.base_version, b.header.base_version);
  EXPECT_EQ(a.first_child, b.first_child);
  EXPECT_EQ(a.colour, b.colour);
  EXPECT_EQ(a.group_parent, b.group_parent);
  EXPECT_EQ(a.depth_flags, b.depth_flags);
  EXPECT_EQ(a.neighbour_mask, b.neighbour_mask);
  EXPECT_EQ(a.changed_cells, b.changed_cells);
  EXPECT_EQ(a.changed_groups, b.changed_groups);
}

// A bundle around hand-made records (raw bytes before compression), with correct checksums:
// reaches the record checks behind the CRCs.
std::vector<std::uint8_t> wrap_records(const std::vector<std::uint8_t>& records,
                                       std::uint32_t count, std::uint64_t epoch) {
  std::vector<std::uint8_t> out(dp::kBundleHeaderSize + ZSTD_compressBound(records.size()));
  const std::size_t n =
      ZSTD_compress(out.data() + dp::kBundleHeaderSize, out.size() - dp::kBundleHeaderSize,
                    records.data(), records.size(), 1);
  EXPECT_FALSE(ZSTD_isError(n));
  out.resize(dp::kBundleHeaderSize + n);
  const auto put = [&](std::size_t off, auto v) { std::memcpy(out.data() + off, &v, sizeof v); };
  put(0, dp::kBundleMagic);
  put(4, dp::kBundleVersion);
  put(6, static_cast<std::uint16_t>(dp::kBundleHeaderSize));
  put(8, count);
  put(12, static_cast<std::uint32_t>(records.size()));
  put(16, epoch);
  put(24, dp::crc32(std::span(out).subspan(dp::kBundleHeaderSize)));
  put(28, dp::crc32(std::span(out).first(28)));
  return out;
}

// The records of a real bundle (decompressed), to edit.
std::vector<std::uint8_t> records_of(const std::vector<std::uint8_t>& bundle) {
  std::uint32_t raw = 0;
  std::memcpy(&raw, bundle.data() + 12, 4);
  std::vector<std::uint8_t> records(raw);
  const std::size_t n =
      ZSTD_decompress(records.data(), records.size(), bundle.data() + dp::kBundleHeaderSize,
                      bundle.size() - dp::kBundleHeaderSize);
  EXPECT_EQ(n, raw);
  return records;
}

}  // namespace

// Property: whatever frames go in, the bundle hands over exactly what decoding each frame alone
// gives, in the same order, and its header counts them and names the newest epoch.
TEST(FrameBundle, DecodesToWhatEachFrameDecodesToAlone) {
  std::mt19937_64 rng(11);
  dp::BlockDecoder single;
  for (int round = 0; round < 200; ++round) {
    const auto frames = random_batch(rng);
    const auto bundle = bundle_of(frames, round % 2 ? 1 : 3);
    ASSERT_TRUE(dp::is_bundle(bundle));
    const Decoded d = decode_all(bundle);
    ASSERT_TRUE(d.result.ok()) << d.result.error().message;
    ASSERT_EQ(d.frames.size(), frames.size());
    EXPECT_EQ(d.result->record_count, frames.size());
    std::uint64_t newest = 0;
    for (std::size_t i = 0; i < frames.size(); ++i) {
      dp::BlockFrame alone;
      ASSERT_TRUE(single.decode(frames[i], alone).ok());
      newest = std::max(newest, alone.header.epoch);
      expect_same_frame(d.frames[i], alone);
    }
    EXPECT_EQ(d.result->epoch, newest);
    const auto header = dp::parse_bundle_header(bundle);
    ASSERT_TRUE(header.ok());
    EXPECT_EQ(header->record_count, frames.size());
  }
}

// A delta handed over by a bundle resolves against its base like the frame itself.
TEST(FrameBundle, ADeltaRecordResolvesAgainstItsBase) {
  std::mt19937_64 rng(12);
  for (int round = 0; round < 20; ++round) {
    Pools base = delta_base(rng);
    base.fields = dp::kFieldAll;
    const Pools next = next_version(rng, base, 1 + rng() % 50);
    dp::BlockEncoder enc;
    std::vector<std::uint8_t> delta;
    ASSERT_TRUE(enc.encode_delta(next.view(), base.view(), delta).ok());
    Decoded d = decode_all(bundle_of({delta}));
    ASSERT_TRUE(d.result.ok());
    ASSERT_EQ(d.frames.size(), 1u);
    ASSERT_TRUE(dp::apply_block_delta(d.frames[0], base.view()).ok());
    expect_equal(next, d.frames[0]);
  }
}

TEST(FrameBundle, EncoderChecksItsInput) {
  dp::BundleEncoder enc;
  std::vector<std::uint8_t> out;
  EXPECT_EQ(enc.finish(out).error().code, Errc::invalid_argument);  // no record
  std::mt19937_64 rng(13);
  auto frame = *dp::BlockEncoder().encode(random_pools(rng).view());
  frame.resize(frame.size() - 1);  // a truncated frame does not parse
  EXPECT_FALSE(enc.add(frame).ok());
  EXPECT_EQ(enc.records(), 0u);
  EXPECT_EQ(enc.raw_size(), 0u);
  // After finish() the encoder starts empty: two bundles of one frame each.
  const auto a = *dp::BlockEncoder().encode(random_pools(rng).view());
  ASSERT_TRUE(enc.add(a).ok());
  ASSERT_TRUE(enc.finish(out).ok());
  EXPECT_EQ(enc.records(), 0u);
  ASSERT_TRUE(enc.add(a).ok());
  std::vector<std::uint8_t> again;
  ASSERT_TRUE(enc.finish(again).ok());
  EXPECT_EQ(out, again);
}

TEST(FrameBundle, EveryTruncatedPrefixIsRejected) {
  std::mt19937_64 rng(14);
  const auto bundle = bundle_of(random_batch(rng));
  for (std::size_t n = 0; n < bundle.size(); ++n) {
    const Decoded d = decode_all(std::span(bundle).first(n));
    EXPECT_FALSE(d.result.ok()) << n;
    EXPECT_TRUE(d.frames.empty()) << n;
  }
}

TEST(FrameBundle, EveryCorruptedByteIsRejectedBeforeAnyFrameIsHandedOver) {
  std::mt19937_64 rng(15);
  const auto bundle = bundle_of(random_batch(rng));
  for (std::size_t i = 0; i < bundle.size(); ++i) {
    auto bad = bundle;
    bad[i] ^= static_cast<std::uint8_t>(1 + rng() % 255);
    const Decoded d = decode_all(bad);
    EXPECT_FALSE(d.result.ok()) << i;
    EXPECT_TRUE(d.frames.empty()) << i;
  }
}

// Behind the checksums: records that do not fill the bundle exactly, a compressed record, a
// record newer than its bundle, a record past the limits, a bad record payload.
TEST(FrameBundle, RecordChecks) {
  std::mt19937_64 rng(16);
  const auto frames = random_batch(rng);
  const auto bundle = bundle_of(frames);
  const auto records = records_of(bundle);
  std::uint64_t epoch = 0;
  std::memcpy(&epoch, bundle.data() + 16, 8);
  const auto count = static_cast<std::uint32_t>(frames.size());
  // As made: accepted.
  ASSERT_TRUE(decode_all(wrap_records(records, count, epoch)).result.ok());
  const auto rejected = [&](const std::vector<std::uint8_t>& recs, std::uint32_t n, std::uint64_t e,
                            const std::string& what) {
    const Decoded d = decode_all(wrap_records(recs, n, e));
    EXPECT_FALSE(d.result.ok()) << what;
    return d;
  };
  // One record more or fewer than the header says, a byte past the records.
  EXPECT_TRUE(rejected(records, count + 1, epoch, "count + 1").frames.empty());
  if (count > 1) {
    EXPECT_TRUE(rejected(records, count - 1, epoch, "count - 1").frames.empty());
  }
  auto longer = records;
  longer.push_back(0);
  EXPECT_TRUE(rejected(longer, count, epoch, "trailing byte").frames.empty());
  // The first record's raw_size off by one either way.
  for (int d : {-1, 1}) {
    auto r = records;
    std::uint32_t raw = 0;
    std::memcpy(&raw, r.data() + 32, 4);
    raw += static_cast<std::uint32_t>(d);
    std::memcpy(r.data() + 32, &raw, 4);
    EXPECT_TRUE(rejected(r, count, epoch, "raw_size").frames.empty());
  }
  // A record older than the bundle is fine; one newer is not.
  if (epoch > 0) rejected(records, count, epoch - 1, "a record newer than its bundle");
  // The compressed flag on a record.
  {
    auto r = records;
    r[0] |= dp::kFlagCompressed;
    EXPECT_EQ(rejected(r, count, epoch, "compressed").result.error().code, Errc::malformed);
  }
  // Record limits: more cells than allowed.
  {
    dp::BundleDecodeLimits limits;
    limits.block.max_cells = 8;
    const Decoded d = decode_all(bundle, limits);
    EXPECT_EQ(d.result.error().code, Errc::limit_exceeded);
  }
  // A bad payload (a full frame's checksum) after the first record.
  if (count > 1) {
    auto r = records;
    std::uint32_t crc = 0;
    std::memcpy(&crc, r.data() + 36, 4);
    // Flip the last record's payload_crc: earlier records are handed over, then it fails.
    std::size_t at = 0, last = 0;
    for (std::uint32_t i = 0; i < count; ++i) {
      last = at;
      std::uint32_t raw = 0;
      std::memcpy(&raw, r.data() + at + 32, 4);
      at += dp::kBundleRecordHeaderSize + raw;
    }
    std::uint16_t flags = 0;
    std::memcpy(&flags, r.data() + last, 2);
    r[last + 36] ^= 1;
    const Decoded d = decode_all(wrap_records(r, count, epoch));
    if (!(flags & dp::kFlagDelta)) {  // a delta's checksum is checked when it is resolved
      EXPECT_FALSE(d.result.ok());
      EXPECT_EQ(d.frames.size(), count - 1);
    }
  }
}

TEST(FrameBundle, OversizedDeclaredSizesAreRejectedBeforeAllocating) {
  std::mt19937_64 rng(17);
  auto bundle = bundle_of(random_batch(rng));
  const auto resign = [](std::vector<std::uint8_t>& b) {
    const std::uint32_t crc = dp::crc32(std::span(b).first(28));
    std::memcpy(b.data() + 28, &crc, 4);
  };
  auto huge = bundle;
  const std::uint32_t raw = 0xFFFFFFF0u;
  std::memcpy(huge.data() + 12, &raw, 4);
  resign(huge);
  EXPECT_EQ(decode_all(huge).result.error().code, Errc::limit_exceeded);
  auto many = bundle;
  const std::uint32_t count = 0x7FFFFFFFu;
  std::memcpy(many.data() + 8, &count, 4);
  resign(many);
  EXPECT_EQ(decode_all(many).result.error().code, Errc::malformed);
  auto none = bundle;
  const std::uint32_t zero = 0;
  std::memcpy(none.data() + 8, &zero, 4);
  resign(none);
  EXPECT_EQ(decode_all(none).result.error().code, Errc::malformed);
  auto version = bundle;
  version[4] = 2;
  resign(version);
  EXPECT_EQ(decode_all(version).result.error().code, Errc::unsupported);
}

// The receiver's callback can stop the bundle: its error is returned, no later record is handed.
TEST(FrameBundle, TheReceiversErrorStopsTheBundle) {
  std::mt19937_64 rng(18);
  std::vector<std::vector<std::uint8_t>> frames;
  while (frames.size() < 3) frames = random_batch(rng);
  const auto bundle = bundle_of(frames);
  dp::BundleDecoder decoder;
  dp::BlockFrame scratch;
  int seen = 0;
  const auto r =
      decoder.decode(bundle, {}, scratch, [&](dp::BlockFrame&) -> deepcanvas::Result<void> {
        if (++seen == 2) return deepcanvas::make_error(Errc::invalid_argument, "no base");
        return {};
      });
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::invalid_argument);
  EXPECT_EQ(seen, 2);
}
