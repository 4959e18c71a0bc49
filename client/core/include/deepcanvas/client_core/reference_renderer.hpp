// The CPU reference ray caster: the same algorithm the GPU's raycast.comp runs, in double
// precision (or, for comparisons with the GPU, in float), used by tests and as the ground truth
// the GPU image is checked against.
//
// Algorithm (cell-local ray casting, the paper's "accurate ray traversal"):
//  * A ray's state is (cell, p): p is the current point in the cell's own frame (origin at the
//    centre, edge 1, p in [-0.5, 0.5]^3). The ray direction d is the same unit vector in every
//    frame (frames differ by a uniform scale), distances t are in units of the current cell's
//    edge. No world coordinate is touched after the start, so precision does not depend on the
//    cell's size or its distance from the canvas centre.
//  * Start: a camera inside the canvas is located once per frame on the CPU (locate_point, in
//    double); a ray from outside enters through the canvas AABB, computed in the canvas frame
//    (canvas edge 1) and stepped down into its root.
//  * Internal cell: go down through first_child into the child containing p (on a face: the
//    side the ray is heading to), p_child = 2 p - offset(child bits), offset = +-1/2 per axis,
//    until a leaf.
//  * Leaf: slab test in local coordinates gives the exit distance t and exit face; the segment
//    is composited; the exit point gets exactly +-1/2 on the exit axis.
//  * Neighbour across the exit face: the sibling (index ^ axis bit) when the face is inside the
//    parent; otherwise the root array (roots) or the group's link N (the parent's same-depth
//    neighbour): N a leaf -> the coarser leaf, p_parent = (p + offset(slot)) / 2; else the
//    same-depth cell first_child[N] + (slot ^ axis bit). p's exit coordinate flips sign.
//    Then down again if the neighbour is internal (finer).
//  * Empty subtrees (RenderOptions::skip_empty_subtrees, where PoolView::filtered_interiors):
//    an interior cell of colour 0 has nothing below it, so the ray treats it as a leaf (it stops
//    going down there), and a link N of colour 0 counts as the coarser leaf (the ray climbs a
//    level into it instead of entering its child). Empty space around and between paintings is
//    then crossed in cells as large as it is, not in the 2:1-balanced small cells the tree keeps
//    there. Only empty cells are merged, so the image is the same (to rounding: the points
//    where a ray enters painted cells are reached through other frames).
//  * Descent variant (Stepping::descent, for the g3_vs_descent benchmark): the same ray, but the
//    neighbour is found by computing its integer address and descending from the root at every
//    step. It visits the same cells with the same local points, so the images are identical
//    (bit for bit; the tests check it).
//
// Compositing (front to back, premultiplied): the density model of the painting side
// (protocol/density_model.hpp): a leaf's alpha a (= A/255) is the opacity of a path one cell
// edge long, so a segment of t cell-local units transmits (1 - a)^t. With transmittance T and
// colour C so far: C += T * (1 - (1 - a)^t) * rgb, T *= (1 - a)^t. At the end C += T *
// background. Early termination: the ray stops once T < termination_transmittance (default
// 1/512: what is left could change no channel by more than half an 8-bit step).
//
// Content cull (RenderOptions::content_bounds, optional): a box (metres) that holds every leaf
// with non-zero alpha (painted_bounds gives the tight one). A ray that misses the box is
// background without a single step; a ray that hits it stops once it has gone past the box's
// far side (distance travelled, summed per step in cell edges times the cell's size in metres,
// beyond 1 + 1/64 of the exit distance: the slack covers float rounding of the sum on the GPU).
// RenderOptions::content_boxes refines the one box into a few for one view (a ray that misses
// them all is background, one that hits some stops past the farthest of their far sides).
// Only empty cells are skipped, so the image is the same with and without the cull (tested,
// bit for bit in double). Without it a ray crosses the 2:1-balanced empty cells around the
// painting down to the canvas boundary: on a framed painting most of the steps of a frame.
//
// Untrusted pools: every index followed is bounds-checked; a ray meeting a bad index or more
// than max_steps_per_ray steps stops there (counted in RenderStats), it never reads out of range
// or loops forever.
//
// Threading: render_reference may use several threads internally (options.threads); the pools
// must not change while it runs.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/pool_view.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_core {

enum class Stepping { g3, descent };
enum class Precision { float64, float32 };

// RenderOptions::content_boxes holds at most this many (the GPU's kRaycastCullBoxes).
inline constexpr std::size_t kMaxContentBoxes = 8;
// A list of at most kMaxContentBoxes boxes (metres), held inline.
struct ContentBoxes {
  std::array<DAabb, kMaxContentBoxes> box{};
  std::size_t count = 0;
  std::span<const DAabb> boxes() const noexcept {
    return {box.data(), std::min(count, box.size())};
  }
  void push_back(const DAabb& b) noexcept {
    if (count < box.size()) box[count++] = b;
  }
};

struct RenderOptions {
  std::array<double, 3> background{0.0, 0.0, 0.0};  // linear RGB in [0, 1]
  double termination_transmittance = 1.0 / 512.0;   // 0 disables early termination
  std::uint32_t max_steps_per_ray = 1u << 16;
  Stepping stepping = Stepping::g3;
  Precision precision = Precision::float64;
  unsigned threads = 1;  // 0 = hardware concurrency
  // Every leaf with non-zero alpha lies inside this box (metres); rays skip what lies outside
  // it (see "Content cull" above). nullopt: no cull. A box that misses painted leaves cuts them
  // out of the image: give painted_bounds of the same pools, or a box containing it.
  std::optional<DAabb> content_bounds;
  // No leaf has non-zero alpha (a StreamingReplica epoch without a content box: nothing painted
  // yet): every ray is background without a step, and content_bounds is not looked at. Without
  // it an empty canvas costs a full frame (every ray crosses the canvas's empty cells). A canvas
  // that does have paint loses it from the image: set it only from the same pools' state.
  bool content_empty = false;
  // Finer than content_bounds, for one camera (content_boxes_for_view makes them): every painted
  // leaf that a ray of this frame can reach lies in one of these boxes (metres). When set they
  // replace content_bounds: a ray that misses all of them is background; one that hits some
  // stops past 1 + 1/64 of the farthest exit among them. An empty list: nothing painted is in
  // view, every ray is background. Each as content_bounds must be.
  std::optional<ContentBoxes> content_boxes;
  // Step over empty subtrees whole (see "Empty subtrees" above); used only where the pools say
  // their interior values are current (PoolView::filtered_interiors).
  bool skip_empty_subtrees = true;
};

// Linear RGBA per pixel, row 0 at the top: rgb composited over the background, a = 1 - T (the
// ray's total opacity, background excluded).
struct RenderImage {
  std::uint32_t width = 0, height = 0;
  std::vector<double> rgba;  // 4 per pixel
  const double* pixel(std::uint32_t x, std::uint32_t y) const {
    return &rgba[(std::size_t{y} * width + x) * 4];
  }
  // 8-bit RGBA, each channel round(v * 255) clamped to [0, 255].
  std::vector<std::uint8_t> to_rgba8() const;
};

struct RenderStats {
  std::uint64_t rays = 0;
  std::uint64_t steps = 0;             // leaves visited (segments), all rays
  std::uint64_t max_steps = 0;         // the most of one ray
  std::uint64_t terminated_early = 0;  // rays stopped by early termination
  std::uint64_t bad_index_rays = 0;    // rays stopped by an out-of-range index (corrupt pools)
  std::uint64_t step_limit_rays = 0;   // rays stopped by max_steps_per_ray
};

// The start of every ray of a frame: for a camera inside the canvas its location on the pools.
struct RayOrigin {
  DVec3 position_m;       // the camera position
  bool inside = false;    // position is inside the canvas
  PoolLocation location;  // valid when inside
};
// Locates the camera (see locate_point); outside the canvas is not an error (inside = false).
Result<RayOrigin> make_ray_origin(const PoolView& pools, const DVec3& position_m);

// The content box (RenderOptions::content_bounds) relative to the camera position, in metres,
// padded by 1e-5 of (its extent + its distance from the camera) so that rounding it to float
// (the GPU gets it so) never cuts a painted cell. Both ray casters cull against this box.
DAabb cull_box_relative_to(const DAabb& bounds, const DVec3& camera_m);
// Finite, min <= max on every axis (what render_reference and the GPU accept as content bounds).
bool valid_content_bounds(const DAabb& bounds);
// Unset, or count <= kMaxContentBoxes and each box valid_content_bounds.
bool valid_content_boxes(const std::optional<ContentBoxes>& boxes);

struct RayResult {
  std::array<double, 3> rgb{};  // premultiplied colour of the volume, background not added
  double transmittance = 1.0;
  std::uint32_t steps = 0;
  bool terminated_early = false, bad_index = false, step_limit = false;
  // The first surface the ray meets: the distance from the ray's origin (metres) at which its
  // opacity (1 - transmittance) reaches one half; -1 when it never does. The studio paints and
  // zooms there.
  double surface_m = -1;
};
// Traces one ray (direction: unit vector) from `origin`.
RayResult trace_ray(const PoolView& pools, const RayOrigin& origin, const DVec3& direction,
                    const RenderOptions& options);

// Renders one frame. invalid_argument for invalid pools (PoolView::validate) or options
// (termination outside [0, 1), zero max steps, invalid content bounds); malformed when the camera's
// cell cannot be located in the pools (a corrupt replica).
Result<RenderImage> render_reference(const PoolView& pools, const Camera& camera,
                                     const RenderOptions& options, RenderStats* stats = nullptr);

}  // namespace deepcanvas::client_core
