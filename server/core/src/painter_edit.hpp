// RecordedEdit: setting cells and refining leaves outside a stroke, every change recorded (for
// undo) and the new cells' marks cleared. What Painter::revert() (painter_undo.cpp) and
// Painter::paste() (painter_paste.cpp) are built on. Private to server_core.
#pragma once

#include <algorithm>
#include <limits>
#include <unordered_set>
#include <vector>

#include "painter_impl.hpp"

namespace deepcanvas::server_core::detail {

struct RecordedEdit {
  Octree& tree;
  MarkPre* marks;
  const std::vector<std::uint32_t>& open_seqs;
  CellDiffRecorder rec;
  std::uint64_t cells_changed = 0;
  std::unordered_set<CellCoord, CellCoordHash> refined;  // the leaves refine() refined

  RecordedEdit(Octree& t, MarkPre* m, std::uint32_t* slots, const std::vector<std::uint32_t>& seqs,
               std::size_t max_records = std::numeric_limits<std::size_t>::max())
      : tree(t), marks(m), open_seqs(seqs), rec(slots, max_records) {}

  // A stroke still open touched the cell last: it keeps what it holds.
  bool held(CellIndex c) const {
    if (open_seqs.empty()) return false;
    const std::uint32_t seq = marks[c].mark >> kSeqShift;
    return std::binary_search(open_seqs.begin(), open_seqs.end(), seq);
  }
  void set(CellIndex c, const CellCoord& k, std::uint32_t v) {
    const std::uint32_t old = tree.colour(c);
    if (old == v) return;
    rec.colour(c, k, tree.is_leaf(c), old, v);
    tree.set_colour(c, v);
    ++cells_changed;
  }
  // Refines leaf c (at k), its coarser face neighbours first (2:1 balance), the children getting
  // the refined colour as the painter's refinements give them.
  Result<void> refine(CellIndex c, const CellCoord& k) {
    for (int f = 0; f < 6; ++f) {
      const CellIndex n = tree.face_neighbour(c, f);
      if (n == kNoCell || !tree.is_leaf(n) || tree.depth(n) >= k.depth) continue;
      CellCoord nk = parent_coord(k);
      std::uint32_t* comp[3] = {&nk.x, &nk.y, &nk.z};
      *comp[f >> 1] += (f & 1) ? 1u : static_cast<std::uint32_t>(-1);
      if (auto r = refine(n, nk); !r) return r;
    }
    if (tree.live_cells() + 8 > tree.config().max_cells)
      return make_error(Errc::out_of_memory, "canvas capacity: no room to refine cells");
    const std::uint32_t colour = tree.colour(c);
    std::uint64_t created = 0;
    if (auto r = tree.refine(c, &created); !r) return r;
    if (created != 8) return make_error(Errc::internal, "edit: octree balanced on its own");
    rec.refine(c, k, colour, colour, tree.first_child(c));
    cells_changed += 8;
    refined.insert(k);
    const CellIndex fc = tree.first_child(c);
    const std::uint32_t v = protocol::density::refine_rgba(colour);
    for (std::uint32_t i = 0; i < 8; ++i) {
      marks[fc + i].mark = 0;  // sequence 0 is never an open stroke's
      set(fc + i, child_coord(k, i), v);
    }
    return {};
  }
};

}  // namespace deepcanvas::server_core::detail
