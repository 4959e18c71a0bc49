#include "deepcanvas/client_core/reference_renderer.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <span>
#include <thread>
#include <type_traits>

#include "deepcanvas/protocol/density_model.hpp"

namespace deepcanvas::client_core {
namespace {

constexpr std::uint32_t kNoCell = PoolView::kNoCell;

// One ray's traversal, templated on the scalar type (double: the reference; float: what the GPU
// computes) and on how the next cell is found (G3 links vs descent from the root).
template <class Real, Stepping kStepping>
class Tracer {
 public:
  Tracer(const PoolView& pools, const RenderOptions& opt)
      : pools_(pools), opt_(opt), skip_empty_(opt.skip_empty_subtrees && pools.filtered_interiors) {}

  RayResult trace(const RayOrigin& origin, const DVec3& direction) const {
    RayResult out;
    if (opt_.content_empty) return out;  // nothing painted: background
    const Real d[3] = {static_cast<Real>(direction.x), static_cast<Real>(direction.y),
                       static_cast<Real>(direction.z)};
    // Content cull: the distance (metres from the camera) past which every cell is empty.
    Real stop_at = std::numeric_limits<Real>::infinity();
    std::span<const DAabb> boxes;
    if (opt_.content_boxes) {
      boxes = opt_.content_boxes->boxes();
    } else if (opt_.content_bounds) {
      boxes = {&*opt_.content_bounds, 1};
    }
    if (opt_.content_boxes || opt_.content_bounds) {
      // The farthest exit among the boxes the ray hits (raycast.comp, "Content cull").
      bool hit = false;
      Real farthest = 0;
      for (const DAabb& b : boxes) {
        const DAabb box = cull_box_relative_to(b, origin.position_m);
        bool inside_slabs = true;
        Real t_near = 0, t_far = std::numeric_limits<Real>::infinity();
        for (int a = 0; a < 3; ++a) {
          const Real lo = static_cast<Real>(box.min[a]), hi = static_cast<Real>(box.max[a]);
          if (d[a] == Real(0)) {
            if (lo > 0 || hi < 0) inside_slabs = false;
            continue;
          }
          // lo * (1/d), as the GPU computes it (one reciprocal per axis for all boxes).
          const Real inv = Real(1) / d[a];
          Real t0 = lo * inv, t1 = hi * inv;
          if (t0 > t1) std::swap(t0, t1);
          t_near = std::max(t_near, t0);
          t_far = std::min(t_far, t1);
        }
        if (inside_slabs && t_near <= t_far) {
          hit = true;
          farthest = std::max(farthest, t_far);
        }
      }
      if (!hit) return out;  // misses every painted cell: background
      stop_at = farthest * (Real(1) + Real(1) / Real(64));
    }
    State s;
    Real travelled = 0;  // metres from the camera
    if (origin.inside) {
      s.cell = origin.location.cell;
      s.depth = origin.location.depth;
      for (int a = 0; a < 3; ++a) {
        s.coord[a] = origin.location.coord[a];
        s.p[a] = static_cast<Real>(origin.location.local[a]);
      }
    } else if (!enter_canvas(origin.position_m, d, s, travelled)) {
      return out;  // misses the canvas
    }
    run(s, d, travelled, stop_at, out);
    return out;
  }

 private:
  struct State {
    std::uint32_t cell = kNoCell;
    int depth = 0;
    std::uint32_t coord[3] = {0, 0, 0};  // integer address (maintained for Stepping::descent)
    Real p[3] = {0, 0, 0};               // the point in the cell's own frame
  };

  static constexpr Real kHalf = Real(0.5);
  static Real offset(bool bit) { return bit ? kHalf : -kHalf; }

  // A ray from outside: the canvas is a cell of edge 1 centred on the origin (canvas frame);
  // slab test against it, then into the root holding the entry point.
  // `travelled` gets the distance to the entry point in metres.
  bool enter_canvas(const DVec3& pos_m, const Real d[3], State& s, Real& travelled) const {
    Real q[3];
    for (int a = 0; a < 3; ++a) q[a] = static_cast<Real>(pos_m[a] / pools_.edge_m);
    Real t_near = 0, t_far = std::numeric_limits<Real>::infinity();
    int near_axis = -1;
    for (int a = 0; a < 3; ++a) {
      if (d[a] == Real(0)) {
        if (q[a] < -kHalf || q[a] > kHalf) return false;
        continue;
      }
      Real t0 = (-kHalf - q[a]) / d[a], t1 = (kHalf - q[a]) / d[a];
      if (t0 > t1) std::swap(t0, t1);
      if (t0 > t_near) {
        t_near = t0;
        near_axis = a;
      }
      t_far = std::min(t_far, t1);
    }
    if (t_near > t_far) return false;
    travelled = t_near * static_cast<Real>(pools_.edge_m);
    const Real n = static_cast<Real>(pools_.roots_per_axis);
    std::uint32_t r[3];
    for (int a = 0; a < 3; ++a) {
      Real e = std::clamp(q[a] + t_near * d[a], -kHalf, kHalf);
      if (a == near_axis) e = d[a] > 0 ? -kHalf : kHalf;  // exactly on the entry face
      const Real sa = (e + kHalf) * n;
      Real i = std::floor(sa);
      // On an internal root face, take the root the ray is heading into.
      if (sa == i && d[a] < 0) i -= 1;
      i = std::clamp(i, Real(0), n - 1);
      r[a] = static_cast<std::uint32_t>(i);
      s.p[a] = std::clamp(sa - i - kHalf, -kHalf, kHalf);
      s.coord[a] = r[a];
    }
    s.cell = r[0] + pools_.roots_per_axis * (r[1] + pools_.roots_per_axis * r[2]);
    s.depth = 0;
    return true;
  }

  // An interior cell of colour 0 holds nothing (only where skip_empty_: see the header).
  bool empty_subtree(std::uint32_t c) const { return skip_empty_ && pools_.colour[c] == 0; }

  // Down through first_child to the leaf containing p (ties go where the ray is heading), or
  // to the first empty subtree on the way.
  bool descend_to_leaf(State& s, const Real d[3]) const {
    for (;;) {
      const std::uint32_t fc = pools_.first_child[s.cell];
      if (fc == kNoCell || empty_subtree(s.cell)) return true;
      if (fc % 8 != 0 || !pools_.in_range(fc) || s.depth >= PoolView::kMaxDepth) return false;
      std::uint32_t bits = 0;
      for (int a = 0; a < 3; ++a) {
        const bool b = s.p[a] > 0 || (s.p[a] == 0 && d[a] >= 0);
        bits |= (b ? 1u : 0u) << a;
        s.p[a] = Real(2) * s.p[a] - offset(b);
        if constexpr (kStepping == Stepping::descent) s.coord[a] = 2 * s.coord[a] + (b ? 1 : 0);
      }
      s.cell = fc + bits;
      ++s.depth;
    }
  }

  enum class Next { ok, left_canvas, bad_index };

  Next step_g3(State& s, int axis, bool positive) const {
    const std::uint32_t n = pools_.roots_per_axis;
    if (s.cell < pools_.root_count()) {
      std::uint32_t r[3] = {s.cell % n, (s.cell / n) % n, s.cell / (n * n)};
      if (positive ? r[axis] + 1 >= n : r[axis] == 0) return Next::left_canvas;
      r[axis] = positive ? r[axis] + 1 : r[axis] - 1;
      s.cell = r[0] + n * (r[1] + n * r[2]);
      s.p[axis] = -s.p[axis];
      return Next::ok;
    }
    const std::uint32_t slot = s.cell & 7u;
    const bool bit = ((slot >> axis) & 1u) != 0;
    if (bit != positive) {  // the sibling inside the same parent
      s.cell ^= 1u << axis;
      s.p[axis] = -s.p[axis];
      return Next::ok;
    }
    const std::uint32_t link = pools_.link(s.cell >> 3, 2 * axis + (positive ? 1 : 0));
    if (link == kNoCell) return Next::left_canvas;
    if (!pools_.in_range(link)) return Next::bad_index;
    const std::uint32_t fc = pools_.first_child[link];
    if (fc == kNoCell || empty_subtree(link)) {
      // The coarser leaf (or empty subtree): re-express p in the parent's frame, then cross the
      // parent's face.
      for (int a = 0; a < 3; ++a) s.p[a] = (s.p[a] + offset(((slot >> a) & 1u) != 0)) * kHalf;
      s.p[axis] = -s.p[axis];
      s.cell = link;
      --s.depth;
      return Next::ok;
    }
    if (fc % 8 != 0 || !pools_.in_range(fc)) return Next::bad_index;
    s.cell = fc + (slot ^ (1u << axis));
    s.p[axis] = -s.p[axis];
    return Next::ok;
  }

  // The neighbour by its integer address, descending from the root (no links, no siblings).
  Next step_descent(State& s, int axis, bool positive) const {
    const std::uint64_t extent = std::uint64_t{pools_.roots_per_axis} << s.depth;
    if (positive ? s.coord[axis] + std::uint64_t{1} >= extent : s.coord[axis] == 0) {
      return Next::left_canvas;
    }
    // The step leaves the parent (step_g3 takes the link then): an empty parent-level neighbour
    // is where it stops, as step_g3 does.
    const bool leaves_parent = ((s.coord[axis] & 1u) != 0) == positive;
    s.coord[axis] = positive ? s.coord[axis] + 1 : s.coord[axis] - 1;
    s.p[axis] = -s.p[axis];
    const std::uint32_t n = pools_.roots_per_axis;
    const int k = s.depth;
    std::uint32_t c = (s.coord[0] >> k) + n * ((s.coord[1] >> k) + n * (s.coord[2] >> k));
    int level = 0;
    while (level < k) {
      if (leaves_parent && level + 1 == k && empty_subtree(c)) break;
      const std::uint32_t fc = pools_.first_child[c];
      if (fc == kNoCell) break;
      if (fc % 8 != 0 || !pools_.in_range(fc)) return Next::bad_index;
      ++level;
      const int sh = k - level;
      c = fc + (((s.coord[0] >> sh) & 1u) | (((s.coord[1] >> sh) & 1u) << 1) |
                (((s.coord[2] >> sh) & 1u) << 2));
    }
    // A coarser leaf: lift p up one level at a time (the same operations as step_g3).
    for (int lv = k; lv > level; --lv) {
      for (int a = 0; a < 3; ++a) s.p[a] = (s.p[a] + offset((s.coord[a] & 1u) != 0)) * kHalf;
      for (int a = 0; a < 3; ++a) s.coord[a] >>= 1;
    }
    s.cell = c;
    s.depth = level;
    return Next::ok;
  }

  void run(State& s, const Real d[3], Real travelled, Real stop_at, RayResult& out) const {
    // A depth-k cell's edge in metres is root_edge_m * 2^-k.
    const Real root_edge_m = static_cast<Real>(pools_.edge_m / pools_.roots_per_axis);
    Real rgb[3] = {0, 0, 0};
    Real trans = 1;
    const Real term = static_cast<Real>(opt_.termination_transmittance);
    for (;;) {
      if (!descend_to_leaf(s, d)) {
        out.bad_index = true;
        break;
      }
      if (out.steps >= opt_.max_steps_per_ray) {
        out.step_limit = true;
        break;
      }
      ++out.steps;
      // Slab test in the leaf's frame: the first face the ray reaches.
      Real t = std::numeric_limits<Real>::infinity();
      int axis = 0;
      for (int a = 0; a < 3; ++a) {
        if (d[a] == 0) continue;
        const Real ta = ((d[a] > 0 ? kHalf : -kHalf) - s.p[a]) / d[a];
        if (ta < t) {
          t = ta;
          axis = a;
        }
      }
      t = std::max(t, Real(0));
      const std::uint32_t rgba = pools_.colour[s.cell];
      const std::uint32_t a8 = rgba >> 24;
      if (a8 != 0 && t > 0) {
        const Real alpha = static_cast<Real>(a8) / Real(255);
        // The density model's transmittance; float mirrors what the GPU computes.
        Real seg_t;
        if constexpr (std::is_same_v<Real, double>) {
          seg_t = protocol::density::transmittance(alpha, t);
        } else {
          seg_t = std::pow(Real(1) - alpha, t);
        }
        // w / 255 as w * (1 / 255): what the GPU computes (a multiply, not three divisions).
        const Real w = trans * (Real(1) - seg_t) * (Real(1) / Real(255));
        rgb[0] += w * static_cast<Real>(rgba & 0xFFu);
        rgb[1] += w * static_cast<Real>((rgba >> 8) & 0xFFu);
        rgb[2] += w * static_cast<Real>((rgba >> 16) & 0xFFu);
        // The first surface (RayResult::surface_m): where the opacity reaches one half, inside
        // this segment: trans * (1 - alpha)^x = 1/2.
        if (out.surface_m < 0 && trans * seg_t <= Real(0.5)) {
          const Real x = alpha >= Real(1) ? Real(0)
                                          : std::log(Real(0.5) / trans) / std::log(Real(1) - alpha);
          out.surface_m = static_cast<double>(
              travelled + std::clamp(x, Real(0), t) * std::ldexp(root_edge_m, -s.depth));
        }
        trans *= seg_t;
        if (trans < term) {
          out.terminated_early = true;
          break;
        }
      }
      travelled += t * std::ldexp(root_edge_m, -s.depth);
      if (travelled > stop_at) break;  // past the content box: only empty cells follow
      const bool positive = d[axis] > 0;
      for (int a = 0; a < 3; ++a) {
        if (a != axis) s.p[a] = std::clamp(s.p[a] + t * d[a], -kHalf, kHalf);
      }
      s.p[axis] = positive ? kHalf : -kHalf;
      const Next next =
          kStepping == Stepping::g3 ? step_g3(s, axis, positive) : step_descent(s, axis, positive);
      if (next == Next::left_canvas) break;
      if (next == Next::bad_index) {
        out.bad_index = true;
        break;
      }
    }
    for (int a = 0; a < 3; ++a) out.rgb[a] = rgb[a];
    out.transmittance = trans;
  }

  const PoolView& pools_;
  const RenderOptions& opt_;
  const bool skip_empty_;  // empty_subtree(): opt_.skip_empty_subtrees and pools_.filtered_interiors
};

template <class Real, Stepping kStepping>
RayResult trace_with(const PoolView& pools, const RayOrigin& origin, const DVec3& direction,
                     const RenderOptions& options) {
  return Tracer<Real, kStepping>(pools, options).trace(origin, direction);
}

RayResult dispatch(const PoolView& pools, const RayOrigin& origin, const DVec3& direction,
                   const RenderOptions& o) {
  if (o.precision == Precision::float64) {
    return o.stepping == Stepping::g3
               ? trace_with<double, Stepping::g3>(pools, origin, direction, o)
               : trace_with<double, Stepping::descent>(pools, origin, direction, o);
  }
  return o.stepping == Stepping::g3
             ? trace_with<float, Stepping::g3>(pools, origin, direction, o)
             : trace_with<float, Stepping::descent>(pools, origin, direction, o);
}

}  // namespace

bool valid_content_bounds(const DAabb& b) {
  return is_finite(b.min) && is_finite(b.max) && b.min.x <= b.max.x && b.min.y <= b.max.y &&
         b.min.z <= b.max.z;
}

bool valid_content_boxes(const std::optional<ContentBoxes>& boxes) {
  if (!boxes) return true;
  const auto list = boxes->boxes();
  return boxes->count <= kMaxContentBoxes &&
         std::all_of(list.begin(), list.end(),
                     [](const DAabb& b) { return valid_content_bounds(b); });
}

DAabb cull_box_relative_to(const DAabb& bounds, const DVec3& camera_m) {
  const DVec3 centre = (bounds.min + bounds.max) * 0.5;
  const DVec3 ext = bounds.max - bounds.min;
  const double pad = 1e-5 * (std::max({ext.x, ext.y, ext.z}) + length(centre - camera_m)) + 1e-30;
  const DVec3 p{pad, pad, pad};
  return {bounds.min - camera_m - p, bounds.max - camera_m + p};
}

std::vector<std::uint8_t> RenderImage::to_rgba8() const {
  std::vector<std::uint8_t> out(rgba.size());
  for (std::size_t i = 0; i < rgba.size(); ++i) {
    out[i] = static_cast<std::uint8_t>(std::clamp(std::lround(rgba[i] * 255.0), 0L, 255L));
  }
  return out;
}

Result<RayOrigin> make_ray_origin(const PoolView& pools, const DVec3& position_m) {
  if (!is_finite(position_m)) {
    return make_error(Errc::invalid_argument, "camera position is not finite");
  }
  RayOrigin o;
  o.position_m = position_m;
  const double half = pools.edge_m * 0.5;
  o.inside = std::abs(position_m.x) <= half && std::abs(position_m.y) <= half &&
             std::abs(position_m.z) <= half;
  if (o.inside) {
    auto loc = locate_point(pools, position_m);
    if (!loc) return std::move(loc).error();
    o.location = *loc;
  }
  return o;
}

RayResult trace_ray(const PoolView& pools, const RayOrigin& origin, const DVec3& direction,
                    const RenderOptions& options) {
  return dispatch(pools, origin, direction, options);
}

Result<RenderImage> render_reference(const PoolView& pools, const Camera& camera,
                                     const RenderOptions& options, RenderStats* stats) {
  if (auto v = pools.validate(); !v) return std::move(v).error();
  if (!(options.termination_transmittance >= 0.0 && options.termination_transmittance < 1.0)) {
    return make_error(Errc::invalid_argument, "termination transmittance must be in [0, 1)");
  }
  if (options.max_steps_per_ray == 0) {
    return make_error(Errc::invalid_argument, "max_steps_per_ray must be positive");
  }
  if (options.content_bounds && !valid_content_bounds(*options.content_bounds)) {
    return make_error(Errc::invalid_argument, "content bounds must be finite with min <= max");
  }
  if (!valid_content_boxes(options.content_boxes)) {
    return make_error(Errc::invalid_argument,
                      "content boxes: at most kMaxContentBoxes, each finite with min <= max");
  }
  auto origin = make_ray_origin(pools, camera.position());
  if (!origin) return std::move(origin).error();

  RenderImage img;
  img.width = camera.width();
  img.height = camera.height();
  img.rgba.assign(std::size_t{img.width} * img.height * 4, 0.0);

  struct Acc {
    std::uint64_t steps = 0, max_steps = 0, early = 0, bad = 0, limit = 0;
  };
  unsigned threads = options.threads == 0 ? std::thread::hardware_concurrency() : options.threads;
  threads = std::clamp(threads, 1u, std::max(1u, img.height));
  std::vector<Acc> acc(threads);
  std::atomic<std::uint32_t> next_row{0};
  auto worker = [&](unsigned id) {
    Acc& a = acc[id];
    for (std::uint32_t y = next_row++; y < img.height; y = next_row++) {
      for (std::uint32_t x = 0; x < img.width; ++x) {
        const RayResult r = dispatch(pools, *origin, camera.ray_direction(x, y), options);
        double* px = &img.rgba[(std::size_t{y} * img.width + x) * 4];
        for (int c = 0; c < 3; ++c) px[c] = r.rgb[c] + r.transmittance * options.background[c];
        px[3] = 1.0 - r.transmittance;
        a.steps += r.steps;
        a.max_steps = std::max<std::uint64_t>(a.max_steps, r.steps);
        a.early += r.terminated_early;
        a.bad += r.bad_index;
        a.limit += r.step_limit;
      }
    }
  };
  if (threads == 1) {
    worker(0);
  } else {
    std::vector<std::thread> pool;
    for (unsigned i = 0; i < threads; ++i) pool.emplace_back(worker, i);
    for (auto& t : pool) t.join();
  }
  if (stats) {
    *stats = {};
    stats->rays = std::uint64_t{img.width} * img.height;
    for (const Acc& a : acc) {
      stats->steps += a.steps;
      stats->max_steps = std::max(stats->max_steps, a.max_steps);
      stats->terminated_early += a.early;
      stats->bad_index_rays += a.bad;
      stats->step_limit_rays += a.limit;
    }
  }
  return img;
}

}  // namespace deepcanvas::client_core
