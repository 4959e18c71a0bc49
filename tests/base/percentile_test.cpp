// base::percentile against its definition written out the slow way: for q = k / (n - 1) it is
// exactly the k-th smallest value; between two such points it moves linearly.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <vector>

#include "deepcanvas/base/percentile.hpp"

namespace {

using deepcanvas::base::percentile;

TEST(Percentile, EmptyIsZeroAndOneValueIsThatValue) {
  EXPECT_EQ(percentile({}, 0.5), 0.0);
  EXPECT_EQ(percentile({7.0}, 0.0), 7.0);
  EXPECT_EQ(percentile({7.0}, 0.99), 7.0);
}

TEST(Percentile, MatchesRanksAndInterpolatesBetweenThem) {
  std::mt19937 rng(12345);
  std::uniform_real_distribution<double> value(-100.0, 100.0);
  for (int trial = 0; trial < 200; ++trial) {
    const std::size_t n = 1 + rng() % 50;
    std::vector<double> sample(n);
    for (double& v : sample) v = value(rng);
    std::vector<double> sorted = sample;
    std::sort(sorted.begin(), sorted.end());
    for (std::size_t k = 0; k < n; ++k) {
      const double q = n == 1 ? 0.0 : static_cast<double>(k) / static_cast<double>(n - 1);
      EXPECT_NEAR(percentile(sample, q), sorted[k], 1e-9);  // q * (n - 1) may round off k
    }
    if (n >= 2) {
      const double mid = 0.5 / static_cast<double>(n - 1);  // halfway between ranks 0 and 1
      EXPECT_NEAR(percentile(sample, mid), 0.5 * (sorted[0] + sorted[1]), 1e-9);
    }
    EXPECT_EQ(percentile(sample, -1.0), sorted.front());
    EXPECT_EQ(percentile(sample, 2.0), sorted.back());
  }
}

TEST(Percentile, MedianOfEvenCountIsMeanOfMiddleTwo) {
  EXPECT_DOUBLE_EQ(percentile({4.0, 1.0, 3.0, 2.0}, 0.5), 2.5);
}

}  // namespace
