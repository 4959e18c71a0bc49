#include "deepcanvas/client_core/camera.hpp"

#include <algorithm>
#include <charconv>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

namespace deepcanvas::client_core {
namespace {

DVec3 normalized(DVec3 v) {
  return v * (1.0 / length(v));
}

constexpr std::uint32_t kMaxImageSide = 16384;

}  // namespace

Result<Camera> Camera::look_at(DVec3 eye, DVec3 target, DVec3 up_hint, double vfov_deg,
                               std::uint32_t width, std::uint32_t height) {
  if (!is_finite(eye) || !is_finite(target) || !is_finite(up_hint) || !std::isfinite(vfov_deg)) {
    return make_error(Errc::invalid_argument, "camera: non-finite eye, target, up or fov");
  }
  if (!(vfov_deg > 0.0 && vfov_deg < 179.0)) {
    return make_error(Errc::invalid_argument, "camera: vertical fov must be in (0, 179) degrees");
  }
  if (width == 0 || height == 0 || width > kMaxImageSide || height > kMaxImageSide) {
    return make_error(Errc::invalid_argument, "camera: image sides must be in 1..16384");
  }
  const DVec3 view = target - eye;
  const double dist = length(view);
  if (!(dist > 0.0) || !std::isfinite(dist)) {
    return make_error(Errc::invalid_argument, "camera: eye and target coincide");
  }
  Camera c;
  c.position_ = eye;
  c.forward_ = view * (1.0 / dist);
  const double up_len = length(up_hint);
  if (!(up_len > 0.0)) return make_error(Errc::invalid_argument, "camera: zero up vector");
  const DVec3 r = cross(c.forward_, up_hint * (1.0 / up_len));
  // A hint within ~0.06 degrees of the view direction gives no usable roll.
  if (length(r) < 1e-3) {
    return make_error(Errc::invalid_argument, "camera: up vector parallel to the view direction");
  }
  c.right_ = normalized(r);
  c.up_ = cross(c.right_, c.forward_);
  c.vfov_rad_ = vfov_deg * std::numbers::pi / 180.0;
  c.tan_half_v_ = std::tan(c.vfov_rad_ / 2.0);
  c.width_ = width;
  c.height_ = height;
  return c;
}

Result<Camera> Camera::frame_box(const DAabb& box, std::uint32_t width, std::uint32_t height,
                                 double vfov_deg, DVec3 view_dir, DVec3 up_hint) {
  if (!is_finite(box.min) || !is_finite(box.max) || box.min.x > box.max.x ||
      box.min.y > box.max.y || box.min.z > box.max.z) {
    return make_error(Errc::invalid_argument, "frame_box: empty or non-finite box");
  }
  if (!is_finite(view_dir) || !(length(view_dir) > 0.0)) {
    return make_error(Errc::invalid_argument, "frame_box: zero view direction");
  }
  if (!(vfov_deg > 0.0 && vfov_deg < 179.0) || width == 0 || height == 0) {
    return make_error(Errc::invalid_argument, "frame_box: bad fov or image size");
  }
  const DVec3 centre = (box.min + box.max) * 0.5;
  const double radius = std::max(length(box.max - box.min) * 0.5, 0.5e-3);
  const double tan_v = std::tan(vfov_deg * std::numbers::pi / 360.0);
  const double tan_narrow = std::min(tan_v, tan_v * width / height);
  // The sphere fits when sin(half angle) * distance >= radius.
  const double half_angle = std::atan(tan_narrow);
  const double dist = radius / std::sin(half_angle) * 1.1;
  const DVec3 dir = normalized(view_dir);
  const DVec3 eye = centre - dir * dist;
  DVec3 up = up_hint;
  if (length(cross(dir, normalized(up))) < 1e-3) up = {0, 1, 0};
  return look_at(eye, centre, up, vfov_deg, width, height);
}

Result<Camera> Camera::fit_box(const DAabb& box, std::uint32_t width, std::uint32_t height,
                               double vfov_deg, DVec3 view_dir, DVec3 up_hint, double margin) {
  if (!(margin >= 0.0 && margin < 0.5)) {
    return make_error(Errc::invalid_argument, "fit_box: margin must be in [0, 0.5)");
  }
  // frame_box validates the arguments and gives the orientation (the basis does not depend on
  // the distance); only the distance changes.
  auto far = frame_box(box, width, height, vfov_deg, view_dir, up_hint);
  if (!far) return far;
  const DVec3 centre = (box.min + box.max) * 0.5;
  // A degenerate box is framed as at least 1 mm, as frame_box does.
  const DVec3 half{std::max((box.max.x - box.min.x) * 0.5, 0.5e-3),
                   std::max((box.max.y - box.min.y) * 0.5, 0.5e-3),
                   std::max((box.max.z - box.min.z) * 0.5, 0.5e-3)};
  const double tan_h = far->tan_half_h() * (1.0 - margin);
  const double tan_v = far->tan_half_v() * (1.0 - margin);
  // Corner c (relative to the centre) at eye distance d projects to
  // (c.r, c.u) / (d + c.f); it is inside when |c.r| <= tan_h (d + c.f) and likewise for up,
  // i.e. d >= |c.r| / tan_h - c.f. The eye must also stay in front of every corner.
  double dist = 0;
  for (int i = 0; i < 8; ++i) {
    const DVec3 c{(i & 1) ? half.x : -half.x, (i & 2) ? half.y : -half.y,
                  (i & 4) ? half.z : -half.z};
    const double x = std::abs(dot(c, far->right())), y = std::abs(dot(c, far->up()));
    const double z = dot(c, far->forward());
    dist = std::max({dist, x / tan_h - z, y / tan_v - z, -z * 1.01 + 1e-6});
  }
  return look_at(centre - far->forward() * dist, centre, far->up(), vfov_deg, width, height);
}

Result<Camera> Camera::parse(std::string_view spec, std::uint32_t width, std::uint32_t height) {
  std::vector<double> v;
  std::size_t pos = 0;
  while (pos <= spec.size()) {
    std::size_t end = spec.find(',', pos);
    if (end == std::string_view::npos) end = spec.size();
    const std::string_view item = spec.substr(pos, end - pos);
    double d = 0;
    const auto [ptr, ec] = std::from_chars(item.data(), item.data() + item.size(), d);
    if (item.empty() || ec != std::errc{} || ptr != item.data() + item.size()) {
      return make_error(Errc::invalid_argument,
                        "camera spec: '" + std::string(item) +
                            "' is not a number (expected EX,EY,EZ,TX,TY,TZ[,FOV])");
    }
    v.push_back(d);
    pos = end + 1;
  }
  if (v.size() != 6 && v.size() != 7) {
    return make_error(Errc::invalid_argument,
                      "camera spec needs 6 or 7 numbers: EX,EY,EZ,TX,TY,TZ[,FOV]");
  }
  const DVec3 eye{v[0], v[1], v[2]}, target{v[3], v[4], v[5]};
  const double fov = v.size() == 7 ? v[6] : 45.0;
  DVec3 up{0, 0, 1};
  const DVec3 view = target - eye;
  if (length(view) > 0 && length(cross(view * (1.0 / length(view)), up)) < 1e-3) up = {0, 1, 0};
  return look_at(eye, target, up, fov, width, height);
}

DVec3 Camera::ray_direction(std::uint32_t px, std::uint32_t py) const noexcept {
  const double sx = (2.0 * (px + 0.5) / width_ - 1.0) * tan_half_h();
  const double sy = (1.0 - 2.0 * (py + 0.5) / height_) * tan_half_v_;
  return normalized(forward_ + right_ * sx + up_ * sy);
}

void grow_by_samples(DAabb& box, std::span<const protocol::StrokeSample> samples) noexcept {
  for (const auto& p : samples) {
    const double r = p.radius;
    box.min = {std::min(box.min.x, p.x - r), std::min(box.min.y, p.y - r),
               std::min(box.min.z, p.z - r)};
    box.max = {std::max(box.max.x, p.x + r), std::max(box.max.y, p.y + r),
               std::max(box.max.z, p.z + r)};
  }
}

Result<PoolLocation> locate_point(const PoolView& pools, const DVec3& p) {
  if (!is_finite(p)) return make_error(Errc::invalid_argument, "locate: non-finite point");
  const double half = pools.edge_m * 0.5;
  if (std::abs(p.x) > half || std::abs(p.y) > half || std::abs(p.z) > half) {
    return make_error(Errc::invalid_argument, "locate: point outside the canvas");
  }
  const std::uint32_t n = pools.roots_per_axis;
  PoolLocation loc;
  std::uint32_t r[3];
  for (int a = 0; a < 3; ++a) {
    // Root-array units: s in [0, n]; the root's local coordinate is s - (i + 1/2).
    const double s = (p[a] / pools.edge_m + 0.5) * n;
    const double i = std::clamp(std::floor(s), 0.0, static_cast<double>(n - 1));
    r[a] = static_cast<std::uint32_t>(i);
    loc.local[a] = std::clamp(s - i - 0.5, -0.5, 0.5);
    loc.coord[a] = r[a];
  }
  std::uint32_t c = r[0] + n * (r[1] + n * r[2]);
  int depth = 0;
  while (pools.first_child[c] != PoolView::kNoCell) {
    const std::uint32_t fc = pools.first_child[c];
    if (fc % 8 != 0 || !pools.in_range(fc) || depth >= PoolView::kMaxDepth) {
      return make_error(Errc::malformed, "locate: corrupt pools (bad child index or too deep)");
    }
    std::uint32_t bits = 0;
    for (int a = 0; a < 3; ++a) {
      const bool b = loc.local[a] >= 0.0;
      bits |= (b ? 1u : 0u) << a;
      // Exact in binary floating point: doubling and subtracting 1/2 within [-1, 1].
      loc.local[a] = 2.0 * loc.local[a] - (b ? 0.5 : -0.5);
      loc.coord[a] = 2 * loc.coord[a] + (b ? 1u : 0u);
    }
    c = fc + bits;
    ++depth;
  }
  loc.cell = c;
  loc.depth = depth;
  return loc;
}

namespace {

// Calls fn(min corner, edge) for every leaf with non-zero alpha (depth first). malformed for
// corrupt pools (out-of-range indices, cycles, too deep).
template <class Fn>
Result<void> for_each_painted_leaf(const PoolView& pools, Fn&& fn) {
  if (auto v = pools.validate(); !v) return std::move(v).error();
  struct Item {
    std::uint32_t cell;
    int depth;
    std::uint32_t x, y, z;
  };
  std::vector<Item> stack;
  const std::uint32_t n = pools.roots_per_axis;
  for (std::uint32_t c = 0; c < pools.root_count(); ++c) {
    stack.push_back({c, 0, c % n, (c / n) % n, c / (n * n)});
  }
  std::uint64_t visited = 0;
  const double lo = -pools.edge_m * 0.5;
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    // A tree visits each cell once; more visits than cells means a cycle.
    if (++visited > pools.cell_count()) {
      return make_error(Errc::malformed, "painted leaves: the pools contain a cycle");
    }
    const std::uint32_t fc = pools.first_child[it.cell];
    if (fc == PoolView::kNoCell) {
      if ((pools.colour[it.cell] >> 24) == 0) continue;
      const double e = pools.cell_edge_m(it.depth);
      fn(DVec3{lo + it.x * e, lo + it.y * e, lo + it.z * e}, e);
      continue;
    }
    if (fc % 8 != 0 || !pools.in_range(fc) || it.depth >= PoolView::kMaxDepth) {
      return make_error(Errc::malformed, "painted leaves: corrupt pools (bad child index)");
    }
    for (std::uint32_t s = 0; s < 8; ++s) {
      stack.push_back({fc + s, it.depth + 1, 2 * it.x + (s & 1), 2 * it.y + ((s >> 1) & 1),
                       2 * it.z + ((s >> 2) & 1)});
    }
  }
  return {};
}

}  // namespace

Result<std::optional<DAabb>> painted_bounds(const PoolView& pools) {
  std::optional<DAabb> box;
  auto r = for_each_painted_leaf(pools, [&](const DVec3& mn, double e) {
    const DVec3 mx{mn.x + e, mn.y + e, mn.z + e};
    if (!box) {
      box = DAabb{mn, mx};
    } else {
      box->min = {std::min(box->min.x, mn.x), std::min(box->min.y, mn.y),
                  std::min(box->min.z, mn.z)};
      box->max = {std::max(box->max.x, mx.x), std::max(box->max.y, mx.y),
                  std::max(box->max.z, mx.z)};
    }
  });
  if (!r) return std::move(r).error();
  return box;
}

Result<Camera> fit_painted(const PoolView& pools, std::uint32_t width, std::uint32_t height,
                           double vfov_deg, DVec3 view_dir, DVec3 up_hint, double margin) {
  auto box = painted_bounds(pools);
  if (!box) return std::move(box).error();
  if (!*box) return make_error(Errc::invalid_argument, "fit_painted: nothing is painted");
  // The orientation (and the argument checks) of fit_box; only the eye moves.
  auto oriented = Camera::fit_box(**box, width, height, vfov_deg, view_dir, up_hint, margin);
  if (!oriented) return oriented;
  const DVec3 centre = ((*box)->min + (*box)->max) * 0.5;
  const DVec3 f = oriented->forward(), r = oriented->right(), u = oriented->up();
  const double th = oriented->tan_half_h() * (1.0 - margin);
  const double tv = oriented->tan_half_v() * (1.0 - margin);
  // Eye E = centre - f d + r sx + u sy. A point v (relative to the centre) is inside when
  // |v.r - sx| <= th (v.f + d) and |v.u - sy| <= tv (v.f + d). Per axis the smallest d over sx
  // is (A+ + A-) / (2 th) at sx = (A+ - A-) / 2, with A+- = max over points of (+-v.r - th v.f);
  // likewise for y. Over a leaf's corners these are its centre's value plus half its edge
  // times the sum of |coefficients|.
  auto abs_sum = [](DVec3 c) { return std::abs(c.x) + std::abs(c.y) + std::abs(c.z); };
  const double kxp = abs_sum(r - f * th), kxm = abs_sum(r * -1.0 - f * th);
  const double kyp = abs_sum(u - f * tv), kym = abs_sum(u * -1.0 - f * tv);
  const double kf = abs_sum(f);
  const double inf = std::numeric_limits<double>::infinity();
  double ax_p = -inf, ax_m = -inf, ay_p = -inf, ay_m = -inf, nearest = inf;
  auto walked = for_each_painted_leaf(pools, [&](const DVec3& mn, double e) {
    const double h = e * 0.5;
    const DVec3 v = mn + DVec3{h, h, h} - centre;
    const double vr = dot(v, r), vu = dot(v, u), vf = dot(v, f);
    ax_p = std::max(ax_p, vr - th * vf + h * kxp);
    ax_m = std::max(ax_m, -vr - th * vf + h * kxm);
    ay_p = std::max(ay_p, vu - tv * vf + h * kyp);
    ay_m = std::max(ay_m, -vu - tv * vf + h * kym);
    nearest = std::min(nearest, vf - h * kf);
  });
  if (!walked) return std::move(walked).error();
  const double dx = (ax_p + ax_m) / (2.0 * th), dy = (ay_p + ay_m) / (2.0 * tv);
  // In front of every painted corner, as fit_box.
  const double dist = std::max({dx, dy, -nearest * 1.01 + 1e-6});
  const double sx = (ax_p - ax_m) / 2.0, sy = (ay_p - ay_m) / 2.0;
  const DVec3 eye = centre - f * dist + r * sx + u * sy;
  return Camera::look_at(eye, eye + f * std::max(dist, 1e-3), u, vfov_deg, width, height);
}

}  // namespace deepcanvas::client_core
