// Tree adjustment: refining queued leaves one level per step, coarser face neighbours first
// (2:1 balance), and evaluating the new children against the stroke's stamps.
#include "painter_impl.hpp"

namespace deepcanvas::server_core {

Result<bool> Painter::Impl::refine_balanced(CellIndex c, const CellCoord& k, std::uint64_t& work,
                                            std::uint64_t cap) {
  for (int f = 0; f < 6; ++f) {
    const CellIndex n = tree.face_neighbour(c, f);
    if (n == kNoCell || !tree.is_leaf(n) || tree.depth(n) >= k.depth) continue;
    CellCoord nk = parent_coord(k);
    std::uint32_t* comp[3] = {&nk.x, &nk.y, &nk.z};
    *comp[f >> 1] += (f & 1) ? 1u : static_cast<std::uint32_t>(-1);
    auto r = refine_balanced(n, nk, work, cap);
    if (!r || !*r) return r;
  }
  if (work >= cap) return false;
  if (auto g = may_grow(); !g) return std::move(g).error();
  std::uint64_t created = 0;
  const std::uint32_t colour = tree.colour(c);
  auto r = tree.refine(c, &created);
  stats.cells_created += created;
  work += created;
  if (!r) return std::move(r).error();
  if (created != 8)
    return make_error(Errc::internal, "painter: octree balanced a refinement on its own");
  if (rec != nullptr)  // the children inherit c's colour
    rec->refine(c, k, colour, colour, tree.first_child(c));
  on_refined(c, k);
  return true;
}

Result<void> Painter::Impl::may_grow() const {
  const std::uint64_t limit = config.limits.max_stroke_cells;
  if (stats.cells_created + 8 > limit)
    return make_error(Errc::limit_exceeded,
                      "stroke created " + std::to_string(stats.cells_created) +
                          " cells: the limit is " + std::to_string(limit) +
                          " (max_stroke_cells); it was stopped, the canvas keeps what it painted");
  const std::uint64_t max_cells = tree.config().max_cells;
  const std::uint64_t cap = brush.mode == BrushMode::erase ? max_cells : growth_cap;
  if (tree.live_cells() + 8 > cap)
    return make_error(Errc::out_of_memory,
                      "canvas capacity: " + std::to_string(tree.live_cells()) + " of " +
                          std::to_string(max_cells) + " cells in use, the last " +
                          std::to_string(max_cells - growth_cap) +
                          " are kept for erasing; the stroke was stopped, the canvas keeps what "
                          "it painted");
  return {};
}

void Painter::Impl::on_refined(CellIndex c, const CellCoord& k) {
  const CellIndex fc = tree.first_child(c);
  queue_merge(c, k.depth);
  if (marked(c)) {
    // The stamps that count at c: those from the turn that first touched it (Impl::TurnSeq).
    const std::uint32_t seq = mark_pre[c].mark >> kSeqShift;
    const std::uint32_t first_stamp = first_stamp_of(seq);
    collect_candidates(k);
    // Internal cells keep their pre-stroke value (as if refined before painting).
    const std::uint32_t pre = mark_pre[c].pre;
    write(c, k, pre);
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
    for (const std::uint32_t id : candidate_ids) {
      if (id < first_stamp) continue;
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
      mark_pre[cc] = {(seq << kSeqShift) | kTouched, cpre};
      strength[cc] = {best[i], src[i]};
      write(cc, ck[i], blend(cpre, best[i], src[i], cd));
      if (refine_mask & (1u << i)) queue_refine(cc, ck[i]);
    }
    return;
  }
  const std::uint32_t v = dm::refine_rgba(tree.colour(c));
  for (std::uint32_t i = 0; i < 8; ++i) write(fc + i, child_coord(k, i), v);
  if (one_shot && can_change(v)) {  // the reference refines before painting: every new child
    collect_candidates(k);
    for (std::uint32_t i = 0; i < 8; ++i) {
      const CellCoord ck = child_coord(k, i);
      const Aabb cbox = geo.cell_box(ck);
      for (const std::uint32_t id : candidate_ids) {
        const Stamp& s = stamps[id];
        if (s.depth > ck.depth && stamp_touches(s, cbox)) {
          queue_refine(fc + i, ck);
          break;
        }
      }
    }
  }
}

bool Painter::Impl::refine_some(std::uint64_t& work, std::uint64_t cap, bool& did, Error& err) {
  for (int d = 0; d < kLevels; ++d) {
    RefineLevel& L = refine_levels[static_cast<std::size_t>(d)];
    if (L.next >= L.queue.size()) continue;
    did = true;
    while (L.next < L.queue.size() && work < cap) {
      const Entry e = L.queue[L.next];
      if (!tree.is_leaf(e.c)) {
        ++L.next;
        ++work;
        continue;
      }
      auto r = refine_balanced(e.c, e.k, work, cap);
      if (!r) {
        err = std::move(r).error();
        return false;
      }
      if (!*r) break;  // the budget ran out inside e's balance chain: go on next step
      ++L.next;
    }
    if (L.next >= L.queue.size()) L = {};
    break;
  }
  return true;
}

}  // namespace deepcanvas::server_core
