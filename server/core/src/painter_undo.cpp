// Undo: Painter::take_stroke_diff() and Painter::revert() (painter.hpp, "undo"). A diff is taken
// back in two passes over its cells: top-down, every cell that still holds what the operation
// left gets its earlier state (cells the operation merged away are refined again first); then
// bottom-up, cells the operation created are merged back where all eight were restored.
#include <functional>
#include <limits>
#include <unordered_map>
#include <unordered_set>

#include "coord_table.hpp"
#include "painter_edit.hpp"
#include "painter_impl.hpp"

namespace deepcanvas::server_core {

std::optional<CellDiff> Painter::take_stroke_diff(std::uint64_t stroke_id) {
  auto it = shared_->finished_diffs.find(stroke_id);
  if (it == shared_->finished_diffs.end()) return std::nullopt;
  CellDiff d = it->second.take();
  shared_->finished_diffs.erase(it);
  return d;
}

namespace {

// One revert: the edit (tree, marks, recorder), the diff's changes, and what it restored.
struct Reverter {
  detail::RecordedEdit edit;
  Octree& tree;
  const std::vector<CellChange>& ch;
  RevertStats st;
  detail::CoordTable at;  // cell address -> its change (the first, should one repeat)
  std::vector<std::uint8_t> ok;  // the cell was restored
  std::vector<std::uint8_t> have_value;
  std::vector<std::uint32_t> value;

  Reverter(Octree& t, MarkPre* m, std::uint32_t* slots, const std::vector<std::uint32_t>& seqs,
           const CellDiff& d)
      // A revert changes about the cells its diff names (bounded when that was recorded).
      : edit(t, m, slots, seqs), tree(t), ch(d.changes), at(d.changes),
        ok(d.size(), 0), have_value(d.size(), 0), value(d.size(), 0) {
    for (std::size_t i = 0; i < ch.size(); ++i) at.insert(static_cast<std::uint32_t>(i));
  }
  // The change of cell k, if the diff has one.
  std::optional<std::size_t> change_of(const CellCoord& k) const {
    const std::uint32_t i = at.find(k);
    if (i == detail::CoordTable::kNone) return std::nullopt;
    return i;
  }
  bool held(CellIndex c) const { return edit.held(c); }
  void set(CellIndex c, const CellCoord& k, std::uint32_t v) { edit.set(c, k, v); }
  Result<void> refine(CellIndex c, const CellCoord& k) { return edit.refine(c, k); }
  // The colour cell i had before the operation; for a cell the operation created, its nearest
  // earlier ancestor's colour refined down to its depth (what the painter's refinement gave it).
  std::optional<std::uint32_t> target_value(std::size_t i) {
    const CellChange& c = ch[i];
    if (c.before.exists) return c.before.colour;
    if (have_value[i]) return value[i];
    if (c.cell.depth == 0) return std::nullopt;
    const auto parent = change_of(parent_coord(c.cell));
    if (!parent) return std::nullopt;  // not a diff this painter recorded
    const auto up = target_value(*parent);
    if (!up) return std::nullopt;
    value[i] = protocol::density::refine_rgba(*up);
    have_value[i] = 1;
    return value[i];
  }
  // Cell c (at k) was a leaf the operation left with colour `from`, and has been painted over
  // more finely since: its leaves that still hold `from` (refined to their depth) get `to`
  // (refined alike).
  void restore_finer(CellIndex c, const CellCoord& k, std::uint32_t from, std::uint32_t to) {
    struct Item {
      CellIndex c;
      CellCoord k;
      std::uint32_t from, to;
    };
    std::vector<Item> stack{{c, k, from, to}};
    while (!stack.empty()) {
      const Item it = stack.back();
      stack.pop_back();
      if (!tree.is_leaf(it.c)) {
        const CellIndex fc = tree.first_child(it.c);
        const std::uint32_t f = protocol::density::refine_rgba(it.from);
        const std::uint32_t t = protocol::density::refine_rgba(it.to);
        for (std::uint32_t i = 0; i < 8; ++i) stack.push_back({fc + i, child_coord(it.k, i), f, t});
        continue;
      }
      if (held(it.c) || tree.colour(it.c) != it.from) {
        ++st.kept;
        continue;
      }
      set(it.c, it.k, it.to);
      ++st.restored;
    }
  }

  Result<void> top_down();
  Result<void> bottom_up();
};

Result<void> Reverter::top_down() {
  for (std::size_t i = 0; i < ch.size(); ++i) {
    const CellChange& c = ch[i];
    const CellState& from = c.after;  // what the operation left
    const CellState& to = c.before;   // what is to come back
    const LocateResult loc = tree.find(c.cell);
    const bool here = loc.cell != kNoCell && loc.coord == c.cell;
    if (!from.exists) {
      // The operation merged this cell away; it comes back where its parent was refined again.
      if (!here || !edit.refined.count(parent_coord(c.cell))) {
        ++st.kept;
        continue;
      }
      set(loc.cell, c.cell, to.colour);
      if (!to.leaf)
        if (auto r = refine(loc.cell, c.cell); !r) return r;
      ok[i] = 1;
      ++st.restored;
      continue;
    }
    if (!here || held(loc.cell)) {
      ++st.kept;
      continue;
    }
    const CellIndex cell = loc.cell;
    const bool leaf = tree.is_leaf(cell);
    // An internal cell's colour is the tree's filtered value of its children (octree.hpp),
    // refreshed since the operation: only a leaf's colour says whether it was painted over.
    if (leaf != from.leaf || (leaf && tree.colour(cell) != from.colour)) {
      // Painted over since. Where it was painted more finely, the finer leaves that still hold
      // what the operation left (each checked on its own) come back.
      const bool to_leafy = !(to.exists && !to.leaf);
      if (!leaf && from.leaf && to_leafy) {
        if (const auto t = target_value(i)) restore_finer(cell, c.cell, from.colour, *t);
      } else {
        ++st.kept;
      }
      continue;
    }
    const auto t = target_value(i);
    if (!t) {
      ++st.kept;
      continue;
    }
    ok[i] = 1;
    ++st.restored;
    if (to.exists && !to.leaf && from.leaf) {  // merged by the operation: split again
      if (auto r = refine(cell, c.cell); !r) return r;
    }
    set(cell, c.cell, *t);
  }
  return {};
}

Result<void> Reverter::bottom_up() {
  for (std::size_t i = ch.size(); i-- > 0;) {
    const CellChange& c = ch[i];
    if (!ok[i] || (c.before.exists && !c.before.leaf)) continue;  // restored cells to be leaves
    const LocateResult loc = tree.find(c.cell);
    if (loc.cell == kNoCell || !(loc.coord == c.cell) || tree.is_leaf(loc.cell)) continue;
    const CellIndex cell = loc.cell;
    const CellIndex fc = tree.first_child(cell);
    std::uint32_t kids[8];
    bool leaves = true, all_restored = true;
    for (std::uint32_t j = 0; j < 8 && leaves; ++j) {
      const CellIndex k = fc + j;
      if (!tree.is_leaf(k) || held(k)) leaves = false;
      kids[j] = tree.colour(k);
      const auto child = change_of(child_coord(c.cell, j));
      if (!child || !ok[*child] || ch[*child].before.exists) all_restored = false;
    }
    if (!leaves) continue;
    // Where others painted some of the children, merge only as any stroke's merge would.
    if (!all_restored && !protocol::density::uniform(kids)) continue;
    if (!tree.can_coarsen(cell)) continue;
    const std::uint32_t old = tree.colour(cell);
    if (auto r = tree.coarsen(cell); !r) return r;
    edit.rec.coarsen(cell, c.cell, old, kids, tree.colour(cell), fc);
    edit.cells_changed += 8;
    const auto t = target_value(i);
    set(cell, c.cell, all_restored && t ? *t : protocol::density::coarsen_rgba(kids));
  }
  return {};
}

}  // namespace

Result<CellDiff> Painter::revert(const CellDiff& diff, RevertStats* stats) {
  Shared& sh = *shared_;
  if (sh.busy != nullptr)
    return make_error(Errc::refused, "painter: stroke " + std::to_string(sh.busy->stroke_id) +
                                         " is still being painted (step() until it is done)");
  sh.last_worker = nullptr;  // the open strokes' next turns take new sequences
  Reverter r(sh.tree, sh.mark_pre_pool->as<MarkPre>(), sh.diff_slot_pool->as<std::uint32_t>(),
             sh.open_seqs, diff);
  // A failure part-way (no capacity left to split merged cells again) leaves a valid, balanced
  // tree with part of the diff taken back, and the error.
  auto a = r.top_down();
  auto b = a ? r.bottom_up() : Result<void>{};
  r.st.cells_changed = r.edit.cells_changed;
  if (stats != nullptr) *stats = r.st;
  if (!a) return std::move(a).error();
  if (!b) return std::move(b).error();
  return r.edit.rec.take();
}

}  // namespace deepcanvas::server_core
