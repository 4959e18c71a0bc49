// Content boxes for one view (RenderOptions::content_boxes): a few boxes around the painted
// content one camera can see, where the content box (RenderOptions::content_bounds) is one box
// around everything painted.
//
// Why: on a canvas painted in many places the one box spans most of the canvas, and a ray that
// misses the painting in front of the camera crosses the empty cells of the rest of the canvas
// up to that box's far side. With a box per cluster of paint in view, such a ray misses every
// box and is background without a step (deepcanvas-bench large: render_one_box_ms against
// render_ms).
#pragma once

#include <cstddef>

#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/pool_view.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"

namespace deepcanvas::client_core {

// Subtrees kept before the boxes are merged (see content_boxes_for_view).
inline constexpr std::size_t kContentBoxCandidates = 64;

// Boxes (metres), at most max_boxes (clamped to 1..kMaxContentBoxes), each inside `bounds`, such
// that every painted leaf of `pools` inside `bounds` that a ray of `camera` can reach lies in
// one of them; an empty list when no painted leaf is in view. `bounds` must hold every painted
// leaf (the replica's content box) and be valid_content_bounds.
//
// How: from the roots down, a subtree whose colour is 0 (nothing painted below it, given
// PoolView::filtered_interiors) or whose cube lies outside the camera's view pyramid is dropped;
// the largest remaining subtree is replaced by its children while at most kContentBoxCandidates
// remain; the remaining cubes, each clipped to `bounds`, are merged pairwise (first the pair
// whose union has the smallest half perimeter) down to max_boxes, and on while two boxes are as
// good as one (their union's half perimeter under the sum of theirs). Last, each face of each
// box is pulled in to the painted leaves of its subtrees: a best-first search by how far a
// cell's cube reaches past that face, whose first painted leaf is the furthest (at most 256
// cells taken per face; past that, the cube taken last bounds the rest).
//
// Pools without filtered interiors, or a bad index on the way, give {bounds} (a bad index while
// pulling a face in leaves that face where it was): never a box that misses paint. Cost: at
// most ~8 x kContentBoxCandidates x kMaxDepth subtrees looked at while splitting, 6 x 256 x 8
// per box while pulling faces in, O(kContentBoxCandidates^3) box operations: ~0.15 ms on the
// real paintings (deepcanvas-bench large: content_boxes_ms), once per frame and view.
// Threading: reads `pools` only; they must not change meanwhile.
ContentBoxes content_boxes_for_view(const PoolView& pools, const Camera& camera,
                                    const DAabb& bounds, std::size_t max_boxes = kMaxContentBoxes);

}  // namespace deepcanvas::client_core
