// A brute-force reference model of the octree's content: the set of leaves, keyed by exact cell
// coordinates, with their colours. It knows nothing about pools, indices or links; refine and
// coarsen implement the rules (children inherit colour, coarser neighbour leaves are
// refined first, coarsening refused when it would break 2:1 face balance, rounded average
// colour) directly on coordinates.
#pragma once

#include <cstdint>
#include <functional>
#include <unordered_map>
#include <vector>

#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::server_core::testing {

struct CoordHash {
  std::size_t operator()(const CellCoord& k) const noexcept {
    std::uint64_t h = static_cast<std::uint64_t>(k.depth) * 0x9e3779b97f4a7c15ull;
    h ^= (std::uint64_t{k.x} + 0x7f4a7c15ull) * 0xbf58476d1ce4e5b9ull;
    h = (h ^ (h >> 29)) * 0x94d049bb133111ebull;
    h ^= (std::uint64_t{k.y} << 32 | k.z) * 0xff51afd7ed558ccdull;
    return static_cast<std::size_t>(h ^ (h >> 31));
  }
};

class ReferenceTree {
 public:
  ReferenceTree(std::uint32_t roots_per_axis, int max_depth)
      : n_(roots_per_axis), max_depth_(max_depth) {
    for (std::uint32_t z = 0; z < n_; ++z)
      for (std::uint32_t y = 0; y < n_; ++y)
        for (std::uint32_t x = 0; x < n_; ++x) leaves_[CellCoord{0, x, y, z}] = 0;
  }

  const std::unordered_map<CellCoord, std::uint32_t, CoordHash>& leaves() const { return leaves_; }
  std::uint64_t live_cells() const { return internal_ * 8 + n_ * n_ * n_; }

  bool in_canvas(const CellCoord& k) const {
    const std::uint64_t lim = std::uint64_t{n_} << k.depth;
    return k.x < lim && k.y < lim && k.z < lim;
  }

  // Depth of the leaf covering cell k, or -1 when k is internal (finer leaves inside it).
  int covering_leaf_depth(const CellCoord& k) const {
    for (int d = 0; d <= k.depth; ++d) {
      const int s = k.depth - d;
      if (leaves_.count(CellCoord{d, k.x >> s, k.y >> s, k.z >> s})) return d;
    }
    return -1;
  }
  bool is_leaf(const CellCoord& k) const { return leaves_.count(k) != 0; }

  static CellCoord step(CellCoord k, int face) {
    std::uint32_t* a = face < 2 ? &k.x : face < 4 ? &k.y : &k.z;
    if (face & 1)
      ++*a;
    else
      --*a;  // wraps to a huge value at 0: in_canvas() rejects it
    return k;
  }

  // Refines leaf k (balance first). Returns false when k is not a leaf or at max depth.
  bool refine(const CellCoord& k) {
    if (!is_leaf(k) || k.depth >= max_depth_) return false;
    refine_balanced(k);
    return true;
  }

  bool can_coarsen(const CellCoord& k) const {
    if (k.depth >= max_depth_ || is_leaf(k) || covering_leaf_depth(k) >= 0) return false;
    for (std::uint32_t i = 0; i < 8; ++i)
      if (!is_leaf(child(k, i))) return false;
    for (int f = 0; f < 6; ++f) {
      const CellCoord nb = step(k, f);
      if (!in_canvas(nb)) continue;
      // The four depth+1 cells of the neighbour that touch k must not be internal.
      const int axis = f >> 1;
      const std::uint32_t want = (f & 1) ? 0u : 1u;
      for (std::uint32_t i = 0; i < 8; ++i) {
        if (((i >> axis) & 1u) != want) continue;
        if (covering_leaf_depth(child(nb, i)) < 0) return false;
      }
    }
    return true;
  }

  bool coarsen(const CellCoord& k) {
    if (!can_coarsen(k)) return false;
    std::uint32_t sum[4] = {0, 0, 0, 0};
    for (std::uint32_t i = 0; i < 8; ++i) {
      const CellCoord c = child(k, i);
      const std::uint32_t v = leaves_.at(c);
      for (int b = 0; b < 4; ++b) sum[b] += (v >> (8 * b)) & 0xFFu;
      leaves_.erase(c);
    }
    std::uint32_t avg = 0;
    for (int b = 0; b < 4; ++b) avg |= ((sum[b] + 4) / 8) << (8 * b);
    leaves_[k] = avg;
    --internal_;
    return true;
  }

  bool set_colour(const CellCoord& k, std::uint32_t rgba) {
    auto it = leaves_.find(k);
    if (it == leaves_.end()) return false;
    it->second = rgba;
    return true;
  }

  static CellCoord child(const CellCoord& k, std::uint32_t i) {
    return CellCoord{k.depth + 1, 2 * k.x + (i & 1u), 2 * k.y + ((i >> 1) & 1u),
                     2 * k.z + ((i >> 2) & 1u)};
  }

 private:
  void refine_balanced(const CellCoord& k) {
    for (int f = 0; f < 6; ++f) {
      const CellCoord nb = step(k, f);
      if (!in_canvas(nb)) continue;
      const int d = covering_leaf_depth(nb);
      if (d >= 0 && d < k.depth) {
        const int s = k.depth - d;
        refine_balanced(CellCoord{d, nb.x >> s, nb.y >> s, nb.z >> s});
      }
    }
    const std::uint32_t col = leaves_.at(k);
    leaves_.erase(k);
    for (std::uint32_t i = 0; i < 8; ++i) leaves_[child(k, i)] = col;
    ++internal_;
  }

  std::uint32_t n_;
  int max_depth_;
  std::uint64_t internal_ = 0;
  std::unordered_map<CellCoord, std::uint32_t, CoordHash> leaves_;
};

// Leaves of a real tree, by coordinate (traversal from the roots).
inline std::unordered_map<CellCoord, std::uint32_t, CoordHash> tree_leaves(const Octree& t) {
  std::unordered_map<CellCoord, std::uint32_t, CoordHash> out;
  const std::uint32_t n = t.config().roots_per_axis;
  std::vector<std::pair<CellIndex, CellCoord>> stack;
  for (CellIndex r = 0; r < t.root_count(); ++r)
    stack.push_back({r, CellCoord{0, r % n, (r / n) % n, r / (n * n)}});
  while (!stack.empty()) {
    auto [c, k] = stack.back();
    stack.pop_back();
    const CellIndex fc = t.first_child(c);
    if (fc == kNoCell) {
      out[k] = t.colour(c);
      continue;
    }
    for (std::uint32_t i = 0; i < 8; ++i) stack.push_back({fc + i, ReferenceTree::child(k, i)});
  }
  return out;
}

}  // namespace deepcanvas::server_core::testing
