// The stamp rasterizer: how a stroke becomes cells. Shared by the painter and by benchmarks that
// paint the same strokes into other structures (OpenVDB), so the geometry lives here, free of any
// tree state.
//
// A stroke's consecutive samples form capsule segments whose radius (sample radius * pressure)
// varies linearly from one sample to the next. Each segment is cut into stamps: short capsule
// pieces no longer than `spacing_radii` times the smaller end radius, so the radius changes little
// along a stamp and stamps overlap generously. Every stroke also gets one spherical stamp at its
// first sample (so a one-sample stroke is a sphere, and streamed strokes get the same stamps).
//
// Coverage of a point p by a stamp: project p onto the stamp's axis (clamped to the piece), take
// the local radius r there and u = |p - axis point| / r; coverage = falloff(u, hardness): 1 inside
// u <= hardness, smoothstep down to 0 at u = 1 (hardness 1 is a hard edge).
//
// Adaptive resolution: a stamp is painted at the depth whose cell edge puts about
// `cells_across` (10) cells across its diameter: depth = round(log2(cells_across * root_edge /
// diameter)), clamped to the tree's depth range; so between ~7 and ~14 cells across.
//
// Threading: pure functions and plain data; StampIndex is not thread-safe for writes.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <type_traits>
#include <unordered_map>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::server_core {

struct StampParams {
  double cells_across = 10.0;         // cells across a stamp's diameter at its target depth
  double spacing_radii = 1.0;         // stamp length, in units of the smaller end radius
  std::size_t max_stamps = 1u << 20;  // per stroke; more is limit_exceeded
};

struct Stamp {
  Vec3d a, b;             // axis end points (equal for a sphere)
  double ra = 0, rb = 0;  // radius at a and at b
  double r_max = 0;
  int depth = 0;  // target depth
  Aabb box;       // bounding box (clamped to the canvas)
};

// Canvas geometry the rasterizer needs (from an OctreeConfig).
struct CanvasGeometry {
  std::uint32_t roots_per_axis = 4;
  double edge_m = 20000.0;
  int max_depth = 24;
  double edges[kMaxSupportedDepth + 1] = {};  // cell edge per depth
  static CanvasGeometry of(const OctreeConfig& c) {
    CanvasGeometry g;
    g.roots_per_axis = c.roots_per_axis;
    g.edge_m = c.edge_m;
    g.max_depth = c.max_depth;
    for (int d = 0; d <= kMaxSupportedDepth; ++d) g.edges[d] = std::ldexp(g.root_edge(), -d);
    return g;
  }
  double root_edge() const { return edge_m / roots_per_axis; }
  double cell_edge(int depth) const { return edges[depth]; }  // root_edge * 2^-depth
  // Inline (hot in the painter).
  Aabb cell_box(const CellCoord& c) const {
    const double e = cell_edge(c.depth);
    const double h = edge_m * 0.5;
    return {{-h + c.x * e, -h + c.y * e, -h + c.z * e},
            {-h + (c.x + 1.0) * e, -h + (c.y + 1.0) * e, -h + (c.z + 1.0) * e}};
  }
  Vec3d cell_centre(const CellCoord& c) const {
    const double e = cell_edge(c.depth);
    const double h = edge_m * 0.5;
    return {-h + (c.x + 0.5) * e, -h + (c.y + 0.5) * e, -h + (c.z + 0.5) * e};
  }
};

int target_depth(const CanvasGeometry& g, double diameter_m, double cells_across);

// Appends the stamps of the segment s0 -> s1 (or of the single sample s0 when `single`).
// limit_exceeded when `out` would exceed params.max_stamps.
Result<void> append_segment_stamps(const CanvasGeometry& g, const StampParams& params,
                                   const protocol::StrokeSample& s0,
                                   const protocol::StrokeSample& s1, bool single,
                                   std::vector<Stamp>& out);
// Turns a stream of samples into stamps: a sphere at the first sample, then segments. Samples
// that stay within kThinning of the last used sample's stamp radius, in both position and
// radius, are held back (a controller at rest reports many nearly equal samples; each would
// repaint the same cells): they only move the segment's end, and the last held-back sample is
// flushed by finish(). The coverage lost is at most ~2 kThinning radii (about one cell).
class StampBuilder {
 public:
  static constexpr double kThinning = 0.1;
  Result<void> add(const CanvasGeometry& g, const StampParams& params,
                   const protocol::StrokeSample& s, std::vector<Stamp>& out,
                   std::size_t already = 0);
  Result<void> finish(const CanvasGeometry& g, const StampParams& params, std::vector<Stamp>& out,
                      std::size_t already = 0);

 private:
  bool have_last_ = false, have_pending_ = false;
  protocol::StrokeSample last_, pending_;
};

// All stamps of a stroke, in order (a StampBuilder over all samples).
Result<std::vector<Stamp>> stroke_stamps(const CanvasGeometry& g, const StampParams& params,
                                         const protocol::Stroke& stroke);

struct StampHit {
  double coverage = 0;  // 0..1
  double diameter = 0;  // local diameter at the projection point (metres)
};
// Inline: the painter evaluates these millions of times per second.
inline double falloff(double u, double hardness) noexcept {
  if (!(u < 1.0)) return 0.0;
  if (u <= hardness) return 1.0;
  const double x = (u - hardness) / (1.0 - hardness);
  return 1.0 - x * x * (3.0 - 2.0 * x);
}

inline StampHit stamp_coverage(const Stamp& s, const Vec3d& p, double hardness) noexcept {
  const double ax = s.b.x - s.a.x, ay = s.b.y - s.a.y, az = s.b.z - s.a.z;
  const double l2 = ax * ax + ay * ay + az * az;
  double t = 0;
  if (l2 > 0) {
    t = ((p.x - s.a.x) * ax + (p.y - s.a.y) * ay + (p.z - s.a.z) * az) / l2;
    t = std::clamp(t, 0.0, 1.0);
  }
  const double cx = s.a.x + ax * t - p.x, cy = s.a.y + ay * t - p.y, cz = s.a.z + az * t - p.z;
  const double r = s.ra + (s.rb - s.ra) * t;
  const double d2 = cx * cx + cy * cy + cz * cz;
  StampHit h;
  h.diameter = 2.0 * r;
  if (d2 >= r * r) return h;
  h.coverage = falloff(std::sqrt(d2) / r, hardness);
  return h;
}

// Conservative: true for every box the capsule intersects (and for some boxes within r_max of the
// axis near their corners). Used to decide which cells a stamp touches (marks, refines).
bool stamp_touches(const Stamp& s, const Aabb& box) noexcept;

// The cubes a stamp paints at `depth` (usually s.depth): calls f(CellCoord, coverage) for every
// cell at that depth whose centre has coverage > 0. This is what a flat/sparse grid at that
// resolution would store for the stamp. f may take the whole StampHit (coverage and local
// diameter) instead of the coverage: f(CellCoord, const StampHit&).
template <class F>
void for_each_stamp_cell(const CanvasGeometry& g, const Stamp& s, int depth, double hardness,
                         F&& f) {
  const double e = g.cell_edge(depth);
  const double h = g.edge_m * 0.5;
  const double lim = static_cast<double>(std::uint64_t{g.roots_per_axis} << depth) - 1.0;
  auto lo = [&](double v) {
    return static_cast<std::uint32_t>(std::clamp(std::floor((v + h) / e - 0.5), 0.0, lim));
  };
  auto hi = [&](double v) {
    return static_cast<std::uint32_t>(std::clamp(std::ceil((v + h) / e - 0.5), 0.0, lim));
  };
  const std::uint32_t x0 = lo(s.box.min.x), x1 = hi(s.box.max.x);
  const std::uint32_t y0 = lo(s.box.min.y), y1 = hi(s.box.max.y);
  const std::uint32_t z0 = lo(s.box.min.z), z1 = hi(s.box.max.z);
  for (std::uint32_t z = z0; z <= z1; ++z)
    for (std::uint32_t y = y0; y <= y1; ++y)
      for (std::uint32_t x = x0; x <= x1; ++x) {
        const CellCoord c{depth, x, y, z};
        const StampHit hit = stamp_coverage(s, g.cell_centre(c), hardness);
        if (hit.coverage > 0) {
          if constexpr (std::is_invocable_v<F&, const CellCoord&, const StampHit&>)
            f(c, hit);
          else
            f(c, hit.coverage);
        }
      }
}

// Spatial index over a stroke's stamps: finds the stamps whose boxes may touch a cell.
// A stamp of target depth t is bucketed at depths b = t-3, t-6, ... and 0 (a bucket at b = t-3
// is 8 target cells wide), into every bucket its box overlaps. A query for a cell at depth d
// looks, for each stamp bucket depth in use, at the one bucket containing the cell at the
// deepest such level <= d, so the candidates are stamps near a region at most ~4x the cell.
class StampIndex {
 public:
  void clear();
  // Returns the number of buckets the stamp went into (its cost).
  std::size_t add(const CanvasGeometry& g, std::uint32_t id, const Stamp& s);
  // Calls f(stamp id) for every stamp that may touch the cell (duplicates possible).
  template <class F>
  void query(const CellCoord& c, F&& f) const {
    std::uint32_t levels = 0;  // bucket levels to look at
    for (int bd = 0; bd <= kMaxSupportedDepth; ++bd) {
      if (!(top_mask_ & (1u << bd))) continue;
      int b = bd;
      if (c.depth < bd) {
        b = bd - 3 * ((bd - c.depth + 2) / 3);
        if (b < 0) b = 0;
      }
      levels |= 1u << b;
    }
    for (int b = 0; b <= kMaxSupportedDepth; ++b) {
      if (!(levels & (1u << b))) continue;
      const int s = c.depth - b;
      auto it = buckets_.find(Key{c.x >> s, c.y >> s, c.z >> s, b});
      if (it != buckets_.end())
        for (std::uint32_t id : it->second) f(id);
    }
  }

 private:
  struct Key {
    std::uint32_t x, y, z;
    int d;
    friend bool operator==(const Key&, const Key&) = default;
  };
  struct KeyHash {
    std::size_t operator()(const Key& k) const noexcept {
      std::uint64_t h = k.x * 0x9E3779B97F4A7C15ull;
      h ^= (k.y + 0x632BE59BD9B4E019ull) * 0xC2B2AE3D27D4EB4Full;
      h ^= (k.z + (std::uint64_t(k.d) << 40)) * 0x165667B19E3779F9ull;
      return static_cast<std::size_t>(h ^ (h >> 29));
    }
  };
  std::unordered_map<Key, std::vector<std::uint32_t>, KeyHash> buckets_;
  std::uint32_t top_mask_ = 0;  // bucket depths t-3 in use
};

}  // namespace deepcanvas::server_core
