// CellPaste: cells set to given values in one operation (an import: a volume or a mesh made into
// cells by the export target's importers, issue "export, import and time-lapse"). It is what the
// canvas applies with Painter::paste(), records in its history (stroke log event kind 6) and
// replays; its change is recorded like a stroke's, so an artist's undo takes an import back.
//
// Semantics: each cell becomes a leaf of the given colour (RGBA8) at its address, replacing what
// the canvas held there (finer paint inside it included; paint elsewhere is untouched). The tree
// is refined down to each cell (2:1 balance kept), and afterwards uniform siblings are merged
// wherever balance allows, as a stroke's merges do. Cells are disjoint: no cell lies inside
// another.
//
// Encoded form (encode_cell_paste; the event payload): zstd frame of
//   u32 magic "DCPS", u32 version (1), u64 n,
//   n x u8 depth, n x u32 x, n x u32 y, n x u32 z, n x u32 colour
// (little-endian, columns, cells in address order: depth, z, y, x). About 1 to 4 bytes a cell.
//
// Untrusted input: decode_cell_paste() checks sizes, the magic, the version, every depth and
// coordinate against the canvas (OctreeConfig), the address order, that no cell lies inside
// another, and `max_cells`; it never reads past the buffer and returns malformed naming the
// field (limit_exceeded past max_cells).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::server_core {

struct PastedCell {
  CellCoord cell;
  std::uint32_t rgba = 0;
};

struct CellPaste {
  std::vector<PastedCell> cells;
  std::size_t size() const noexcept { return cells.size(); }
};

// The most cells one paste may hold (what one stroke's change may hold: the undo recorder's cap).
inline constexpr std::uint64_t kMaxPastedCells = std::uint64_t{1} << 22;

// Sorts the cells into address order and checks them as decode does (for cells made in memory).
Result<void> normalise_cell_paste(CellPaste& paste, const OctreeConfig& canvas,
                                  std::uint64_t max_cells = kMaxPastedCells);

std::vector<std::uint8_t> encode_cell_paste(const CellPaste& paste);
Result<CellPaste> decode_cell_paste(std::span<const std::uint8_t> bytes, const OctreeConfig& canvas,
                                    std::uint64_t max_cells = kMaxPastedCells);

}  // namespace deepcanvas::server_core
