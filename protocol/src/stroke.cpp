#include "deepcanvas/protocol/stroke.hpp"

#include <cmath>
#include <string>

namespace deepcanvas::protocol {

namespace {
constexpr std::string_view kModeNames[kBrushModeCount] = {"paint", "erase", "recolor", "smudge",
                                                          "pick_up"};

bool in_unit(float v) {
  return std::isfinite(v) && v >= 0.0f && v <= 1.0f;
}

Error bad(std::string what) {
  return make_error(Errc::invalid_argument, std::move(what));
}
}  // namespace

std::string_view brush_mode_name(BrushMode mode) noexcept {
  const auto i = static_cast<int>(mode);
  return i >= 0 && i < kBrushModeCount ? kModeNames[i] : std::string_view("unknown");
}

Result<BrushMode> parse_brush_mode(std::string_view name) {
  for (int i = 0; i < kBrushModeCount; ++i)
    if (kModeNames[i] == name) return static_cast<BrushMode>(i);
  return bad("unknown brush mode '" + std::string(name) + "'");
}

Result<void> validate_brush(const Brush& brush) {
  const auto mode = static_cast<int>(brush.mode);
  if (mode < 0 || mode >= kBrushModeCount) return bad("brush.mode: unknown mode");
  for (int c = 0; c < 4; ++c)
    if (!in_unit(brush.colour[c]))
      return bad("brush.colour[" + std::to_string(c) + "]: must be a number in 0..1");
  if (!in_unit(brush.opacity)) return bad("brush.opacity: must be a number in 0..1");
  if (!in_unit(brush.hardness)) return bad("brush.hardness: must be a number in 0..1");
  return {};
}

Result<void> validate_sample(const StrokeSample& s, std::size_t index, const CanvasBounds& bounds,
                             const StrokeLimits& limits) {
  const double half = bounds.edge_m * 0.5;
  const auto at = [index] { return "samples[" + std::to_string(index) + "]."; };
  for (double v : {s.x, s.y, s.z}) {
    if (!std::isfinite(v)) return bad(at() + "position: not a finite number");
    if (v < -half || v > half) return bad(at() + "position: outside the canvas");
  }
  if (!std::isfinite(s.radius) || s.radius < limits.min_radius_m || s.radius > limits.max_radius_m)
    return bad(at() + "radius: must be within [" + std::to_string(limits.min_radius_m) + ", " +
               std::to_string(limits.max_radius_m) + "] metres");
  if (!std::isfinite(s.pressure) || s.pressure <= 0.0f || s.pressure > 1.0f)
    return bad(at() + "pressure: must be in (0, 1]");
  return {};
}

Result<void> validate_stroke(const Stroke& stroke, const CanvasBounds& bounds,
                             const StrokeLimits& limits) {
  if (auto r = validate_brush(stroke.brush); !r) return r;
  if (stroke.samples.empty()) return bad("samples: a stroke needs at least one sample");
  if (stroke.samples.size() > limits.max_samples)
    return make_error(Errc::limit_exceeded, "samples: " + std::to_string(stroke.samples.size()) +
                                                " exceed the limit of " +
                                                std::to_string(limits.max_samples));
  for (std::size_t i = 0; i < stroke.samples.size(); ++i)
    if (auto r = validate_sample(stroke.samples[i], i, bounds, limits); !r) return r;
  return {};
}

}  // namespace deepcanvas::protocol
