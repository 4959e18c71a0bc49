// The stroke model shared by server, clients and tools: what an artist's stroke is.
//
// A stroke is a sequence of samples plus one brush. Consecutive samples form capsule segments
// whose radius varies linearly between the two samples; the painter places stamps along them.
// Untrusted input: every Stroke that arrives from outside (wire, .apa file, stroke log) passes
// validate_stroke() before it reaches a canvas.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string_view>
#include <vector>

#include "deepcanvas/protocol/result.hpp"

namespace deepcanvas::protocol {

enum class BrushMode : std::uint8_t {
  paint = 0,    // blend the brush colour and density in
  erase = 1,    // remove density (and colour with it)
  recolor = 2,  // change colour, keep density
  smudge = 3,   // drag colour along the stroke, mixing it with what is there
  pick_up = 4,  // read colour and density at the first sample; changes nothing
};
inline constexpr int kBrushModeCount = 5;

std::string_view brush_mode_name(BrushMode mode) noexcept;
Result<BrushMode> parse_brush_mode(std::string_view name);

struct Brush {
  BrushMode mode = BrushMode::paint;
  float colour[4] = {1, 1, 1, 1};  // linear RGB in 0..1, alpha = density of the paint in 0..1
  float opacity = 1.0f;            // stroke-level opacity in 0..1 (no build-up beyond it)
  float hardness = 0.5f;           // 0 = soft falloff from the centre, 1 = hard edge
};

struct StrokeSample {
  double x = 0, y = 0, z = 0;  // canvas metres
  float radius = 0.01f;        // metres, > 0; the stamp radius is radius * pressure
  float pressure = 1.0f;       // (0, 1]
  std::uint32_t t_ms = 0;      // artist's clock, for replays at recorded pace
};

struct Stroke {
  std::uint64_t id = 0;  // assigned by the server when it orders strokes; 0 from clients
  Brush brush;
  std::vector<StrokeSample> samples;
};

// Limits a canvas enforces on incoming strokes.
struct StrokeLimits {
  std::size_t max_samples = 100000;
  double max_radius_m = 1000.0;
  double min_radius_m = 1e-5;
};

// Canvas bounds as a centred cube of edge `edge_m`.
struct CanvasBounds {
  double edge_m = 20000.0;
};

// invalid_argument naming the first bad field (sample index included) for: no samples, NaN or
// infinite values, positions outside the canvas, radius or pressure out of range, colour or
// opacity or hardness outside 0..1, unknown mode; limit_exceeded for too many samples.
Result<void> validate_stroke(const Stroke& stroke, const CanvasBounds& bounds,
                             const StrokeLimits& limits);

// The two halves of validate_stroke, for strokes that arrive in pieces (stroke_begin carries the
// brush, stroke_samples carry samples). validate_sample names the sample as samples[index].
Result<void> validate_brush(const Brush& brush);
Result<void> validate_sample(const StrokeSample& sample, std::size_t index,
                             const CanvasBounds& bounds, const StrokeLimits& limits);

}  // namespace deepcanvas::protocol
