// Painter::Impl: the painter's state and its small inline helpers (marks, brush model, queues).
// Private to server_core. Its work is split by responsibility:
//   painter_coverage.cpp  painting stamps on existing leaves (coverage, strength, blending)
//   painter_adjust.cpp    refining the tree towards the stamps' depth (2:1 balance kept)
//   painter_merge.cpp     merging uniform children back after end_stroke()
//   painter.cpp           stroke lifecycle, step() and the public Painter API
// See docs/architecture.md section 4 for the algorithm.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "deepcanvas/protocol/density_model.hpp"
#include "deepcanvas/server_core/cell_diff.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas::server_core {

namespace dm = protocol::density;
using protocol::BrushMode;

namespace painter_detail {
constexpr std::uint32_t kNoStamp = 0xFFFFFFFFu;
constexpr int kLevels = kMaxSupportedDepth + 1;
// Mark word per cell: (stroke sequence << 3) | flags; flags are valid only when the sequence is
// the stroke's own, so the pools never need clearing between strokes. Every open stroke has its
// own sequences; the last stroke to touch a cell owns its mark (painter.hpp, "Concurrent
// strokes"). A stroke takes a new sequence for a turn when other work was given to the painter
// since its last turn (Painter::Shared::turn_sequence()), so the sequence in a cell's mark also
// says from which turn on the stroke's stamps count there (Impl::TurnSeq).
//   kTouched      the stroke touched the cell (its pre-stroke value is in MarkPre::pre)
//   kQueued       queued for refinement
//   kMergeQueued  in a merge queue (deduplicates the queue in O(1), no sort)
constexpr std::uint32_t kTouched = 1u, kQueued = 2u, kMergeQueued = 4u;
constexpr int kSeqShift = 3;
constexpr std::uint32_t kMaxSeq = (1u << (32 - kSeqShift)) - 1;
// Sequences kept for open strokes' turns: a stroke opens only while last_seq is below
// kMaxSeq - kTurnSeqHeadroom (the pools are cleared at the wrap, when no stroke is open).
constexpr std::uint32_t kTurnSeqHeadroom = 1u << 20;
constexpr std::uint64_t kUnbounded = ~std::uint64_t{0};
// A stamp bound no stored strength compares equal to or greater than (NaN): never skip.
constexpr float kNeverSkip = std::numeric_limits<float>::quiet_NaN();
// Half the diagonal of a cube of edge 1, rounded up (sqrt(3) / 2 = 0.86602540378443864676...).
constexpr double kHalfDiagonal = 0.8660254037844387;
// Smudge: fraction of the canvas colour the brush picks up per radius travelled.
constexpr double kSmudgePickup = 0.15;

struct MarkPre {
  std::uint32_t mark;
  std::uint32_t pre;  // pre-stroke RGBA8 at the cell's own depth
};
struct StrengthSrc {
  float s;            // the stroke's strength at the cell (max over stamps)
  std::uint32_t src;  // the stamp that gave it (smudge), lowest id on ties
};
static_assert(sizeof(MarkPre) == 8 && sizeof(StrengthSrc) == 8);
}  // namespace painter_detail
using namespace painter_detail;  // NOLINT(google-build-using-namespace): private header

// One open stroke's state. The octree and the temporary pools are the canvas's (Painter::Shared,
// painter.cpp); `open_seqs` lists the sequences of every open stroke, this one's included,
// ascending.
struct Painter::Impl {
  Octree& tree;
  PainterConfig config;
  CanvasGeometry geo;
  MarkPre* mark_pre = nullptr;
  StrengthSrc* strength = nullptr;
  const std::vector<std::uint32_t>* open_seqs = nullptr;
  std::uint32_t stroke_seq = 0;  // the sequence of the stroke's current turn (seqs.back())
  // The stroke's sequences, ascending, each with the first stamp of the turn that took it. A
  // leaf the stroke first touches in a turn starts over from the cell as it is then (another
  // stroke or an edit may have changed it since the stroke's earlier turns): only the stamps
  // from that turn on count there, and the cells refined from it inherit its sequence, so a
  // refinement weighs the same stamps whether it comes before or after the turn's paint reaches
  // the children (the result does not depend on the step sizes). Without other work between
  // turns every stamp that touches a leaf has reached it, so the stroke keeps its sequence.
  struct TurnSeq {
    std::uint32_t seq;
    std::uint32_t first_stamp;
  };
  std::vector<TurnSeq> seqs;

  // ---- stroke state ----
  bool active = false, ended = false, one_shot = false;
  protocol::Brush brush;
  double brush_density = 0;  // A * O (paint)
  double full_log = 0;       // -log1p(-brush_density) when brush_density < 1
  std::uint64_t stroke_id = 0;
  StampBuilder builder;
  protocol::SampleBox sample_box;  // of every sample given (limits.max_extent_m)
  std::vector<Stamp> stamps;
  std::vector<std::array<float, 3>> carried;  // smudge: colour carried at each stamp
  std::array<float, 3> carry{};
  bool carry_loaded = false;
  StampIndex index;
  std::size_t indexed = 0;  // stamps [0, indexed) are in `index`
  // flags (paint_some() only): kInside, every point of the cell lies within the stamp's reach
  // (every cell below it touches the stamp); kCore, every point has coverage 1.
  static constexpr std::uint32_t kInside = 1u, kCore = 2u;
  struct Entry {
    CellIndex c;
    CellCoord k;
    std::uint32_t flags = 0;
  };
  struct RefineLevel {
    std::vector<Entry> queue;
    std::size_t next = 0;  // entries before it are done
  };
  struct MergeLevel {
    std::vector<CellIndex> queue;
    std::size_t next = 0;  // entries before it are done
  };
  std::array<RefineLevel, kLevels> refine_levels;
  std::array<MergeLevel, kLevels> merge_levels;
  // The paint pass, resumable: stamps [0, paint_next) have been started; `paint_stack` holds the
  // cells still to visit for stamp `paint_stamp` (a depth-first descent kept explicitly so that a
  // step can stop after any cell and the next one goes on).
  std::size_t paint_next = 0;
  std::uint32_t paint_stamp = 0;
  float paint_bound = kNeverSkip;  // max_strength(stamps[paint_stamp])
  // Stamp paint_stamp's shortcut radii (see start_stamp()); negative: no shortcut.
  double paint_inside_r = -1, paint_core_r = -1;
  float paint_core_strength = 0;  // the strength of coverage 1 where kCore applies
  std::vector<Entry> paint_stack;
  StrokeStats stats;
  // PainterConfig::record_diffs: every change this stroke makes, by cell address (undo).
  CellDiffRecorder recorder;
  CellDiffRecorder* rec = nullptr;  // &recorder when recording

  Impl(Octree& octree, const PainterConfig& c)
      : tree(octree), config(c), geo(CanvasGeometry::of(octree.config())) {}

  // ---- marks ----
  // This stroke's entry for sequence `seq`, or null (seqs is short: one per interrupted turn).
  const TurnSeq* find_seq(std::uint32_t seq) const {
    const auto it = std::lower_bound(seqs.begin(), seqs.end(), seq,
                                     [](const TurnSeq& t, std::uint32_t v) { return t.seq < v; });
    return it != seqs.end() && it->seq == seq ? &*it : nullptr;
  }
  // The turn sequence `seq` is one of this stroke's; the current one is checked first (the
  // only one of a stroke nothing interrupted).
  bool own_seq(std::uint32_t seq) const {
    if (seq == stroke_seq) return true;
    if (seqs.size() <= 1 || seq < seqs.front().seq || seq > stroke_seq) return false;
    return find_seq(seq) != nullptr;
  }
  // The first stamp that counts at a cell marked with this stroke's sequence `seq`.
  std::uint32_t first_stamp_of(std::uint32_t seq) const {
    const TurnSeq* t = find_seq(seq);
    return t != nullptr ? t->first_stamp : 0;
  }
  bool this_stroke(CellIndex c) const { return own_seq(mark_pre[c].mark >> kSeqShift); }
  bool marked(CellIndex c) const { return this_stroke(c) && (mark_pre[c].mark & kTouched); }
  bool queued(CellIndex c) const { return this_stroke(c) && (mark_pre[c].mark & kQueued); }
  bool merge_queued(CellIndex c) const {
    return this_stroke(c) && (mark_pre[c].mark & kMergeQueued);
  }
  // Another open stroke touched c last (its mark is theirs): a merge must not free c.
  bool held_by_other(CellIndex c) const {
    if (open_seqs->size() <= seqs.size()) return false;  // every open sequence is this stroke's
    const std::uint32_t seq = mark_pre[c].mark >> kSeqShift;
    return !own_seq(seq) && std::binary_search(open_seqs->begin(), open_seqs->end(), seq);
  }
  void set_flag(CellIndex c, std::uint32_t f) {
    mark_pre[c].mark = this_stroke(c) ? (mark_pre[c].mark | f) : ((stroke_seq << kSeqShift) | f);
  }


  // ---- brush model ----
  bool can_change(std::uint32_t pre) const {
    switch (brush.mode) {
      case BrushMode::paint:
        return true;
      case BrushMode::pick_up:
        return false;
      default:
        return (pre >> 24) != 0;
    }
  }
  // The per-stamp strength at a point, in a domain where "max over stamps" is cheap: for paint
  // the optical depth per metre tau = -ln(1 - A O c) / D (the cell alpha q = 1 - exp(-tau h) =
  // density::brush_cell_alpha(A O, c, h / D) is taken once per cell in blend()), otherwise O c.
  // `hit` has coverage > 0.
  double strength_of(const StampHit& hit) const {
    if (brush.mode == BrushMode::paint) {
      const double k = brush_density * hit.coverage;
      if (k >= 1.0) return INFINITY;
      // Full coverage (inside the hardness radius) is common: its log is taken once per stroke.
      return (hit.coverage == 1.0 ? full_log : -std::log1p(-k)) / hit.diameter;
    }
    return double{brush.opacity} * hit.coverage;
  }
  // An upper bound of strength_of() over every point of stamp s, rounded to float the way the
  // strengths are stored (rounding is monotonic, so float(v) <= the bound for every v). Paint:
  // coverage <= 1 gives -log1p(-A O c) <= full_log, and the local diameter is at least
  // 2 min(ra, rb); the 1e-9 margin absorbs the last-ulp slack of log1p and of the radius
  // interpolation. Other modes: O c <= O exactly.
  float max_strength(const Stamp& s) const {
    if (brush.mode == BrushMode::paint) {
      if (!(brush_density < 1.0)) return INFINITY;
      return static_cast<float>(full_log / (2.0 * std::min(s.ra, s.rb)) * (1.0 + 1e-9));
    }
    return brush.opacity;
  }
  // Stamp s starts painting: its skip bound and shortcut radii. A cell whose every point lies
  // within paint_inside_r of the axis touches the stamp: stamp_touches() inflates by r_max, and the
  // margin (relative to r_max and to the canvas, whose coordinates set the rounding) keeps
  // its floating-point answer true. Within paint_core_r = hardness * min(ra, rb) less the margin,
  // stamp_coverage() gives u <= hardness, coverage 1: the strength there is paint_core_strength
  // when it does not depend on the local diameter (paint at full density: infinite; other modes:
  // the opacity), else there is no core shortcut.
  void start_stamp(const Stamp& s) {
    paint_bound = kNeverSkip;
    paint_inside_r = paint_core_r = -1;
    if (!config.exact_shortcuts) return;
    paint_bound = max_strength(s);
    const double margin = 1e-6 * s.r_max + 1e-11 * geo.edge_m;
    paint_inside_r = s.r_max - margin;
    const bool flat = brush.mode != BrushMode::paint || !(brush_density < 1.0);
    paint_core_strength = brush.mode == BrushMode::paint ? INFINITY : brush.opacity;
    if (flat) paint_core_r = double{brush.hardness} * std::min(s.ra, s.rb) - margin;
  }
  // True when strength_of(hit) < x, decided without the logarithm where it can be (paint, partial
  // coverage: -log1p(-k) <= k / (1 - k), with a 1e-9 margin for rounding), so a leaf that an
  // earlier stamp already painted more strongly costs no log1p.
  bool surely_weaker(const StampHit& hit, float x) const {
    if (brush.mode != BrushMode::paint || !(x > 0)) return false;
    const double k = brush_density * hit.coverage;
    if (!(k < 1.0) || hit.coverage == 1.0) return false;
    return static_cast<float>(k / (1.0 - k) / hit.diameter * (1.0 + 1e-9)) < x;
  }

  // Squared distance from p to the stamp's axis segment (no rounding subtleties needed: used
  // only with generous margins).
  static double axis_dist2(const Stamp& s, const Vec3d& p) {
    const double ax = s.b.x - s.a.x, ay = s.b.y - s.a.y, az = s.b.z - s.a.z;
    const double l2 = ax * ax + ay * ay + az * az;
    double t = 0;
    if (l2 > 0)
      t = std::clamp(((p.x - s.a.x) * ax + (p.y - s.a.y) * ay + (p.z - s.a.z) * az) / l2, 0.0, 1.0);
    const double cx = s.a.x + ax * t - p.x, cy = s.a.y + ay * t - p.y, cz = s.a.z + az * t - p.z;
    return cx * cx + cy * cy + cz * cz;
  }
  std::uint32_t blend(std::uint32_t pre, float s, std::uint32_t src, int depth) const {
    if (s <= 0) return pre;
    switch (brush.mode) {
      case BrushMode::paint:
        return dm::paint_over(pre,
                              std::isinf(s) ? 1.0 : -std::expm1(-double{s} * geo.cell_edge(depth)),
                              brush.colour);
      case BrushMode::erase:
        return dm::erase(pre, s);
      case BrushMode::recolor:
        return dm::recolor(pre, s, brush.colour);
      case BrushMode::smudge:
        return dm::recolor(pre, s, carried[src].data());
      case BrushMode::pick_up:
        return pre;
    }
    return pre;
  }
  void write(CellIndex c, const CellCoord& k, std::uint32_t v) {
    const std::uint32_t old = tree.colour(c);
    if (old == v) return;
    if (rec != nullptr) rec->colour(c, k, tree.is_leaf(c), old, v);
    tree.set_colour(c, v);
    ++stats.cells_recoloured;
  }

  // ---- queues ----
  void queue_refine(CellIndex c, const CellCoord& k) {
    if (queued(c)) return;
    set_flag(c, kQueued);
    refine_levels[static_cast<std::size_t>(k.depth)].queue.push_back({c, k});
  }
  // Deduplicated by the kMergeQueued flag (cleared when the entry is taken), so a level's queue
  // never needs sorting: merges within one level are independent of their order (a merge at
  // depth d reads and frees only its own children, and can_coarsen() of another depth-d cell
  // only looks at depth-d+1 cells that a depth-d merge cannot create).
  void queue_merge(CellIndex p, int depth) {
    if (merge_queued(p)) return;
    set_flag(p, kMergeQueued);
    merge_levels[static_cast<std::size_t>(depth)].queue.push_back(p);
  }

  // ---- the stamp index (filled lazily, see paint_some()) ----
  // Returns the number of index buckets filled (the cost, in work units).
  std::uint64_t index_up_to(std::size_t n) {
    std::uint64_t buckets = 0;
    for (; indexed < n; ++indexed)
      buckets += index.add(geo, static_cast<std::uint32_t>(indexed), stamps[indexed]);
    return buckets;
  }
  // Candidate stamps for the children of the cell at k: indexed stamps whose boxes overlap k's
  // box, each once (a generation counter per stamp instead of sort + unique).
  std::vector<std::uint32_t> candidate_ids;
  std::vector<std::uint32_t> candidate_seen;
  std::uint32_t candidate_gen = 0;
  void collect_candidates(const CellCoord& k);

  // ---- painting a stamp on the existing leaves ----
  void touch_leaf(CellIndex c, const CellCoord& k, std::uint32_t sid, bool refine, bool core);

  template <class F>
  void for_roots(const Aabb& box, F&& f) const {
    const std::uint32_t n = geo.roots_per_axis;
    const double e = geo.root_edge(), h = geo.edge_m * 0.5;
    auto idx = [&](double v) {
      return static_cast<std::uint32_t>(std::clamp(std::floor((v + h) / e), 0.0, n - 1.0));
    };
    for (std::uint32_t z = idx(box.min.z); z <= idx(box.max.z); ++z)
      for (std::uint32_t y = idx(box.min.y); y <= idx(box.max.y); ++y)
        for (std::uint32_t x = idx(box.min.x); x <= idx(box.max.x); ++x)
          f(x + n * (y + n * z), CellCoord{0, x, y, z});
  }

  // Pushes where stamp `sid`'s descent starts onto `stack` if it touches the stamp (popped
  // last-in first-out, so cells are visited in the order of a recursive descent from the roots).
  // Every cell the stamp touches lies inside the deepest cell whose box strictly contains the
  // stamp's box (cells outside it are disjoint from that box, and stamp_touches() rejects them), so
  // the descent starts at the deepest existing cell on that path instead of at the roots: this
  // skips ~8 box tests per level above the stamp.
  void push_start(std::uint32_t sid, std::vector<Entry>& stack) const;

  bool paint_pending() const { return !paint_stack.empty() || paint_next < stamps.size(); }

  // Paints pending stamps on the leaves they touch, until `budget` work units are spent (one
  // per stamp started plus one per index bucket it fills, one per cell taken from the stack,
  // one per child box tested). Returns the units spent (<= budget + kStepWorkSlack). With
  // `refine`, touched leaves shallower than the stamp's target depth are queued for refinement.
  std::uint64_t paint_some(std::uint64_t budget, bool refine);

  // ---- refinement ----
  // The live cells paint, recolor and smudge strokes may grow the tree to (erase: max_cells).
  std::uint64_t growth_cap = 0;
  // Whether one more split (8 cells) is allowed: the stroke's max_stroke_cells and the tree's
  // capacity (painter.hpp, "Bounded strokes").
  Result<void> may_grow() const;
  // Refines leaf c (at k) after its coarser face neighbours (2:1 balance), each split through
  // on_refined(). Every split costs 8 work units; a split is started only while work < cap, so
  // a call overshoots the cap by at most 7 units. Returns false when it stopped for the budget
  // before splitting c (the tree is valid and balanced: every split done had its coarser
  // neighbours split first); calling it again later goes on where it stopped.
  Result<bool> refine_balanced(CellIndex c, const CellCoord& k, std::uint64_t& work,
                               std::uint64_t cap);

  // New children of c: their values and whether they need refining further. Equal to
  // evaluating every stamp at every child (the reference: the strongest stamp, lowest id on
  // ties, so the order of evaluation does not matter), computed stamp by stamp with fewer
  // tests: a stamp whose axis is farther from c's centre than r_max plus the centre-to-child-
  // centre distance covers no child centre; coverage > 0 at a child's centre implies the stamp
  // touches the child's box; a stamp that does not touch c's box touches none of its children;
  // only stamps targeting deeper than the children can ask for their refinement, and one such
  // touching stamp settles it for a child.
  void on_refined(CellIndex c, const CellCoord& k);

  // ---- merging back ----
  // True when p merged (8 cells freed).
  bool merge_one(CellIndex p, int d);
  // One level of merging (the deepest with entries) until `cap` units are spent: 9 units per
  // merge, 1 per entry that does not merge. Sets `did` when a level had entries.
  void merge_some(std::uint64_t& work, std::uint64_t cap, bool& did);

  void reset_stroke();

  // One level of refinement (the shallowest with entries) until `cap` units are spent.
  // Returns false and leaves `err` set on a failed refinement.
  bool refine_some(std::uint64_t& work, std::uint64_t cap, bool& did, Error& err);

  // One bounded step; see painter.hpp for what a work unit is. Pending paint gets half the
  // budget, then one level of refinement, then paint again with what is left; after
  // end_stroke(), once nothing else is pending, one level of merging (deepest first).
  // Interleaving paint and refinement gives the same result as painting first: new children
  // are evaluated against every stamp already started (in the index), and a stamp started
  // later reaches them through its own descent (a cell's value is a maximum over stamps, and
  // both paths queue the same refinements). It lets a whole stroke given at once change the
  // tree from its first step.
  Result<bool> step(std::uint64_t max_work);

  // ---- strokes ----
  // Opens the stroke (its sequence is set by the caller). `b` satisfies the canvas's stroke
  // rules (the callers take validated types).
  void start(const protocol::Brush& b, std::uint64_t id);

  // Turns new samples into stamps (with `finish`, flushes the builder: the stroke's last
  // samples) and queues them for painting; no cell is visited here (step() paints). A limit
  // error leaves the stroke as it was (the builder and stamps untouched).
  Result<void> add(std::span<const protocol::StrokeSample> samples, bool finish = false);

  Result<PickResult> pick(const Vec3d& p) const;
};

// The canvas's side of the painter: the tree, the temporary pools and the open strokes.
struct Painter::Shared {
  Shared(Octree& t, const PainterConfig& c)
      : tree(t), config(c), recording_budget(c.max_recording_bytes) {}
  Octree& tree;
  PainterConfig config;
  // The strokes' recorders (open, spare and finished) count against it: declared before them.
  CellDiffBudget recording_budget;
  std::unique_ptr<Octree::FieldPool> mark_pre_pool, strength_pool;
  // Undo: each cell's record number in the recorder that touched it last (CellDiffRecorder).
  std::unique_ptr<Octree::FieldPool> diff_slot_pool;
  std::uint64_t growth_cap = 0;
  std::uint32_t last_seq = 0;
  std::vector<std::unique_ptr<Impl>> open;   // in the order they began
  std::vector<std::uint32_t> open_seqs;      // their sequences (every turn's), ascending
  // The stroke the painter was last given work for; null after an edit (revert, paste) or
  // when none was yet. A stroke whose turn follows other work takes a new sequence.
  const Impl* last_worker = nullptr;
  std::vector<std::unique_ptr<Impl>> spare;  // finished strokes' state, reused (allocations)
  Impl* busy = nullptr;
  StrokeStats last_stats;
  std::optional<PickResult> picked;
  // PainterConfig::record_diffs: the changes of strokes that finished or were stopped, until
  // take_stroke_diff() takes them.
  // The recorder is kept as it is: sorting its records into a CellDiff is left to the caller's
  // take_stroke_diff(), off the step that finishes the stroke.
  std::map<std::uint64_t, CellDiffRecorder> finished_diffs;

  Impl* find(std::uint64_t id) const {
    for (const auto& s : open)
      if (s->stroke_id == id) return s.get();
    return nullptr;
  }
  Result<void> may_give_work(const Impl* s) const {
    if (busy != nullptr && busy != s)
      return make_error(Errc::refused, "painter: stroke " + std::to_string(busy->stroke_id) +
                                           " is still being painted (step() until it is done)");
    return {};
  }
  // Opens stroke `id` (no samples yet).
  Result<Impl*> open_stroke(const protocol::Brush& brush, std::uint64_t id);
  // Stroke `s` is given its next turn: a new sequence when other work came since its last one.
  void turn_sequence(Impl& s);
  // Closes `s` (finished or failed): its state goes back to `spare`.
  void close(Impl* s);
};

}  // namespace deepcanvas::server_core
