// Random block pools for the block frame and frame bundle tests: index values chosen to hit the
// delta coder's edge cases, every field subset, and the check that a decoded frame holds them.
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <type_traits>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"

namespace random_blocks {

namespace dp = deepcanvas::protocol;

// Pools of one block plus the view over them.
struct Pools {
  std::uint32_t block_id = 0, first_cell = 0, cell_count = 0;
  std::uint64_t version = 0, epoch = 0;
  std::vector<std::uint32_t> first_child, colour, group_parent;
  std::vector<std::uint8_t> depth_flags;
  std::vector<std::uint64_t> mask;
  std::uint16_t fields = dp::kFieldAll;

  dp::BlockView view() const {
    dp::BlockView v;
    v.block_id = block_id;
    v.version = version;
    v.epoch = epoch;
    v.first_cell = first_cell;
    v.cell_count = cell_count;
    if (fields & dp::kFieldFirstChild) v.first_child = first_child;
    if (fields & dp::kFieldColour) v.colour = colour;
    if (fields & dp::kFieldGroupParent) v.group_parent = group_parent;
    if (fields & dp::kFieldDepthFlags) v.depth_flags = depth_flags;
    if (fields & dp::kFieldNeighbourMask) v.neighbour_mask = mask;
    return v;
  }
};

// Index values: runs of "previous + stride" (what the delta coder predicts), kNoCell, the
// extremes around the prediction (residuals of +-2^31, the code kNoCell would have had), random.
inline std::uint32_t index_value(std::mt19937_64& rng, std::uint32_t& last, std::uint32_t stride) {
  std::uint32_t v = 0;
  switch (rng() % 9) {
    case 0:
    case 1:
      v = dp::kNoCellWire;
      break;
    case 2:
    case 3:
      v = last + stride;
      break;
    case 4:
      v = last + stride + 0x80000000u;
      break;
    case 5:
      v = last + stride + 0x7FFFFFFFu;
      break;
    case 6:
      v = dp::kNoCellWire - 1;
      break;
    case 7:
      v = static_cast<std::uint32_t>(rng() % 3);
      break;
    default:
      v = static_cast<std::uint32_t>(rng());
      break;
  }
  if (v != dp::kNoCellWire) last = v;
  return v;
}

inline Pools random_pools(std::mt19937_64& rng, std::uint32_t max_cells = 4096) {
  Pools p;
  p.cell_count = 8 * (1 + static_cast<std::uint32_t>(rng() % (max_cells / 8)));
  p.block_id = static_cast<std::uint32_t>(rng() % 1000);
  p.first_cell =
      p.block_id * 4096 + 8 * static_cast<std::uint32_t>(rng() % ((4096 - p.cell_count) / 8 + 1));
  p.version = rng();
  p.epoch = rng();
  const std::uint32_t groups = p.cell_count / 8;
  std::uint32_t last = 0;
  for (std::uint32_t i = 0; i < p.cell_count; ++i)
    p.first_child.push_back(index_value(rng, last, 8));
  for (std::uint32_t i = 0; i < p.cell_count; ++i)
    p.colour.push_back(rng() % 2 ? 0xFF336699u : static_cast<std::uint32_t>(rng()));
  last = 0;
  for (std::uint32_t g = 0; g < groups; ++g) p.group_parent.push_back(index_value(rng, last, 1));
  for (std::uint32_t g = 0; g < groups; ++g)
    p.depth_flags.push_back(static_cast<std::uint8_t>(rng()));
  p.mask.resize((groups + 63) / 64);
  for (auto& w : p.mask) w = rng();  // bits past the last group too: the encoder drops them
  p.fields = static_cast<std::uint16_t>(1 + rng() % dp::kFieldAll);
  return p;
}

inline void expect_equal(const Pools& p, const dp::BlockFrame& f) {
  const std::uint32_t groups = p.cell_count / 8;
  EXPECT_EQ(f.header.block_id, p.block_id);
  EXPECT_EQ(f.header.version, p.version);
  EXPECT_EQ(f.header.epoch, p.epoch);
  EXPECT_EQ(f.header.first_cell, p.first_cell);
  EXPECT_EQ(f.header.cell_count, p.cell_count);
  EXPECT_EQ(f.header.fields, p.fields);
  const auto want = [&](std::uint16_t bit, const auto& v) {
    using V = std::decay_t<decltype(v)>;
    return (p.fields & bit) ? v : V{};
  };
  EXPECT_EQ(f.first_child, want(dp::kFieldFirstChild, p.first_child));
  EXPECT_EQ(f.colour, want(dp::kFieldColour, p.colour));
  EXPECT_EQ(f.group_parent, want(dp::kFieldGroupParent, p.group_parent));
  EXPECT_EQ(f.depth_flags, want(dp::kFieldDepthFlags, p.depth_flags));
  if (p.fields & dp::kFieldNeighbourMask) {
    auto m = p.mask;
    if (groups % 64) m.back() &= (std::uint64_t{1} << (groups % 64)) - 1;
    EXPECT_EQ(f.neighbour_mask, m);
  } else {
    EXPECT_TRUE(f.neighbour_mask.empty());
  }
}

// Random pools as the base of a delta: a version far from overflow.
inline Pools delta_base(std::mt19937_64& rng, std::uint32_t max_cells = 4096) {
  Pools p = random_pools(rng, max_cells);
  p.version = 1 + rng() % 1000000;
  return p;
}

// A newer version of `p`: a few cells (and groups) changed in every pool, same range and fields.
inline Pools next_version(std::mt19937_64& rng, const Pools& p, std::size_t changes) {
  Pools q = p;
  q.version = p.version + 1 + rng() % 1000;
  q.epoch = p.epoch + 1;
  const std::uint32_t groups = p.cell_count / 8;
  for (std::size_t k = 0; k < changes; ++k) {
    const std::size_t c = rng() % p.cell_count, g = rng() % groups;
    q.first_child[c] = static_cast<std::uint32_t>(rng());
    q.colour[c] = static_cast<std::uint32_t>(rng());
    q.group_parent[g] = static_cast<std::uint32_t>(rng());
    q.depth_flags[g] = static_cast<std::uint8_t>(rng());
  }
  for (auto& w : q.mask) w = rng();
  return q;
}

}  // namespace random_blocks
