// Navigation of the studio window: an orbit view (a focus point, a distance, yaw and pitch) and
// the moves an artist makes with the mouse and keys, turned into a Camera for the ray casters.
//
// Scale. The canvas is about 20 km across with cells down to 0.3 mm (2^26 scales); the view
// spans all of them. Every quantity is a double in metres: the focus point's absolute position
// keeps 2^-52 of 20 km (about 4e-12 m) of precision, far below the finest cell, and the ray
// casters locate the camera in cell-local coordinates from it (make_ray_origin), so nothing
// loses precision at any zoom. The distance is clamped to [kMinDistance, kMaxDistance].
//
// Zoom toward a point: each wheel notch scales the distance from the camera to the point under
// the cursor by a constant factor (kNotchFactor per notch in, its inverse out), moving the focus
// point along with it, so that point stays under the cursor. A notch in and a notch out at the
// same point are exact inverses up to rounding: twenty in and twenty out return to the view
// they started from (tested).
//
// Threading: plain values, no synchronisation.
#pragma once

#include <cstdint>
#include <optional>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_core/camera.hpp"

namespace deepcanvas::client_core {

struct OrbitView {
  static constexpr double kMinDistance = 1e-4;  // 0.1 mm: a third of the finest cell
  static constexpr double kMaxDistance = 1e5;   // 100 km: the whole canvas, small
  static constexpr double kNotchFactor = 0.8;   // distance factor per wheel notch in

  DVec3 focus{0, 0, 0};  // metres: the point the view orbits, at the centre of the image
  double distance = 3;   // metres from the eye to the focus
  double yaw_rad = 0.6;  // around +y (the paintings' up), 0: looking along -z
  double pitch_rad = 0.35;  // above the horizon, in (-pi/2, pi/2)
  double vfov_deg = 45;

  // The eye position and the unit view direction (eye -> focus).
  DVec3 forward() const noexcept;
  DVec3 eye() const noexcept;
  // The camera for an image of width x height (+y up).
  Result<Camera> camera(std::uint32_t width, std::uint32_t height) const;
  // Metres one pixel covers at `depth` metres from the eye, for an image `height` pixels tall.
  double metres_per_pixel(double depth, std::uint32_t height) const noexcept;

  // Orbit around the focus by the pointer's motion in pixels (a full image height turns by pi).
  void orbit(double dx_px, double dy_px, std::uint32_t height) noexcept;
  // Move the focus (and the eye) in the image plane so the point at the focus depth follows the
  // pointer's motion in pixels.
  void pan(double dx_px, double dy_px, std::uint32_t height) noexcept;
  // Move the eye toward the focus by `factor` of the distance (< 1: closer).
  void dolly(double factor) noexcept;
  // Zoom `notches` (> 0: in) toward `point` (metres; the surface under the cursor, or a point at
  // the focus depth): the eye-to-point distance scales by kNotchFactor^notches, and the focus
  // moves with it so that `point` stays where it is in the image.
  void zoom_toward(const DVec3& point, double notches) noexcept;
  // Look at `box` from the current direction, at the distance that fits it in the image.
  void frame(const DAabb& box, std::uint32_t width, std::uint32_t height) noexcept;
  // A view that looks from `eye` at `target` (another artist's view).
  static std::optional<OrbitView> looking_at(const DVec3& eye, const DVec3& target,
                                             double vfov_deg) noexcept;
};

// The point `depth` metres along pixel (px, py)'s ray (pixel coordinates may be fractional, the
// window's cursor), and that ray's unit direction.
DVec3 ray_direction_at(const Camera& camera, double px, double py) noexcept;

}  // namespace deepcanvas::client_core
