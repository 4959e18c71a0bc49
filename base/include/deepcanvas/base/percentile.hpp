// The one percentile every report in the tree uses (replay, watch, benchmarks): linear
// interpolation between the two nearest ranks, numpy's default ("linear"), so p50 of an even
// count is the mean of the middle two and p100 is the maximum. q is a fraction in [0, 1]
// (clamped); an empty sample gives 0.
//
// Pure functions, thread-safe. percentile() copies and sorts; percentile_sorted() takes a sample
// already in ascending order, for several percentiles of one sample.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <span>
#include <vector>

namespace deepcanvas::base {

inline double percentile_sorted(std::span<const double> sorted, double q) {
  if (sorted.empty()) return 0.0;
  const double h = std::clamp(q, 0.0, 1.0) * static_cast<double>(sorted.size() - 1);
  const auto lo = static_cast<std::size_t>(std::floor(h));
  const std::size_t hi = std::min(lo + 1, sorted.size() - 1);
  return sorted[lo] + (h - static_cast<double>(lo)) * (sorted[hi] - sorted[lo]);
}

inline double percentile(std::vector<double> sample, double q) {
  std::sort(sample.begin(), sample.end());
  return percentile_sorted(sample, q);
}

}  // namespace deepcanvas::base
