// The scale-correct density model: how a cell's stored alpha becomes opacity, how it changes
// when a cell is refined or coarsened, and how a brush's density maps to cells. Shared by the
// server's painter and the clients' renderers (GPU and CPU reference), so it is pure math with
// no dependencies. Thread-safe (the only state is constant tables).
//
// Model
// -----
// A cell stores RGBA8; its alpha a = A/255 is the opacity of a path ONE CELL EDGE long through
// the cell. So the cell's extinction coefficient is sigma = -ln(1 - a) / h for cell edge h, and a
// ray segment of length t*h inside it (t measured in cell edges, the cell-local unit of the ray
// caster) transmits (1 - a)^t. No world units appear: a renderer working in cell-local frames
// only needs a and t. Colour RGB is emitted/absorbed colour, composited front to back:
//   C += T * (1 - (1-a)^t) * rgb;  T *= (1-a)^t.
//
// Level changes keep sigma:
//   refine  (d -> d+1): child a' = 1 - (1 - a)^(1/2); rgb inherited.
//   coarsen (d+1 -> d): parent a = 1 - (prod_i (1 - a_i))^(2/8) (the mean of sigma over the
//                       eight children, times the doubled edge; any opaque child makes the
//                       parent opaque); rgb = average weighted by each child's alpha (all
//                       alphas 0 gives RGBA 0, the canonical empty cell, see below).
// So a region looks the same whether it is stored at depth d or d+1, up to 8-bit quantisation:
// refine() then coarsen() of one cell returns within 1/255 of the start (exactly the start for
// most values; coarsen_uniform() chooses the exact inverse where one exists, so merging eight
// untouched children of a refined cell restores the parent's value whenever 8 bits allow).
//
// Brushes are defined relative to the stamp, not to metres: a stroke with colour alpha A and
// opacity O has optical depth -ln(1 - A*O) across one stamp DIAMETER D. Painted at cell edge h a
// fully covered cell gets a = 1 - (1 - A*O)^(h/D); with ~10 cells across D that is the same
// number of cells at every scale, so a stroke painted at 1 mm and at 1 km looks equally
// transparent. Coverage c (hardness falloff, 0..1) scales A*O: a = 1 - (1 - c*A*O)^(h/D).
//
// Canonical empty: a cell whose alpha quantises to 0 stores RGBA 0 (no stray colour), so empty
// space is uniform and merges back.
//
// Quantisation tolerance: every function below rounds to nearest; painter results are within
// 1/255 per channel of the exact real-valued model, and merging uniform children is accepted
// when all channels of all eight children lie within kMergeTolerance quanta of each other.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace deepcanvas::protocol::density {

inline constexpr int kMergeTolerance = 1;  // quanta (1/255) per channel

struct Rgba8 {
  std::uint8_t r = 0, g = 0, b = 0, a = 0;
};

inline constexpr Rgba8 unpack(std::uint32_t v) noexcept {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8),
          static_cast<std::uint8_t>(v >> 16), static_cast<std::uint8_t>(v >> 24)};
}
inline constexpr std::uint32_t pack(Rgba8 c) noexcept {
  if (c.a == 0) return 0;  // canonical empty
  return std::uint32_t{c.r} | (std::uint32_t{c.g} << 8) | (std::uint32_t{c.b} << 16) |
         (std::uint32_t{c.a} << 24);
}

// round(v * 255) for v clamped to [0, 1], halves away from zero (std::lround's rule) without
// the libm call (the painter quantises three channels per blended cell): y's integer part,
// plus one when its fraction (y - trunc(y), exact) is at least a half. NaN gives 0.
inline std::uint8_t quantise(double v) noexcept {
  const double y = std::clamp(v, 0.0, 1.0) * 255.0;
  if (!(y >= 0.0)) return 0;
  const auto r = static_cast<std::uint32_t>(y);
  return static_cast<std::uint8_t>(r + (y - r >= 0.5 ? 1u : 0u));
}

// Transmittance of t cell edges through a cell of stored alpha a (0..1).
inline double transmittance(double a, double t) noexcept {
  return std::pow(1.0 - a, t);
}
// Extinction per metre for a cell of edge h_m (infinite for a = 1).
inline double sigma_per_m(double a, double h_m) noexcept {
  return -std::log1p(-a) / h_m;
}

// Alpha after refining `levels` times (levels may be negative: the exact real-valued inverse).
inline double alpha_at_level_offset(double a, int levels) noexcept {
  return 1.0 - std::pow(1.0 - a, std::ldexp(1.0, -levels));
}

// One refinement of an 8-bit alpha: round to nearest, but never 0 for a non-zero parent
// (density does not vanish by refining).
std::uint8_t refine_alpha(std::uint8_t a) noexcept;
std::uint32_t refine_rgba(std::uint32_t rgba) noexcept;

// The parent of eight children (RGBA8 each), per the model above.
std::uint32_t coarsen_rgba(const std::uint32_t children[8]) noexcept;

// The value an interior cell carries for its eight children (RGBA8 each): what a client shows
// in place of a subtree it has not received yet (a progressive join, PROTOCOL.md 4.4). Sigma
// is averaged as in coarsen_rgba, but an opaque child counts as kOpaqueOpticalDepth per edge
// (coarsen_rgba's "any opaque child makes the parent opaque" would turn one opaque finest cell
// into a 20 km opaque cube a few levels up), and RGB is weighted by each child's optical depth.
// A sheet one child thick keeps its optical depth at every level; a thin line fades by 2x a
// level, as its share of the volume does. 0 exactly when all eight children are 0 (a faint
// child keeps alpha 1), so an interior value of 0 says the whole subtree is empty. Pure
// arithmetic on a fixed table: the same bytes on every machine.
std::uint32_t filter_rgba(const std::uint32_t children[8]) noexcept;

// True when all eight children are within kMergeTolerance quanta per channel.
bool uniform(const std::uint32_t children[8]) noexcept;

// Per-cell alpha of a brush of density A*O (0..1) at coverage c (0..1), painted into cells of
// edge h for a stamp of diameter D (h_over_d = h / D).
inline double brush_cell_alpha(double density, double coverage, double h_over_d) noexcept {
  const double k = std::clamp(density * coverage, 0.0, 1.0);
  if (k >= 1.0) return 1.0;
  return 1.0 - std::pow(1.0 - k, h_over_d);
}

// "Over" of the stroke (cell alpha q, colour rgb) on the pre-stroke cell: alpha adds in sigma
// (transmittances multiply), colour is the usual premultiplied over. Scale-correct: applying it
// at depth d or at d+1 then coarsening gives the same alpha.
std::uint32_t paint_over(std::uint32_t pre, double q, const float rgb[3]) noexcept;
// Erase removes a fraction e of the density: sigma' = (1 - e) sigma. An opaque cell (a = 1,
// infinite sigma) is treated as optical depth kOpaqueOpticalDepth per cell edge.
inline constexpr double kOpaqueOpticalDepth = 6.931471805599453;  // ln(1024)
std::uint32_t erase(std::uint32_t pre, double e) noexcept;
// Recolour towards rgb by weight w (0..1), density kept.
std::uint32_t recolor(std::uint32_t pre, double w, const float rgb[3]) noexcept;

// Front-to-back compositing state, the reference for renderers.
struct Composite {
  double rgb[3] = {0, 0, 0};
  double transmittance = 1.0;
  // A ray segment of t cell edges through a cell of RGBA8 `cell`.
  void add(std::uint32_t cell, double t) noexcept {
    const Rgba8 c = unpack(cell);
    if (c.a == 0 || t <= 0) return;
    const double tr = density::transmittance(c.a / 255.0, t);
    const double w = transmittance * (1.0 - tr);
    rgb[0] += w * c.r / 255.0;
    rgb[1] += w * c.g / 255.0;
    rgb[2] += w * c.b / 255.0;
    transmittance *= tr;
  }
};

}  // namespace deepcanvas::protocol::density
