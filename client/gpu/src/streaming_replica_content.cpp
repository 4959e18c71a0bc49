// The content box step of StreamingReplica (see streaming_replica_content.hpp and "Content box"
// in streaming_replica.hpp).
#include "streaming_replica_content.hpp"

#include <algorithm>
#include <array>

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
// per group. `no`: the cell is in a freed group (or under one) that nothing points to;
// `anomaly`: the state is not a tree there.
template <class State>
class CellLocator {
 public:
  CellLocator(const State& s, std::uint32_t roots_per_axis, ContentTracker::GroupMemo& memo)
      : s_(s),
        n_(roots_per_axis),
        roots_(roots_per_axis * roots_per_axis * roots_per_axis),
        memo_(memo) {}
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
    if (!pointed) return e;  // a live group its parent does not point to
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
};

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
  const std::uint64_t w = std::uint64_t{1} << width_log2;
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
  CellLocator<BatchState> new_loc(after, mirror.roots_per_axis, after_);

  // 1. What changed: cells whose first_child changed, or leaves whose colour changed; paint
  //    removed (a painted leaf that is no longer one, a freed group's painted leaves), located in
  //    the state before.
  std::vector<std::uint32_t> attached, leaves;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> reparented;  // (live group, old parent)
  std::optional<DAabb> removed;
  bool removed_unknown = false;
  auto remove = [&](std::uint64_t c) {
    CellPos p;
    const Reach r = old_loc.locate(c, p);
    if (r == Reach::yes) {
      boxes.add(removed, p);
    } else if (r == Reach::anomaly) {
      removed_unknown = true;
    }
  };
  // Group g (the row's k-th) is live before and after the batch under the same parent.
  auto group_kept = [&](std::uint64_t g, const BatchState::Row& src, std::uint64_t k) {
    if (g >= old_cells / 8) return false;
    const std::uint32_t np = src.epoch->group_parent[src.first / 8 + k];
    const bool live = !(src.epoch->depth_flags[src.first / 8 + k] & PoolView::kFreeFlag);
    return live && !(before.depth_flags(g) & PoolView::kFreeFlag) && np == before.group_parent(g);
  };
  for (const std::uint32_t r : rows) {
    const std::uint64_t c0 = std::uint64_t{r} * w;
    if (c0 >= new_cells || after.row(r).epoch == nullptr) continue;
    const BatchState::Row& src = after.row(r);
    const std::uint64_t n = std::min(w, new_cells - c0);
    for (std::uint64_t k = 0; k < n; ++k) {
      const std::uint64_t c = c0 + k;
      const std::uint32_t nf = src.epoch->first_child[src.first + k];
      const std::uint32_t nc = src.epoch->colour[src.first + k];
      const bool had = c < old_cells;
      const std::uint32_t of = had ? before.first_child(c) : kNoCell;
      const std::uint32_t oc = had ? before.colour(c) : 0u;
      if (nf == of && (nf != kNoCell || nc == oc)) continue;
      ++out.changed_cells;
      const bool was_painted_leaf = of == kNoCell && painted(oc);
      if (was_painted_leaf && !(nf == kNoCell && painted(nc))) remove(c);
      if (nf != kNoCell) {
        attached.push_back(static_cast<std::uint32_t>(c));
      } else if (painted(nc) && !(was_painted_leaf && group_kept(c / 8, src, (c - c0) / 8))) {
        // (A painted leaf only recoloured, in a group that kept its parent, is where it was:
        // inside box_before already. Most of a stroke over painted cells is such recolouring.
        // Had an ancestor group moved, the walk from its new parent in step 2 adds the leaf.)
        leaves.push_back(static_cast<std::uint32_t>(c));
      }
    }
    for (std::uint64_t k = 0; k < n / 8; ++k) {
      const std::uint64_t g = c0 / 8 + k;
      const bool had = g < old_cells / 8;
      const std::uint32_t np = src.epoch->group_parent[src.first / 8 + k];
      const std::uint32_t op = had ? before.group_parent(g) : kNoCell;
      const bool live = !(src.epoch->depth_flags[src.first / 8 + k] & PoolView::kFreeFlag);
      const bool was_live = had && !(before.depth_flags(g) & PoolView::kFreeFlag);
      if (live && np != op && op != kNoCell) reparented.emplace_back(g, op);
      // A freed group's cells may keep their values: their paint is gone all the same.
      if (was_live && !live)
        for (std::uint64_t s = 0; s < 8; ++s)
          if (before.first_child(g * 8 + s) == kNoCell && painted(before.colour(g * 8 + s)))
            remove(g * 8 + s);
    }
  }

  // 2. Growth in the state after. A cell whose first_child changed may hold a subtree whose
  //    cells did not change (a reused slot with the same values): walk it whole.
  std::vector<std::pair<std::uint64_t, CellPos>> stack;
  // Root groups are never walked into (a child group is never a root group).
  auto walked = [&](std::uint64_t c) { return walked_[c >> 3] == walk_now_; };
  for (const std::uint32_t c : attached) {
    if (walked(c)) continue;  // inside a subtree walked already
    CellPos pos;
    const Reach r = new_loc.locate(c, pos);
    if (r == Reach::no) continue;  // in a freed group: nothing renders it
    if (r == Reach::anomaly) {
      out.fallback = true;
      return out;
    }
    stack.assign(1, {c, pos});
    while (!stack.empty()) {
      const auto [cell, p] = stack.back();
      stack.pop_back();
      const std::uint32_t fc = after.first_child(cell);
      if (fc == kNoCell) {
        if (painted(after.colour(cell))) boxes.add(out.box, p);
        continue;
      }
      if (fc % 8 != 0 || fc >= new_cells || p.depth >= PoolView::kMaxDepth ||
          after.group_parent(fc >> 3) != cell) {
        out.fallback = true;
        return out;
      }
      if (walked_[fc >> 3] == walk_now_) continue;
      walked_[fc >> 3] = walk_now_;
      for (std::uint32_t s = 0; s < 8; ++s) stack.push_back({fc + s, child_pos(p, s)});
    }
  }
  for (const std::uint32_t c : leaves) {
    if (walked(c)) continue;  // the walk added it
    CellPos pos;
    const Reach r = new_loc.locate(c, pos);
    if (r == Reach::no) continue;
    if (r == Reach::anomaly) {
      out.fallback = true;
      return out;
    }
    boxes.add(out.box, pos);
  }
  // A group moved to a new parent must no longer hang under its previous one.
  for (const auto& [g, old_parent] : reparented) {
    if (old_parent < new_cells && after.first_child(old_parent) == g * 8) {
      out.fallback = true;
      return out;
    }
  }
  out.loose = removed_unknown || (removed && box_before && touches_faces(*removed, *box_before));
  return out;
}

}  // namespace deepcanvas::client_gpu::detail
