#include "deepcanvas/server_core/painter.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "deepcanvas/protocol/density_model.hpp"

namespace deepcanvas::server_core {

namespace dm = protocol::density;
using protocol::BrushMode;

namespace {
constexpr std::uint32_t kNoStamp = 0xFFFFFFFFu;
constexpr int kLevels = kMaxSupportedDepth + 1;
// Mark word per cell: (stroke sequence << 3) | flags; flags are valid only when the sequence is
// the current stroke's, so the pools never need clearing between strokes.
//   kTouched      the stroke touched the cell (its pre-stroke value is in MarkPre::pre)
//   kQueued       queued for refinement
//   kMergeQueued  in a merge queue (deduplicates the queue in O(1), no sort)
constexpr std::uint32_t kTouched = 1u, kQueued = 2u, kMergeQueued = 4u;
constexpr int kSeqShift = 3;
constexpr std::uint32_t kMaxSeq = (1u << (32 - kSeqShift)) - 1;
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
}  // namespace

struct Painter::Impl {
  Octree& t;
  PainterConfig cfg;
  CanvasGeometry geo;
  std::unique_ptr<Octree::FieldPool> markpre_pool, strength_pool;
  MarkPre* mp = nullptr;
  StrengthSrc* st = nullptr;
  std::uint32_t seq = 0;

  // ---- stroke state ----
  bool active = false, ended = false, one_shot = false;
  protocol::Brush brush;
  double brush_density = 0;  // A * O (paint)
  double full_log = 0;       // -log1p(-brush_density) when brush_density < 1
  std::uint64_t stroke_id = 0;
  StampBuilder builder;
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
    std::vector<Entry> q;
    std::size_t cur = 0;
  };
  struct MergeLevel {
    std::vector<CellIndex> q;
    std::size_t cur = 0;
  };
  std::array<RefineLevel, kLevels> refine_q;
  std::array<MergeLevel, kLevels> merge_q;
  // The paint pass, resumable: stamps [0, paint_next) have been started; `pstack` holds the
  // cells still to visit for stamp `psid` (a depth-first descent kept explicitly so that a step
  // can stop after any cell and the next one goes on).
  std::size_t paint_next = 0;
  std::uint32_t psid = 0;
  float pbound = kNeverSkip;  // max_strength(stamps[psid])
  // Stamp psid's shortcut radii (see start_stamp()); negative: no shortcut.
  double p_inside_r = -1, p_core_r = -1;
  float p_core_v = 0;  // the strength of coverage 1 where kCore applies
  std::vector<Entry> pstack;
  StrokeStats stats;
  std::optional<PickResult> picked;

  Impl(Octree& tree, const PainterConfig& c)
      : t(tree), cfg(c), geo(CanvasGeometry::of(tree.config())) {}

  // ---- marks ----
  bool cur(CellIndex c) const { return (mp[c].mark >> kSeqShift) == seq; }
  bool marked(CellIndex c) const { return cur(c) && (mp[c].mark & kTouched); }
  bool queued(CellIndex c) const { return cur(c) && (mp[c].mark & kQueued); }
  bool merge_queued(CellIndex c) const { return cur(c) && (mp[c].mark & kMergeQueued); }
  void set_flag(CellIndex c, std::uint32_t f) {
    mp[c].mark = cur(c) ? (mp[c].mark | f) : ((seq << kSeqShift) | f);
  }

  static CellCoord child_coord(const CellCoord& k, std::uint32_t i) {
    return CellCoord{k.depth + 1, 2 * k.x + (i & 1), 2 * k.y + ((i >> 1) & 1), 2 * k.z + (i >> 2)};
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
  // within p_inside_r of the axis touches the stamp: stamp_touches() inflates by r_max, and the
  // margin (relative to r_max and to the canvas, whose coordinates set the rounding) keeps
  // its floating-point answer true. Within p_core_r = hardness * min(ra, rb) less the margin,
  // stamp_coverage() gives u <= hardness, coverage 1: the strength there is p_core_v when it
  // does not depend on the local diameter (paint at full density: infinite; other modes: the
  // opacity), else there is no core shortcut.
  void start_stamp(const Stamp& s) {
    pbound = kNeverSkip;
    p_inside_r = p_core_r = -1;
    if (!cfg.exact_shortcuts) return;
    pbound = max_strength(s);
    const double margin = 1e-6 * s.r_max + 1e-11 * geo.edge_m;
    p_inside_r = s.r_max - margin;
    const bool flat = brush.mode != BrushMode::paint || !(brush_density < 1.0);
    p_core_v = brush.mode == BrushMode::paint ? INFINITY : brush.opacity;
    if (flat) p_core_r = double{brush.hardness} * std::min(s.ra, s.rb) - margin;
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
  void write(CellIndex c, std::uint32_t v) {
    if (t.colour(c) == v) return;
    t.set_colour(c, v);
    ++stats.cells_recoloured;
  }

  // ---- queues ----
  void queue_refine(CellIndex c, const CellCoord& k) {
    if (queued(c)) return;
    set_flag(c, kQueued);
    refine_q[static_cast<std::size_t>(k.depth)].q.push_back({c, k});
  }
  // Deduplicated by the kMergeQueued flag (cleared when the entry is taken), so a level's queue
  // never needs sorting: merges within one level are independent of their order (a merge at
  // depth d reads and frees only its own children, and can_coarsen() of another depth-d cell
  // only looks at depth-d+1 cells that a depth-d merge cannot create).
  void queue_merge(CellIndex p, int depth) {
    if (merge_queued(p)) return;
    set_flag(p, kMergeQueued);
    merge_q[static_cast<std::size_t>(depth)].q.push_back(p);
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
  std::vector<std::uint32_t> cand;
  std::vector<std::uint32_t> seen;
  std::uint32_t seen_gen = 0;
  void candidates(const CellCoord& k) {
    cand.clear();
    if (seen.size() < indexed) seen.resize(indexed, 0u);
    if (++seen_gen == 0) {
      std::fill(seen.begin(), seen.end(), 0u);
      seen_gen = 1;
    }
    const Aabb box = geo.cell_box(k);
    index.query(k, [&](std::uint32_t id) {
      if (seen[id] == seen_gen) return;
      seen[id] = seen_gen;
      const Aabb& b = stamps[id].box;
      if (box.max.x < b.min.x || box.min.x > b.max.x || box.max.y < b.min.y ||
          box.min.y > b.max.y || box.max.z < b.min.z || box.min.z > b.max.z)
        return;
      cand.push_back(id);
    });
  }

  // ---- painting a stamp on the existing leaves ----
  void touch_leaf(CellIndex c, const CellCoord& k, std::uint32_t sid, bool refine, bool core) {
    const Stamp& s = stamps[sid];
    if (!marked(c)) {
      set_flag(c, kTouched);
      mp[c].pre = t.colour(c);
      st[c] = {0.0f, kNoStamp};
      if (c >= t.root_count()) queue_merge(t.parent(c), k.depth - 1);
    }
    StrengthSrc& x = st[c];
    // Saturated: no v <= pbound beats x (v > x.s, or a tie won by a lower id) when
    // x.s > pbound, or x.s == pbound from a stamp no later than this one.
    if (!(x.s > pbound || (x.s == pbound && x.src <= sid))) {
      // v = 0 (no coverage, or surely weaker) never wins below.
      float v = p_core_v;
      if (!core) {
        const StampHit hit = stamp_coverage(s, geo.cell_centre(k), brush.hardness);
        const bool weaker = cfg.exact_shortcuts && hit.coverage > 0 && surely_weaker(hit, x.s);
        v = hit.coverage > 0 && !weaker ? static_cast<float>(strength_of(hit)) : 0.0f;
      }
      if (v > x.s || (v == x.s && v > 0 && sid < x.src)) {
        x = {v, sid};
        write(c, blend(mp[c].pre, x.s, x.src, k.depth));
      }
    }
    if (refine && k.depth < s.depth && can_change(mp[c].pre)) queue_refine(c, k);
  }

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
  void push_start(std::uint32_t sid, std::vector<Entry>& stack) const {
    const Stamp& s = stamps[sid];
    const double h = geo.edge_m * 0.5;
    int best = -1;
    CellCoord bk;
    for (int d = 0; d <= geo.max_depth; ++d) {
      const double e = geo.cell_edge(d);
      const double lim = static_cast<double>(std::uint64_t{geo.roots_per_axis} << d) - 1.0;
      auto idx = [&](double v) {
        return static_cast<std::uint32_t>(std::clamp(std::floor((v + h) / e), 0.0, lim));
      };
      const CellCoord k{d, idx(s.box.min.x), idx(s.box.min.y), idx(s.box.min.z)};
      const Aabb cb = geo.cell_box(k);
      if (!(cb.min.x < s.box.min.x && s.box.max.x < cb.max.x && cb.min.y < s.box.min.y &&
            s.box.max.y < cb.max.y && cb.min.z < s.box.min.z && s.box.max.z < cb.max.z))
        break;
      best = d;
      bk = k;
    }
    if (best >= 0) {
      const LocateResult r = t.find(bk);
      if (stamp_touches(s, geo.cell_box(r.coord))) stack.push_back({r.cell, r.coord});
      return;
    }
    const std::size_t first = stack.size();
    for_roots(s.box, [&](CellIndex r, const CellCoord& k) {
      if (stamp_touches(s, geo.cell_box(k))) stack.push_back({r, k});
    });
    std::reverse(stack.begin() + static_cast<std::ptrdiff_t>(first), stack.end());
  }

  bool paint_pending() const { return !pstack.empty() || paint_next < stamps.size(); }

  // Paints pending stamps on the leaves they touch, until `budget` work units are spent (one
  // per stamp started plus one per index bucket it fills, one per cell taken from the stack,
  // one per child box tested). Returns the units spent (<= budget + kStepWorkSlack). With
  // `refine`, touched leaves shallower than the stamp's target depth are queued for refinement.
  std::uint64_t paint_some(std::uint64_t budget, bool refine) {
    std::uint64_t work = 0;
    while (work < budget) {
      if (pstack.empty()) {
        if (paint_next >= stamps.size()) break;
        psid = static_cast<std::uint32_t>(paint_next++);
        // A stamp enters the index when its painting starts: refinement (which evaluates new
        // children against the index) runs only once every stamp has been started.
        work += 1 + index_up_to(paint_next);
        start_stamp(stamps[psid]);
        push_start(psid, pstack);
        continue;
      }
      // Entries on the stack touch the stamp (tested before they were pushed, so that cells
      // that do not never enter the stack).
      const Entry v = pstack.back();
      pstack.pop_back();
      ++work;
      const CellIndex fc = t.first_child(v.c);
      if (fc == kNoCell) {
        touch_leaf(v.c, v.k, psid, refine, (v.flags & kCore) != 0);
        continue;
      }
      const Stamp& s = stamps[psid];
      work += 8;
      const int cd = v.k.depth + 1;
      std::uint32_t flags = v.flags;
      if (p_inside_r > 0 && (!(flags & kInside) || (!(flags & kCore) && p_core_r > 0))) {
        // Every point of v's box lies within reach: its centre's distance to the axis plus
        // its half diagonal. Then every child touches (no box tests below v) and, within
        // p_core_r, has coverage 1 at every point.
        const double reach = std::sqrt(axis_dist2(s, geo.cell_centre(v.k))) +
                             kHalfDiagonal * geo.cell_edge(v.k.depth);
        if (reach <= p_inside_r) flags = kInside | (reach <= p_core_r ? kCore : 0u);
      }
      if (flags & kInside) {
        std::size_t n = pstack.size();
        pstack.resize(n + 8);
        Entry* out = pstack.data() + n;
        for (std::uint32_t i = 8; i-- > 0;) *out++ = {fc + i, child_coord(v.k, i), flags};
        continue;
      }
      // The children's boxes from the three planes per axis they share (the same arithmetic as
      // geo.cell_box(child), so the same doubles, with 9 products instead of 48).
      const double e = geo.cell_edge(cd), h = geo.edge_m * 0.5;
      double px[3], py[3], pz[3];
      for (std::uint32_t j = 0; j < 3; ++j) {
        px[j] = -h + (2.0 * v.k.x + j) * e;
        py[j] = -h + (2.0 * v.k.y + j) * e;
        pz[j] = -h + (2.0 * v.k.z + j) * e;
      }
      std::size_t n = pstack.size();
      pstack.resize(n + 8);  // capacity stays after the first strokes: no allocation here
      Entry* out = pstack.data();
      for (std::uint32_t i = 8; i-- > 0;) {
        const std::uint32_t bx = i & 1, by = (i >> 1) & 1, bz = i >> 2;
        const Aabb cb{{px[bx], py[by], pz[bz]}, {px[bx + 1], py[by + 1], pz[bz + 1]}};
        if (stamp_touches(s, cb))
          out[n++] = {fc + i, CellCoord{cd, 2 * v.k.x + bx, 2 * v.k.y + by, 2 * v.k.z + bz}};
      }
      pstack.resize(n);
    }
    return work;
  }

  // ---- refinement ----
  // Refines leaf c (at k) after its coarser face neighbours (2:1 balance), each split through
  // on_refined(). Every split costs 8 work units; a split is started only while work < cap, so
  // a call overshoots the cap by at most 7 units. Returns false when it stopped for the budget
  // before splitting c (the tree is valid and balanced: every split done had its coarser
  // neighbours split first); calling it again later goes on where it stopped.
  Result<bool> refine_balanced(CellIndex c, const CellCoord& k, std::uint64_t& work,
                               std::uint64_t cap) {
    for (int f = 0; f < 6; ++f) {
      const CellIndex n = t.face_neighbour(c, f);
      if (n == kNoCell || !t.is_leaf(n) || t.depth(n) >= k.depth) continue;
      CellCoord nk{k.depth - 1, k.x >> 1, k.y >> 1, k.z >> 1};
      std::uint32_t* comp[3] = {&nk.x, &nk.y, &nk.z};
      *comp[f >> 1] += (f & 1) ? 1u : static_cast<std::uint32_t>(-1);
      auto r = refine_balanced(n, nk, work, cap);
      if (!r || !*r) return r;
    }
    if (work >= cap) return false;
    std::uint64_t created = 0;
    auto r = t.refine(c, &created);
    stats.cells_created += created;
    work += created;
    if (!r) return std::move(r).error();
    if (created != 8)
      return make_error(Errc::internal, "painter: octree balanced a refinement on its own");
    on_refined(c, k);
    return true;
  }

  // New children of c: their values and whether they need refining further. Equal to
  // evaluating every stamp at every child (the reference: the strongest stamp, lowest id on
  // ties, so the order of evaluation does not matter), computed stamp by stamp with fewer
  // tests: a stamp whose axis is farther from c's centre than r_max plus the centre-to-child-
  // centre distance covers no child centre; coverage > 0 at a child's centre implies the stamp
  // touches the child's box; a stamp that does not touch c's box touches none of its children;
  // only stamps targeting deeper than the children can ask for their refinement, and one such
  // touching stamp settles it for a child.
  void on_refined(CellIndex c, const CellCoord& k) {
    const CellIndex fc = t.first_child(c);
    queue_merge(c, k.depth);
    if (marked(c)) {
      candidates(k);
      // Internal cells keep their pre-stroke value (as if refined before painting).
      const std::uint32_t pre = mp[c].pre;
      write(c, pre);
      const std::uint32_t cpre = dm::refine_rgba(pre);
      const bool changeable = can_change(cpre);
      const int cd = k.depth + 1;
      CellCoord ck[8];
      Vec3d centre[8];
      float best[8];
      std::uint32_t src[8];
      std::uint32_t undecided = changeable ? 0xFFu : 0u;  // children whose refinement is open
      for (std::uint32_t i = 0; i < 8; ++i) {
        ck[i] = child_coord(k, i);
        centre[i] = geo.cell_centre(ck[i]);
        best[i] = 0;
        src[i] = kNoStamp;
      }
      Aabb cbox[8];
      std::uint32_t have_box = 0;
      const Vec3d pc = geo.cell_centre(k);
      const Aabb pbox = geo.cell_box(k);
      // Distance from c's centre to a child's centre, with a margin far above rounding.
      const double off = 0.43301270189221935 * geo.cell_edge(k.depth) * (1.0 + 1e-6);
      for (const std::uint32_t id : cand) {
        const Stamp& s = stamps[id];
        const bool wants_deeper = undecided != 0 && s.depth > cd;
        const double reach = (s.r_max * (1.0 + 1e-6) + off);
        if (axis_dist2(s, pc) < reach * reach) {
          for (std::uint32_t i = 0; i < 8; ++i) {
            const StampHit hit = stamp_coverage(s, centre[i], brush.hardness);
            if (!(hit.coverage > 0)) continue;
            if (wants_deeper) undecided &= ~(1u << i);
            const auto v = static_cast<float>(strength_of(hit));
            if (v > best[i] || (v == best[i] && v > 0 && id < src[i])) {
              best[i] = v;
              src[i] = id;
            }
          }
        }
        if (wants_deeper && (undecided != 0) && stamp_touches(s, pbox)) {
          for (std::uint32_t i = 0; i < 8; ++i) {
            if (!(undecided & (1u << i))) continue;
            if (!(have_box & (1u << i))) {
              cbox[i] = geo.cell_box(ck[i]);
              have_box |= 1u << i;
            }
            if (stamp_touches(s, cbox[i])) undecided &= ~(1u << i);
          }
        }
      }
      // Children no longer undecided were settled by a deeper-targeting stamp touching them.
      const std::uint32_t refine_mask = changeable ? (~undecided & 0xFFu) : 0u;
      for (std::uint32_t i = 0; i < 8; ++i) {
        const CellIndex cc = fc + i;
        mp[cc] = {(seq << kSeqShift) | kTouched, cpre};
        st[cc] = {best[i], src[i]};
        write(cc, blend(cpre, best[i], src[i], cd));
        if (refine_mask & (1u << i)) queue_refine(cc, ck[i]);
      }
      return;
    }
    const std::uint32_t v = dm::refine_rgba(t.colour(c));
    for (std::uint32_t i = 0; i < 8; ++i) write(fc + i, v);
    if (one_shot && can_change(v)) {  // the reference refines before painting: every new child
      candidates(k);
      for (std::uint32_t i = 0; i < 8; ++i) {
        const CellCoord ck = child_coord(k, i);
        const Aabb cbox = geo.cell_box(ck);
        for (const std::uint32_t id : cand) {
          const Stamp& s = stamps[id];
          if (s.depth > ck.depth && stamp_touches(s, cbox)) {
            queue_refine(fc + i, ck);
            break;
          }
        }
      }
    }
  }

  // ---- merging back ----
  // True when p merged (8 cells freed).
  bool merge_one(CellIndex p, int d) {
    if (!t.is_live(p) || t.is_leaf(p)) return false;
    const CellIndex fc = t.first_child(p);
    std::uint32_t ch[8];
    for (std::uint32_t i = 0; i < 8; ++i) {
      if (!t.is_leaf(fc + i)) return false;
      ch[i] = t.colour(fc + i);
    }
    if (!dm::uniform(ch) || !t.can_coarsen(p)) return false;
    const std::uint32_t v = dm::coarsen_rgba(ch);
    if (!t.coarsen(p)) return false;
    stats.cells_freed += 8;
    write(p, v);
    if (p < t.root_count()) return true;
    const CellIndex up = t.parent(p);
    queue_merge(up, d - 1);
    // p's children no longer face the children of up's neighbours: those neighbours (same depth
    // as up) may now coarsen without breaking balance, though the stroke never touched them
    // (balance refinements of earlier strokes unwind this way).
    for (int f = 0; f < 6; ++f) {
      const CellIndex n = t.face_neighbour(up, f);
      if (n != kNoCell && !t.is_leaf(n) && t.depth(n) == d - 1) queue_merge(n, d - 1);
    }
    return true;
  }

  void reset_stroke() {
    active = ended = one_shot = false;
    builder = StampBuilder{};
    stamps.clear();
    carried.clear();
    index.clear();
    indexed = 0;
    paint_next = 0;
    pstack.clear();
    for (auto& l : refine_q) l = {};
    for (auto& l : merge_q) l = {};
  }

  // One level of refinement (the shallowest with entries) until `cap` units are spent.
  // Returns false and leaves `err` set on a failed refinement.
  bool refine_some(std::uint64_t& work, std::uint64_t cap, bool& did, Error& err) {
    for (int d = 0; d < kLevels; ++d) {
      RefineLevel& L = refine_q[static_cast<std::size_t>(d)];
      if (L.cur >= L.q.size()) continue;
      did = true;
      while (L.cur < L.q.size() && work < cap) {
        const Entry e = L.q[L.cur];
        if (!t.is_leaf(e.c)) {
          ++L.cur;
          ++work;
          continue;
        }
        auto r = refine_balanced(e.c, e.k, work, cap);
        if (!r) {
          err = std::move(r).error();
          return false;
        }
        if (!*r) break;  // the budget ran out inside e's balance chain: go on next step
        ++L.cur;
      }
      if (L.cur >= L.q.size()) L = {};
      break;
    }
    return true;
  }

  // One bounded step; see painter.hpp for what a work unit is. Pending paint gets half the
  // budget, then one level of refinement, then paint again with what is left; after
  // end_stroke(), once nothing else is pending, one level of merging (deepest first).
  // Interleaving paint and refinement gives the same result as painting first: new children
  // are evaluated against every stamp already started (in the index), and a stamp started
  // later reaches them through its own descent (a cell's value is a maximum over stamps, and
  // both paths queue the same refinements). It lets a whole stroke given at once change the
  // tree from its first step.
  Result<bool> step(std::uint64_t max_work) {
    if (!active) return false;
    const std::uint64_t cap = std::max<std::uint64_t>(max_work, 8);
    std::uint64_t work = 0;
    bool did = false;
    if (paint_pending()) {
      work += paint_some(cap / 2, true);
      did = true;
    }
    if (work < cap) {
      Error err;
      if (!refine_some(work, cap, did, err)) {
        reset_stroke();
        return err;
      }
    }
    if (work < cap && paint_pending()) work += paint_some(cap - work, true);
    if (!did && ended) {
      for (int d = kLevels - 1; d >= 0; --d) {
        MergeLevel& M = merge_q[static_cast<std::size_t>(d)];
        if (M.cur >= M.q.size()) continue;
        did = true;
        while (M.cur < M.q.size() && work < cap) {
          const CellIndex p = M.q[M.cur++];
          mp[p].mark &= ~kMergeQueued;
          work += merge_one(p, d) ? 9 : 1;
        }
        if (M.cur >= M.q.size()) M = {};
        break;
      }
    }
    if (did) {
      ++stats.steps;
      stats.work += work;
      stats.max_step_work = std::max(stats.max_step_work, work);
      return true;
    }
    if (!ended) return false;
    reset_stroke();
    return false;
  }

  // ---- strokes ----
  // `b` and `samples` satisfy the canvas's stroke rules (the callers take validated types).
  Result<void> start(const protocol::Brush& b, std::uint64_t id,
                     std::span<const protocol::StrokeSample> samples) {
    if (active) return make_error(Errc::refused, "painter: a stroke is already active");
    brush = b;
    if (seq >= kMaxSeq) {
      markpre_pool->clear();
      strength_pool->clear();
      seq = 0;
    }
    ++seq;
    reset_stroke();
    active = true;
    stroke_id = id;
    stats = {};
    brush_density = double{b.colour[3]} * b.opacity;
    full_log = brush_density < 1.0 ? -std::log1p(-brush_density) : INFINITY;
    carry = {b.colour[0], b.colour[1], b.colour[2]};
    carry_loaded = false;
    if (b.mode == BrushMode::pick_up) {
      picked.reset();
      if (!samples.empty()) {
        auto p = pick(Vec3d{samples[0].x, samples[0].y, samples[0].z});
        if (p) picked = *p;
      }
    }
    return {};
  }

  // Turns new samples into stamps (with `finish`, flushes the builder: the stroke's last
  // samples) and queues them for painting; no cell is visited here (step() paints). A limit
  // error leaves the stroke as it was (the builder and stamps untouched).
  Result<void> add(std::span<const protocol::StrokeSample> samples, bool finish = false) {
    if (brush.mode == BrushMode::pick_up) {
      stats.samples += samples.size();
      return {};
    }
    std::vector<Stamp> fresh;
    StampBuilder b = builder;
    for (const auto& s : samples) {
      auto r = b.add(geo, cfg.stamps, s, fresh, stamps.size() + fresh.size());
      if (!r) return r;
    }
    if (finish) {
      auto r = b.finish(geo, cfg.stamps, fresh, stamps.size() + fresh.size());
      if (!r) return r;
    }
    builder = b;
    stats.samples += samples.size();
    for (const Stamp& s : fresh) {
      stamps.push_back(s);
      if (brush.mode == BrushMode::smudge) {
        // The brush loads the colour under its first non-empty stamp, then picks up
        // kSmudgePickup of what is under it per radius travelled (scale-free). The pre-stroke
        // colour there does not depend on how far painting has got: a touched cell keeps it in
        // `pre`, an untouched leaf still holds it, and refinement keeps rgb.
        auto loc = t.locate(s.a, geo.max_depth);
        if (loc) {
          const CellIndex c = loc->cell;
          const std::uint32_t v = marked(c) ? mp[c].pre : t.colour(c);
          if ((v >> 24) != 0) {
            const double dx = s.b.x - s.a.x, dy = s.b.y - s.a.y, dz = s.b.z - s.a.z;
            const double travel = std::sqrt(dx * dx + dy * dy + dz * dz) / s.r_max;
            const float m = carry_loaded
                                ? static_cast<float>(1.0 - std::pow(1.0 - kSmudgePickup, travel))
                                : 1.0f;
            carry_loaded = true;
            for (int k = 0; k < 3; ++k)
              carry[static_cast<std::size_t>(k)] =
                  (1.0f - m) * carry[static_cast<std::size_t>(k)] +
                  m * static_cast<float>((v >> (8 * k)) & 0xFFu) / 255.0f;
          }
        }
        carried.push_back(carry);
      }
    }
    stats.stamps = stamps.size();
    return {};
  }

  Result<PickResult> pick(const Vec3d& p) const {
    auto loc = t.locate(p, geo.max_depth);
    if (!loc) return std::move(loc).error();
    PickResult r;
    r.cell = loc->cell;
    r.depth = loc->coord.depth;
    r.cell_edge_m = geo.cell_edge(r.depth);
    const dm::Rgba8 c = dm::unpack(t.colour(r.cell));
    r.rgb[0] = c.r / 255.0f;
    r.rgb[1] = c.g / 255.0f;
    r.rgb[2] = c.b / 255.0f;
    r.alpha = c.a / 255.0f;
    r.sigma_per_m = c.a == 255 ? INFINITY : dm::sigma_per_m(c.a / 255.0, r.cell_edge_m);
    return r;
  }
};

Painter::Painter(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Painter::~Painter() = default;

Result<std::unique_ptr<Painter>> Painter::create(Octree& tree, const PainterConfig& config) {
  auto impl = std::make_unique<Impl>(tree, config);
  auto a = tree.add_field_pool("paint.mark_pre", 8);
  if (!a) return std::move(a).error();
  auto b = tree.add_field_pool("paint.strength", 8);
  if (!b) return std::move(b).error();
  impl->markpre_pool = std::move(*a);
  impl->strength_pool = std::move(*b);
  impl->mp = impl->markpre_pool->as<MarkPre>();
  impl->st = impl->strength_pool->as<StrengthSrc>();
  return std::unique_ptr<Painter>(new Painter(std::move(impl)));
}

protocol::StrokeRules Painter::stroke_rules() const noexcept {
  return protocol::StrokeRules{protocol::CanvasBounds{impl_->geo.edge_m}, impl_->cfg.limits};
}

Result<void> Painter::begin_stroke(const protocol::ValidatedBrush& brush, std::uint64_t stroke_id,
                                   const protocol::ValidatedSamples& samples) {
  Impl& m = *impl_;
  if (auto r = m.start(brush.get(), stroke_id, samples.span()); !r) return r;
  auto r = m.add(samples.span());
  if (!r) m.reset_stroke();  // only a stamp limit can fail here
  return r;
}

Result<void> Painter::add_samples(const protocol::ValidatedSamples& samples) {
  Impl& m = *impl_;
  if (!m.active || m.ended)
    return make_error(Errc::refused, "painter: no stroke is accepting samples");
  if (samples.empty()) return {};
  return m.add(samples.span());
}

Result<void> Painter::end_stroke() {
  Impl& m = *impl_;
  if (!m.active || m.ended) return make_error(Errc::refused, "painter: no stroke to end");
  m.ended = true;
  // The builder's held-back last sample (validated already; the stamp limit is the only error).
  return m.add({}, true);
}

Result<bool> Painter::step() {
  return impl_->step(impl_->cfg.max_cells_per_step);
}
Result<bool> Painter::step(std::uint64_t max_work) {
  return impl_->step(max_work);
}
bool Painter::stroke_active() const noexcept {
  return impl_->active;
}
bool Painter::stroke_painted() const noexcept {
  const Impl& m = *impl_;
  if (!m.active || !m.ended || m.paint_pending()) return false;
  for (const auto& L : m.refine_q)
    if (L.cur < L.q.size()) return false;
  return true;
}

Result<StrokeStats> Painter::apply_stroke(const protocol::ValidatedStroke& stroke) {
  if (auto r = begin_stroke(stroke.brush(), stroke.id(), stroke.samples()); !r)
    return std::move(r).error();
  (void)end_stroke();
  for (;;) {
    auto more = step();
    if (!more) return std::move(more).error();
    if (!*more) break;
  }
  return impl_->stats;
}

Result<StrokeStats> Painter::paint_one_shot(const protocol::ValidatedStroke& stroke) {
  Impl& m = *impl_;
  if (auto r = m.start(stroke.brush().get(), stroke.id(), stroke.samples().span()); !r)
    return std::move(r).error();
  m.one_shot = true;
  if (auto r = m.add(stroke.samples().span(), true); !r) {
    m.reset_stroke();
    return std::move(r).error();
  }
  m.index_up_to(m.stamps.size());
  // 1. Refine everything the stroke touches to its target depth (to a fixpoint).
  std::vector<Impl::Entry> stack;
  for (std::uint32_t id = 0; id < m.stamps.size(); ++id) {
    const Stamp& s = m.stamps[id];
    m.push_start(id, stack);
    while (!stack.empty()) {
      const Impl::Entry v = stack.back();  // touches s (tested before the push)
      stack.pop_back();
      const CellIndex fc = m.t.first_child(v.c);
      if (fc == kNoCell) {
        if (v.k.depth < s.depth && m.can_change(m.t.colour(v.c))) m.queue_refine(v.c, v.k);
        continue;
      }
      for (std::uint32_t i = 8; i-- > 0;) {
        const CellCoord ck = Impl::child_coord(v.k, i);
        if (stamp_touches(s, m.geo.cell_box(ck))) stack.push_back({fc + i, ck});
      }
    }
  }
  for (bool again = true; again;) {
    again = false;
    for (auto& L : m.refine_q) {
      while (L.cur < L.q.size()) {
        const Impl::Entry e = L.q[L.cur++];
        if (!m.t.is_leaf(e.c)) continue;
        std::uint64_t work = 0;
        auto r = m.refine_balanced(e.c, e.k, work, kUnbounded);
        if (!r) {
          m.reset_stroke();
          return std::move(r).error();
        }
        again = true;
      }
      L = {};
    }
  }
  m.one_shot = false;
  // 2. Paint once on the final leaves.
  (void)m.paint_some(kUnbounded, false);
  // 3. Merge back, exactly as the multi-step path does.
  m.ended = true;
  for (;;) {
    auto more = m.step(m.cfg.max_cells_per_step);
    if (!more) return std::move(more).error();
    if (!*more) break;
  }
  return m.stats;
}

Result<void> Painter::begin_stroke(const protocol::Brush& brush, std::uint64_t stroke_id,
                                   std::span<const protocol::StrokeSample> samples) {
  auto b = protocol::ValidatedBrush::make(brush);
  if (!b) return std::move(b).error();
  auto s = protocol::ValidatedSamples::make({samples.begin(), samples.end()}, stroke_rules());
  if (!s) return std::move(s).error();
  return begin_stroke(*b, stroke_id, *s);
}

Result<void> Painter::add_samples(std::span<const protocol::StrokeSample> samples) {
  auto s = protocol::ValidatedSamples::make({samples.begin(), samples.end()}, stroke_rules());
  if (!s) return std::move(s).error();
  return add_samples(*s);
}

Result<StrokeStats> Painter::apply_stroke(const protocol::Stroke& stroke) {
  auto s = protocol::ValidatedStroke::make(stroke, stroke_rules());
  if (!s) return std::move(s).error();
  return apply_stroke(*s);
}

Result<StrokeStats> Painter::paint_one_shot(const protocol::Stroke& stroke) {
  auto s = protocol::ValidatedStroke::make(stroke, stroke_rules());
  if (!s) return std::move(s).error();
  return paint_one_shot(*s);
}

Result<PickResult> Painter::pick(const Vec3d& p) const {
  return impl_->pick(p);
}
const std::optional<PickResult>& Painter::last_pick() const noexcept {
  return impl_->picked;
}
const StrokeStats& Painter::stroke_stats() const noexcept {
  return impl_->stats;
}

}  // namespace deepcanvas::server_core
