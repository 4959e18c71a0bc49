// Stereo for headsets: the artist's pose (head in the room, the room placed and scaled in the
// canvas) and the two eye cameras it gives.
//
// Room and canvas. A headset tracks the head in the artist's room (metres, OpenXR's stage
// convention: +y up, the head looking down -z, +x to its right). The artist's world scale is
// part of the pose (as in Open Brush and Medium: a two-handed grab scales and moves the world):
// one room metre is `world_scale` canvas metres, and the room's origin lies at `world_origin`
// in the canvas. world_scale 1e4 puts the whole 20 km canvas in a 2 m room; 1e-3 makes a 0.3 mm
// cell 30 cm across at arm's length. Room axes are canvas axes (no world rotation).
//
// Precision. Everything here is double: at 10 km from the canvas centre a double resolves about
// 2e-12 m, so eyes 63 nm apart (63 mm at world_scale 1e-6) are still 30000 steps apart, and the
// ray casters take each eye's position as its own located origin (make_ray_origin): the stereo
// is as exact at the finest cells as at room scale.
//
// Threading: plain values and pure functions.
#pragma once

#include <array>
#include <cstdint>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_core/camera.hpp"

namespace deepcanvas::client_core {

// A unit rotation quaternion (w, x, y, z).
struct Quat {
  double w = 1, x = 0, y = 0, z = 0;
  friend bool operator==(const Quat&, const Quat&) = default;
};
// `v` rotated by `q` (q need not be normalised: it is, here).
DVec3 rotate(const Quat& q, const DVec3& v) noexcept;
// Rotation by `angle_rad` about `axis` (any non-zero length).
Quat axis_angle(const DVec3& axis, double angle_rad) noexcept;
Quat multiply(const Quat& a, const Quat& b) noexcept;
// Normalised linear blend (nlerp) along the shorter arc: enough between samples 11 ms apart.
Quat blend(const Quat& a, const Quat& b, double t) noexcept;

struct ArtistPose {
  DVec3 head;         // head position in the room, metres (the point between the eyes)
  Quat orientation;   // head orientation in the room
  double world_scale = 1;  // canvas metres per room metre, > 0
  DVec3 world_origin;      // the canvas point (metres) at the room's origin
};

// A room point in canvas metres.
DVec3 room_to_canvas(const ArtistPose& pose, const DVec3& room_point) noexcept;

// The two-handed grab (Open Brush, Medium): both grips held, the hands at left0/right0 in the
// room when the grab began (the pose then `at_grab`) and at left/right now. Pulling the hands
// apart makes the world larger (world_scale shrinks by the ratio of their distances), and the
// canvas point that was between the hands at the start stays between them, so the artist
// scales and moves the world about the hands. Hands closer than 1 mm keep the scale.
ArtistPose grab_world(const ArtistPose& at_grab, const DVec3& left0, const DVec3& right0,
                      const DVec3& left, const DVec3& right) noexcept;

// The headset's eyes: each rendered at width x height (the paper's Vive: 1680 x 1512 an eye)
// with a symmetric vertical field of view, from the head pose and the eye offsets.
struct EyeSetup {
  double ipd_m = 0.063;  // distance between the eyes in the room
  double vfov_deg = 100;
  std::uint32_t width = 1680, height = 1512;
};

// The left and right eye cameras at `render_scale` (0, 1] of the eye size (each side at least
// 1 pixel): positions head -/+ ipd/2 along the head's right axis, both looking along the head's
// forward axis, in canvas metres (eyes world_scale * ipd apart). invalid_argument for a bad
// pose (non-finite, world_scale <= 0) or setup.
Result<std::array<Camera, 2>> eye_cameras(const ArtistPose& pose, const EyeSetup& eyes,
                                          double render_scale = 1.0);

// Dynamic resolution with hysteresis: the render scale (fraction of each eye side) that keeps
// frames inside the headset's interval. A frame that took more than `high` of the interval drops
// the scale at once to what the cost model predicts would take `aim` of it (at least a 0.95
// step; only that step where no scale would reach `aim` but a lower one would not have missed). The scale rises after
// `settle_frames` frames in a row whose recent load, predicted one `raise` step up, stays below
// the rise threshold; it rises as far as the model says stays below it, at most `max_raise` a
// step, never above 1. The gap between the rise threshold and `high` keeps it from oscillating
// around the limit. Pure; one per render loop.
//
// Cost model: a frame's time is a share that scales with the pixels (scale squared) and a rest
// that does not. The pixel share starts at 1 (lavapipe, where every ray is CPU work) and is
// learnt from the mean frame time before and after each change of scale. On a GPU a frame can
// be bound by its slowest rays rather than its pixel count (an H200's stereo frame took about
// the same time at scale 0.25 as at 1): there a drop buys little and the share falls towards 0.
//
// Frames the scale cannot save: a GPU at 90 Hz has a few frames in a hundred over `high`
// whatever the scale (single spikes, and on a fresh H200 bursts of several frames with ~6 ms
// more host time every ~0.34 s). While the share is below one half, a frame over `high` counts
// only when another of the last kRecent frames was over it too, and the rise looks at the
// recent load (the second largest of the last kRecent frames), so a lone spike neither drops
// the scale nor holds it down. A frame the model says no scale would have kept under `high`
// drops nothing, unless all of the last kRecent frames were over it: then the scale drops by
// 0.8, enough for the next frames to re-teach the share. The rise threshold goes from `low` x
// raise^2 (share 1: the old rule "below `low`") to `aim` (share 0: a rise costs nothing).
class ResolutionController {
 public:
  struct Options {
    double interval_ms = 1000.0 / 90.0;
    double min_scale = 0.25;
    double high = 0.85, aim = 0.6, low = 0.45;
    int settle_frames = 30;
    double raise = 1.05, max_raise = 1.25;
  };
  static constexpr int kRecent = 8;
  explicit ResolutionController(Options o) : o_(o) {}
  double scale() const noexcept { return scale_; }
  // The share of the frame time that scales with the pixels, as learnt so far (0..1).
  double pixel_share() const noexcept { return share_; }
  // The render time of the frame just rendered at scale(): updates the scale for the next one.
  void frame_done(double render_ms) noexcept;
  // A probe frame rendered at `probe_scale` before the first displayed one took `probe_ms`:
  // starts at the scale that would take `aim` of the interval (cost ~ pixels ~ scale^2), so the
  // first displayed frame does not have to miss to find it. Ignored when not finite or <= 0.
  void calibrate(double probe_scale, double probe_ms) noexcept;
  // Two probe frames of the same view at two scales: also sets the pixel share from how their
  // times differ, so a frame that costs the same at any scale (a GPU bound by its slowest rays)
  // starts at scale 1 instead of where the pixel model would put it. Ignored when not finite,
  // <= 0 or the scales are equal.
  void calibrate(double scale_a, double ms_a, double scale_b, double ms_b) noexcept;
  // The largest scale in [min_scale, scale()] that the cost model (the pixel share learnt so
  // far) says renders within `budget_ms`, given a frame of `ms_at` at scale `at` (min_scale
  // where none does). For a frame whose slot is partly spent (the calibration probes): it is
  // rendered smaller, and not passed to frame_done().
  double scale_within(double budget_ms, double at, double ms_at) const noexcept;
  const Options& options() const noexcept { return o_; }

 private:
  // The time a frame that took `ms` at scale() would take at scale `to`.
  double predict(double ms, double to) const noexcept;
  void set_scale(double s) noexcept;
  void learn() noexcept;
  // The second largest of the recent frames at this scale (the largest while there is one).
  double recent_load() const noexcept;
  Options o_;
  double scale_ = 1.0;
  int calm_ = 0;
  double share_ = 1.0;
  // This scale's frames so far (frames over `high` left out), and the last scale's mean.
  double sum_ms_ = 0;
  int count_ = 0;
  double last_mean_ms_ = 0, last_scale_ = 0;
  // The last kRecent frame times at this scale, a ring.
  std::array<double, kRecent> recent_{};
  int recent_count_ = 0;
};

}  // namespace deepcanvas::client_core
