// Content boxes for one view (content_boxes_for_view, RenderOptions::content_boxes): the image
// with them is the image without any cull, bit for bit, in double and in float; every painted
// leaf a ray of the camera can reach lies in one of them (brute force over the leaves); they
// cut the steps below one content box's where the paint is in separate clusters; no box when no
// paint is in view; the one content box where the pools' interior values are not current.
#include <gtest/gtest.h>

#include <random>

#include "deepcanvas/client_core/content_boxes.hpp"
#include "render_scenes.hpp"

namespace deepcanvas::render_test {
namespace {

using client_core::ContentBoxes;
using client_core::DAabb;
using client_core::Precision;
using client_core::RenderOptions;
using client_core::RenderStats;

bool contains(const DAabb& outer, const DVec3& mn, const DVec3& mx) {
  return outer.min.x <= mn.x && outer.min.y <= mn.y && outer.min.z <= mn.z && mx.x <= outer.max.x &&
         mx.y <= outer.max.y && mx.z <= outer.max.z;
}

// Every painted leaf with a corner or its centre in view (in front of the camera, inside the
// image's edges) lies in one of the boxes.
void expect_visible_paint_boxed(const Octree& tree, const Camera& cam, const ContentBoxes& boxes) {
  const DVec3 f = cam.forward(), r = cam.right(), u = cam.up();
  const double th = cam.tan_half_h(), tv = cam.tan_half_v();
  const auto in_view = [&](const DVec3& p) {
    const DVec3 v = p - cam.position();
    const double z = dot(v, f);
    return z > 0 && std::abs(dot(v, r)) <= th * z && std::abs(dot(v, u)) <= tv * z;
  };
  int checked = 0;
  for (const LeafBox& leaf : leaf_boxes(tree)) {
    if ((leaf.colour >> 24) == 0) continue;
    bool seen = in_view((leaf.min + leaf.max) * 0.5);
    for (int k = 0; k < 8 && !seen; ++k) {
      seen = in_view({(k & 1) ? leaf.max.x : leaf.min.x, (k & 2) ? leaf.max.y : leaf.min.y,
                      (k & 4) ? leaf.max.z : leaf.min.z});
    }
    if (!seen) continue;
    ++checked;
    bool boxed = false;
    for (const DAabb& b : boxes.boxes()) boxed = boxed || contains(b, leaf.min, leaf.max);
    EXPECT_TRUE(boxed) << "a painted leaf in view lies in no box";
    if (!boxed) return;
  }
}

TEST(ContentBoxes, SameImageAsNoCullAndFewerSteps) {
  std::mt19937_64 rng(77);
  std::uint64_t one_box_steps = 0, boxes_steps = 0;
  std::size_t views = 0, split_views = 0;
  for (std::uint64_t seed = 1; seed <= 4; ++seed) {
    auto tree = clustered_tree(seed, 6);
    const PoolView pools = pool_view_of(*tree);
    ASSERT_TRUE(pools.filtered_interiors);
    auto b = client_core::painted_bounds(pools);
    ASSERT_TRUE(b.ok() && b->has_value());
    const DAabb bounds = **b;
    const double size = length(bounds.max - bounds.min);
    // Inside the paint, next to it, far away inside the canvas and outside the canvas.
    for (double reach : {0.3 * size, 0.5 * size, 3.0 * size, 40000.0, 90000.0}) {
      const Camera cam = camera_near_box(rng, bounds, reach, 24, 18);
      const ContentBoxes boxes = client_core::content_boxes_for_view(pools, cam, bounds);
      ASSERT_LE(boxes.count, client_core::kMaxContentBoxes);
      for (const DAabb& box : boxes.boxes()) EXPECT_TRUE(contains(bounds, box.min, box.max));
      expect_visible_paint_boxed(*tree, cam, boxes);
      ++views;
      split_views += boxes.count > 1;
      for (Precision prec : {Precision::float64, Precision::float32}) {
        RenderOptions opt;
        opt.precision = prec;
        opt.background = {0.3, 0.2, 0.1};
        const RenderImage full = render_or_fail(pools, cam, opt);
        RenderStats one_st, boxes_st;
        opt.content_bounds = bounds;
        const RenderImage one = render_or_fail(pools, cam, opt, &one_st);
        opt.content_boxes = boxes;
        const RenderImage culled = render_or_fail(pools, cam, opt, &boxes_st);
        EXPECT_EQ(full.rgba, one.rgba);
        EXPECT_EQ(full.rgba, culled.rgba)
            << "seed " << seed << " reach " << reach << " precision " << static_cast<int>(prec)
            << ", " << boxes.count << " boxes";
        one_box_steps += one_st.steps;
        boxes_steps += boxes_st.steps;
      }
    }
  }
  EXPECT_GT(split_views, 0u) << "no view gave more than one box: the clusters were never split";
  EXPECT_LT(boxes_steps, one_box_steps);
  std::printf("content boxes: %zu of %zu views split; steps %llu with them, %llu with one box\n",
              split_views, views, static_cast<unsigned long long>(boxes_steps),
              static_cast<unsigned long long>(one_box_steps));
}

TEST(ContentBoxes, MultiScaleAndPrecisionScenes) {
  MultiScaleScene ms = multiscale_scene(4, 32, 24);
  ASSERT_TRUE(ms.tree);
  PrecisionSceneData ps = precision_scene(32, 24);
  ASSERT_TRUE(ps.tree);
  ms.tree->refresh_interior_colours();
  ps.tree->refresh_interior_colours();
  struct Case {
    const Octree* tree;
    const Camera* cam;
  };
  for (const Case& c : {Case{ms.tree.get(), &ms.wide}, Case{ms.tree.get(), &ms.close},
                        Case{ps.tree.get(), &ps.camera}}) {
    const PoolView pools = pool_view_of(*c.tree);
    auto b = client_core::painted_bounds(pools);
    ASSERT_TRUE(b.ok() && b->has_value());
    const ContentBoxes boxes = client_core::content_boxes_for_view(pools, *c.cam, **b);
    expect_visible_paint_boxed(*c.tree, *c.cam, boxes);
    for (Precision prec : {Precision::float64, Precision::float32}) {
      RenderOptions opt;
      opt.precision = prec;
      opt.termination_transmittance = 0;
      const RenderImage full = render_or_fail(pools, *c.cam, opt);
      opt.content_bounds = **b;
      opt.content_boxes = boxes;
      EXPECT_EQ(full.rgba, render_or_fail(pools, *c.cam, opt).rgba);
    }
  }
}

// Looking away from all paint: no box, and every ray is background without a step.
TEST(ContentBoxes, NothingInViewGivesNoBox) {
  auto tree = clustered_tree(2, 6);
  const PoolView pools = pool_view_of(*tree);
  auto b = client_core::painted_bounds(pools);
  ASSERT_TRUE(b.ok() && b->has_value());
  const DVec3 c = ((*b)->min + (*b)->max) * 0.5;
  const double size = length((*b)->max - (*b)->min);
  auto cam =
      Camera::look_at(c + DVec3{2 * size, 0, 0}, c + DVec3{4 * size, 0, 0}, {0, 0, 1}, 40, 16, 12);
  ASSERT_TRUE(cam.ok());
  const ContentBoxes boxes = client_core::content_boxes_for_view(pools, *cam, **b);
  EXPECT_EQ(boxes.count, 0u);
  RenderOptions opt;
  opt.background = {0.5, 0.4, 0.3};
  const RenderImage full = render_or_fail(pools, *cam, opt);
  opt.content_bounds = **b;
  opt.content_boxes = boxes;
  RenderStats st;
  EXPECT_EQ(full.rgba, render_or_fail(pools, *cam, opt, &st).rgba);
  EXPECT_EQ(st.steps, 0u);
}

// Without current interior values the tree cannot tell empty subtrees: the one content box.
// max_boxes 1: one box, holding every painted leaf in view.
TEST(ContentBoxes, FallsBackToTheContentBox) {
  auto tree = clustered_tree(3, 6);
  PoolView pools = pool_view_of(*tree);
  auto b = client_core::painted_bounds(pools);
  ASSERT_TRUE(b.ok() && b->has_value());
  auto cam = Camera::frame_box(**b, 32, 24);
  ASSERT_TRUE(cam.ok());
  const ContentBoxes one = client_core::content_boxes_for_view(pools, *cam, **b, 1);
  ASSERT_EQ(one.count, 1u);
  expect_visible_paint_boxed(*tree, *cam, one);
  pools.filtered_interiors = false;
  const ContentBoxes whole = client_core::content_boxes_for_view(pools, *cam, **b);
  ASSERT_EQ(whole.count, 1u);
  EXPECT_EQ(whole.box[0].min.x, (*b)->min.x);
  EXPECT_EQ(whole.box[0].max.z, (*b)->max.z);
}

// More boxes than kMaxContentBoxes, or an invalid one, are refused before any ray.
TEST(ContentBoxes, InvalidBoxesAreRefused) {
  auto tree = clustered_tree(1, 6);
  const PoolView pools = pool_view_of(*tree);
  auto cam = Camera::frame_box({{-1, -1, -1}, {1, 1, 1}}, 8, 6);
  ASSERT_TRUE(cam.ok());
  RenderOptions opt;
  ContentBoxes bad;
  bad.push_back({{0, 0, 0}, {1, 1, 1}});
  bad.count = client_core::kMaxContentBoxes + 1;
  opt.content_boxes = bad;
  EXPECT_FALSE(client_core::render_reference(pools, *cam, opt).ok());
  ContentBoxes nan_box;
  nan_box.push_back({{0, 0, 0}, {std::nan(""), 1, 1}});
  opt.content_boxes = nan_box;
  EXPECT_FALSE(client_core::render_reference(pools, *cam, opt).ok());
}

}  // namespace
}  // namespace deepcanvas::render_test
