// The stroke rules (StrokeRules in stroke.hpp): the only place where a brush or a sample is
// checked. Everything that takes a Validated* type relies on these checks having passed.
#include "deepcanvas/protocol/stroke.hpp"

#include <algorithm>
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

Result<void> check_brush(const Brush& brush) {
  const auto mode = static_cast<int>(brush.mode);
  if (mode < 0 || mode >= kBrushModeCount) return bad("brush.mode: unknown mode");
  for (int c = 0; c < 4; ++c)
    if (!in_unit(brush.colour[c]))
      return bad("brush.colour[" + std::to_string(c) + "]: must be a number in 0..1");
  if (!in_unit(brush.opacity)) return bad("brush.opacity: must be a number in 0..1");
  if (!in_unit(brush.hardness)) return bad("brush.hardness: must be a number in 0..1");
  return {};
}

Result<void> check_sample(const StrokeSample& s, std::size_t index, const StrokeRules& rules) {
  const double half = rules.bounds.edge_m * 0.5;
  const auto at = [index] { return "samples[" + std::to_string(index) + "]."; };
  for (double v : {s.x, s.y, s.z}) {
    if (!std::isfinite(v)) return bad(at() + "position: not a finite number");
    if (v < -half || v > half) return bad(at() + "position: outside the canvas");
  }
  const StrokeLimits& lim = rules.limits;
  if (!std::isfinite(s.radius) || s.radius < lim.min_radius_m || s.radius > lim.max_radius_m)
    return bad(at() + "radius: must be within [" + std::to_string(lim.min_radius_m) + ", " +
               std::to_string(lim.max_radius_m) + "] metres");
  if (!std::isfinite(s.pressure) || s.pressure <= 0.0f || s.pressure > 1.0f)
    return bad(at() + "pressure: must be in (0, 1]");
  return {};
}

// Each sample first, so that the extent is only measured over finite, in-range values.
Result<void> check_samples(std::span<const StrokeSample> samples, const StrokeRules& rules) {
  if (auto r = check_sample_count(samples.size(), rules.limits); !r) return r;
  for (std::size_t i = 0; i < samples.size(); ++i)
    if (auto r = check_sample(samples[i], i, rules); !r) return r;
  SampleBox box;
  box.add(samples);
  return check_extent(box, rules.limits);
}

// Brush, then at least one sample, then the count, then each sample, then the extent: the first
// bad field is the one reported.
Result<void> check_not_empty(std::size_t samples) {
  if (samples == 0) return bad("samples: a stroke needs at least one sample");
  return {};
}

Result<void> check_stroke(const Stroke& stroke, const StrokeRules& rules) {
  if (auto r = check_brush(stroke.brush); !r) return r;
  if (auto r = check_not_empty(stroke.samples.size()); !r) return r;
  return check_samples(stroke.samples, rules);
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

Result<void> check_sample_count(std::size_t count, const StrokeLimits& limits) {
  if (count > limits.max_samples)
    return make_error(Errc::limit_exceeded, "samples: " + std::to_string(count) +
                                                " exceed the limit of " +
                                                std::to_string(limits.max_samples));
  return {};
}

void SampleBox::add(const StrokeSample& s) noexcept {
  const double p[3] = {s.x, s.y, s.z};
  for (int a = 0; a < 3; ++a) {
    min[a] = std::min(min[a], p[a] - double{s.radius});
    max[a] = std::max(max[a], p[a] + double{s.radius});
  }
}

void SampleBox::add(std::span<const StrokeSample> samples) noexcept {
  for (const auto& s : samples) add(s);
}

double SampleBox::extent_m() const noexcept {
  if (empty()) return 0;
  return std::max({max[0] - min[0], max[1] - min[1], max[2] - min[2]});
}

Result<void> check_extent(const SampleBox& box, const StrokeLimits& limits) {
  const double e = box.extent_m();
  if (!(e <= limits.max_extent_m))
    return make_error(Errc::limit_exceeded, "stroke extent: " + std::to_string(e) +
                                                " m exceeds the limit of " +
                                                std::to_string(limits.max_extent_m) +
                                                " m (max_extent_m)");
  return {};
}

Result<ValidatedBrush> ValidatedBrush::make(const Brush& brush) {
  if (auto r = check_brush(brush); !r) return std::move(r).error();
  return ValidatedBrush(brush);
}

Result<ValidatedSamples> ValidatedSamples::make(std::vector<StrokeSample> samples,
                                                const StrokeRules& rules) {
  if (auto r = check_samples(samples, rules); !r) return std::move(r).error();
  return ValidatedSamples(std::move(samples));
}

ValidatedSamples ValidatedSamples::slice(std::size_t first, std::size_t count) const {
  const std::size_t from = std::min(first, samples_.size());
  const std::size_t to = from + std::min(count, samples_.size() - from);
  return ValidatedSamples(
      std::vector<StrokeSample>(samples_.begin() + static_cast<std::ptrdiff_t>(from),
                                samples_.begin() + static_cast<std::ptrdiff_t>(to)));
}

void ValidatedSamples::append(const ValidatedSamples& more) {
  samples_.insert(samples_.end(), more.samples_.begin(), more.samples_.end());
}

Result<ValidatedStroke> ValidatedStroke::make(Stroke stroke, const StrokeRules& rules) {
  if (auto r = check_stroke(stroke, rules); !r) return std::move(r).error();
  return ValidatedStroke(stroke.id, ValidatedBrush(stroke.brush),
                         ValidatedSamples(std::move(stroke.samples)));
}

Result<ValidatedStroke> ValidatedStroke::make(ValidatedBrush brush, ValidatedSamples samples) {
  if (auto r = check_not_empty(samples.size()); !r) return std::move(r).error();
  return ValidatedStroke(0, brush, std::move(samples));
}

Stroke ValidatedStroke::to_stroke() const {
  Stroke s;
  s.id = id_;
  s.brush = brush_.get();
  s.samples.assign(samples_.begin(), samples_.end());
  return s;
}

Result<void> validate_stroke(const Stroke& stroke, const CanvasBounds& bounds,
                             const StrokeLimits& limits) {
  return check_stroke(stroke, StrokeRules{bounds, limits});
}

}  // namespace deepcanvas::protocol
