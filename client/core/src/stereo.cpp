// Headset stereo: quaternions, the artist's pose, the eye cameras and the resolution controller
// (stereo.hpp).
#include "deepcanvas/client_core/stereo.hpp"

#include <algorithm>
#include <cmath>

namespace deepcanvas::client_core {

namespace {

Quat normalised(const Quat& q) noexcept {
  const double n = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  if (!(n > 0) || !std::isfinite(n)) return {};
  return {q.w / n, q.x / n, q.y / n, q.z / n};
}

bool finite(const Quat& q) noexcept {
  return std::isfinite(q.w) && std::isfinite(q.x) && std::isfinite(q.y) && std::isfinite(q.z);
}

}  // namespace

DVec3 rotate(const Quat& q0, const DVec3& v) noexcept {
  const Quat q = normalised(q0);
  // v + 2 w (u x v) + 2 u x (u x v), u the vector part.
  const DVec3 u{q.x, q.y, q.z};
  const DVec3 t = cross(u, v) * 2.0;
  return v + t * q.w + cross(u, t);
}

Quat axis_angle(const DVec3& axis, double angle_rad) noexcept {
  const double n = length(axis);
  if (!(n > 0)) return {};
  const double s = std::sin(angle_rad / 2) / n;
  return {std::cos(angle_rad / 2), axis.x * s, axis.y * s, axis.z * s};
}

Quat multiply(const Quat& a, const Quat& b) noexcept {
  return {a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z,
          a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
          a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x,
          a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w};
}

Quat blend(const Quat& a, const Quat& b0, double t) noexcept {
  Quat b = b0;
  if (a.w * b.w + a.x * b.x + a.y * b.y + a.z * b.z < 0) b = {-b.w, -b.x, -b.y, -b.z};
  return normalised({a.w + (b.w - a.w) * t, a.x + (b.x - a.x) * t, a.y + (b.y - a.y) * t,
                     a.z + (b.z - a.z) * t});
}

DVec3 room_to_canvas(const ArtistPose& pose, const DVec3& p) noexcept {
  return pose.world_origin + p * pose.world_scale;
}

ArtistPose grab_world(const ArtistPose& at_grab, const DVec3& left0, const DVec3& right0,
                      const DVec3& left, const DVec3& right) noexcept {
  ArtistPose p = at_grab;
  const double d0 = length(right0 - left0), d1 = length(right - left);
  if (d0 > 1e-3 && d1 > 1e-3) p.world_scale = at_grab.world_scale * d0 / d1;
  // canvas(m0) at the start = canvas(m1) now: O1 = O0 + m0 s0 - m1 s1.
  const DVec3 m0 = (left0 + right0) * 0.5, m1 = (left + right) * 0.5;
  p.world_origin = at_grab.world_origin + m0 * at_grab.world_scale - m1 * p.world_scale;
  return p;
}

Result<std::array<Camera, 2>> eye_cameras(const ArtistPose& pose, const EyeSetup& eyes,
                                          double render_scale) {
  if (!is_finite(pose.head) || !is_finite(pose.world_origin) || !finite(pose.orientation) ||
      !std::isfinite(pose.world_scale) || !(pose.world_scale > 0))
    return make_error(Errc::invalid_argument, "head pose: non-finite values or world scale <= 0");
  if (!std::isfinite(eyes.ipd_m) || eyes.ipd_m < 0 || eyes.ipd_m > 1)
    return make_error(Errc::invalid_argument, "eye distance must be in [0, 1] m");
  if (!std::isfinite(render_scale) || !(render_scale > 0) || render_scale > 1)
    return make_error(Errc::invalid_argument, "render scale must be in (0, 1]");
  const auto side = [&](std::uint32_t n) {
    return std::max<std::uint32_t>(1, static_cast<std::uint32_t>(std::lround(n * render_scale)));
  };
  const DVec3 right = rotate(pose.orientation, {1, 0, 0});
  const DVec3 up = rotate(pose.orientation, {0, 1, 0});
  const DVec3 forward = rotate(pose.orientation, {0, 0, -1});
  std::array<Camera, 2> out;
  for (int e = 0; e < 2; ++e) {
    const DVec3 eye_room = pose.head + right * ((e == 0 ? -0.5 : 0.5) * eyes.ipd_m);
    const DVec3 eye = room_to_canvas(pose, eye_room);
    // The target one canvas metre ahead (not one room metre: at world scale 1e-6 that would be
    // 1 um from an eye whose coordinates resolve 2e-12 m, a direction good to only 1e-6 rad).
    const DVec3 target = eye + forward;
    auto cam = Camera::look_at(eye, target, up, eyes.vfov_deg, side(eyes.width), side(eyes.height));
    if (!cam) return std::move(cam).error();
    out[static_cast<std::size_t>(e)] = *cam;
  }
  return out;
}

void ResolutionController::calibrate(double probe_scale, double probe_ms) noexcept {
  if (!std::isfinite(probe_ms) || probe_ms <= 0 || !std::isfinite(probe_scale) || probe_scale <= 0)
    return;
  set_scale(std::clamp(probe_scale * std::sqrt(o_.aim * o_.interval_ms / probe_ms), o_.min_scale, 1.0));
  calm_ = 0;
}

void ResolutionController::calibrate(double scale_a, double ms_a, double scale_b,
                                     double ms_b) noexcept {
  for (double v : {scale_a, ms_a, scale_b, ms_b})
    if (!std::isfinite(v) || v <= 0) return;
  const double q = (scale_b / scale_a) * (scale_b / scale_a);
  if (std::abs(1 - q) < 0.05) return;
  share_ = std::clamp((1 - ms_b / ms_a) / (1 - q), 0.0, 1.0);
  // (1 - share) + share x (s / scale_a)^2 = aim / ms_a.
  const double want = o_.aim * o_.interval_ms / ms_a - (1 - share_);
  const double s = want <= 0 ? o_.min_scale : share_ > 0 ? scale_a * std::sqrt(want / share_) : 1.0;
  sum_ms_ = 0;
  count_ = 0;
  last_scale_ = 0;
  scale_ = std::clamp(s, o_.min_scale, 1.0);
  calm_ = 0;
}

double ResolutionController::predict(double ms, double to) const noexcept {
  const double q = (to / scale_) * (to / scale_);
  return ms * ((1 - share_) + share_ * q);
}

// A new scale: the frames at the old one, if enough to trust, become the comparison for the next.
void ResolutionController::set_scale(double s) noexcept {
  if (s == scale_) return;
  if (count_ >= 5) {
    last_mean_ms_ = sum_ms_ / count_;
    last_scale_ = scale_;
  }
  sum_ms_ = 0;
  count_ = 0;
  scale_ = s;
}

// settle_frames frames at this scale: compares their mean with the last scale's. Model: the
// ratio of the means r = (1 - share) + share x q, q the ratio of the pixel counts.
void ResolutionController::learn() noexcept {
  if (last_scale_ <= 0 || last_mean_ms_ <= 0) return;
  const double q = (scale_ / last_scale_) * (scale_ / last_scale_);
  if (std::abs(1 - q) < 0.05) return;
  const double r = (sum_ms_ / count_) / last_mean_ms_;
  const double seen = std::clamp((1 - r) / (1 - q), 0.0, 1.0);
  share_ = 0.5 * share_ + 0.5 * seen;
}

void ResolutionController::frame_done(double render_ms) noexcept {
  if (!std::isfinite(render_ms) || render_ms < 0) return;
  const double interval = o_.interval_ms;
  if (render_ms > o_.high * interval) {
    // The scale at which this frame would have taken `aim`: (1 - share) + share x q = aim / t.
    // Where no scale would (the frame's time is not in its pixels: a spike, or a GPU frame bound
    // by its slowest rays), only a step down: the next frames show whether it helped.
    const double want = o_.aim * interval / render_ms - (1 - share_);
    const double s = want > 0 && share_ > 0 ? scale_ * std::sqrt(want / share_) : scale_;
    set_scale(std::clamp(std::min(s, scale_ * 0.95), o_.min_scale, 1.0));
    calm_ = 0;
    return;
  }
  sum_ms_ += render_ms;
  if (++count_ == o_.settle_frames) learn();
  const double raised = std::min(1.0, scale_ * o_.raise);
  const double threshold =
      (share_ * o_.low * o_.raise * o_.raise + (1 - share_) * o_.aim) * interval;
  if (scale_ < 1.0 && predict(render_ms, raised) < threshold) {
    if (++calm_ >= o_.settle_frames) {
      set_scale(raised);
      calm_ = 0;
    }
  } else {
    calm_ = 0;
  }
}

}  // namespace deepcanvas::client_core
