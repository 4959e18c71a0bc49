// Camera and camera location for ray casting the canvas.
//
// The camera lives in canvas metres as doubles (a double resolves ~2e-12 m at 10 km, nine
// orders of magnitude below the finest cell), so placing it is exact at every depth. What the
// ray casters consume is not the metre position but its location on the pools: the leaf that
// contains it plus the position in that leaf's own frame (origin at the cell centre, edge 1,
// coordinates in [-0.5, 0.5]). That is computed here in double; a GPU gets it as floats, which
// resolve 2^-25 of a cell whatever the cell's size or its distance from the canvas centre.
//
// Pixel (0, 0) is the top-left pixel; rays pass through pixel centres.
//
// Threading: plain values and pure functions; PoolView rules apply to the pools.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <optional>
#include <span>
#include <string_view>

#include "deepcanvas/client_core/pool_view.hpp"
#include "deepcanvas/protocol/stroke.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_core {

struct DVec3 {
  double x = 0, y = 0, z = 0;
  double operator[](int i) const noexcept { return i == 0 ? x : (i == 1 ? y : z); }
  friend DVec3 operator+(DVec3 a, DVec3 b) noexcept { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
  friend DVec3 operator-(DVec3 a, DVec3 b) noexcept { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
  friend DVec3 operator*(DVec3 a, double s) noexcept { return {a.x * s, a.y * s, a.z * s}; }
  friend DVec3 operator*(double s, DVec3 a) noexcept { return a * s; }
  friend bool operator==(const DVec3&, const DVec3&) = default;
};
inline double dot(DVec3 a, DVec3 b) noexcept {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
inline DVec3 cross(DVec3 a, DVec3 b) noexcept {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double length(DVec3 a) noexcept {
  return std::sqrt(dot(a, a));
}
inline bool is_finite(DVec3 a) noexcept {
  return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z);
}

struct DAabb {
  DVec3 min, max;
};
// A box holding nothing yet (min above max), to grow from.
inline DAabb empty_box() noexcept {
  return {{1e300, 1e300, 1e300}, {-1e300, -1e300, -1e300}};
}
// Grows `box` to hold every sample's sphere (its position and radius).
void grow_by_samples(DAabb& box, std::span<const protocol::StrokeSample> samples) noexcept;

class Camera {
 public:
  // A camera at `eye` looking at `target`; `up_hint` picks the roll (any vector not parallel to
  // the view direction). vfov_deg in (0, 179). invalid_argument for non-finite values, eye ==
  // target, a parallel up hint, a bad fov or an empty / oversized image (each side 1..16384).
  static Result<Camera> look_at(DVec3 eye, DVec3 target, DVec3 up_hint, double vfov_deg,
                                std::uint32_t width, std::uint32_t height);

  // A camera that shows the whole box: looks at its centre along `view_dir` (from the eye
  // towards the box) from the distance at which the box's bounding sphere fits the narrower
  // field of view, with 10% margin. A degenerate (zero-size) box is framed as a 1 mm box.
  static Result<Camera> frame_box(const DAabb& box, std::uint32_t width, std::uint32_t height,
                                  double vfov_deg = 45.0, DVec3 view_dir = {-0.6, -0.45, -0.66},
                                  DVec3 up_hint = {0, 0, 1});

  // Like frame_box, but as close as the box's eight corners allow: from the nearest distance at
  // which every corner projects inside the image with `margin` (a fraction of each half extent)
  // to spare, so the box fills the frame along its tighter axis (frame_box fits the bounding
  // sphere, which leaves a flat or elongated painting small). Used to frame painted content
  // (`render` and the render loop without --camera). Errors as frame_box; margin in [0, 0.5).
  static Result<Camera> fit_box(const DAabb& box, std::uint32_t width, std::uint32_t height,
                                double vfov_deg = 45.0, DVec3 view_dir = {-0.6, -0.45, -0.66},
                                DVec3 up_hint = {0, 0, 1}, double margin = 0.05);

  // Parses "EX,EY,EZ,TX,TY,TZ[,FOV]" (eye and target in metres, vertical fov in degrees,
  // default 45; up is +z unless the view is vertical, then +y). invalid_argument on anything
  // else.
  static Result<Camera> parse(std::string_view spec, std::uint32_t width, std::uint32_t height);

  const DVec3& position() const noexcept { return position_; }
  const DVec3& forward() const noexcept { return forward_; }
  const DVec3& right() const noexcept { return right_; }
  const DVec3& up() const noexcept { return up_; }
  double vfov_rad() const noexcept { return vfov_rad_; }
  std::uint32_t width() const noexcept { return width_; }
  std::uint32_t height() const noexcept { return height_; }
  // tan(vfov / 2) and that times the aspect ratio: the half extents of the image plane at
  // distance 1.
  double tan_half_v() const noexcept { return tan_half_v_; }
  double tan_half_h() const noexcept { return tan_half_v_ * width_ / height_; }

  // Unit direction of the ray through pixel (px, py)'s centre. The GPU computes the same
  // formula in float from forward/right/up and the two tangents.
  DVec3 ray_direction(std::uint32_t px, std::uint32_t py) const noexcept;

 private:
  DVec3 position_, forward_, right_, up_;
  double vfov_rad_ = 0, tan_half_v_ = 0;
  std::uint32_t width_ = 0, height_ = 0;
};

// A point located on the pools: the leaf containing it, the leaf's exact integer address
// (depth, coordinates in units of that depth's cell edge from the canvas minimum corner) and
// the point in the leaf's own frame (centre origin, edge 1, each coordinate in [-0.5, 0.5]).
// Points exactly on a face between two cells go to the cell on the positive side.
struct PoolLocation {
  std::uint32_t cell = PoolView::kNoCell;
  int depth = 0;
  std::array<std::uint32_t, 3> coord{};
  std::array<double, 3> local{};
};

// Locates `p` (metres) by descending from its root. nullopt-like error cases: invalid_argument
// for non-finite points or points outside the canvas (the closed cube); malformed when the
// pools name an out-of-range child or are deeper than kMaxDepth (a corrupt replica).
Result<PoolLocation> locate_point(const PoolView& pools, const DVec3& p);

// A camera that frames the painted leaves themselves rather than their bounding box (whose
// corners, seen from the side, can lie far outside a painting): fit_box's orientation, moved
// sideways so that the leaves' projection is centred and back to the nearest distance at which
// every corner of every painted leaf projects inside the image with `margin` to spare (exact
// for that orientation). O(painted leaves), two passes. Errors: those of painted_bounds and
// fit_box; invalid_argument when nothing is painted.
Result<Camera> fit_painted(const PoolView& pools, std::uint32_t width, std::uint32_t height,
                           double vfov_deg = 45.0, DVec3 view_dir = {-0.6, -0.45, -0.66},
                           DVec3 up_hint = {0, 0, 1}, double margin = 0.05);

// Bounding box (metres) of the painted content: the union of the leaves whose density (alpha)
// is non-zero; nullopt when nothing is painted. malformed for corrupt pools (out-of-range
// indices, cycles). O(live cells).
Result<std::optional<DAabb>> painted_bounds(const PoolView& pools);

}  // namespace deepcanvas::client_core
