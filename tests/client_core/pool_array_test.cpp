// PoolArray against std::vector: random resizes (with and without a fill), writes, copies and
// moves; every element must read as the vector's. New elements read as zero without a fill,
// including after a shrink and a regrow, data written before a growth survives it, and the
// storage does not move when it grows (one reservation of the whole capacity).
#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <stdexcept>
#include <vector>

#include "deepcanvas/client_core/pool_array.hpp"

namespace deepcanvas::test {
namespace {

using client_core::PoolArray;

template <class T>
void expect_same(const PoolArray<T>& a, const std::vector<T>& v) {
  ASSERT_EQ(a.size(), v.size());
  for (std::size_t i = 0; i < v.size(); ++i) ASSERT_EQ(a[i], v[i]) << "element " << i;
}

TEST(PoolArray, AgreesWithAVectorThroughRandomGrowthWritesAndCopies) {
  for (std::uint64_t seed = 1; seed <= 6; ++seed) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    std::mt19937_64 rng(seed);
    PoolArray<std::uint32_t> a(300000);
    std::vector<std::uint32_t> v;
    for (int step = 0; step < 200; ++step) {
      switch (rng() % 5) {
        case 0: {  // grow or shrink, new elements zero
          const std::size_t n = rng() % 3 == 0 ? rng() % 300000 : rng() % 5000;
          a.resize(n);
          v.resize(n, 0);
          break;
        }
        case 1: {  // grow or shrink with a fill
          const std::size_t n = rng() % 200000;
          const std::uint32_t fill = rng() % 2 ? 0xFFFFFFFFu : 0u;
          a.resize(n, fill);
          v.resize(n, fill);
          break;
        }
        case 2:  // writes
          for (int k = 0; k < 50 && !v.empty(); ++k) {
            const std::size_t i = rng() % v.size();
            const auto x = static_cast<std::uint32_t>(rng());
            a[i] = x;
            v[i] = x;
          }
          break;
        case 3: {  // a copy, then the original changed: the copy keeps its values
          PoolArray<std::uint32_t> c = a;
          const std::vector<std::uint32_t> cv = v;
          if (!v.empty()) {
            a[0] ^= 1u;
            v[0] ^= 1u;
          }
          expect_same(c, cv);
          break;
        }
        case 4: {  // moved out and back
          PoolArray<std::uint32_t> m(std::move(a));
          a = std::move(m);
          break;
        }
      }
      expect_same(a, v);
      if (HasFatalFailure()) return;
    }
  }
}

TEST(PoolArray, ALargeGrowthReadsZeroAndKeepsWhatWasWritten) {
  PoolArray<std::uint64_t> a(std::size_t{1} << 28);  // 2 GiB of address space
  a.resize(std::size_t{1} << 27);
  const std::uint64_t* at = a.data();
  EXPECT_EQ(a[0], 0u);
  EXPECT_EQ(a[(std::size_t{1} << 27) - 1], 0u);
  a[12345] = 7;
  a.resize(std::size_t{1} << 28);
  EXPECT_EQ(a.data(), at);  // grown in place
  EXPECT_EQ(a[12345], 7u);
  EXPECT_EQ(a[(std::size_t{1} << 28) - 1], 0u);
  a.resize(10);
  a.resize(20000);
  EXPECT_EQ(a[12345], 0u);  // zero again after a shrink
  EXPECT_THROW(a.resize((std::size_t{1} << 28) + 1), std::length_error);
  EXPECT_EQ(a.size(), 20000u);  // unchanged by the refused growth
  PoolArray<std::uint8_t> bytes(128);
  bytes.resize(100, 0x80);
  EXPECT_EQ(bytes[99], 0x80);
  EXPECT_TRUE(PoolArray<int>{}.empty());
  EXPECT_THROW(PoolArray<int>{}.resize(1), std::length_error);
}

}  // namespace
}  // namespace deepcanvas::test
