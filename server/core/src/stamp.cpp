#include "deepcanvas/server_core/stamp.hpp"

#include <cmath>

namespace deepcanvas::server_core {

namespace {
Vec3d lerp(const Vec3d& a, const Vec3d& b, double t) {
  return {a.x + (b.x - a.x) * t, a.y + (b.y - a.y) * t, a.z + (b.z - a.z) * t};
}
}  // namespace

int target_depth(const CanvasGeometry& g, double diameter_m, double cells_across) {
  if (!(diameter_m > 0)) return g.max_depth;
  const double d = std::round(std::log2(cells_across * g.root_edge() / diameter_m));
  if (!(d > 0)) return 0;
  return d >= g.max_depth ? g.max_depth : static_cast<int>(d);
}

Result<void> append_segment_stamps(const CanvasGeometry& g, const StampParams& params,
                                   const protocol::StrokeSample& s0,
                                   const protocol::StrokeSample& s1, bool single,
                                   std::vector<Stamp>& out) {
  const Vec3d p0{s0.x, s0.y, s0.z}, p1{s1.x, s1.y, s1.z};
  const double r0 = static_cast<double>(s0.radius) * s0.pressure;
  const double r1 = single ? r0 : static_cast<double>(s1.radius) * s1.pressure;
  const Vec3d q1 = single ? p0 : p1;
  const double dx = q1.x - p0.x, dy = q1.y - p0.y, dz = q1.z - p0.z;
  const double len = std::sqrt(dx * dx + dy * dy + dz * dz);
  const double piece = params.spacing_radii * std::min(r0, r1);
  double nd = piece > 0 ? std::ceil(len / piece) : 1.0;
  if (!(nd >= 1)) nd = 1;
  if (nd > static_cast<double>(params.max_stamps) ||
      out.size() + static_cast<std::size_t>(nd) > params.max_stamps)
    return make_error(Errc::limit_exceeded, "stroke needs more than " +
                                                std::to_string(params.max_stamps) +
                                                " stamps (too long for its radius)");
  const auto n = static_cast<std::size_t>(nd);
  const double h = g.edge_m * 0.5;
  for (std::size_t i = 0; i < n; ++i) {
    const double t0 = static_cast<double>(i) / static_cast<double>(n);
    const double t1 = static_cast<double>(i + 1) / static_cast<double>(n);
    Stamp s;
    s.a = lerp(p0, q1, t0);
    s.b = lerp(p0, q1, t1);
    s.ra = r0 + (r1 - r0) * t0;
    s.rb = r0 + (r1 - r0) * t1;
    s.r_max = std::max(s.ra, s.rb);
    s.depth = target_depth(g, 2.0 * s.r_max, params.cells_across);
    auto clampc = [h](double v) { return std::clamp(v, -h, h); };
    s.box.min = {clampc(std::min(s.a.x, s.b.x) - s.r_max), clampc(std::min(s.a.y, s.b.y) - s.r_max),
                 clampc(std::min(s.a.z, s.b.z) - s.r_max)};
    s.box.max = {clampc(std::max(s.a.x, s.b.x) + s.r_max), clampc(std::max(s.a.y, s.b.y) + s.r_max),
                 clampc(std::max(s.a.z, s.b.z) + s.r_max)};
    out.push_back(s);
  }
  return {};
}

Result<void> StampBuilder::add(const CanvasGeometry& g, const StampParams& params,
                               const protocol::StrokeSample& s, std::vector<Stamp>& out,
                               std::size_t already) {
  StampParams p = params;
  p.max_stamps = params.max_stamps > already ? params.max_stamps - already : 0;
  if (!have_last_) {
    auto r = append_segment_stamps(g, p, s, s, true, out);
    if (!r) return r;
    last_ = s;
    have_last_ = true;
    return {};
  }
  const double rl = double{last_.radius} * last_.pressure, rs = double{s.radius} * s.pressure;
  const double tol = kThinning * std::min(rl, rs);
  const double dx = s.x - last_.x, dy = s.y - last_.y, dz = s.z - last_.z;
  if (dx * dx + dy * dy + dz * dz < tol * tol && std::abs(rs - rl) < tol) {
    pending_ = s;
    have_pending_ = true;
    return {};
  }
  auto r = append_segment_stamps(g, p, last_, s, false, out);
  if (!r) return r;
  last_ = s;
  have_pending_ = false;
  return {};
}

Result<void> StampBuilder::finish(const CanvasGeometry& g, const StampParams& params,
                                  std::vector<Stamp>& out, std::size_t already) {
  if (!have_pending_) return {};
  StampParams p = params;
  p.max_stamps = params.max_stamps > already ? params.max_stamps - already : 0;
  auto r = append_segment_stamps(g, p, last_, pending_, false, out);
  if (!r) return r;
  last_ = pending_;
  have_pending_ = false;
  return {};
}

Result<std::vector<Stamp>> stroke_stamps(const CanvasGeometry& g, const StampParams& params,
                                         const protocol::Stroke& stroke) {
  std::vector<Stamp> out;
  StampBuilder b;
  for (const auto& s : stroke.samples) {
    auto r = b.add(g, params, s, out);
    if (!r) return std::move(r).error();
  }
  auto r = b.finish(g, params, out);
  if (!r) return std::move(r).error();
  return out;
}

bool stamp_touches(const Stamp& s, const Aabb& box) noexcept {
  if (box.max.x < s.box.min.x || box.min.x > s.box.max.x || box.max.y < s.box.min.y ||
      box.min.y > s.box.max.y || box.max.z < s.box.min.z || box.min.z > s.box.max.z)
    return false;
  // Slab test of the axis segment against the box inflated by r_max.
  const double r = s.r_max;
  const double a[3] = {s.a.x, s.a.y, s.a.z};
  const double d[3] = {s.b.x - s.a.x, s.b.y - s.a.y, s.b.z - s.a.z};
  const double lo[3] = {box.min.x - r, box.min.y - r, box.min.z - r};
  const double hi[3] = {box.max.x + r, box.max.y + r, box.max.z + r};
  const bool sphere = d[0] == 0 && d[1] == 0 && d[2] == 0;
  // Fast accept, with the slab test's exact answer: when the axis start a lies in the inflated
  // box, every slab gives u0 <= 0 <= u1 (lo - a <= 0 <= hi - a), so t = 0 survives and a piece
  // is accepted below anyway.
  if (!sphere && lo[0] <= a[0] && a[0] <= hi[0] && lo[1] <= a[1] && a[1] <= hi[1] &&
      lo[2] <= a[2] && a[2] <= hi[2])
    return true;
  double t0 = 0, t1 = 1;
  for (int k = 0; k < 3; ++k) {
    if (d[k] == 0) {
      if (a[k] < lo[k] || a[k] > hi[k]) return false;
      continue;
    }
    double u0 = (lo[k] - a[k]) / d[k], u1 = (hi[k] - a[k]) / d[k];
    if (u0 > u1) std::swap(u0, u1);
    t0 = std::max(t0, u0);
    t1 = std::min(t1, u1);
    if (t0 > t1) return false;
  }
  // A sphere (zero-length axis) gets the exact sphere-box test; pieces keep the slab answer,
  // which may include boxes near the inflated box's corners (harmless: they are marked but get
  // no coverage).
  if (sphere) {
    double q = 0;
    const double bl[3] = {box.min.x, box.min.y, box.min.z},
                 bh[3] = {box.max.x, box.max.y, box.max.z};
    for (int k = 0; k < 3; ++k) {
      const double v = a[k] < bl[k] ? bl[k] - a[k] : a[k] > bh[k] ? a[k] - bh[k] : 0.0;
      q += v * v;
    }
    return q < r * r;
  }
  return true;
}

void StampIndex::clear() {
  buckets_.clear();
  top_mask_ = 0;
}

std::size_t StampIndex::add(const CanvasGeometry& g, std::uint32_t id, const Stamp& s) {
  std::size_t n = 0;
  const int bd = std::max(0, s.depth - 3);
  top_mask_ |= 1u << bd;
  const double h = g.edge_m * 0.5;
  for (int b = bd;; b = std::max(0, b - 3)) {
    const double e = g.cell_edge(b);
    const double lim = static_cast<double>(std::uint64_t{g.roots_per_axis} << b) - 1.0;
    auto idx = [&](double v) {
      return static_cast<std::uint32_t>(std::clamp(std::floor((v + h) / e), 0.0, lim));
    };
    const std::uint32_t x0 = idx(s.box.min.x), x1 = idx(s.box.max.x);
    const std::uint32_t y0 = idx(s.box.min.y), y1 = idx(s.box.max.y);
    const std::uint32_t z0 = idx(s.box.min.z), z1 = idx(s.box.max.z);
    for (std::uint32_t z = z0; z <= z1; ++z)
      for (std::uint32_t y = y0; y <= y1; ++y)
        for (std::uint32_t x = x0; x <= x1; ++x) {
          auto& v = buckets_[Key{x, y, z, b}];
          ++n;
          // Consecutive stamps share buckets: skip a repeat of the last id.
          if (v.empty() || v.back() != id) v.push_back(id);
        }
    if (b == 0) break;
  }
  return n;
}

}  // namespace deepcanvas::server_core
