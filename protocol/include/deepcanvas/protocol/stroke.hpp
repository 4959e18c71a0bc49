// The stroke model shared by server, clients and tools: what an artist's stroke is, and the one
// set of rules a stroke must satisfy before it reaches a canvas.
//
// A stroke is a sequence of samples plus one brush. Consecutive samples form capsule segments
// whose radius varies linearly between the two samples; the painter places stamps along them.
//
// Untrusted input: a plain Stroke, Brush or StrokeSample may hold anything (NaN, a position far
// outside the canvas, a negative radius). ValidatedBrush, ValidatedSamples and ValidatedStroke
// can only be made by their make() factories, which check StrokeRules; every consumer that
// changes a canvas (server_core::CanvasService, server_core::Painter) takes these types and
// does not check again. The boundary where bytes become a stroke makes them once: the message
// decoder (messages.hpp) for the wire, and code that builds strokes itself (the .apa reader's
// callers, tests, benchmarks) calls make() with the canvas's rules.
//
// Threading: plain values; the factories are pure.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

#include "deepcanvas/base/result.hpp"

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

// Limits a canvas enforces on incoming strokes. max_samples bounds one message's worth: a whole
// stroke, a stroke_begin's or one stroke_samples' samples (a streamed stroke's total is a
// per-session limit of the server, SessionLimits::max_samples_per_stroke).
//
// Why the last two: the work and memory a stroke costs grow with its length over its radius
// cubed-ish (cells ~ length x (diameter / cell)^2 at ~10 cells across the diameter), so a few
// bytes can ask for gigabytes: two samples 10 km apart with a 5 cm radius want ~10^9 cells.
//   max_extent_m      the largest edge of the stroke's box: the axis-aligned box of its sample
//                     positions, each inflated by its radius (SampleBox). A whole stroke past it
//                     is refused by make() (limit_exceeded) and changes nothing; a streamed
//                     stroke's pieces are each checked by make(), and the server refuses a piece
//                     that would take the stroke's box past it (the stroke keeps what it has).
//   max_stroke_cells  the cells one stroke may create (refinement, balance included). It
//                     cannot be known up front (it depends on what the canvas holds): the
//                     painter stops a stroke that reaches it with limit_exceeded, the canvas
//                     keeping what the stroke had painted (server_core/painter.hpp).
struct StrokeLimits {
  std::size_t max_samples = 100000;
  double max_radius_m = 1000.0;
  double min_radius_m = 1e-5;
  double max_extent_m = 100.0;
  std::uint64_t max_stroke_cells = 4000000;
};

// The box of a stroke's samples, each inflated by its radius (the largest a stamp there can
// be: pressure <= 1), grown sample by sample (a streamed stroke's pieces add to it).
struct SampleBox {
  double min[3] = {INFINITY, INFINITY, INFINITY};
  double max[3] = {-INFINITY, -INFINITY, -INFINITY};
  void add(const StrokeSample& s) noexcept;
  void add(std::span<const StrokeSample> samples) noexcept;
  bool empty() const noexcept { return !(min[0] <= max[0]); }
  // The largest edge in metres; 0 when empty.
  double extent_m() const noexcept;
};

// limit_exceeded when `box` is larger than limits.max_extent_m: "stroke extent: X m exceeds
// the limit of Y m (max_extent_m)".
Result<void> check_extent(const SampleBox& box, const StrokeLimits& limits);

// Canvas bounds as a centred cube of edge `edge_m`.
struct CanvasBounds {
  double edge_m = 20000.0;
};

// Every rule a stroke is checked against, in one place (the checks: stroke.cpp):
//   brush    a known mode; colour, opacity and hardness finite and in 0..1
//   sample   position finite and inside `bounds` (boundary included); radius finite and in
//            [limits.min_radius_m, limits.max_radius_m]; pressure finite and in (0, 1]
//   count    at most limits.max_samples per make() call (limit_exceeded); a whole stroke has at
//            least one sample
//   extent   the SampleBox of the samples of one make() call at most limits.max_extent_m
//            (limit_exceeded); a streamed stroke's whole box is the server's check (above)
// Errors name the first bad field ("brush.opacity", "samples[3].radius"): invalid_argument,
// or limit_exceeded for the count.
struct StrokeRules {
  CanvasBounds bounds;
  StrokeLimits limits;
};

// limit_exceeded when `count` samples are more than one message may carry. The message decoder
// calls it before it reads the samples, so that an oversized array costs no parsing.
Result<void> check_sample_count(std::size_t count, const StrokeLimits& limits);

// A brush that satisfies StrokeRules.
class ValidatedBrush {
 public:
  static Result<ValidatedBrush> make(const Brush& brush);
  const Brush& get() const noexcept { return brush_; }
  BrushMode mode() const noexcept { return brush_.mode; }

 private:
  friend class ValidatedStroke;  // its make() checks the brush with the whole stroke
  explicit ValidatedBrush(const Brush& brush) : brush_(brush) {}
  Brush brush_;
};

// Samples each of which satisfies the StrokeRules they were made with. Empty is valid (a
// stroke_begin without samples). slice() and append() keep every sample valid; the count limit
// is checked by make() only (it bounds one message, not the sum of a streamed stroke's pieces).
class ValidatedSamples {
 public:
  ValidatedSamples() = default;
  // Errors name the sample as samples[index] within `samples`.
  static Result<ValidatedSamples> make(std::vector<StrokeSample> samples, const StrokeRules& rules);

  std::span<const StrokeSample> span() const noexcept { return samples_; }
  std::size_t size() const noexcept { return samples_.size(); }
  bool empty() const noexcept { return samples_.empty(); }
  const StrokeSample& operator[](std::size_t i) const { return samples_[i]; }
  auto begin() const noexcept { return samples_.cbegin(); }
  auto end() const noexcept { return samples_.cend(); }

  // Samples [first, first + count), clamped to what there is.
  ValidatedSamples slice(std::size_t first, std::size_t count) const;
  void append(const ValidatedSamples& more);
  void clear() noexcept { samples_.clear(); }

 private:
  friend class ValidatedStroke;  // its make() checks the samples with the whole stroke
  explicit ValidatedSamples(std::vector<StrokeSample> samples) : samples_(std::move(samples)) {}
  std::vector<StrokeSample> samples_;
};

// A whole stroke that satisfies StrokeRules: a valid brush and at least one valid sample.
class ValidatedStroke {
 public:
  static Result<ValidatedStroke> make(Stroke stroke, const StrokeRules& rules);
  // From parts validated already: adds the one whole-stroke rule (invalid_argument when
  // `samples` is empty). id 0.
  static Result<ValidatedStroke> make(ValidatedBrush brush, ValidatedSamples samples);

  // The id is the server's order, not part of what is validated.
  std::uint64_t id() const noexcept { return id_; }
  void set_id(std::uint64_t id) noexcept { id_ = id; }
  const ValidatedBrush& brush() const noexcept { return brush_; }
  const ValidatedSamples& samples() const& noexcept { return samples_; }
  ValidatedSamples samples() && noexcept { return std::move(samples_); }
  // A plain copy (to encode or log it).
  Stroke to_stroke() const;

 private:
  ValidatedStroke(std::uint64_t id, ValidatedBrush brush, ValidatedSamples samples)
      : id_(id), brush_(brush), samples_(std::move(samples)) {}
  std::uint64_t id_ = 0;
  ValidatedBrush brush_;
  ValidatedSamples samples_;
};

// The same checks as ValidatedStroke::make without keeping the result, for painters outside
// the server that take plain strokes (the OpenVDB comparison peer of deepcanvas-bench).
Result<void> validate_stroke(const Stroke& stroke, const CanvasBounds& bounds,
                             const StrokeLimits& limits);

}  // namespace deepcanvas::protocol
