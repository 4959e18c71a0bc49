// Reader for A-Painter `.apa` paintings (version 1), the real artist input used by replays,
// tests and benchmarks. Format: ../shared/data/apainter/README.md (summarised in apa.cpp).
//
// Untrusted input: parse_apa() reads the bytes strictly. Anything that is not exactly one
// version-1 painting (bad magic or version, a truncation anywhere, trailing bytes, a brush index
// out of range, NaN/inf or out-of-range numbers) is rejected with Errc::malformed (or
// Errc::unsupported for another version) and a message that names the byte offset and the
// problem. Nothing is returned on error. Pure function, thread-safe.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"

namespace deepcanvas::paintings {

// Places a painting in the canvas: p_canvas = p_file * scale + offset (metres). Radii scale too.
struct ApaTransform {
  double scale = 1.0;
  double offset[3] = {0, 0, 0};
};

struct ApaPainting {
  std::vector<std::string> brush_names;
  // Mapping to the stroke model: radius = size * scale / 2 and pressure = the sample's pressure
  // (the stamp radius is radius * pressure, as the README suggests); colour RGB from the file
  // with alpha 1; mode paint; opacity 1; hardness Brush's default. Pressure is clamped to
  // [kApaMinPressure, 1]: 0 (a controller that reports none) would make an unpaintable sample,
  // and demo.apa records pressures up to 2 (another device's scale).
  std::vector<protocol::Stroke> strokes;
  std::vector<std::uint8_t> stroke_brush;  // brush name index of each stroke
  std::size_t sample_count = 0;
};

inline constexpr float kApaMinPressure = 1e-3f;

// Parses a whole file image. See the header comment for the error contract.
Result<ApaPainting> parse_apa(std::span<const std::uint8_t> bytes, const ApaTransform& transform);

// Reads `path` and parses it; Errc::not_found / io_error when the file cannot be read; the
// message of every error starts with the path.
Result<ApaPainting> read_apa_file(const std::string& path, const ApaTransform& transform);

// Reads a whole file into memory (shared helper for the other file readers). Refuses files
// larger than `max_bytes` with limit_exceeded.
Result<std::vector<std::uint8_t>> read_file_bytes(const std::string& path,
                                                  std::uint64_t max_bytes = 1ull << 31);

}  // namespace deepcanvas::paintings
