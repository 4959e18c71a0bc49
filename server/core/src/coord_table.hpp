// CoordTable: a flat open-addressing index over an array of changes (CellChange), from a cell
// address to the number of the change that names it, for the undo code's per-change lookups
// (cell_diff.cpp, painter_undo.cpp): one probe sequence in one array of 4-byte change numbers,
// the addresses read from the changes themselves (2 to 4 slots a change: 8 to 16 bytes, where
// storing the addresses too would take 40 to 80; this runs while a large stroke's change is
// held, so it counts). Private to server_core.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "deepcanvas/server_core/cell_diff.hpp"

namespace deepcanvas::server_core::detail {

class CoordTable {
 public:
  static constexpr std::uint32_t kNone = 0xFFFFFFFFu;
  // Room for all of `changes` at most half full; `changes` must outlive the table and not move.
  explicit CoordTable(std::span<const CellChange> changes) : changes_(changes) {
    std::size_t cap = 16;
    while (cap < 2 * changes.size()) cap *= 2;
    slots_.assign(cap, kNone);
    mask_ = cap - 1;
  }
  // The number of the change stored for k, or kNone.
  std::uint32_t find(const CellCoord& k) const {
    for (std::size_t i = CellCoordHash{}(k) & mask_;; i = (i + 1) & mask_) {
      if (slots_[i] == kNone) return kNone;
      if (changes_[slots_[i]].cell == k) return slots_[i];
    }
  }
  // Stores change v under its address unless one is there; returns the change stored there now.
  std::uint32_t insert(std::uint32_t v) {
    const CellCoord& k = changes_[v].cell;
    for (std::size_t i = CellCoordHash{}(k) & mask_;; i = (i + 1) & mask_) {
      if (slots_[i] == kNone) {
        slots_[i] = v;
        return v;
      }
      if (changes_[slots_[i]].cell == k) return slots_[i];
    }
  }

 private:
  std::span<const CellChange> changes_;
  std::vector<std::uint32_t> slots_;
  std::size_t mask_ = 0;
};

}  // namespace deepcanvas::server_core::detail
