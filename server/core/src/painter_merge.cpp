// Merging back after end_stroke(): uniform leaf children into their parent, deepest level first.
#include "painter_impl.hpp"

namespace deepcanvas::server_core {

bool Painter::Impl::merge_one(CellIndex p, int d) {
  // The entry may be stale: another stroke's merge may have freed p since it was queued (and a
  // refinement reused the index, at another depth).
  if (!tree.is_live(p) || tree.is_leaf(p) || tree.depth(p) != d) return false;
  const CellIndex fc = tree.first_child(p);
  std::uint32_t ch[8];
  for (std::uint32_t i = 0; i < 8; ++i) {
    if (!tree.is_leaf(fc + i) || held_by_other(fc + i)) return false;
    ch[i] = tree.colour(fc + i);
  }
  if (!dm::uniform(ch) || !tree.can_coarsen(p)) return false;
  const std::uint32_t v = dm::coarsen_rgba(ch);
  const std::uint32_t old = tree.colour(p);
  const CellIndex fc_freed = fc;
  if (!tree.coarsen(p)) return false;
  stats.cells_freed += 8;
  // Merges are far fewer than writes: the address is found by walking up (O(depth)).
  const CellCoord pk = rec != nullptr ? tree.coord(p) : CellCoord{};
  if (rec != nullptr) rec->coarsen(p, pk, old, ch, tree.colour(p), fc_freed);
  write(p, pk, v);
  // p is a leaf again, holding what its children showed: no open stroke's pre-stroke value of
  // the cell p was before refinement applies to it any more.
  mark_pre[p].mark = stroke_seq << kSeqShift;
  if (p < tree.root_count()) return true;
  const CellIndex up = tree.parent(p);
  queue_merge(up, d - 1);
  // p's children no longer face the children of up's neighbours: those neighbours (same depth
  // as up) may now coarsen without breaking balance, though the stroke never touched them
  // (balance refinements of earlier strokes unwind this way).
  for (int f = 0; f < 6; ++f) {
    const CellIndex n = tree.face_neighbour(up, f);
    if (n != kNoCell && !tree.is_leaf(n) && tree.depth(n) == d - 1) queue_merge(n, d - 1);
  }
  return true;
}

void Painter::Impl::merge_some(std::uint64_t& work, std::uint64_t cap, bool& did) {
  for (int d = kLevels - 1; d >= 0; --d) {
    MergeLevel& M = merge_levels[static_cast<std::size_t>(d)];
    if (M.next >= M.queue.size()) continue;
    did = true;
    while (M.next < M.queue.size() && work < cap) {
      const CellIndex p = M.queue[M.next++];
      if (this_stroke(p)) mark_pre[p].mark &= ~kMergeQueued;
      work += merge_one(p, d) ? 9 : 1;
    }
    if (M.next >= M.queue.size()) M = {};
    break;
  }
}

}  // namespace deepcanvas::server_core
