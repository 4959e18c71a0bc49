#include "deepcanvas/server_core/painter.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include "deepcanvas/protocol/density_model.hpp"

namespace deepcanvas::server_core {

namespace dm = protocol::density;
using protocol::BrushMode;

namespace {
constexpr std::uint32_t kNoStamp = 0xFFFFFFFFu;
constexpr int kLevels = kMaxSupportedDepth + 1;
// Mark word per cell: (stroke sequence << 2) | flags; flags are valid only when the sequence is
// the current stroke's, so the pools never need clearing between strokes.
constexpr std::uint32_t kTouched = 1u, kQueued = 2u;
constexpr std::uint32_t kMaxSeq = (1u << 30) - 1;
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
  std::uint64_t stroke_id = 0;
  StampBuilder builder;
  std::vector<Stamp> stamps;
  std::vector<std::array<float, 3>> carried;  // smudge: colour carried at each stamp
  std::array<float, 3> carry{};
  bool carry_loaded = false;
  StampIndex index;
  struct Entry {
    CellIndex c;
    CellCoord k;
  };
  struct RefineLevel {
    std::vector<Entry> q;
    std::size_t cur = 0;
  };
  struct MergeLevel {
    std::vector<CellIndex> q;
    std::size_t cur = 0;
    bool sorted = false;
  };
  std::array<RefineLevel, kLevels> refine_q;
  std::array<MergeLevel, kLevels> merge_q;
  StrokeStats stats;
  std::optional<PickResult> picked;

  Impl(Octree& tree, const PainterConfig& c)
      : t(tree), cfg(c), geo(CanvasGeometry::of(tree.config())) {}

  // ---- marks ----
  bool cur(CellIndex c) const { return (mp[c].mark >> 2) == seq; }
  bool marked(CellIndex c) const { return cur(c) && (mp[c].mark & kTouched); }
  bool queued(CellIndex c) const { return cur(c) && (mp[c].mark & kQueued); }
  void set_flag(CellIndex c, std::uint32_t f) {
    mp[c].mark = cur(c) ? (mp[c].mark | f) : ((seq << 2) | f);
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
  double strength_at(const Stamp& s, const Vec3d& p) const {
    const StampHit hit = stamp_coverage(s, p, brush.hardness);
    if (hit.coverage <= 0) return 0;
    if (brush.mode == BrushMode::paint) {
      const double k = double{brush.colour[3]} * brush.opacity * hit.coverage;
      if (k >= 1.0) return INFINITY;
      return -std::log1p(-k) / hit.diameter;
    }
    return double{brush.opacity} * hit.coverage;
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
  void queue_merge(CellIndex p, int depth) {
    merge_q[static_cast<std::size_t>(depth)].q.push_back(p);
  }

  // ---- painting a stamp on the existing leaves ----
  void touch_leaf(CellIndex c, const CellCoord& k, std::uint32_t sid, bool refine) {
    const Stamp& s = stamps[sid];
    if (!marked(c)) {
      set_flag(c, kTouched);
      mp[c].pre = t.colour(c);
      st[c] = {0.0f, kNoStamp};
      if (c >= t.root_count()) queue_merge(t.parent(c), k.depth - 1);
    }
    const auto v = static_cast<float>(strength_at(s, geo.cell_centre(k)));
    StrengthSrc& x = st[c];
    if (v > x.s || (v == x.s && v > 0 && sid < x.src)) {
      x = {v, sid};
      write(c, blend(mp[c].pre, x.s, x.src, k.depth));
    }
    if (refine && k.depth < s.depth && can_change(mp[c].pre)) queue_refine(c, k);
  }

  void descend(CellIndex c, const CellCoord& k, std::uint32_t sid, bool refine) {
    if (!stamp_touches(stamps[sid], geo.cell_box(k))) return;
    const CellIndex fc = t.first_child(c);
    if (fc == kNoCell) {
      touch_leaf(c, k, sid, refine);
      return;
    }
    for (std::uint32_t i = 0; i < 8; ++i)
      descend(
          fc + i,
          CellCoord{k.depth + 1, 2 * k.x + (i & 1), 2 * k.y + ((i >> 1) & 1), 2 * k.z + (i >> 2)},
          sid, refine);
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

  void paint_stamp(std::uint32_t sid, bool refine) {
    for_roots(stamps[sid].box,
              [&](CellIndex r, const CellCoord& k) { descend(r, k, sid, refine); });
  }

  // ---- evaluating a new cell against every stamp ----
  struct Eval {
    bool touched = false;
    int max_target = -1;
    float s = 0;
    std::uint32_t src = kNoStamp;
  };
  // The stamps that may touch the children of the cell at k (those touching the cell).
  std::vector<std::uint32_t> cand;
  void candidates(const CellCoord& k) {
    cand.clear();
    const Aabb box = geo.cell_box(k);
    index.query(k, [&](std::uint32_t id) {
      if (stamp_touches(stamps[id], box)) cand.push_back(id);
    });
    std::sort(cand.begin(), cand.end());
    cand.erase(std::unique(cand.begin(), cand.end()), cand.end());
  }
  Eval evaluate(const CellCoord& k) const {
    Eval ev;
    const Aabb box = geo.cell_box(k);
    const Vec3d centre = geo.cell_centre(k);
    for (const std::uint32_t id : cand) {
      const Stamp& s = stamps[id];
      if (!stamp_touches(s, box)) continue;
      ev.touched = true;
      ev.max_target = std::max(ev.max_target, s.depth);
      const auto v = static_cast<float>(strength_at(s, centre));
      if (v > ev.s || (v == ev.s && v > 0 && id < ev.src)) {
        ev.s = v;
        ev.src = id;
      }
    }
    return ev;
  }

  // ---- refinement ----
  Result<void> refine_balanced(CellIndex c, const CellCoord& k) {
    for (int f = 0; f < 6; ++f) {
      const CellIndex n = t.face_neighbour(c, f);
      if (n == kNoCell || !t.is_leaf(n) || t.depth(n) >= k.depth) continue;
      CellCoord nk{k.depth - 1, k.x >> 1, k.y >> 1, k.z >> 1};
      std::uint32_t* comp[3] = {&nk.x, &nk.y, &nk.z};
      *comp[f >> 1] += (f & 1) ? 1u : static_cast<std::uint32_t>(-1);
      auto r = refine_balanced(n, nk);
      if (!r) return r;
    }
    std::uint64_t created = 0;
    auto r = t.refine(c, &created);
    stats.cells_created += created;
    if (!r) return r;
    if (created != 8)
      return make_error(Errc::internal, "painter: octree balanced a refinement on its own");
    on_refined(c, k);
    return {};
  }

  void on_refined(CellIndex c, const CellCoord& k) {
    const CellIndex fc = t.first_child(c);
    queue_merge(c, k.depth);
    auto child = [&](std::uint32_t i) {
      return CellCoord{k.depth + 1, 2 * k.x + (i & 1), 2 * k.y + ((i >> 1) & 1),
                       2 * k.z + (i >> 2)};
    };
    if (marked(c)) {
      candidates(k);
      // Internal cells keep their pre-stroke value (as if refined before painting).
      const std::uint32_t pre = mp[c].pre;
      write(c, pre);
      const std::uint32_t cpre = dm::refine_rgba(pre);
      for (std::uint32_t i = 0; i < 8; ++i) {
        const CellIndex cc = fc + i;
        const CellCoord ck = child(i);
        mp[cc] = {(seq << 2) | kTouched, cpre};
        const Eval ev = evaluate(ck);
        st[cc] = {ev.s, ev.src};
        write(cc, blend(cpre, ev.s, ev.src, ck.depth));
        if (ev.touched && ck.depth < ev.max_target && can_change(cpre)) queue_refine(cc, ck);
      }
      return;
    }
    const std::uint32_t v = dm::refine_rgba(t.colour(c));
    if (one_shot) candidates(k);
    for (std::uint32_t i = 0; i < 8; ++i) {
      write(fc + i, v);
      if (one_shot) {  // the reference refines before painting: look at every new child
        const CellCoord ck = child(i);
        const Eval ev = evaluate(ck);
        if (ev.touched && ck.depth < ev.max_target && can_change(v)) queue_refine(fc + i, ck);
      }
    }
  }

  // ---- merging back ----
  void merge_one(CellIndex p, int d) {
    if (!t.is_live(p) || t.is_leaf(p)) return;
    const CellIndex fc = t.first_child(p);
    std::uint32_t ch[8];
    for (std::uint32_t i = 0; i < 8; ++i) {
      if (!t.is_leaf(fc + i)) return;
      ch[i] = t.colour(fc + i);
    }
    if (!dm::uniform(ch) || !t.can_coarsen(p)) return;
    const std::uint32_t v = dm::coarsen_rgba(ch);
    if (!t.coarsen(p)) return;
    stats.cells_freed += 8;
    write(p, v);
    if (p < t.root_count()) return;
    const CellIndex up = t.parent(p);
    queue_merge(up, d - 1);
    // p's children no longer face the children of up's neighbours: those neighbours (same depth
    // as up) may now coarsen without breaking balance, though the stroke never touched them
    // (balance refinements of earlier strokes unwind this way).
    for (int f = 0; f < 6; ++f) {
      const CellIndex n = t.face_neighbour(up, f);
      if (n != kNoCell && !t.is_leaf(n) && t.depth(n) == d - 1) queue_merge(n, d - 1);
    }
  }

  void reset_stroke() {
    active = ended = one_shot = false;
    builder = StampBuilder{};
    stamps.clear();
    carried.clear();
    index.clear();
    for (auto& l : refine_q) l = {};
    for (auto& l : merge_q) l = {};
  }

  Result<bool> step() {
    if (!active) return false;
    const std::uint64_t cap = std::max<std::uint64_t>(cfg.max_cells_per_step, 8);
    for (int d = 0; d < kLevels; ++d) {
      RefineLevel& L = refine_q[static_cast<std::size_t>(d)];
      if (L.cur >= L.q.size()) continue;
      const std::uint64_t start = stats.cells_created;
      while (L.cur < L.q.size() && stats.cells_created - start < cap) {
        const Entry e = L.q[L.cur++];
        if (!t.is_leaf(e.c)) continue;
        auto r = refine_balanced(e.c, e.k);
        if (!r) {
          reset_stroke();
          return std::move(r).error();
        }
      }
      if (L.cur >= L.q.size()) L = {};
      ++stats.steps;
      return true;
    }
    if (!ended) return false;
    for (int d = kLevels - 1; d >= 0; --d) {
      MergeLevel& M = merge_q[static_cast<std::size_t>(d)];
      if (M.cur >= M.q.size()) continue;
      if (!M.sorted) {
        std::sort(M.q.begin(), M.q.end());
        M.q.erase(std::unique(M.q.begin(), M.q.end()), M.q.end());
        M.sorted = true;
      }
      std::uint64_t n = 0;
      while (M.cur < M.q.size() && n++ < cap) merge_one(M.q[M.cur++], d);
      if (M.cur >= M.q.size()) M = {};
      ++stats.steps;
      return true;
    }
    reset_stroke();
    return false;
  }

  // ---- strokes ----
  Result<void> validate(std::span<const protocol::StrokeSample> samples) const {
    protocol::Stroke tmp;
    tmp.brush = brush;
    if (samples.empty()) {
      protocol::StrokeSample s;
      s.radius = static_cast<float>(std::max(cfg.limits.min_radius_m, 1e-3));
      tmp.samples.push_back(s);
    } else {
      tmp.samples.assign(samples.begin(), samples.end());
    }
    return protocol::validate_stroke(tmp, protocol::CanvasBounds{geo.edge_m}, cfg.limits);
  }

  Result<void> start(const protocol::Brush& b, std::uint64_t id,
                     std::span<const protocol::StrokeSample> samples) {
    if (active) return make_error(Errc::refused, "painter: a stroke is already active");
    const protocol::Brush saved = brush;
    brush = b;
    if (auto r = validate(samples); !r) {
      brush = saved;
      return r;
    }
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
  // samples); with `paint`, paints each new stamp at once. A limit error leaves the stroke as
  // it was (the builder and stamps untouched).
  Result<void> add(std::span<const protocol::StrokeSample> samples, bool paint,
                   bool finish = false) {
    if (brush.mode == BrushMode::pick_up) {
      stats.samples += samples.size();
      return {};
    }
    const std::size_t first_new = stamps.size();
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
      const auto id = static_cast<std::uint32_t>(stamps.size());
      stamps.push_back(s);
      if (brush.mode == BrushMode::smudge) {
        // The brush loads the colour under its first non-empty stamp, then picks up
        // kSmudgePickup of what is under it per radius travelled (scale-free).
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
      index.add(geo, id, s);
    }
    stats.stamps = stamps.size();
    if (paint)
      for (std::size_t id = first_new; id < stamps.size(); ++id)
        paint_stamp(static_cast<std::uint32_t>(id), true);
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

Result<void> Painter::begin_stroke(const protocol::Brush& brush, std::uint64_t stroke_id,
                                   std::span<const protocol::StrokeSample> samples) {
  Impl& m = *impl_;
  if (auto r = m.start(brush, stroke_id, samples); !r) return r;
  auto r = m.add(samples, true);
  if (!r) m.reset_stroke();  // validated already; only a stamp limit can fail here
  return r;
}

Result<void> Painter::add_samples(std::span<const protocol::StrokeSample> samples) {
  Impl& m = *impl_;
  if (!m.active || m.ended)
    return make_error(Errc::refused, "painter: no stroke is accepting samples");
  if (samples.empty()) return {};
  if (auto r = m.validate(samples); !r) return r;
  return m.add(samples, true);
}

Result<void> Painter::end_stroke() {
  Impl& m = *impl_;
  if (!m.active || m.ended) return make_error(Errc::refused, "painter: no stroke to end");
  m.ended = true;
  // The builder's held-back last sample (validated already; the stamp limit is the only error).
  return m.add({}, true, true);
}

Result<bool> Painter::step() {
  return impl_->step();
}
bool Painter::stroke_active() const noexcept {
  return impl_->active;
}

Result<StrokeStats> Painter::apply_stroke(const protocol::Stroke& stroke) {
  if (auto r = begin_stroke(stroke.brush, stroke.id, stroke.samples); !r)
    return std::move(r).error();
  (void)end_stroke();
  for (;;) {
    auto more = step();
    if (!more) return std::move(more).error();
    if (!*more) break;
  }
  return impl_->stats;
}

Result<StrokeStats> Painter::paint_one_shot(const protocol::Stroke& stroke) {
  Impl& m = *impl_;
  if (auto r = m.start(stroke.brush, stroke.id, stroke.samples); !r) return std::move(r).error();
  m.one_shot = true;
  if (auto r = m.add(stroke.samples, false, true); !r) {
    m.reset_stroke();
    return std::move(r).error();
  }
  // 1. Refine everything the stroke touches to its target depth (to a fixpoint).
  for (std::uint32_t id = 0; id < m.stamps.size(); ++id) {
    const Stamp& s = m.stamps[id];
    m.for_roots(s.box, [&](CellIndex r, const CellCoord& k) {
      auto visit = [&](auto& self, CellIndex c, const CellCoord& ck) -> void {
        if (!stamp_touches(s, m.geo.cell_box(ck))) return;
        const CellIndex fc = m.t.first_child(c);
        if (fc == kNoCell) {
          if (ck.depth < s.depth && m.can_change(m.t.colour(c))) m.queue_refine(c, ck);
          return;
        }
        for (std::uint32_t i = 0; i < 8; ++i)
          self(self, fc + i,
               CellCoord{ck.depth + 1, 2 * ck.x + (i & 1), 2 * ck.y + ((i >> 1) & 1),
                         2 * ck.z + (i >> 2)});
      };
      visit(visit, r, k);
    });
  }
  for (bool again = true; again;) {
    again = false;
    for (auto& L : m.refine_q) {
      while (L.cur < L.q.size()) {
        const Impl::Entry e = L.q[L.cur++];
        if (!m.t.is_leaf(e.c)) continue;
        auto r = m.refine_balanced(e.c, e.k);
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
  for (std::uint32_t id = 0; id < m.stamps.size(); ++id) m.paint_stamp(id, false);
  // 3. Merge back, exactly as the multi-step path does.
  m.ended = true;
  for (;;) {
    auto more = m.step();
    if (!more) return std::move(more).error();
    if (!*more) break;
  }
  return m.stats;
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
