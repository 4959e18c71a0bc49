// CoordTable: a flat open-addressing map from a cell address (CellCoord) to a record number, for
// the undo code's per-change lookups (cell_diff.cpp, painter_undo.cpp): one probe sequence in
// one array, no node per entry. Private to server_core.
#pragma once

#include <cstdint>
#include <vector>

#include "deepcanvas/server_core/cell_diff.hpp"

namespace deepcanvas::server_core::detail {

class CoordTable {
 public:
  static constexpr std::uint32_t kNone = 0xFFFFFFFFu;
  // Room for `n` entries at most half full.
  explicit CoordTable(std::size_t n) {
    std::size_t cap = 16;
    while (cap < 2 * n) cap *= 2;
    keys_.resize(cap);
    values_.assign(cap, kNone);
    mask_ = cap - 1;
  }
  // The value stored for k, or kNone.
  std::uint32_t find(const CellCoord& k) const {
    for (std::size_t i = CellCoordHash{}(k) & mask_;; i = (i + 1) & mask_) {
      if (values_[i] == kNone) return kNone;
      if (keys_[i] == k) return values_[i];
    }
  }
  // Stores v for k unless k is present; returns the value k has now.
  std::uint32_t insert(const CellCoord& k, std::uint32_t v) {
    for (std::size_t i = CellCoordHash{}(k) & mask_;; i = (i + 1) & mask_) {
      if (values_[i] == kNone) {
        keys_[i] = k;
        values_[i] = v;
        return v;
      }
      if (keys_[i] == k) return values_[i];
    }
  }

 private:
  std::vector<CellCoord> keys_;
  std::vector<std::uint32_t> values_;
  std::size_t mask_ = 0;
};

}  // namespace deepcanvas::server_core::detail
