#include "deepcanvas/server_core/painter.hpp"

#include "painter_impl.hpp"

namespace deepcanvas::server_core {

void Painter::Impl::reset_stroke() {
  active = ended = one_shot = false;
  builder = StampBuilder{};
  sample_box = {};
  stamps.clear();
  carried.clear();
  index.clear();
  indexed = 0;
  paint_next = 0;
  paint_stack.clear();
  for (auto& l : refine_levels) l = {};
  for (auto& l : merge_levels) l = {};
}

Result<bool> Painter::Impl::step(std::uint64_t max_work) {
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
  if (!did && ended) merge_some(work, cap, did);
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

void Painter::Impl::start(const protocol::Brush& b, std::uint64_t id) {
  brush = b;
  reset_stroke();
  seqs.clear();  // the caller gives the first (Shared::open_stroke); close() still needs them
  stroke_seq = 0;
  active = true;
  stroke_id = id;
  stats = {};
  recorder.clear();
  brush_density = double{b.colour[3]} * b.opacity;
  full_log = brush_density < 1.0 ? -std::log1p(-brush_density) : INFINITY;
  carry = {b.colour[0], b.colour[1], b.colour[2]};
  carry_loaded = false;
}

Result<void> Painter::Impl::add(std::span<const protocol::StrokeSample> samples, bool finish) {
  if (brush.mode == BrushMode::pick_up) {
    stats.samples += samples.size();
    return {};
  }
  protocol::SampleBox grown = sample_box;
  grown.add(samples);
  if (auto r = protocol::check_extent(grown, config.limits); !r) return r;
  std::vector<Stamp> fresh;
  StampBuilder b = builder;
  for (const auto& s : samples) {
    auto r = b.add(geo, config.stamps, s, fresh, stamps.size() + fresh.size());
    if (!r) return r;
  }
  if (finish) {
    auto r = b.finish(geo, config.stamps, fresh, stamps.size() + fresh.size());
    if (!r) return r;
  }
  builder = b;
  sample_box = grown;
  stats.samples += samples.size();
  for (const Stamp& s : fresh) {
    stamps.push_back(s);
    if (brush.mode == BrushMode::smudge) {
      // The brush loads the colour under its first non-empty stamp, then picks up
      // kSmudgePickup of what is under it per radius travelled (scale-free). The pre-stroke
      // colour there does not depend on how far painting has got: a touched cell keeps it in
      // `pre`, an untouched leaf still holds it, and refinement keeps rgb.
      auto loc = tree.locate(s.a, geo.max_depth);
      if (loc) {
        const CellIndex c = loc->cell;
        const std::uint32_t v = marked(c) ? mark_pre[c].pre : tree.colour(c);
        if ((v >> 24) != 0) {
          const double dx = s.b.x - s.a.x, dy = s.b.y - s.a.y, dz = s.b.z - s.a.z;
          const double travel = std::sqrt(dx * dx + dy * dy + dz * dz) / s.r_max;
          const float m =
              carry_loaded ? static_cast<float>(1.0 - std::pow(1.0 - kSmudgePickup, travel)) : 1.0f;
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

namespace {
Result<PickResult> pick_in(const Octree& tree, const CanvasGeometry& geo, const Vec3d& p) {
  auto loc = tree.locate(p, geo.max_depth);
  if (!loc) return std::move(loc).error();
  PickResult r;
  r.cell = loc->cell;
  r.depth = loc->coord.depth;
  r.cell_edge_m = geo.cell_edge(r.depth);
  const dm::Rgba8 c = dm::unpack(tree.colour(r.cell));
  r.rgb[0] = c.r / 255.0f;
  r.rgb[1] = c.g / 255.0f;
  r.rgb[2] = c.b / 255.0f;
  r.alpha = c.a / 255.0f;
  r.sigma_per_m = c.a == 255 ? INFINITY : dm::sigma_per_m(c.a / 255.0, r.cell_edge_m);
  return r;
}
}  // namespace

Result<PickResult> Painter::Impl::pick(const Vec3d& p) const {
  return pick_in(tree, geo, p);
}

// The canvas's side of the painter: the tree, the temporary pools every stroke shares, and the
// open strokes (at most one busy: painter.hpp, "Concurrent strokes").
Result<Painter::Impl*> Painter::Shared::open_stroke(const protocol::Brush& brush,
                                                    std::uint64_t id) {
  if (auto r = may_give_work(nullptr); !r) return std::move(r).error();
  if (find(id) != nullptr)
    return make_error(Errc::refused, "painter: stroke " + std::to_string(id) + " is already open");
  if (last_seq >= kMaxSeq - kTurnSeqHeadroom) {
    // The pools' marks are cleared once every 2^29 strokes, when no stroke holds marks.
    if (!open.empty())
      return make_error(Errc::refused,
                        "painter: stroke sequence numbers wrap: open strokes must end first");
    mark_pre_pool->clear();
    strength_pool->clear();
    last_seq = 0;
  }
  std::unique_ptr<Impl> s;
  if (!spare.empty()) {
    s = std::move(spare.back());
    spare.pop_back();
  } else {
    s = std::make_unique<Impl>(tree, config);
    s->mark_pre = mark_pre_pool->as<MarkPre>();
    s->strength = strength_pool->as<StrengthSrc>();
    s->growth_cap = growth_cap;
    s->open_seqs = &open_seqs;
    s->recorder = CellDiffRecorder(diff_slot_pool->as<std::uint32_t>(),
                                   CellDiffRecorder::kDefaultMaxRecords, &recording_budget);
  }
  s->rec = config.record_diffs ? &s->recorder : nullptr;
  s->start(brush, id);
  s->stroke_seq = ++last_seq;
  s->seqs.push_back({s->stroke_seq, 0});
  open_seqs.push_back(s->stroke_seq);
  last_worker = s.get();
  open.push_back(std::move(s));
  return open.back().get();
}

void Painter::Shared::turn_sequence(Impl& s) {
  if (last_worker == &s) return;
  last_worker = &s;
  // Past the headroom (2^20 interrupted turns of strokes open across the wrap) the stroke keeps
  // its sequence: refinements then may weigh its earlier stamps where another stroke took cells.
  if (last_seq >= kMaxSeq) return;
  s.stroke_seq = ++last_seq;
  s.seqs.push_back({s.stroke_seq, static_cast<std::uint32_t>(s.stamps.size())});
  open_seqs.push_back(s.stroke_seq);
}

void Painter::Shared::close(Impl* s) {
  if (busy == s) busy = nullptr;
  for (std::size_t i = 0; i < open.size(); ++i) {
    if (open[i].get() != s) continue;
    if (s->rec != nullptr) {
      finished_diffs.insert_or_assign(s->stroke_id, std::move(s->recorder));
      s->recorder = CellDiffRecorder(diff_slot_pool->as<std::uint32_t>(),
                                     CellDiffRecorder::kDefaultMaxRecords, &recording_budget);
      s->rec = &s->recorder;
    }
    std::erase_if(open_seqs, [&](std::uint32_t q) { return s->own_seq(q); });
    s->reset_stroke();
    if (last_worker == s) last_worker = nullptr;
    if (spare.size() < 4) spare.push_back(std::move(open[i]));
    open.erase(open.begin() + static_cast<std::ptrdiff_t>(i));
    return;
  }
}

Painter::Painter(std::unique_ptr<Shared> shared) : shared_(std::move(shared)) {}
Painter::~Painter() = default;

Result<std::unique_ptr<Painter>> Painter::create(Octree& tree, const PainterConfig& config) {
  if (!(config.capacity_reserve >= 0.0 && config.capacity_reserve <= 0.5))
    return make_error(Errc::invalid_argument, "painter: capacity_reserve must be in [0, 0.5]");
  auto sh = std::make_unique<Shared>(tree, config);
  const std::uint64_t max_cells = tree.config().max_cells;
  sh->growth_cap = max_cells - static_cast<std::uint64_t>(static_cast<double>(max_cells) *
                                                          config.capacity_reserve);
  auto a = tree.add_field_pool("paint.mark_pre", 8);
  if (!a) return std::move(a).error();
  auto b = tree.add_field_pool("paint.strength", 8);
  if (!b) return std::move(b).error();
  auto c = tree.add_field_pool("paint.diff_slot", 4);
  if (!c) return std::move(c).error();
  sh->mark_pre_pool = std::move(*a);
  sh->strength_pool = std::move(*b);
  sh->diff_slot_pool = std::move(*c);
  return std::unique_ptr<Painter>(new Painter(std::move(sh)));
}

void Painter::set_record_diffs(bool on) noexcept {
  shared_->config.record_diffs = on;
}

const CellDiffBudget& Painter::recording_budget() const noexcept {
  return shared_->recording_budget;
}

const OctreeConfig& Painter::octree_config() const noexcept {
  return shared_->tree.config();
}

protocol::StrokeRules Painter::stroke_rules() const noexcept {
  return protocol::StrokeRules{
      protocol::CanvasBounds{CanvasGeometry::of(shared_->tree.config()).edge_m},
      shared_->config.limits};
}

Result<void> Painter::begin_stroke(const protocol::ValidatedBrush& brush, std::uint64_t stroke_id,
                                   const protocol::ValidatedSamples& samples) {
  Shared& sh = *shared_;
  auto opened = sh.open_stroke(brush.get(), stroke_id);
  if (!opened) return std::move(opened).error();
  Impl& m = **opened;
  if (brush.get().mode == BrushMode::pick_up) {
    sh.picked.reset();
    if (!samples.empty()) {
      const auto& p = samples.span()[0];
      if (auto r = m.pick(Vec3d{p.x, p.y, p.z}); r) sh.picked = *r;
    }
  }
  auto r = m.add(samples.span());
  sh.last_stats = m.stats;
  if (!r) {
    sh.close(&m);  // only a stamp limit can fail here
    return r;
  }
  sh.busy = &m;
  return r;
}

Result<void> Painter::add_samples(std::uint64_t stroke_id,
                                  const protocol::ValidatedSamples& samples) {
  Shared& sh = *shared_;
  Impl* m = sh.find(stroke_id);
  if (m == nullptr || m->ended)
    return make_error(Errc::refused,
                      "painter: stroke " + std::to_string(stroke_id) + " is not accepting samples");
  if (auto r = sh.may_give_work(m); !r) return r;
  if (samples.empty()) return {};
  sh.turn_sequence(*m);
  auto r = m->add(samples.span());
  sh.last_stats = m->stats;
  if (r) sh.busy = m;
  return r;
}

Result<void> Painter::end_stroke(std::uint64_t stroke_id) {
  Shared& sh = *shared_;
  Impl* m = sh.find(stroke_id);
  if (m == nullptr || m->ended)
    return make_error(Errc::refused,
                      "painter: no open stroke " + std::to_string(stroke_id) + " to end");
  if (auto r = sh.may_give_work(m); !r) return r;
  m->ended = true;
  sh.busy = m;
  sh.turn_sequence(*m);
  // The builder's held-back last sample (validated already; the stamp limit is the only error).
  auto r = m->add({}, true);
  sh.last_stats = m->stats;
  return r;
}

namespace {
Result<std::uint64_t> only_open(const std::vector<std::uint64_t>& ids) {
  if (ids.size() != 1)
    return make_error(Errc::refused, "painter: " + std::to_string(ids.size()) +
                                         " strokes are open: name the stroke");
  return ids[0];
}
}  // namespace

Result<void> Painter::add_samples(const protocol::ValidatedSamples& samples) {
  std::vector<std::uint64_t> ids;
  for (const auto& s : shared_->open) ids.push_back(s->stroke_id);
  auto id = only_open(ids);
  if (!id) return std::move(id).error();
  return add_samples(*id, samples);
}

Result<void> Painter::end_stroke() {
  std::vector<std::uint64_t> ids;
  for (const auto& s : shared_->open) ids.push_back(s->stroke_id);
  auto id = only_open(ids);
  if (!id) return std::move(id).error();
  return end_stroke(*id);
}

Result<bool> Painter::step() {
  return step(shared_->config.max_cells_per_step);
}
Result<bool> Painter::step(std::uint64_t max_work) {
  Shared& sh = *shared_;
  Impl* m = sh.busy;
  if (m == nullptr) return false;
  auto r = m->step(max_work);
  sh.last_stats = m->stats;
  if (!r || !*r) {
    sh.busy = nullptr;
    if (!m->active) sh.close(m);  // finished, or stopped by the error
  }
  return r;
}
bool Painter::stroke_active() const noexcept {
  return !shared_->open.empty();
}
bool Painter::stroke_open(std::uint64_t stroke_id) const noexcept {
  return shared_->find(stroke_id) != nullptr;
}
std::size_t Painter::open_strokes() const noexcept {
  return shared_->open.size();
}
std::optional<std::uint64_t> Painter::busy_stroke() const noexcept {
  if (shared_->busy == nullptr) return std::nullopt;
  return shared_->busy->stroke_id;
}
bool Painter::stroke_painted() const noexcept {
  const Impl* m = shared_->busy;
  if (m == nullptr || !m->ended || m->paint_pending()) return false;
  for (const auto& L : m->refine_levels)
    if (L.next < L.queue.size()) return false;
  return true;
}

Result<StrokeStats> Painter::apply_stroke(const protocol::ValidatedStroke& stroke) {
  if (auto r = begin_stroke(stroke.brush(), stroke.id(), stroke.samples()); !r)
    return std::move(r).error();
  (void)end_stroke(stroke.id());
  for (;;) {
    auto more = step();
    if (!more) return std::move(more).error();
    if (!*more) break;
  }
  return shared_->last_stats;
}

Result<StrokeStats> Painter::paint_one_shot(const protocol::ValidatedStroke& stroke) {
  Shared& sh = *shared_;
  auto opened = sh.open_stroke(stroke.brush().get(), stroke.id());
  if (!opened) return std::move(opened).error();
  Impl& m = **opened;
  m.one_shot = true;
  if (auto r = m.add(stroke.samples().span(), true); !r) {
    sh.close(&m);
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
      const CellIndex fc = m.tree.first_child(v.c);
      if (fc == kNoCell) {
        if (v.k.depth < s.depth && m.can_change(m.tree.colour(v.c))) m.queue_refine(v.c, v.k);
        continue;
      }
      for (std::uint32_t i = 8; i-- > 0;) {
        const CellCoord ck = child_coord(v.k, i);
        if (stamp_touches(s, m.geo.cell_box(ck))) stack.push_back({fc + i, ck});
      }
    }
  }
  for (bool again = true; again;) {
    again = false;
    for (auto& L : m.refine_levels) {
      while (L.next < L.queue.size()) {
        const Impl::Entry e = L.queue[L.next++];
        if (!m.tree.is_leaf(e.c)) continue;
        std::uint64_t work = 0;
        auto r = m.refine_balanced(e.c, e.k, work, kUnbounded);
        if (!r) {
          sh.last_stats = m.stats;
          sh.close(&m);
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
  sh.busy = &m;
  for (;;) {
    auto more = step(m.config.max_cells_per_step);
    if (!more) return std::move(more).error();
    if (!*more) break;
  }
  return sh.last_stats;
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

Result<void> Painter::add_samples(std::uint64_t stroke_id,
                                  std::span<const protocol::StrokeSample> samples) {
  auto s = protocol::ValidatedSamples::make({samples.begin(), samples.end()}, stroke_rules());
  if (!s) return std::move(s).error();
  return add_samples(stroke_id, *s);
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
  return pick_in(shared_->tree, CanvasGeometry::of(shared_->tree.config()), p);
}
const std::optional<PickResult>& Painter::last_pick() const noexcept {
  return shared_->picked;
}
const StrokeStats& Painter::stroke_stats() const noexcept {
  return shared_->last_stats;
}

}  // namespace deepcanvas::server_core
