// The content cull (RenderOptions::content_bounds): it skips only empty cells, so images with
// and without it are identical, bit for bit, in double and in float, on synthetic scenes and on
// real paintings; it does cut the steps; a box that leaves painted cells out does change the
// image (the cull is really applied); invalid boxes are refused.
#include <gtest/gtest.h>

#include <cstdlib>
#include <random>

#include "render_scenes.hpp"

namespace deepcanvas::render_test {
namespace {

using client_core::DAabb;
using client_core::Precision;
using client_core::RenderOptions;
using client_core::RenderStats;

// Renders with and without `bounds`: equal images; returns the steps (without, with).
std::pair<std::uint64_t, std::uint64_t> expect_cull_exact(const PoolView& pools, const Camera& cam,
                                                          const DAabb& bounds, Precision prec,
                                                          double termination) {
  RenderOptions opt;
  opt.precision = prec;
  opt.termination_transmittance = termination;
  opt.background = {0.3, 0.2, 0.1};
  RenderStats full_st, cull_st;
  const RenderImage full = render_or_fail(pools, cam, opt, &full_st);
  opt.content_bounds = bounds;
  const RenderImage culled = render_or_fail(pools, cam, opt, &cull_st);
  EXPECT_EQ(full.rgba, culled.rgba) << "precision " << static_cast<int>(prec);
  EXPECT_LE(cull_st.steps, full_st.steps);
  return {full_st.steps, cull_st.steps};
}

// random_tree with the leaves shallower than `depth` emptied: the paint sits in the refined
// clusters, so the painted box is smaller than the canvas and the cull has work to do.
std::unique_ptr<Octree> paint_fine_leaves_only(std::unique_ptr<Octree> tree, int depth) {
  for (std::uint32_t c = 0; c < tree->high_water_cells(); ++c) {
    if (tree->is_live(c) && tree->is_leaf(c) && tree->depth(c) < depth) tree->set_colour(c, 0);
  }
  return tree;
}

TEST(ContentCull, SameImageOnRandomScenes) {
  std::mt19937_64 rng(21);
  std::uint64_t full = 0, culled = 0;
  for (std::uint64_t seed = 1; seed <= 4; ++seed) {
    auto tree = paint_fine_leaves_only(random_tree(seed, 300, 10), 6);
    const PoolView pools = pool_view_of(*tree);
    auto b = client_core::painted_bounds(pools);
    ASSERT_TRUE(b.ok() && b->has_value());
    const DAabb box = **b;
    const double size = length(box.max - box.min);
    // Inside the box, next to it, far away inside the canvas and outside the canvas.
    for (double reach : {0.5 * size, 3.0 * size, 40000.0, 90000.0}) {
      const Camera cam = camera_near_box(rng, box, reach, 24, 18);
      for (Precision prec : {Precision::float64, Precision::float32}) {
        for (double term : {0.0, 1.0 / 512}) {
          auto [f, c] = expect_cull_exact(pools, cam, box, prec, term);
          full += f;
          culled += c;
        }
      }
    }
  }
  EXPECT_LT(culled, full);  // the cull does skip steps
}

TEST(ContentCull, SameImageOnMultiScaleScene) {
  MultiScaleScene scene = multiscale_scene(4, 32, 24);
  ASSERT_TRUE(scene.tree);
  const PoolView pools = pool_view_of(*scene.tree);
  auto b = client_core::painted_bounds(pools);
  ASSERT_TRUE(b.ok() && b->has_value());
  for (const Camera* cam : {&scene.wide, &scene.close}) {
    for (Precision prec : {Precision::float64, Precision::float32}) {
      expect_cull_exact(pools, *cam, **b, prec, 1.0 / 512);
    }
  }
}

TEST(ContentCull, PrecisionScene) {
  PrecisionSceneData scene = precision_scene(32, 24);
  ASSERT_TRUE(scene.tree);
  const PoolView pools = pool_view_of(*scene.tree);
  auto b = client_core::painted_bounds(pools);
  ASSERT_TRUE(b.ok() && b->has_value());
  for (Precision prec : {Precision::float64, Precision::float32}) {
    expect_cull_exact(pools, scene.camera, **b, prec, 0.0);
  }
}

// A box that leaves out part of the paint changes the image: the cull is applied, and the
// tests above would see a wrong one.
TEST(ContentCull, BoxMissingPaintChangesTheImage) {
  auto tree = random_tree(3, 300, 10);
  const PoolView pools = pool_view_of(*tree);
  auto b = client_core::painted_bounds(pools);
  ASSERT_TRUE(b.ok() && b->has_value());
  const DAabb box = **b;
  auto cam = Camera::frame_box(box, 32, 24);
  ASSERT_TRUE(cam.ok());
  RenderOptions opt;
  const RenderImage full = render_or_fail(pools, *cam, opt);
  DAabb half = box;
  half.max.x = (box.min.x + box.max.x) / 2;
  opt.content_bounds = half;
  EXPECT_GT(max_channel_diff(full, render_or_fail(pools, *cam, opt)), 0.05);
}

// content_empty (a canvas with no painted leaf): the same image as without it, in both
// precisions and from inside and outside the canvas, without a single step; and on a painted
// canvas it does remove the paint (the flag is really applied).
TEST(ContentCull, EmptyCanvasIsBackgroundWithoutSteps) {
  auto tree = random_tree(5, 300, 10);
  for (std::uint32_t c = 0; c < tree->high_water_cells(); ++c)
    if (tree->is_live(c)) tree->set_colour(c, 0);
  const PoolView pools = pool_view_of(*tree);
  auto b = client_core::painted_bounds(pools);
  ASSERT_TRUE(b.ok());
  ASSERT_FALSE(b->has_value());  // nothing painted
  std::mt19937_64 rng(5);
  const DAabb around{{-100, -100, -100}, {100, 100, 100}};
  for (double reach : {200.0, 15000.0, 90000.0}) {
    const Camera cam = camera_near_box(rng, around, reach, 16, 12);
    for (Precision prec : {Precision::float64, Precision::float32}) {
      RenderOptions opt;
      opt.precision = prec;
      opt.background = {0.3, 0.2, 0.1};
      RenderStats full_st, empty_st;
      const RenderImage full = render_or_fail(pools, cam, opt, &full_st);
      opt.content_empty = true;
      const RenderImage empty = render_or_fail(pools, cam, opt, &empty_st);
      EXPECT_EQ(full.rgba, empty.rgba) << "reach " << reach;
      EXPECT_EQ(empty_st.steps, 0u);
      if (reach < 20000) {
        EXPECT_GT(full_st.steps, 0u);  // inside the canvas: rays do cross it
      }
    }
  }
  auto painted = random_tree(5, 300, 10);
  const PoolView pp = pool_view_of(*painted);
  auto pb = client_core::painted_bounds(pp);
  ASSERT_TRUE(pb.ok() && pb->has_value());
  auto cam = Camera::frame_box(**pb, 32, 24);
  ASSERT_TRUE(cam.ok());
  RenderOptions opt;
  const RenderImage full = render_or_fail(pp, *cam, opt);
  opt.content_empty = true;
  EXPECT_GT(max_channel_diff(full, render_or_fail(pp, *cam, opt)), 0.05);
}

TEST(ContentCull, RejectsInvalidBounds) {
  auto tree = random_tree(4, 10, 3);
  const PoolView pools = pool_view_of(*tree);
  auto cam = Camera::look_at({0, 0, 0}, {1, 0, 0}, {0, 0, 1}, 60, 4, 4);
  ASSERT_TRUE(cam.ok());
  RenderOptions opt;
  opt.content_bounds = DAabb{{1, 0, 0}, {0, 1, 1}};
  EXPECT_EQ(client_core::render_reference(pools, *cam, opt).error().code, Errc::invalid_argument);
  opt.content_bounds = DAabb{{0, 0, 0}, {std::nan(""), 1, 1}};
  EXPECT_EQ(client_core::render_reference(pools, *cam, opt).error().code, Errc::invalid_argument);
}

// Real paintings (demo.apa at scale 1; the multi-scale pair): the cull is exact there too, and
// on a framed painting it removes most of the steps.
TEST(ContentCull, SameImageOnPaintings) {
  DEEPCANVAS_REQUIRE_PAINTING(path, "demo.apa");
  PaintingScene scene = painting_scene(path, 1000);
  ASSERT_TRUE(scene.tree);
  const PoolView pools = pool_view_of(*scene.tree);
  std::mt19937_64 rng(5);
  const double size = length(scene.bounds.max - scene.bounds.min);
  auto framed = Camera::frame_box(scene.bounds, 48, 27);
  ASSERT_TRUE(framed.ok());
  auto [full, culled] =
      expect_cull_exact(pools, *framed, scene.bounds, Precision::float32, 1.0 / 512);
  EXPECT_LT(culled * 2, full);
  for (double reach : {0.5 * size, 30000.0}) {
    const Camera cam = camera_near_box(rng, scene.bounds, reach, 32, 18);
    for (Precision prec : {Precision::float64, Precision::float32}) {
      expect_cull_exact(pools, cam, scene.bounds, prec, 1.0 / 512);
    }
  }
}

TEST(ContentCull, SameImageOnMultiScalePaintings) {
  DEEPCANVAS_REQUIRE_PAINTING(big, "demo.apa");
  DEEPCANVAS_REQUIRE_PAINTING(tiny, "palmtree.apa");
  MultiScalePaintingScene scene = multiscale_painting_scene(big, tiny, 32, 18);
  ASSERT_TRUE(scene.tree);
  const PoolView pools = pool_view_of(*scene.tree);
  for (const Camera& cam : scene.cameras) {
    for (Precision prec : {Precision::float64, Precision::float32}) {
      expect_cull_exact(pools, cam, scene.bounds, prec, 1.0 / 512);
    }
  }
}

}  // namespace
}  // namespace deepcanvas::render_test
