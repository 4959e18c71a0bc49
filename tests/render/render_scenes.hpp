// Test scenes and the brute-force reference renderer shared by render_test and render_gpu_test.
//
// The brute force knows nothing of links, siblings or cell-local frames: it lists every leaf of
// the server's Octree with its box in metres (Octree::coord + Octree::bounds_m), intersects each
// ray with every box in double world coordinates, sorts the segments by entry distance and
// composites them with the density model's reference (protocol::density::Composite), segment
// length in cell edges = metres / the leaf's edge.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "deepcanvas/bridge/pool_view_of_octree.hpp"
#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/pool_view.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::render_test {

using client_core::Camera;
using client_core::DVec3;
using client_core::PoolView;
using client_core::RenderImage;
using server_core::Octree;

using bridge::pool_view_of;

// A canvas of default geometry with `refines` random refinements of random leaves up to
// `max_depth` (balance refinements included), then random colours on every leaf: about a
// quarter empty, some opaque, the rest random alpha. Interior values are current
// (PoolView::filtered_interiors), so the renderers step over empty subtrees.
std::unique_ptr<Octree> random_tree(std::uint64_t seed, int refines, int max_depth,
                                    server_core::OctreeConfig config = {});

// Refines until every point of `points` lies in a leaf of depth `depth`.
void refine_around(Octree& tree, const std::vector<DVec3>& points, int depth);

struct LeafBox {
  DVec3 min, max;
  double edge;
  std::uint32_t colour;
};
std::vector<LeafBox> leaf_boxes(const Octree& tree);

// The painted leaves the ray o + t d (t >= 0) crosses, as [t0, t1) in metres, nearest first.
struct LeafSegment {
  double t0, t1;
  const LeafBox* leaf;
};
std::vector<LeafSegment> painted_segments(const std::vector<LeafBox>& leaves, const DVec3& o,
                                          const DVec3& d);

// Brute force, background composited behind, no early termination. a = 1 - T.
RenderImage brute_force_render(const std::vector<LeafBox>& leaves, const Camera& camera,
                               std::array<double, 3> background);

// The precision scene: depth-24 cells (0.3 mm) over a ~2 mm cube near the +x+y+z canvas
// corner (10 km from the centre on every axis), half of them painted with a hashed pattern,
// everything coarser empty; the camera sits inside the region looking across it.
struct PrecisionSceneData {
  std::unique_ptr<Octree> tree;
  Camera camera = *Camera::look_at({0, 0, 0}, {1, 0, 0}, {0, 0, 1}, 60, 1, 1);
};
PrecisionSceneData precision_scene(std::uint32_t width = 48, std::uint32_t height = 36);

// A multi-scale scene: a broad painted cluster (cells of ~40 m) and, next to it, a tiny one
// refined to depth ~20 (cells of ~5 mm), both painted; a camera framing each.
struct MultiScaleScene {
  std::unique_ptr<Octree> tree;
  Camera wide = *Camera::look_at({0, 0, 0}, {1, 0, 0}, {0, 0, 1}, 60, 1, 1);
  Camera close = wide;
};
MultiScaleScene multiscale_scene(std::uint64_t seed, std::uint32_t width, std::uint32_t height);

// ---- scenes from the real paintings (A-Painter files in $DEEPCANVAS_PAINTINGS) ----

// The path of painting `file` in $DEEPCANVAS_PAINTINGS; nullopt when the variable is unset (the
// caller skips, saying why). A set variable naming a directory without the file is a failure
// (ADD_FAILURE here, nullopt returned): a configured data set must not silently skip tests.
std::optional<std::string> painting_path(const std::string& file);

// Skips the test when $DEEPCANVAS_PAINTINGS is unset; fails it when the file is missing.
#define DEEPCANVAS_REQUIRE_PAINTING(path_var, file)                                   \
  std::string path_var;                                                               \
  if (std::getenv("DEEPCANVAS_PAINTINGS") == nullptr) {                               \
    GTEST_SKIP() << "DEEPCANVAS_PAINTINGS is unset: no real paintings to render";     \
  } else if (auto found_ = ::deepcanvas::render_test::painting_path(file); !found_) { \
    FAIL() << "painting " << (file) << " missing from $DEEPCANVAS_PAINTINGS";         \
  } else {                                                                            \
    path_var = *found_;                                                               \
  }

// Paints the first `max_strokes` strokes of the .apa file at `path`, placed by `transform`,
// through the server's Painter (as the server does). Returns the strokes applied (a stroke the
// painter refuses, e.g. a radius below its limit at a tiny scale, is skipped and not counted).
std::size_t paint_apa(Octree& tree, const std::string& path,
                      const paintings::ApaTransform& transform, std::size_t max_strokes);

// One painting at scale 1 on a default canvas (strokes limited as above), with its painted
// bounds; tree == nullptr after a failure (reported with ADD_FAILURE).
struct PaintingScene {
  std::unique_ptr<Octree> tree;
  client_core::DAabb bounds;
};
PaintingScene painting_scene(const std::string& path, std::size_t max_strokes);

// The multi-scale painting scene: `big_path` painted at 1000x (hundreds of metres, cells of
// metres) and, next to it, `tiny_path` at 0.001x (about a millimetre across, cells of 0.3 mm at
// the canvas's depth limit); their painted bounds; cameras framing both, the tiny one alone,
// and one inside the big one.
struct MultiScalePaintingScene {
  std::unique_ptr<Octree> tree;
  client_core::DAabb bounds, big_bounds, tiny_bounds;
  std::vector<Camera> cameras;
};
MultiScalePaintingScene multiscale_painting_scene(const std::string& big_path,
                                                  const std::string& tiny_path, std::uint32_t width,
                                                  std::uint32_t height);

// A camera at a random point within `reach` of `box`'s centre (uniform in a cube of edge
// `reach`), looking at a random point of the box, 60 degrees vertical field of view.
Camera camera_near_box(std::mt19937_64& rng, const client_core::DAabb& box, double reach,
                       std::uint32_t w, std::uint32_t h);

// render_reference, failing the test (and returning an empty image) where it errs.
RenderImage render_or_fail(const PoolView& pools, const Camera& cam,
                           const client_core::RenderOptions& opt,
                           client_core::RenderStats* stats = nullptr);

// random_tree(seed, 300, 10) with the leaves shallower than `depth` emptied and the interior
// values refreshed: paint in a few separate clusters, PoolView::filtered_interiors true.
std::unique_ptr<Octree> clustered_tree(std::uint64_t seed, int depth);

// Largest absolute difference over all channels (rgb and a) of two images of equal size.
double max_channel_diff(const RenderImage& a, const RenderImage& b);

}  // namespace deepcanvas::render_test
