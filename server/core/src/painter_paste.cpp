// Painter::paste(): cells set to given values as one recorded operation (cell_paste.hpp). Three
// passes: each pasted cell is reached (the tree refined down to it, balanced) and made to hold
// its value (a cell with finer cells below has each of its leaves set to the value refined to
// its depth); then, deepest first, the parents of what changed are merged where their eight
// children are uniform leaves and balance allows; last, every pasted cell that is a leaf again
// gets exactly its value.
#include <map>
#include <set>
#include <unordered_set>

#include "deepcanvas/server_core/cell_paste.hpp"
#include "painter_edit.hpp"
#include "painter_impl.hpp"

namespace deepcanvas::server_core {

namespace {

namespace dm = protocol::density;

struct Paster {
  detail::RecordedEdit edit;
  Octree& tree;
  // Merge candidates by depth: internal cells whose children may now be uniform leaves.
  std::map<int, std::set<CellIndex>, std::greater<>> candidates;

  Paster(Octree& t, MarkPre* m, std::uint32_t* slots, const std::vector<std::uint32_t>& seqs)
      : edit(t, m, slots, seqs, CellDiffRecorder::kDefaultMaxRecords), tree(t) {}

  void candidate(CellIndex c, int depth) {
    if (depth >= 0 && c != kNoCell && !tree.is_leaf(c)) candidates[depth].insert(c);
  }

  Result<void> put(const PastedCell& pc) {
    const CellCoord& k = pc.cell;
    LocateResult loc = tree.find(k);
    if (loc.cell == kNoCell) return make_error(Errc::internal, "paste: no root above a cell");
    while (loc.coord.depth < k.depth) {  // a leaf above k: refine towards it
      if (auto r = edit.refine(loc.cell, loc.coord); !r) return r;
      loc = tree.find(k);
    }
    // k and everything below it take the value (refined to each leaf's depth).
    struct Item {
      CellIndex c;
      CellCoord k;
      std::uint32_t v;
    };
    std::vector<Item> stack{{loc.cell, k, pc.rgba}};
    while (!stack.empty()) {
      const Item it = stack.back();
      stack.pop_back();
      edit.marks[it.c].mark = 0;  // no open stroke's pre-stroke value applies to it any more
      edit.set(it.c, it.k, it.v);
      const CellIndex fc = tree.first_child(it.c);
      if (fc == kNoCell) continue;
      candidate(it.c, it.k.depth);
      const std::uint32_t down = dm::refine_rgba(it.v);
      for (std::uint32_t i = 0; i < 8; ++i) stack.push_back({fc + i, child_coord(it.k, i), down});
    }
    if (k.depth > 0) candidate(tree.parent(loc.cell), k.depth - 1);
    return {};
  }

  // One merge: c's eight children are leaves, none held by an open stroke, uniform, and
  // coarsening keeps balance.
  bool merge(CellIndex c, int depth) {
    if (!tree.is_live(c) || tree.is_leaf(c) || tree.depth(c) != depth) return false;
    const CellIndex fc = tree.first_child(c);
    std::uint32_t kids[8];
    for (std::uint32_t i = 0; i < 8; ++i) {
      if (!tree.is_leaf(fc + i) || edit.held(fc + i)) return false;
      kids[i] = tree.colour(fc + i);
    }
    if (!dm::uniform(kids) || !tree.can_coarsen(c)) return false;
    const CellCoord k = tree.coord(c);
    const std::uint32_t old = tree.colour(c);
    if (!tree.coarsen(c)) return false;
    edit.rec.coarsen(c, k, old, kids, tree.colour(c), fc);
    edit.cells_changed += 8;
    edit.marks[c].mark = 0;
    edit.set(c, k, dm::coarsen_rgba(kids));
    if (c < tree.root_count()) return true;
    const CellIndex up = tree.parent(c);
    candidate(up, depth - 1);
    // As a stroke's merges: neighbours of the parent may now coarsen without breaking balance.
    for (int f = 0; f < 6; ++f) {
      const CellIndex n = tree.face_neighbour(up, f);
      if (n != kNoCell && !tree.is_leaf(n) && tree.depth(n) == depth - 1) candidate(n, depth - 1);
    }
    return true;
  }

  void merge_all() {
    while (!candidates.empty()) {
      auto level = candidates.begin();  // the deepest
      const int depth = level->first;
      const std::set<CellIndex> cells = std::move(level->second);
      candidates.erase(level);
      for (CellIndex c : cells) merge(c, depth);
    }
  }
};

}  // namespace

Result<CellDiff> Painter::paste(const CellPaste& paste, PasteStats* stats) {
  Shared& sh = *shared_;
  if (sh.busy != nullptr)
    return make_error(Errc::refused, "painter: stroke " + std::to_string(sh.busy->stroke_id) +
                                         " is still being painted (step() until it is done)");
  const Octree& t = sh.tree;
  // Capacity first, so that a paste the canvas cannot hold changes nothing: each leaf refined on
  // the way down to a pasted cell makes 8 cells (counted once however many cells lie below it),
  // and balance may refine about as many again.
  std::unordered_set<CellCoord, CellCoordHash> refined;
  for (const PastedCell& pc : paste.cells) {
    const LocateResult loc = t.find(pc.cell);
    if (loc.cell == kNoCell) return make_error(Errc::invalid_argument, "paste: a cell outside the canvas");
    for (CellCoord up = pc.cell; up.depth > loc.coord.depth;) {
      up = parent_coord(up);
      if (!refined.insert(up).second) break;
    }
  }
  const std::uint64_t growth = 16 * static_cast<std::uint64_t>(refined.size());
  if (t.live_cells() + growth > t.config().max_cells)
    return make_error(Errc::out_of_memory,
                      "canvas capacity: the import needs up to " + std::to_string(growth) +
                          " more cells, the canvas has room for " +
                          std::to_string(t.config().max_cells - t.live_cells()));
  sh.last_worker = nullptr;  // the open strokes' next turns take new sequences
  Paster p(sh.tree, sh.mark_pre_pool->as<MarkPre>(), sh.diff_slot_pool->as<std::uint32_t>(),
           sh.open_seqs);
  Result<void> r;
  for (const PastedCell& pc : paste.cells)
    if (r = p.put(pc); !r) break;
  if (r) {
    p.merge_all();
    // A pasted cell that is a leaf again holds exactly its value (a merge gives the children's
    // coarsened value, which may differ from it by rounding).
    for (const PastedCell& pc : paste.cells) {
      const LocateResult loc = sh.tree.find(pc.cell);
      if (loc.cell != kNoCell && loc.coord == pc.cell && sh.tree.is_leaf(loc.cell))
        p.edit.set(loc.cell, pc.cell, pc.rgba);
    }
  }
  CellDiff diff = p.edit.rec.take();
  if (stats != nullptr) {
    stats->cells = paste.size();
    stats->cells_changed = p.edit.cells_changed;
  }
  if (!r) {
    // Nothing half done: what was applied is taken back.
    (void)revert(diff);
    return std::move(r).error();
  }
  return diff;
}

}  // namespace deepcanvas::server_core
