// The undo history's encoder thread (server/core/src/change_encoder.hpp, a private header):
// every change comes back, in push order, with exactly the bytes encode_cell_diff gives in place,
// however pushes, take_done and wait_all interleave.
#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "change_encoder.hpp"

namespace deepcanvas::test {
namespace {

using server_core::CellChange;
using server_core::CellDiff;
using server_core::ChangeEncoder;
using Kind = ChangeEncoder::Change::Kind;

CellDiff random_diff(std::mt19937& rng) {
  CellDiff d;
  const std::size_t n = std::uniform_int_distribution<std::size_t>(0, 3000)(rng);
  for (std::size_t i = 0; i < n; ++i) {
    CellChange c;
    c.cell.depth = static_cast<int>(rng() % 12);
    c.cell.x = rng() % 4096;
    c.cell.y = rng() % 4096;
    c.cell.z = rng() % 4096;
    c.before = {static_cast<std::uint32_t>(rng()), (rng() & 1) != 0, (rng() & 2) != 0};
    c.after = {static_cast<std::uint32_t>(rng()), true, (rng() & 4) != 0};
    d.changes.push_back(c);
  }
  return d;
}

TEST(ChangeEncoder, ChangesComeBackInPushOrderEncodedAsInPlace) {
  std::mt19937 rng(7);
  for (int round = 0; round < 20; ++round) {
    ChangeEncoder enc;
    std::vector<std::vector<std::uint8_t>> want;
    std::vector<Kind> kinds;
    std::vector<ChangeEncoder::Change> got;
    const int n = 1 + static_cast<int>(rng() % 12);
    for (int i = 0; i < n; ++i) {
      ChangeEncoder::Change c;
      c.kind = static_cast<Kind>(rng() % 4);
      c.artist = rng() % 3;
      c.stroke = static_cast<std::uint64_t>(i + 1);
      if (c.kind != Kind::too_large) c.diff = random_diff(rng);
      want.push_back(c.kind == Kind::too_large ? std::vector<std::uint8_t>{}
                                               : server_core::encode_cell_diff(c.diff));
      kinds.push_back(c.kind);
      enc.push(std::move(c));
      if (rng() % 3 == 0)
        for (auto& d : enc.take_done()) got.push_back(std::move(d));
    }
    for (auto& d : enc.wait_all()) got.push_back(std::move(d));
    EXPECT_TRUE(enc.empty());
    EXPECT_EQ(enc.bytes_in_flight(), 0u);
    ASSERT_EQ(got.size(), want.size()) << "round " << round;
    for (std::size_t i = 0; i < got.size(); ++i) {
      EXPECT_EQ(got[i].stroke, i + 1) << "round " << round;
      EXPECT_EQ(got[i].kind, kinds[i]);
      EXPECT_FALSE(got[i].failed);
      EXPECT_TRUE(got[i].diff.empty());  // released once encoded
      EXPECT_EQ(got[i].bytes, want[i]) << "round " << round << " change " << i;
    }
  }
}

TEST(ChangeEncoder, CountsTheDiffsInFlightAndDrainsOnDestruction) {
  std::mt19937 rng(11);
  auto enc = std::make_unique<ChangeEncoder>();
  ChangeEncoder::Change c;
  c.diff = random_diff(rng);
  while (c.diff.empty()) c.diff = random_diff(rng);
  const std::uint64_t b = ChangeEncoder::bytes_of(c.diff);
  EXPECT_EQ(b, c.diff.size() * sizeof(CellChange));
  enc->push(std::move(c));
  EXPECT_LE(enc->bytes_in_flight(), b);  // b, or 0 once the thread encoded it
  EXPECT_FALSE(enc->empty());
  ChangeEncoder::Change more;
  more.diff = random_diff(rng);
  enc->push(std::move(more));
  enc.reset();  // joins with changes still pushed: no hang, no leak (ASan)
}

}  // namespace
}  // namespace deepcanvas::test
