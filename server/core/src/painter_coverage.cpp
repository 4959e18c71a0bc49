// Painting stamps on the leaves the tree has: the candidate stamps from the index, one leaf's
// strength and blended colour, and the resumable depth-first descent of paint_some().
#include "painter_impl.hpp"

namespace deepcanvas::server_core {

void Painter::Impl::collect_candidates(const CellCoord& k) {
  candidate_ids.clear();
  if (candidate_seen.size() < indexed) candidate_seen.resize(indexed, 0u);
  if (++candidate_gen == 0) {
    std::fill(candidate_seen.begin(), candidate_seen.end(), 0u);
    candidate_gen = 1;
  }
  const Aabb box = geo.cell_box(k);
  index.query(k, [&](std::uint32_t id) {
    if (candidate_seen[id] == candidate_gen) return;
    candidate_seen[id] = candidate_gen;
    const Aabb& b = stamps[id].box;
    if (box.max.x < b.min.x || box.min.x > b.max.x || box.max.y < b.min.y || box.min.y > b.max.y ||
        box.max.z < b.min.z || box.min.z > b.max.z)
      return;
    candidate_ids.push_back(id);
  });
}

void Painter::Impl::touch_leaf(CellIndex c, const CellCoord& k, std::uint32_t sid, bool refine,
                               bool core) {
  const Stamp& s = stamps[sid];
  if (!marked(c)) {
    // First touched in this turn: the turn's sequence says from which stamp on this stroke
    // counts here (Impl::TurnSeq); flags the stroke set on the cell stay.
    const std::uint32_t flags = this_stroke(c) ? (mark_pre[c].mark & (kQueued | kMergeQueued)) : 0u;
    mark_pre[c].mark = (stroke_seq << kSeqShift) | flags | kTouched;
    mark_pre[c].pre = tree.colour(c);
    strength[c] = {0.0f, kNoStamp};
    if (c >= tree.root_count()) queue_merge(tree.parent(c), k.depth - 1);
  }
  StrengthSrc& x = strength[c];
  // Saturated: no v <= paint_bound beats x (v > x.s, or a tie won by a lower id) when
  // x.s > paint_bound, or x.s == paint_bound from a stamp no later than this one.
  if (!(x.s > paint_bound || (x.s == paint_bound && x.src <= sid))) {
    // v = 0 (no coverage, or surely weaker) never wins below.
    float v = paint_core_strength;
    if (!core) {
      const StampHit hit = stamp_coverage(s, geo.cell_centre(k), brush.hardness);
      const bool weaker = config.exact_shortcuts && hit.coverage > 0 && surely_weaker(hit, x.s);
      v = hit.coverage > 0 && !weaker ? static_cast<float>(strength_of(hit)) : 0.0f;
    }
    if (v > x.s || (v == x.s && v > 0 && sid < x.src)) {
      x = {v, sid};
      write(c, k, blend(mark_pre[c].pre, x.s, x.src, k.depth));
    }
  }
  if (refine && k.depth < s.depth && can_change(mark_pre[c].pre)) queue_refine(c, k);
}

void Painter::Impl::push_start(std::uint32_t sid, std::vector<Entry>& stack) const {
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
    const LocateResult r = tree.find(bk);
    if (stamp_touches(s, geo.cell_box(r.coord))) stack.push_back({r.cell, r.coord});
    return;
  }
  const std::size_t first = stack.size();
  for_roots(s.box, [&](CellIndex r, const CellCoord& k) {
    if (stamp_touches(s, geo.cell_box(k))) stack.push_back({r, k});
  });
  std::reverse(stack.begin() + static_cast<std::ptrdiff_t>(first), stack.end());
}

std::uint64_t Painter::Impl::paint_some(std::uint64_t budget, bool refine) {
  std::uint64_t work = 0;
  while (work < budget) {
    if (paint_stack.empty()) {
      if (paint_next >= stamps.size()) break;
      paint_stamp = static_cast<std::uint32_t>(paint_next++);
      // A stamp enters the index when its painting starts: refinement (which evaluates new
      // children against the index) runs only once every stamp has been started.
      work += 1 + index_up_to(paint_next);
      start_stamp(stamps[paint_stamp]);
      push_start(paint_stamp, paint_stack);
      continue;
    }
    // Entries on the stack touch the stamp (tested before they were pushed, so that cells
    // that do not never enter the stack).
    const Entry v = paint_stack.back();
    paint_stack.pop_back();
    ++work;
    const CellIndex fc = tree.first_child(v.c);
    if (fc == kNoCell) {
      touch_leaf(v.c, v.k, paint_stamp, refine, (v.flags & kCore) != 0);
      continue;
    }
    const Stamp& s = stamps[paint_stamp];
    work += 8;
    const int cd = v.k.depth + 1;
    std::uint32_t flags = v.flags;
    if (paint_inside_r > 0 && (!(flags & kInside) || (!(flags & kCore) && paint_core_r > 0))) {
      // Every point of v's box lies within reach: its centre's distance to the axis plus
      // its half diagonal. Then every child touches (no box tests below v) and, within
      // paint_core_r, has coverage 1 at every point.
      const double reach =
          std::sqrt(axis_dist2(s, geo.cell_centre(v.k))) + kHalfDiagonal * geo.cell_edge(v.k.depth);
      if (reach <= paint_inside_r) flags = kInside | (reach <= paint_core_r ? kCore : 0u);
    }
    if (flags & kInside) {
      std::size_t n = paint_stack.size();
      paint_stack.resize(n + 8);
      Entry* out = paint_stack.data() + n;
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
    std::size_t n = paint_stack.size();
    paint_stack.resize(n + 8);  // capacity stays after the first strokes: no allocation here
    Entry* out = paint_stack.data();
    for (std::uint32_t i = 8; i-- > 0;) {
      const std::uint32_t bx = i & 1, by = (i >> 1) & 1, bz = i >> 2;
      const Aabb cb{{px[bx], py[by], pz[bz]}, {px[bx + 1], py[by + 1], pz[bz + 1]}};
      if (stamp_touches(s, cb))
        out[n++] = {fc + i, CellCoord{cd, 2 * v.k.x + bx, 2 * v.k.y + by, 2 * v.k.z + bz}};
    }
    paint_stack.resize(n);
  }
  return work;
}

}  // namespace deepcanvas::server_core
