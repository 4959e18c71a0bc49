// The CPU reference renderer against a brute-force renderer, G3 stepping against descent from
// the root, and the camera / pool-view helpers against the server's Octree.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>

#include "render_scenes.hpp"

namespace deepcanvas::render_test {
namespace {

using client_core::DAabb;
using client_core::Precision;
using client_core::RenderOptions;
using client_core::RenderStats;
using client_core::Stepping;

// Double-precision renders agree with the brute force to rounding: both compute segment
// lengths from doubles (relative error ~1e-16 of distances up to ~3e4 m, i.e. < 1e-11 m, a
// tiny fraction of any cell edge in these scenes, >= 0.3 mm), and a segment's contribution
// changes by at most |ln(1 - a)| <= ln(255) ~ 5.5 per cell edge of length error, over at most a
// few thousand segments. 1e-7 leaves ample margin and still catches any wrong cell, wrong
// neighbour or wrong segment length (those show up as errors of 1e-3 and more).
constexpr double kDoubleTolerance = 1e-7;

Camera random_camera(std::mt19937_64& rng, double edge, std::uint32_t w, std::uint32_t h,
                     bool inside) {
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  for (;;) {
    const double reach = inside ? edge * 0.98 : edge * 2.5;
    DVec3 eye{u(rng) * reach, u(rng) * reach, u(rng) * reach};
    if (!inside && std::max({std::abs(eye.x), std::abs(eye.y), std::abs(eye.z)}) <= edge / 2) {
      continue;
    }
    DVec3 target{u(rng) * edge * 0.6, u(rng) * edge * 0.6, u(rng) * edge * 0.6};
    auto cam = Camera::look_at(eye, target, {0, 0, 1}, 40.0 + 50.0 * (u(rng) + 0.5), w, h);
    if (cam.ok()) return *cam;
  }
}

RenderImage render(const PoolView& pools, const Camera& cam, RenderOptions opt,
                   RenderStats* stats = nullptr) {
  auto img = client_core::render_reference(pools, cam, opt, stats);
  EXPECT_TRUE(img.ok()) << (img.ok() ? "" : img.error().message);
  return img.ok() ? std::move(img).value() : RenderImage{};
}

TEST(PoolView, FaceNeighbourMatchesOctree) {
  for (std::uint64_t seed = 1; seed <= 4; ++seed) {
    auto tree = random_tree(seed, 300, 8);
    const PoolView pools = pool_view_of(*tree);
    ASSERT_TRUE(pools.validate().ok());
    for (std::uint32_t c = 0; c < tree->high_water_cells(); ++c) {
      if (!tree->is_live(c)) continue;
      for (int f = 0; f < 6; ++f) {
        ASSERT_EQ(pools.face_neighbour(c, f), tree->face_neighbour(c, f))
            << "cell " << c << " face " << f;
      }
    }
  }
}

TEST(PoolView, ValidateRejectsInconsistentSizes) {
  auto tree = random_tree(9, 20, 4);
  PoolView pools = pool_view_of(*tree);
  ASSERT_TRUE(pools.validate().ok());
  PoolView bad = pools;
  bad.colour = bad.colour.subspan(1);
  EXPECT_EQ(bad.validate().error().code, Errc::invalid_argument);
  bad = pools;
  bad.group_links = bad.group_links.subspan(6);
  EXPECT_FALSE(bad.validate().ok());
  bad = pools;
  bad.roots_per_axis = 3;
  EXPECT_FALSE(bad.validate().ok());
  bad = pools;
  bad.edge_m = std::nan("");
  EXPECT_FALSE(bad.validate().ok());
}

TEST(Camera, LocatePointMatchesOctreeLocate) {
  auto tree = random_tree(11, 400, 10);
  const PoolView pools = pool_view_of(*tree);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  for (int i = 0; i < 2000; ++i) {
    const DVec3 p{u(rng) * 20000.0 * 0.3, u(rng) * 20000.0, u(rng) * 20000.0};
    auto mine = client_core::locate_point(pools, p);
    auto ref = tree->locate({p.x, p.y, p.z}, 24);
    ASSERT_TRUE(mine.ok());
    ASSERT_TRUE(ref.ok());
    ASSERT_EQ(mine->cell, ref->cell);
    EXPECT_EQ(mine->depth, ref->coord.depth);
    EXPECT_EQ(mine->coord[0], ref->coord.x);
    EXPECT_EQ(mine->coord[1], ref->coord.y);
    EXPECT_EQ(mine->coord[2], ref->coord.z);
    // The local position reproduces the point: centre + local * edge.
    const auto b = tree->bounds_m(ref->coord);
    const double e = tree->cell_edge_m(ref->coord.depth);
    const double centre[3] = {(b.min.x + b.max.x) / 2, (b.min.y + b.max.y) / 2,
                              (b.min.z + b.max.z) / 2};
    for (int a = 0; a < 3; ++a) {
      EXPECT_LE(std::abs(mine->local[a]), 0.5);
      EXPECT_NEAR(centre[a] + mine->local[a] * e, p[a], 1e-9);
    }
  }
  EXPECT_FALSE(client_core::locate_point(pools, {1e5, 0, 0}).ok());
  EXPECT_FALSE(client_core::locate_point(pools, {std::nan(""), 0, 0}).ok());
  // Faces: the positive side's cell; the canvas's max corner is still inside.
  auto corner = client_core::locate_point(pools, {10000, 10000, 10000});
  ASSERT_TRUE(corner.ok());
  EXPECT_EQ(corner->local[0], 0.5);
}

TEST(Camera, LookAtBasisAndPixelRays) {
  auto cam = Camera::look_at({1, 2, 3}, {4, -2, 3.5}, {0, 0, 1}, 60, 101, 51);
  ASSERT_TRUE(cam.ok());
  const DVec3 f = cam->forward(), r = cam->right(), u = cam->up();
  EXPECT_NEAR(client_core::length(f), 1, 1e-12);
  EXPECT_NEAR(client_core::length(r), 1, 1e-12);
  EXPECT_NEAR(client_core::length(u), 1, 1e-12);
  EXPECT_NEAR(client_core::dot(f, r), 0, 1e-12);
  EXPECT_NEAR(client_core::dot(f, u), 0, 1e-12);
  EXPECT_GT(u.z, 0);  // roll from the hint
  // The centre pixel of an odd-sized image looks straight ahead; the top row looks up by
  // almost half the vertical fov.
  const DVec3 c = cam->ray_direction(50, 25);
  EXPECT_NEAR(client_core::dot(c, f), 1.0, 1e-12);
  const DVec3 top = cam->ray_direction(50, 0);
  const double angle = std::atan2(client_core::dot(top, u), client_core::dot(top, f));
  EXPECT_NEAR(angle, std::atan(std::tan(M_PI / 6) * 50.0 / 51.0), 1e-9);
  const DVec3 left = cam->ray_direction(0, 25);
  EXPECT_LT(client_core::dot(left, r), 0);

  EXPECT_FALSE(Camera::look_at({0, 0, 0}, {0, 0, 0}, {0, 0, 1}, 60, 8, 8).ok());
  EXPECT_FALSE(Camera::look_at({0, 0, 0}, {0, 0, 1}, {0, 0, 1}, 60, 8, 8).ok());
  EXPECT_FALSE(Camera::look_at({0, 0, 0}, {1, 0, 0}, {0, 0, 1}, 180, 8, 8).ok());
  EXPECT_FALSE(Camera::look_at({0, 0, 0}, {1, 0, 0}, {0, 0, 1}, 60, 0, 8).ok());
  EXPECT_FALSE(Camera::look_at({INFINITY, 0, 0}, {1, 0, 0}, {0, 0, 1}, 60, 8, 8).ok());
}

TEST(Camera, ParseSpec) {
  auto cam = Camera::parse("10,0,0,0,0,0,30", 64, 32);
  ASSERT_TRUE(cam.ok());
  EXPECT_EQ(cam->position(), (DVec3{10, 0, 0}));
  EXPECT_NEAR(cam->forward().x, -1, 1e-15);
  EXPECT_NEAR(cam->vfov_rad(), M_PI / 6, 1e-15);
  EXPECT_TRUE(Camera::parse("0,0,10,0,0,0", 64, 32).ok());  // vertical view: up falls back
  EXPECT_FALSE(Camera::parse("1,2,3", 64, 32).ok());
  EXPECT_FALSE(Camera::parse("1,2,3,4,5,x", 64, 32).ok());
  EXPECT_FALSE(Camera::parse("1,2,3,4,5,6,7,8", 64, 32).ok());
  EXPECT_FALSE(Camera::parse("", 64, 32).ok());
  EXPECT_FALSE(Camera::parse("1,2,3,4,5,6,", 64, 32).ok());
}

TEST(Camera, FrameBoxShowsEveryCorner) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int i = 0; i < 50; ++i) {
    const double s = std::pow(10.0, 4 * u(rng));
    const DVec3 c{u(rng) * 5000, u(rng) * 5000, u(rng) * 5000};
    const DAabb box{c, c + DVec3{s * (1.1 + u(rng)), s * (1.1 + u(rng)), s * (1.1 + u(rng))}};
    const std::uint32_t w = 320 + static_cast<std::uint32_t>(200 * u(rng)), h = 240;
    auto cam = Camera::frame_box(box, w, h);
    ASSERT_TRUE(cam.ok());
    for (int k = 0; k < 8; ++k) {
      const DVec3 corner{k & 1 ? box.max.x : box.min.x, k & 2 ? box.max.y : box.min.y,
                         k & 4 ? box.max.z : box.min.z};
      const DVec3 v = corner - cam->position();
      const double z = client_core::dot(v, cam->forward());
      ASSERT_GT(z, 0);
      EXPECT_LE(std::abs(client_core::dot(v, cam->right()) / z), cam->tan_half_h());
      EXPECT_LE(std::abs(client_core::dot(v, cam->up()) / z), cam->tan_half_v());
    }
  }
  EXPECT_FALSE(Camera::frame_box({{1, 0, 0}, {0, 0, 0}}, 8, 8).ok());
}

// fit_box against brute force: every corner inside the image with the margin, and the fit is
// tight (some corner reaches the margin on one axis; 1% closer, some corner would be cut off),
// for random boxes (flat, elongated, cubic), view directions, fields of view and aspects.
TEST(Camera, FitBoxIsTheClosestViewShowingEveryCorner) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int i = 0; i < 200; ++i) {
    const double s = std::pow(10.0, 3 * u(rng));
    const DVec3 c{u(rng) * 5000, u(rng) * 5000, u(rng) * 5000};
    // At least 2 mm a side: below 1 mm fit_box frames the 1 mm box instead (as frame_box).
    auto side = [&] { return std::max(2e-3, s * std::pow(10.0, u(rng))); };
    const DVec3 ext{side(), side(), side()};
    const DAabb box{c, c + ext};
    const std::uint32_t w = 64 + static_cast<std::uint32_t>(rng() % 900), h = 48 + rng() % 700;
    const double fov = 20 + 100 * (u(rng) + 1) / 2;
    const DVec3 dir{u(rng), u(rng), u(rng) + 0.01};
    const double margin = 0.1 * (u(rng) + 1) / 2;
    auto cam = Camera::fit_box(box, w, h, fov, dir, {0, 0, 1}, margin);
    ASSERT_TRUE(cam.ok()) << i;
    auto worst = [&](const Camera& k) {  // largest |projection| / half extent over corners
      double m = 0;
      for (int q = 0; q < 8; ++q) {
        const DVec3 corner{q & 1 ? box.max.x : box.min.x, q & 2 ? box.max.y : box.min.y,
                           q & 4 ? box.max.z : box.min.z};
        const DVec3 v = corner - k.position();
        const double z = client_core::dot(v, k.forward());
        if (!(z > 0)) return 1e9;
        m = std::max({m, std::abs(client_core::dot(v, k.right()) / z) / k.tan_half_h(),
                      std::abs(client_core::dot(v, k.up()) / z) / k.tan_half_v()});
      }
      return m;
    };
    const double fit = worst(*cam);
    EXPECT_LE(fit, 1.0 - margin + 1e-9) << i;
    // Tight: a corner touches the margin, unless the eye had to stay in front of the nearest
    // corner (a wide field of view could otherwise frame the box from inside it).
    double nearest = 1e300, deepest_behind_centre = 0;
    for (int q = 0; q < 8; ++q) {
      const DVec3 corner{q & 1 ? box.max.x : box.min.x, q & 2 ? box.max.y : box.min.y,
                         q & 4 ? box.max.z : box.min.z};
      nearest = std::min(nearest, client_core::dot(corner - cam->position(), cam->forward()));
      deepest_behind_centre =
          std::max(deepest_behind_centre,
                   -client_core::dot(corner - (box.min + box.max) * 0.5, cam->forward()));
    }
    const bool in_front_binds = nearest <= 0.011 * deepest_behind_centre + 2e-6;
    if (!in_front_binds) {
      EXPECT_GE(fit, 1.0 - margin - 1e-6) << i;
    }
    // 1% closer along the same ray: some corner leaves the margin.
    const DVec3 centre = (box.min + box.max) * 0.5;
    const double d = client_core::length(centre - cam->position());
    auto closer =
        Camera::look_at(centre - cam->forward() * (d * 0.99), centre, cam->up(), fov, w, h);
    ASSERT_TRUE(closer.ok());
    EXPECT_GT(worst(*closer), 1.0 - margin) << i;
    // Same orientation as frame_box, and never farther than it (the bounding sphere with 10%
    // to spare) while the margin asked for is at most frame_box's (about 9% at narrow fields).
    auto sphere = Camera::frame_box(box, w, h, fov, dir, {0, 0, 1});
    ASSERT_TRUE(sphere.ok());
    if (margin <= 0.05) {
      EXPECT_LE(d, client_core::length(centre - sphere->position()) * (1 + 1e-9)) << i;
    }
    EXPECT_NEAR(client_core::dot(cam->forward(), sphere->forward()), 1.0, 1e-9);
  }
  EXPECT_FALSE(Camera::fit_box({{0, 0, 0}, {1, 1, 1}}, 8, 8, 45, {1, 0, 0}, {0, 0, 1}, 0.6).ok());
  EXPECT_FALSE(Camera::fit_box({{1, 0, 0}, {0, 0, 0}}, 8, 8).ok());
}

TEST(Camera, PaintedBoundsIsTheUnionOfPaintedLeaves) {
  auto tree = random_tree(21, 200, 7);
  const PoolView pools = pool_view_of(*tree);
  auto got = client_core::painted_bounds(pools);
  ASSERT_TRUE(got.ok());
  ASSERT_TRUE(got->has_value());
  DAabb want{{1e30, 1e30, 1e30}, {-1e30, -1e30, -1e30}};
  for (const LeafBox& l : leaf_boxes(*tree)) {
    if ((l.colour >> 24) == 0) continue;
    for (int a = 0; a < 3; ++a) {
      double& mn = a == 0 ? want.min.x : (a == 1 ? want.min.y : want.min.z);
      double& mx = a == 0 ? want.max.x : (a == 1 ? want.max.y : want.max.z);
      mn = std::min(mn, l.min[a]);
      mx = std::max(mx, l.max[a]);
    }
  }
  EXPECT_EQ((*got)->min, want.min);
  EXPECT_EQ((*got)->max, want.max);
  // Nothing painted: no box.
  auto empty = Octree::create({});
  ASSERT_TRUE(empty.ok());
  auto none = client_core::painted_bounds(pool_view_of(**empty));
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE(none->has_value());
}

// fit_painted against brute force over the painted leaves (leaf_boxes): every corner of every
// painted leaf projects inside the image with the margin, and the fit is tight: on the binding
// axis a corner touches the margin on both sides (the view is centred), unless the eye had to
// stay in front of the nearest corner. Never farther than fit_box on the same scene.
TEST(Camera, FitPaintedFramesThePaintedLeavesExactly) {
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<double> u(-1, 1);
  for (std::uint64_t seed = 1; seed <= 12; ++seed) {
    auto tree = random_tree(seed + 40, 60 + 20 * static_cast<int>(seed), 3 + seed % 5);
    const PoolView pools = pool_view_of(*tree);
    const std::uint32_t w = 64 + static_cast<std::uint32_t>(rng() % 600), h = 48 + rng() % 400;
    const double fov = 25 + 60 * (u(rng) + 1) / 2, margin = 0.1 * (u(rng) + 1) / 2;
    const DVec3 dir{u(rng), u(rng), u(rng) + 0.01};
    auto cam = client_core::fit_painted(pools, w, h, fov, dir, {0, 0, 1}, margin);
    auto box = client_core::painted_bounds(pools);
    ASSERT_TRUE(box.ok());
    if (!box->has_value()) {
      EXPECT_FALSE(cam.ok());
      continue;
    }
    ASSERT_TRUE(cam.ok()) << seed;
    double left = 0, right = 0, down = 0, upper = 0, nearest = 1e300, extent = 0;
    for (const LeafBox& l : leaf_boxes(*tree)) {
      if ((l.colour >> 24) == 0) continue;
      for (int q = 0; q < 8; ++q) {
        const DVec3 corner{q & 1 ? l.max[0] : l.min[0], q & 2 ? l.max[1] : l.min[1],
                           q & 4 ? l.max[2] : l.min[2]};
        const DVec3 v = corner - cam->position();
        const double z = client_core::dot(v, cam->forward());
        ASSERT_GT(z, 0) << seed;
        const double x = client_core::dot(v, cam->right()) / z / cam->tan_half_h();
        const double y = client_core::dot(v, cam->up()) / z / cam->tan_half_v();
        right = std::max(right, x);
        left = std::max(left, -x);
        upper = std::max(upper, y);
        down = std::max(down, -y);
        nearest = std::min(nearest, z);
        extent = std::max(extent, client_core::length(corner - ((*box)->min + (*box)->max) * 0.5));
      }
    }
    const double limit = 1.0 - margin;
    EXPECT_LE(std::max({left, right, down, upper}), limit + 1e-9) << seed;
    if (nearest > 0.02 * extent) {  // the in-front constraint did not bind
      const bool x_binds = std::abs(left - limit) < 1e-6 && std::abs(right - limit) < 1e-6;
      const bool y_binds = std::abs(down - limit) < 1e-6 && std::abs(upper - limit) < 1e-6;
      EXPECT_TRUE(x_binds || y_binds)
          << seed << ": " << left << " " << right << " " << down << " " << upper;
    }
    auto boxed = Camera::fit_box(**box, w, h, fov, dir, {0, 0, 1}, margin);
    ASSERT_TRUE(boxed.ok());
    const DVec3 centre = ((*box)->min + (*box)->max) * 0.5;
    EXPECT_LE(client_core::dot(centre - cam->position(), cam->forward()),
              client_core::dot(centre - boxed->position(), boxed->forward()) * (1 + 1e-9))
        << seed;
  }
  auto empty = Octree::create({});
  ASSERT_TRUE(empty.ok());
  EXPECT_FALSE(client_core::fit_painted(pool_view_of(**empty), 64, 48).ok());
}

// The cell-local renderer (double) equals the brute force on random scenes, from cameras
// inside and outside the canvas, without early termination.
TEST(ReferenceRenderer, MatchesBruteForceOnRandomScenes) {
  std::mt19937_64 rng(77);
  for (std::uint64_t seed = 1; seed <= 6; ++seed) {
    auto tree = random_tree(seed, 250, 4 + static_cast<int>(seed));
    const PoolView pools = pool_view_of(*tree);
    const auto leaves = leaf_boxes(*tree);
    // Two random cameras inside, one outside, one close to the finest leaf looking at it.
    const LeafBox* finest = &leaves[0];
    for (const LeafBox& l : leaves) finest = l.edge < finest->edge ? &l : finest;
    for (int k = 0; k < 4; ++k) {
      Camera cam = random_camera(rng, pools.edge_m, 24, 18, k != 2);
      if (k == 3) {
        const DVec3 c = (finest->min + finest->max) * 0.5;
        const double e = finest->edge;
        cam = *Camera::look_at(c + DVec3{3.3 * e, 2.1 * e, 1.7 * e}, c, {0, 0, 1}, 60, 24, 18);
      }
      RenderOptions opt;
      opt.termination_transmittance = 0;
      opt.background = {0.25, 0.5, 0.75};
      RenderStats stats;
      const RenderImage got = render(pools, cam, opt, &stats);
      const RenderImage want = brute_force_render(leaves, cam, opt.background);
      EXPECT_LE(max_channel_diff(got, want), kDoubleTolerance) << "seed " << seed << " cam " << k;
      EXPECT_EQ(stats.bad_index_rays, 0u);
      EXPECT_EQ(stats.step_limit_rays, 0u);
      EXPECT_GT(stats.steps, stats.rays);  // the rays did cross cells
    }
  }
}

// A camera exactly on cell corners (the canvas centre is a corner of 8 roots) and on the
// canvas boundary: ties are resolved consistently.
TEST(ReferenceRenderer, MatchesBruteForceFromCellCorners) {
  auto tree = random_tree(42, 400, 7);
  const PoolView pools = pool_view_of(*tree);
  const auto leaves = leaf_boxes(*tree);
  const DVec3 eyes[] = {{0, 0, 0}, {2500, -5000, 0}, {10000, 1234.5, -77}, {-10000, -10000, 0}};
  for (const DVec3& eye : eyes) {
    auto cam = Camera::look_at(eye, {300, 200, 100}, {0, 0, 1}, 70, 20, 20);
    ASSERT_TRUE(cam.ok());
    RenderOptions opt;
    opt.termination_transmittance = 0;
    EXPECT_LE(max_channel_diff(render(pools, *cam, opt), brute_force_render(leaves, *cam, {})),
              kDoubleTolerance);
  }
}

std::vector<server_core::CellIndex> live_leaves(const Octree& tree) {
  std::vector<server_core::CellIndex> out;
  for (std::uint32_t c = 0; c < tree.high_water_cells(); ++c)
    if (tree.is_live(c) && tree.is_leaf(c)) out.push_back(c);
  return out;
}

// A tree painted only near one of its refined clusters, so that most subtrees are empty; its
// interior values current.
std::unique_ptr<Octree> sparse_tree(std::uint64_t seed) {
  auto tree = random_tree(seed, 400, 10);
  const auto leaves = live_leaves(*tree);
  const std::uint32_t keep = leaves[leaves.size() / 2];
  const auto k = tree->coord(keep);
  for (auto c : leaves) {
    const auto q = tree->coord(c);
    // Keep the leaves within a few cells of one deep leaf (compared at the coarser depth).
    const int dd = std::min<int>(q.depth, k.depth);
    bool near = true;
    const std::uint32_t qa[3] = {q.x, q.y, q.z}, ka[3] = {k.x, k.y, k.z};
    for (int a = 0; a < 3; ++a) {
      const std::int64_t x = std::int64_t{qa[a] >> (q.depth - dd)};
      const std::int64_t y = std::int64_t{ka[a] >> (k.depth - dd)};
      near = near && std::abs(x - y) <= 3;
    }
    if (!near) tree->set_colour(c, 0);
  }
  tree->refresh_interior_colours();
  return tree;
}

// Stepping over empty subtrees (interior colour 0) changes no pixel beyond rounding, in double
// and in float, and takes fewer steps where most of the canvas is empty; without current
// interior values (filtered_interiors false) nothing is skipped.
TEST(ReferenceRenderer, SkippingEmptySubtreesKeepsTheImage) {
  std::mt19937_64 rng(31);
  std::uint64_t with_steps = 0, without_steps = 0;
  for (std::uint64_t seed = 40; seed <= 43; ++seed) {
    auto tree = sparse_tree(seed);
    PoolView pools = pool_view_of(*tree);
    ASSERT_TRUE(pools.filtered_interiors);
    for (Precision prec : {Precision::float64, Precision::float32}) {
      const Camera cam = random_camera(rng, pools.edge_m, 32, 24, seed % 2 == 0);
      RenderOptions opt;
      opt.precision = prec;
      opt.termination_transmittance = 0;
      RenderStats with, without, stale;
      const RenderImage a = render(pools, cam, opt, &with);
      opt.skip_empty_subtrees = false;
      const RenderImage b = render(pools, cam, opt, &without);
      EXPECT_LE(max_channel_diff(a, b), prec == Precision::float64 ? kDoubleTolerance : 1.0 / 255)
          << "seed " << seed;
      EXPECT_LE(with.steps, without.steps);
      with_steps += with.steps;
      without_steps += without.steps;
      opt.skip_empty_subtrees = true;
      PoolView unknown = pools;
      unknown.filtered_interiors = false;
      (void)render(unknown, cam, opt, &stale);
      EXPECT_EQ(stale.steps, without.steps);
    }
  }
  EXPECT_LT(with_steps, without_steps);
  std::printf("steps with the skip %llu, without %llu\n",
              static_cast<unsigned long long>(with_steps),
              static_cast<unsigned long long>(without_steps));
}

// Where an interior value is stale the skip would lose paint, so pool_view_of says whether the
// tree's are current: a write makes them stale until the next refresh.
TEST(PoolView, FilteredInteriorsOnlyWhileTheTreeHasRefreshedThem) {
  auto tree = random_tree(44, 50, 6);
  EXPECT_TRUE(pool_view_of(*tree).filtered_interiors);
  const auto leaves = live_leaves(*tree);
  const auto deep = std::find_if(leaves.begin(), leaves.end(),
                                 [&](auto c) { return tree->coord(c).depth > 0; });
  ASSERT_NE(deep, leaves.end());
  // A root leaf has no parent to make stale; a deeper one does.
  tree->set_colour(*deep, tree->colour(*deep) == 0xFF00FF00u ? 0xFF0000FFu : 0xFF00FF00u);
  EXPECT_FALSE(pool_view_of(*tree).filtered_interiors);
  tree->refresh_interior_colours();
  EXPECT_TRUE(pool_view_of(*tree).filtered_interiors);
}

// G3 stepping and descent from the root visit the same cells with the same local points:
// bit-identical images, in double and in float, with and without early termination.
TEST(ReferenceRenderer, G3EqualsDescentExactly) {
  std::mt19937_64 rng(8);
  for (std::uint64_t seed = 10; seed <= 15; ++seed) {
    // Seeds 14 and 15: mostly empty, so the steps over empty subtrees are many.
    auto tree = seed < 14 ? random_tree(seed, 300, 9) : sparse_tree(seed);
    const PoolView pools = pool_view_of(*tree);
    for (Precision prec : {Precision::float64, Precision::float32}) {
      for (double term : {0.0, 1.0 / 512}) {
        const Camera cam = random_camera(rng, pools.edge_m, 20, 16, seed % 2 == 0);
        RenderOptions opt;
        opt.precision = prec;
        opt.termination_transmittance = term;
        RenderStats s_g3, s_desc;
        const RenderImage a = render(pools, cam, opt, &s_g3);
        opt.stepping = Stepping::descent;
        const RenderImage b = render(pools, cam, opt, &s_desc);
        ASSERT_EQ(a.rgba.size(), b.rgba.size());
        EXPECT_EQ(0, std::memcmp(a.rgba.data(), b.rgba.data(), a.rgba.size() * sizeof(double)));
        EXPECT_EQ(s_g3.steps, s_desc.steps);
      }
    }
  }
}

// Early termination at T < 1/512 changes no channel by more than what is left (< 1/512), and it
// does stop rays in a dense scene.
TEST(ReferenceRenderer, EarlyTerminationBound) {
  std::mt19937_64 rng(9);
  auto tree = random_tree(5, 400, 8);
  const PoolView pools = pool_view_of(*tree);
  for (int k = 0; k < 3; ++k) {
    const Camera cam = random_camera(rng, pools.edge_m, 24, 24, true);
    RenderOptions full;
    full.termination_transmittance = 0;
    RenderOptions early;
    RenderStats st;
    const double d = max_channel_diff(render(pools, cam, full), render(pools, cam, early, &st));
    EXPECT_LT(d, 1.0 / 512);
    EXPECT_GT(st.terminated_early, 0u);
  }
}

// The float cell-local variant (what the GPU computes) stays within 2/255 of the reference.
TEST(ReferenceRenderer, FloatCellLocalCloseToDouble) {
  std::mt19937_64 rng(10);
  for (std::uint64_t seed = 30; seed <= 32; ++seed) {
    auto tree = random_tree(seed, 300, 9);
    const PoolView pools = pool_view_of(*tree);
    const Camera cam = random_camera(rng, pools.edge_m, 32, 24, seed != 31);
    RenderOptions opt;
    const RenderImage a = render(pools, cam, opt);
    opt.precision = Precision::float32;
    EXPECT_LE(max_channel_diff(a, render(pools, cam, opt)), 2.0 / 255);
  }
}

TEST(ReferenceRenderer, ThreadsGiveTheSameImage) {
  std::mt19937_64 rng(12);
  auto tree = random_tree(3, 300, 8);
  const PoolView pools = pool_view_of(*tree);
  const Camera cam = random_camera(rng, pools.edge_m, 40, 30, true);
  RenderOptions opt;
  const RenderImage a = render(pools, cam, opt);
  opt.threads = 3;
  const RenderImage b = render(pools, cam, opt);
  EXPECT_EQ(a.rgba, b.rgba);
}

TEST(ReferenceRenderer, ToRgba8RoundsAndClamps) {
  RenderImage img;
  img.width = 1;
  img.height = 1;
  img.rgba = {0.5, -0.1, 1.2, 1.0 / 255 * 0.49};
  EXPECT_EQ(img.to_rgba8(), (std::vector<std::uint8_t>{128, 0, 255, 0}));
}

// Corrupt pools (as a hostile server could send): out-of-range children, self-referencing
// links, cycles. Rendering stops those rays and never reads out of range.
TEST(ReferenceRenderer, CorruptPoolsAreSurvived) {
  auto tree = random_tree(4, 100, 5);
  const PoolView good = pool_view_of(*tree);
  std::vector<std::uint32_t> fc(good.first_child.begin(), good.first_child.end());
  std::vector<std::uint32_t> links(good.group_links.begin(), good.group_links.end());
  std::mt19937_64 rng(1);
  const std::uint32_t cells = static_cast<std::uint32_t>(fc.size());
  for (int i = 0; i < 200; ++i) {
    const std::uint32_t c = static_cast<std::uint32_t>(rng() % cells);
    switch (rng() % 3) {
      case 0:
        fc[c] = cells + 8;
        break;  // out of range
      case 1:
        fc[c] = c & ~7u;
        break;  // a cycle to its own group
      default:
        links[rng() % links.size()] = static_cast<std::uint32_t>(rng() % (cells + 16));
    }
  }
  PoolView bad = good;
  bad.first_child = fc;
  bad.group_links = links;
  RenderOptions opt;
  opt.max_steps_per_ray = 4096;
  for (int k = 0; k < 4; ++k) {
    const Camera cam = random_camera(rng, good.edge_m, 16, 16, k % 2 == 0);
    RenderStats st;
    auto img = client_core::render_reference(bad, cam, opt, &st);
    if (!img.ok()) {
      EXPECT_EQ(img.error().code, Errc::malformed);  // the camera's own cell is corrupt
      continue;
    }
    EXPECT_EQ(st.rays, 256u);
  }
  auto bounds = client_core::painted_bounds(bad);
  if (!bounds.ok()) {
    EXPECT_EQ(bounds.error().code, Errc::malformed);
  }
}

TEST(ReferenceRenderer, RejectsBadOptions) {
  auto tree = random_tree(4, 10, 3);
  const PoolView pools = pool_view_of(*tree);
  auto cam = Camera::look_at({0, 0, 0}, {1, 0, 0}, {0, 0, 1}, 60, 4, 4);
  ASSERT_TRUE(cam.ok());
  RenderOptions opt;
  opt.termination_transmittance = 1.0;
  EXPECT_EQ(client_core::render_reference(pools, *cam, opt).error().code, Errc::invalid_argument);
  opt = {};
  opt.max_steps_per_ray = 0;
  EXPECT_FALSE(client_core::render_reference(pools, *cam, opt).ok());
}

}  // namespace
}  // namespace deepcanvas::render_test

namespace deepcanvas::render_test {
namespace {

// Two scales a factor 8192 apart side by side: the reference renderer still matches the brute
// force from a camera framing both and from one next to the tiny cluster.
TEST(ReferenceRenderer, MatchesBruteForceOnMultiScaleScene) {
  MultiScaleScene scene = multiscale_scene(4, 32, 24);
  ASSERT_TRUE(scene.tree);
  const PoolView pools = pool_view_of(*scene.tree);
  const auto leaves = leaf_boxes(*scene.tree);
  for (const Camera* cam : {&scene.wide, &scene.close}) {
    client_core::RenderOptions opt;
    opt.termination_transmittance = 0;
    opt.background = {0.1, 0.1, 0.1};
    auto img = client_core::render_reference(pools, *cam, opt);
    ASSERT_TRUE(img.ok());
    const RenderImage want = brute_force_render(leaves, *cam, opt.background);
    EXPECT_LE(max_channel_diff(*img, want), 1e-7);
    double hi = 0;
    for (std::size_t i = 3; i < want.rgba.size(); i += 4) hi = std::max(hi, want.rgba[i]);
    EXPECT_GT(hi, 0.3);  // the camera does see paint
  }
}

}  // namespace
}  // namespace deepcanvas::render_test
