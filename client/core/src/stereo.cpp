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

double ResolutionController::scale_within(double budget_ms, double at, double ms_at) const noexcept {
  if (!(std::isfinite(budget_ms) && std::isfinite(at) && at > 0 && std::isfinite(ms_at) && ms_at > 0))
    return scale_;
  // ms_at x ((1 - share) + share x (s / at)^2) <= budget_ms.
  const double want = budget_ms / ms_at - (1 - share_);
  double s = scale_;
  if (want <= 0)
    s = o_.min_scale;
  else if (share_ > 0)
    s = at * std::sqrt(want / share_);
  return std::clamp(s, o_.min_scale, scale_);
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
  recent_count_ = 0;
  scale_ = s;
}

// settle_frames frames at this scale: compares their mean with the last scale's. Model: the
// ratio of the means r = (1 - share) + share x q, q the ratio of the pixel counts.
void ResolutionController::learn() noexcept {
  if (last_scale_ <= 0 || last_mean_ms_ <= 0) return;
  const double q = (scale_ / last_scale_) * (scale_ / last_scale_);
  // A small step says little: what the content and the view did meanwhile swamps it.
  if (std::abs(1 - q) < 0.2) return;
  const double r = (sum_ms_ / count_) / last_mean_ms_;
  const double seen = std::clamp((1 - r) / (1 - q), 0.0, 1.0);
  share_ = 0.5 * share_ + 0.5 * seen;
}

double ResolutionController::recent_load() const noexcept {
  const int n = std::min(recent_count_, kRecent);
  double first = 0, second = 0;
  for (int i = 0; i < n; ++i) {
    const double v = recent_[static_cast<std::size_t>(i)];
    if (v > first) {
      second = first;
      first = v;
    } else if (v > second) {
      second = v;
    }
  }
  return n >= 2 ? second : first;
}

void ResolutionController::frame_done(double render_ms) noexcept {
  if (!std::isfinite(render_ms) || render_ms < 0) return;
  const double interval = o_.interval_ms;
  recent_[static_cast<std::size_t>(recent_count_++ % kRecent)] = render_ms;
  if (recent_count_ >= 2 * kRecent) recent_count_ -= kRecent;  // keeps the ring's position
  if (render_ms > o_.high * interval) {
    const double high = o_.high * interval;
    // A lone spike where the pixels are not most of the cost: the scale could not have saved
    // it; a second one among the recent frames says the load itself is too high.
    if (share_ < 0.5 && recent_load() <= high) return;
    calm_ = 0;
    sum_ms_ += render_ms;  // part of this scale's load, for learning the share
    if (++count_ == o_.settle_frames) learn();
    // The scale at which this frame would have taken `aim`: (1 - share) + share x q = aim / t.
    const double want = o_.aim * interval / render_ms - (1 - share_);
    double s = scale_;
    if (want > 0 && share_ > 0) {
      s = std::min(scale_ * std::sqrt(want / share_), scale_ * 0.95);
    } else if (predict(render_ms, o_.min_scale) <= high) {
      s = scale_ * 0.95;  // no scale reaches `aim`, a lower one would still not have missed
    } else if (recent_count_ >= kRecent &&
               *std::min_element(recent_.begin(), recent_.end()) > high) {
      // The model says no scale helps, yet every recent frame is over: it may have learnt
      // wrong. A drop large enough to learn from (pixels x 0.64) shows whether it helps.
      s = scale_ * 0.8;
    }
    set_scale(std::clamp(s, o_.min_scale, 1.0));
    return;
  }
  sum_ms_ += render_ms;
  if (++count_ == o_.settle_frames) learn();
  if (scale_ >= 1.0) return;
  const double load = recent_load();
  const double raised = std::min(1.0, scale_ * o_.raise);
  const double threshold =
      (share_ * o_.low * o_.raise * o_.raise + (1 - share_) * o_.aim) * interval;
  if (predict(load, raised) >= threshold) {
    calm_ = 0;
    return;
  }
  if (++calm_ < o_.settle_frames) return;
  // As far up as the model keeps the recent load below the threshold, at most max_raise.
  const double room = threshold / std::max(load, 1e-9) - (1 - share_);
  const double up = share_ > 0 && room > 0 ? scale_ * std::sqrt(room / share_) : scale_ * o_.max_raise;
  set_scale(std::min({1.0, std::max(raised, std::min(up, scale_ * o_.max_raise))}));
  calm_ = 0;
}

}  // namespace deepcanvas::client_core
