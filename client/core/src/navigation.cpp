// The studio's orbit view (see navigation.hpp).
#include "deepcanvas/client_core/navigation.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace deepcanvas::client_core {
namespace {

constexpr double kMaxPitch = std::numbers::pi / 2 - 1e-3;
constexpr DVec3 kUp{0, 1, 0};

DVec3 normalized(DVec3 v) noexcept {
  const double l = length(v);
  return l > 0 ? v * (1.0 / l) : v;
}

}  // namespace

DVec3 OrbitView::forward() const noexcept {
  // yaw 0, pitch 0: looking along -z; positive pitch looks down from above.
  const double cp = std::cos(pitch_rad);
  return {-std::sin(yaw_rad) * cp, -std::sin(pitch_rad), -std::cos(yaw_rad) * cp};
}

DVec3 OrbitView::eye() const noexcept {
  return focus - forward() * distance;
}

Result<Camera> OrbitView::camera(std::uint32_t width, std::uint32_t height) const {
  return Camera::look_at(eye(), focus, kUp, vfov_deg, width, height);
}

double OrbitView::metres_per_pixel(double depth, std::uint32_t height) const noexcept {
  const double tan_half = std::tan(vfov_deg * std::numbers::pi / 360.0);
  return 2.0 * depth * tan_half / std::max<std::uint32_t>(height, 1);
}

void OrbitView::orbit(double dx_px, double dy_px, std::uint32_t height) noexcept {
  const double per_px = std::numbers::pi / std::max<std::uint32_t>(height, 1);
  yaw_rad = std::remainder(yaw_rad - dx_px * per_px, 2 * std::numbers::pi);
  pitch_rad = std::clamp(pitch_rad + dy_px * per_px, -kMaxPitch, kMaxPitch);
}

void OrbitView::pan(double dx_px, double dy_px, std::uint32_t height) noexcept {
  const DVec3 f = forward();
  const DVec3 right = normalized(cross(f, kUp));
  const DVec3 up = cross(right, f);
  const double m = metres_per_pixel(distance, height);
  focus = focus - right * (dx_px * m) + up * (dy_px * m);
}

void OrbitView::dolly(double factor) noexcept {
  if (!(factor > 0) || !std::isfinite(factor)) return;
  distance = std::clamp(distance * factor, kMinDistance, kMaxDistance);
}

void OrbitView::zoom_toward(const DVec3& point, double notches) noexcept {
  if (!is_finite(point) || !std::isfinite(notches)) return;
  double factor = std::pow(kNotchFactor, notches);
  // Clamp the distance, keeping `point` fixed in the image: scale what is left of the move.
  const double wanted = distance * factor;
  if (wanted < kMinDistance) factor = kMinDistance / distance;
  if (wanted > kMaxDistance) factor = kMaxDistance / distance;
  // The eye moves toward the point by `factor` (a homothety centred on the point), and so does
  // the focus: the direction is unchanged, every point on the line eye->point keeps its pixel.
  const DVec3 e = eye();
  const DVec3 new_eye = point + (e - point) * factor;
  focus = point + (focus - point) * factor;
  distance = length(focus - new_eye);
}

void OrbitView::frame(const DAabb& box, std::uint32_t width, std::uint32_t height) noexcept {
  const DVec3 centre = (box.min + box.max) * 0.5;
  const DVec3 half = (box.max - box.min) * 0.5;
  const double radius = std::max(length(half), 0.5e-3);
  const double tan_half_v = std::tan(vfov_deg * std::numbers::pi / 360.0);
  const double aspect = height > 0 ? static_cast<double>(width) / height : 1.0;
  const double tan_half = std::min(tan_half_v, tan_half_v * aspect);
  focus = centre;
  distance = std::clamp(radius / std::sin(std::atan(tan_half)) * 1.1, kMinDistance, kMaxDistance);
}

std::optional<OrbitView> OrbitView::looking_at(const DVec3& eye, const DVec3& target,
                                               double vfov_deg) noexcept {
  const DVec3 d = target - eye;
  const double dist = length(d);
  if (!(dist > 0) || !std::isfinite(dist) || !(vfov_deg > 0 && vfov_deg < 179)) return std::nullopt;
  OrbitView v;
  v.focus = target;
  v.distance = std::clamp(dist, kMinDistance, kMaxDistance);
  v.vfov_deg = vfov_deg;
  const DVec3 f = d * (1.0 / dist);
  v.pitch_rad = std::clamp(std::asin(std::clamp(-f.y, -1.0, 1.0)), -kMaxPitch, kMaxPitch);
  v.yaw_rad = std::atan2(-f.x, -f.z);
  return v;
}

DVec3 ray_direction_at(const Camera& camera, double px, double py) noexcept {
  const double sx = (2.0 * px / camera.width() - 1.0) * camera.tan_half_h();
  const double sy = (1.0 - 2.0 * py / camera.height()) * camera.tan_half_v();
  return normalized(camera.forward() + camera.right() * sx + camera.up() * sy);
}

}  // namespace deepcanvas::client_core
