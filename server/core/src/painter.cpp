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

Result<void> Painter::Impl::start(const protocol::Brush& b, std::uint64_t id,
                                  std::span<const protocol::StrokeSample> samples) {
  if (active) return make_error(Errc::refused, "painter: a stroke is already active");
  brush = b;
  if (stroke_seq >= kMaxSeq) {
    mark_pre_pool->clear();
    strength_pool->clear();
    stroke_seq = 0;
  }
  ++stroke_seq;
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

Result<PickResult> Painter::Impl::pick(const Vec3d& p) const {
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

Painter::Painter(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Painter::~Painter() = default;

Result<std::unique_ptr<Painter>> Painter::create(Octree& tree, const PainterConfig& config) {
  if (!(config.capacity_reserve >= 0.0 && config.capacity_reserve <= 0.5))
    return make_error(Errc::invalid_argument, "painter: capacity_reserve must be in [0, 0.5]");
  auto impl = std::make_unique<Impl>(tree, config);
  const std::uint64_t max_cells = tree.config().max_cells;
  impl->growth_cap =
      max_cells - static_cast<std::uint64_t>(static_cast<double>(max_cells) * config.capacity_reserve);
  auto a = tree.add_field_pool("paint.mark_pre", 8);
  if (!a) return std::move(a).error();
  auto b = tree.add_field_pool("paint.strength", 8);
  if (!b) return std::move(b).error();
  impl->mark_pre_pool = std::move(*a);
  impl->strength_pool = std::move(*b);
  impl->mark_pre = impl->mark_pre_pool->as<MarkPre>();
  impl->strength = impl->strength_pool->as<StrengthSrc>();
  return std::unique_ptr<Painter>(new Painter(std::move(impl)));
}

protocol::StrokeRules Painter::stroke_rules() const noexcept {
  return protocol::StrokeRules{protocol::CanvasBounds{impl_->geo.edge_m}, impl_->config.limits};
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
  return impl_->step(impl_->config.max_cells_per_step);
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
  for (const auto& L : m.refine_levels)
    if (L.next < L.queue.size()) return false;
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
      const CellIndex fc = m.tree.first_child(v.c);
      if (fc == kNoCell) {
        if (v.k.depth < s.depth && m.can_change(m.tree.colour(v.c))) m.queue_refine(v.c, v.k);
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
    for (auto& L : m.refine_levels) {
      while (L.next < L.queue.size()) {
        const Impl::Entry e = L.queue[L.next++];
        if (!m.tree.is_leaf(e.c)) continue;
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
    auto more = m.step(m.config.max_cells_per_step);
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
