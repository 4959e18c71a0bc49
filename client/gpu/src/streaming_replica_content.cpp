// The content box step of StreamingReplica (see streaming_replica_content.hpp and "Content box"
// in streaming_replica.hpp).
#include "streaming_replica_content.hpp"

#include <algorithm>
#include <array>
#include <utility>

namespace deepcanvas::client_gpu::detail {
namespace {

using client_core::DAabb;
using client_core::DVec3;
using client_core::PoolView;
constexpr std::uint32_t kNoCell = PoolView::kNoCell;

bool painted(std::uint32_t rgba) {
  return (rgba >> 24) != 0;
}

// A cell's integer coordinates at its depth (roots: 0 .. roots_per_axis - 1), as painted_bounds
// walks them.
struct CellPos {
  std::uint32_t x = 0, y = 0, z = 0;
  int depth = 0;
};

CellPos child_pos(const CellPos& p, std::uint32_t slot) {
  return {2 * p.x + (slot & 1), 2 * p.y + ((slot >> 1) & 1), 2 * p.z + ((slot >> 2) & 1),
          p.depth + 1};
}

// Adds cells' boxes with painted_bounds' arithmetic (so that the boxes compare exactly), the
// edge per depth computed once (std::ldexp per cell was a fifth of a step's time).
class CellBoxes {
 public:
  explicit CellBoxes(const PoolView& geometry) : lo_(-geometry.edge_m * 0.5) {
    for (int d = 0; d <= PoolView::kMaxDepth; ++d) edge_[d] = geometry.cell_edge_m(d);
  }
  void add(std::optional<DAabb>& box, const CellPos& p) const {
    const double e = edge_[p.depth];
    const DVec3 mn{lo_ + p.x * e, lo_ + p.y * e, lo_ + p.z * e};
    const DVec3 mx{mn.x + e, mn.y + e, mn.z + e};
    if (!box) {
      box = DAabb{mn, mx};
      return;
    }
    box->min = {std::min(box->min.x, mn.x), std::min(box->min.y, mn.y), std::min(box->min.z, mn.z)};
    box->max = {std::max(box->max.x, mx.x), std::max(box->max.y, mx.y), std::max(box->max.z, mx.z)};
  }

 private:
  double lo_;
  std::array<double, PoolView::kMaxDepth + 1> edge_{};
};

// Whether `inner` reaches a face of `outer` (or past it) on some axis.
bool touches_faces(const DAabb& inner, const DAabb& outer) {
  for (int a = 0; a < 3; ++a)
    if (inner.min[a] <= outer.min[a] || inner.max[a] >= outer.max[a]) return true;
  return false;
}

enum class Reach : std::uint8_t { yes, no, anomaly };

// The state before the batch: the mirror as it is.
class MirrorState {
 public:
  explicit MirrorState(const PoolView& v) : v_(v) {}
  std::uint64_t cells() const { return v_.cell_count(); }
  std::uint32_t first_child(std::uint64_t c) const { return v_.first_child[c]; }
  std::uint32_t colour(std::uint64_t c) const { return v_.colour[c]; }
  std::uint32_t group_parent(std::uint64_t g) const { return v_.group_parent[g]; }
  std::uint8_t depth_flags(std::uint64_t g) const { return v_.group_depth_flags[g]; }

 private:
  const PoolView& v_;
};

// The state after the batch without writing it: the batch's rows (the last epoch carrying a row
// wins) over the mirror; cells past the mirror outside those rows hold the never-used values.
class BatchState {
 public:
  struct Row {
    const EpochUpload* epoch = nullptr;
    std::uint64_t first = 0;  // the row's first cell in the epoch's arrays
  };

  BatchState(const PoolView& mirror, const std::vector<EpochUpload>& batch,
             std::uint32_t width_log2)
      : mirror_(mirror), width_log2_(width_log2), mask_((std::uint64_t{1} << width_log2) - 1) {
    cells_ = mirror.cell_count();
    for (const EpochUpload& e : batch) cells_ = std::max(cells_, e.cell_count);
    rows_.resize((cells_ + mask_) >> width_log2);
    for (const EpochUpload& e : batch)
      for (std::size_t i = 0; i < e.rows.size(); ++i)
        if (e.rows[i] < rows_.size()) rows_[e.rows[i]] = {&e, std::uint64_t{i} << width_log2};
  }
  std::uint64_t cells() const { return cells_; }
  const Row& row(std::uint64_t r) const { return rows_[r]; }
  std::uint32_t first_child(std::uint64_t c) const {
    const Row& r = rows_[c >> width_log2_];
    if (r.epoch) return r.epoch->first_child[r.first + (c & mask_)];
    return c < mirror_.cell_count() ? mirror_.first_child[c] : kNoCell;
  }
  std::uint32_t colour(std::uint64_t c) const {
    const Row& r = rows_[c >> width_log2_];
    if (r.epoch) return r.epoch->colour[r.first + (c & mask_)];
    return c < mirror_.cell_count() ? mirror_.colour[c] : 0u;
  }
  std::uint32_t group_parent(std::uint64_t g) const {
    const Row& r = rows_[(g * 8) >> width_log2_];
    if (r.epoch) return r.epoch->group_parent[(r.first + ((g * 8) & mask_)) / 8];
    return g < mirror_.group_parent.size() ? mirror_.group_parent[g] : kNoCell;
  }
  std::uint8_t depth_flags(std::uint64_t g) const {
    const Row& r = rows_[(g * 8) >> width_log2_];
    if (r.epoch) return r.epoch->depth_flags[(r.first + ((g * 8) & mask_)) / 8];
    return g < mirror_.group_depth_flags.size() ? mirror_.group_depth_flags[g]
                                                : PoolView::kFreeFlag;
  }

 private:
  const PoolView& mirror_;
  std::uint32_t width_log2_;
  std::uint64_t mask_;
  std::uint64_t cells_ = 0;
  std::vector<Row> rows_;
};

// Locates cells of one state through their group_parent chain, every step checked against the
// parent's first_child (so a located position is the cell's real path from its root), memoised
// per group. `no`: the cell is in a freed group (or under one) that nothing points to, or, in
// a part of a progressive join (`parts`), in a live group whose parent's block has not come
// yet: nothing renders it until its parent comes and points to it, which the step then sees as
// an attached cell and walks; `anomaly`: the state is not a tree there.
template <class State>
class CellLocator {
 public:
  CellLocator(const State& s, std::uint32_t roots_per_axis, ContentTracker::GroupMemo& memo,
              bool parts = false)
      : s_(s),
        n_(roots_per_axis),
        roots_(roots_per_axis * roots_per_axis * roots_per_axis),
        memo_(memo),
        parts_(parts) {}
  Reach locate(std::uint64_t c, CellPos& out) { return cell(c, out, PoolView::kMaxDepth + 1); }

 private:
  Reach cell(std::uint64_t c, CellPos& out, int budget) {
    if (c < roots_) {
      const auto i = static_cast<std::uint32_t>(c);
      out = {i % n_, (i / n_) % n_, i / (n_ * n_), 0};
      return Reach::yes;
    }
    if (c >= s_.cells()) return Reach::anomaly;
    const std::uint64_t g = c >> 3;
    if (memo_.entries[g].stamp != memo_.now) {
      const auto e = group(g, budget);  // recursion writes other entries first
      memo_.entries[g] = e;
    }
    const auto& e = memo_.entries[g];
    if (static_cast<Reach>(e.reach) != Reach::yes) return static_cast<Reach>(e.reach);
    out = child_pos({e.x, e.y, e.z, e.depth}, static_cast<std::uint32_t>(c & 7));
    return Reach::yes;
  }

  ContentTracker::GroupMemo::Entry group(std::uint64_t g, int budget) {
    ContentTracker::GroupMemo::Entry e;
    e.stamp = memo_.now;
    e.reach = static_cast<std::uint8_t>(Reach::anomaly);
    if (budget <= 0) return e;  // a cycle through group_parent
    const std::uint32_t p = s_.group_parent(g);
    const std::uint8_t flags = s_.depth_flags(g);
    const bool pointed = p < s_.cells() && s_.first_child(p) == g * 8;
    if (flags & PoolView::kFreeFlag) {
      if (!pointed) e.reach = static_cast<std::uint8_t>(Reach::no);
      return e;
    }
    if (!pointed) {  // a live group its parent does not point to
      if (parts_) e.reach = static_cast<std::uint8_t>(Reach::no);
      return e;
    }
    CellPos pp;
    const Reach r = cell(p, pp, budget - 1);
    if (r != Reach::yes) {
      e.reach = static_cast<std::uint8_t>(r);
      return e;
    }
    if (pp.depth + 1 > PoolView::kMaxDepth || (flags & PoolView::kDepthMask) != pp.depth + 1)
      return e;
    e.x = pp.x;
    e.y = pp.y;
    e.z = pp.z;
    e.depth = static_cast<std::uint8_t>(pp.depth);
    e.reach = static_cast<std::uint8_t>(Reach::yes);
    return e;
  }

  const State& s_;
  std::uint32_t n_, roots_;
  ContentTracker::GroupMemo& memo_;
  bool parts_;
};

// What a batch changes (step 1), in the state before and the state after.
struct BatchChanges {
  std::vector<std::uint32_t> attached;  // cells whose first_child changed to a child group
  std::vector<std::uint32_t> leaves;    // painted leaves that may lie outside the box before
  std::vector<std::pair<std::uint64_t, std::uint32_t>> reparented;  // (live group, old parent)
  std::optional<DAabb> removed;  // the box of the removed paint that could be located
  bool removed_unknown = false;  // paint was removed where the state before is not a tree
  std::uint64_t changed_cells = 0;
};

// Step 1: the cells whose first_child changed, or leaves whose colour changed; paint removed (a
// painted leaf that is no longer one, a freed group's painted leaves), located in the state
// before.
class ChangeScan {
 public:
  ChangeScan(const MirrorState& before, const BatchState& after, const CellBoxes& boxes,
             CellLocator<MirrorState>& old_loc, std::uint32_t width_log2)
      : before_(before),
        after_(after),
        boxes_(boxes),
        old_loc_(old_loc),
        w_(std::uint64_t{1} << width_log2),
        old_cells_(before.cells()),
        new_cells_(after.cells()) {}

  BatchChanges scan(std::span<const std::uint32_t> rows) {
    for (const std::uint32_t r : rows) {
      const std::uint64_t c0 = std::uint64_t{r} * w_;
      if (c0 >= new_cells_ || after_.row(r).epoch == nullptr) continue;
      const std::uint64_t n = std::min(w_, new_cells_ - c0);
      scan_cells(after_.row(r), c0, n);
      scan_groups(after_.row(r), c0, n);
    }
    return std::move(out_);
  }

 private:
  void remove(std::uint64_t c) {
    CellPos p;
    const Reach r = old_loc_.locate(c, p);
    if (r == Reach::yes) {
      boxes_.add(out_.removed, p);
    } else if (r == Reach::anomaly) {
      out_.removed_unknown = true;
    }
  }

  // Group g (the row's k-th) is live before and after the batch under the same parent.
  bool group_kept(std::uint64_t g, const BatchState::Row& src, std::uint64_t k) const {
    if (g >= old_cells_ / 8) return false;
    const std::uint32_t np = src.epoch->group_parent[src.first / 8 + k];
    const bool live = !(src.epoch->depth_flags[src.first / 8 + k] & PoolView::kFreeFlag);
    return live && !(before_.depth_flags(g) & PoolView::kFreeFlag) && np == before_.group_parent(g);
  }

  // The row's cells c0 .. c0 + n - 1.
  void scan_cells(const BatchState::Row& src, std::uint64_t c0, std::uint64_t n) {
    for (std::uint64_t k = 0; k < n; ++k) {
      const std::uint64_t c = c0 + k;
      const std::uint32_t nf = src.epoch->first_child[src.first + k];
      const std::uint32_t nc = src.epoch->colour[src.first + k];
      const bool had = c < old_cells_;
      const std::uint32_t of = had ? before_.first_child(c) : kNoCell;
      const std::uint32_t oc = had ? before_.colour(c) : 0u;
      if (nf == of && (nf != kNoCell || nc == oc)) continue;
      ++out_.changed_cells;
      const bool was_painted_leaf = of == kNoCell && painted(oc);
      if (was_painted_leaf && !(nf == kNoCell && painted(nc))) remove(c);
      if (nf != kNoCell) {
        out_.attached.push_back(static_cast<std::uint32_t>(c));
      } else if (painted(nc) && !(was_painted_leaf && group_kept(c / 8, src, (c - c0) / 8))) {
        // (A painted leaf only recoloured, in a group that kept its parent, is where it was:
        // inside box_before already. Most of a stroke over painted cells is such recolouring.
        // Had an ancestor group moved, the walk from its new parent in step 2 adds the leaf.)
        out_.leaves.push_back(static_cast<std::uint32_t>(c));
      }
    }
  }

  // The row's groups: moved to a new parent, or freed.
  void scan_groups(const BatchState::Row& src, std::uint64_t c0, std::uint64_t n) {
    for (std::uint64_t k = 0; k < n / 8; ++k) {
      const std::uint64_t g = c0 / 8 + k;
      const bool had = g < old_cells_ / 8;
      const std::uint32_t np = src.epoch->group_parent[src.first / 8 + k];
      const std::uint32_t op = had ? before_.group_parent(g) : kNoCell;
      const bool live = !(src.epoch->depth_flags[src.first / 8 + k] & PoolView::kFreeFlag);
      const bool was_live = had && !(before_.depth_flags(g) & PoolView::kFreeFlag);
      if (live && np != op && op != kNoCell) out_.reparented.emplace_back(g, op);
      // A freed group's cells may keep their values: their paint is gone all the same.
      if (was_live && !live)
        for (std::uint64_t s = 0; s < 8; ++s)
          if (before_.first_child(g * 8 + s) == kNoCell && painted(before_.colour(g * 8 + s)))
            remove(g * 8 + s);
    }
  }

  const MirrorState& before_;
  const BatchState& after_;
  const CellBoxes& boxes_;
  CellLocator<MirrorState>& old_loc_;
  std::uint64_t w_, old_cells_, new_cells_;
  BatchChanges out_;
};

// Step 2: growth in the state after, added to `box`. A cell whose first_child changed may hold
// a subtree whose cells did not change (a reused slot with the same values): it is walked whole.
// `walked` stamps the groups walked in this step with `walk_now`. False where the state after is
// not a tree (the caller falls back to the exact box).
class GrowthWalk {
 public:
  GrowthWalk(const BatchState& after, const CellBoxes& boxes, CellLocator<BatchState>& new_loc,
             std::vector<std::uint16_t>& walked, std::uint16_t walk_now)
      : after_(after), boxes_(boxes), new_loc_(new_loc), walked_(walked), now_(walk_now) {}

  bool add(const BatchChanges& changes, std::optional<DAabb>& box) {
    for (const std::uint32_t c : changes.attached) {
      if (walked(c)) continue;  // inside a subtree walked already
      CellPos pos;
      const Reach r = new_loc_.locate(c, pos);
      if (r == Reach::no) continue;  // in a freed group: nothing renders it
      if (r == Reach::anomaly || !walk_subtree(c, pos, box)) return false;
    }
    for (const std::uint32_t c : changes.leaves) {
      if (walked(c)) continue;  // the walk added it
      CellPos pos;
      const Reach r = new_loc_.locate(c, pos);
      if (r == Reach::no) continue;
      if (r == Reach::anomaly) return false;
      boxes_.add(box, pos);
    }
    return true;
  }

 private:
  // Root groups are never walked into (a child group is never a root group).
  bool walked(std::uint64_t c) const { return walked_[c >> 3] == now_; }

  bool walk_subtree(std::uint64_t c, const CellPos& pos, std::optional<DAabb>& box) {
    const std::uint64_t new_cells = after_.cells();
    stack_.assign(1, {c, pos});
    while (!stack_.empty()) {
      const auto [cell, p] = stack_.back();
      stack_.pop_back();
      const std::uint32_t fc = after_.first_child(cell);
      if (fc == kNoCell) {
        if (painted(after_.colour(cell))) boxes_.add(box, p);
        continue;
      }
      if (fc % 8 != 0 || fc >= new_cells || p.depth >= PoolView::kMaxDepth ||
          after_.group_parent(fc >> 3) != cell) {
        return false;
      }
      if (walked_[fc >> 3] == now_) continue;
      walked_[fc >> 3] = now_;
      for (std::uint32_t s = 0; s < 8; ++s) stack_.push_back({fc + s, child_pos(p, s)});
    }
    return true;
  }

  const BatchState& after_;
  const CellBoxes& boxes_;
  CellLocator<BatchState>& new_loc_;
  std::vector<std::uint16_t>& walked_;
  std::uint16_t now_;
  std::vector<std::pair<std::uint64_t, CellPos>> stack_;
};

// Step 3: a group moved to a new parent must no longer hang under its previous one.
bool still_under_old_parent(const BatchState& after, const BatchChanges& changes) {
  for (const auto& [g, old_parent] : changes.reparented) {
    if (old_parent < after.cells() && after.first_child(old_parent) == g * 8) return true;
  }
  return false;
}

}  // namespace

void ContentTracker::GroupMemo::begin(std::uint64_t groups) {
  if (entries.size() < groups) entries.resize(groups);
  if (++now == 0) {  // the stamp wrapped: forget everything once
    for (auto& e : entries) e.stamp = 0;
    now = 1;
  }
}

ContentStep ContentTracker::step(const PoolView& mirror, const std::optional<DAabb>& box_before,
                                 const std::vector<EpochUpload>& batch,
                                 std::span<const std::uint32_t> rows, std::uint32_t width_log2) {
  ContentStep out;
  out.box = box_before;
  const MirrorState before(mirror);
  const BatchState after(mirror, batch, width_log2);
  const std::uint64_t old_cells = before.cells(), new_cells = after.cells();
  before_.begin(old_cells / 8);
  after_.begin(new_cells / 8);
  if (walked_.size() < new_cells / 8) walked_.resize(new_cells / 8);
  if (++walk_now_ == 0) {
    std::fill(walked_.begin(), walked_.end(), std::uint16_t{0});
    walk_now_ = 1;
  }
  const CellBoxes boxes(mirror);
  CellLocator<MirrorState> old_loc(before, mirror.roots_per_axis, before_);
  // A part of a progressive join may hold groups whose parents come in a later part.
  CellLocator<BatchState> new_loc(after, mirror.roots_per_axis, after_, batch.back().partial);

  const BatchChanges changes = ChangeScan(before, after, boxes, old_loc, width_log2).scan(rows);
  out.changed_cells = changes.changed_cells;
  if (!GrowthWalk(after, boxes, new_loc, walked_, walk_now_).add(changes, out.box) ||
      still_under_old_parent(after, changes)) {
    out.fallback = true;
    return out;
  }
  out.loose = changes.removed_unknown ||
              (changes.removed && box_before && touches_faces(*changes.removed, *box_before));
  return out;
}

}  // namespace deepcanvas::client_gpu::detail
