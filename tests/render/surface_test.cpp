// RayResult::surface_m (the first surface a ray meets: where its opacity reaches one half, the
// point the studio paints on and zooms toward) against a brute force that knows nothing of the
// tree's structure: every painted leaf's box intersected with the ray in world coordinates, the
// segments sorted, the transmittance followed through them with the density model, and the
// half-opacity point solved inside the segment that crosses it.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "deepcanvas/protocol/density_model.hpp"
#include "render_scenes.hpp"

namespace deepcanvas::render_test {
namespace {

// The brute force: -1 when the ray's opacity never reaches one half.
double brute_force_surface(const std::vector<LeafBox>& leaves, const DVec3& o, const DVec3& d) {
  double trans = 1;
  for (const LeafSegment& s : painted_segments(leaves, o, d)) {
    const double alpha = static_cast<double>(s.leaf->colour >> 24) / 255.0;
    const double cells = (s.t1 - s.t0) / s.leaf->edge;
    const double after = trans * protocol::density::transmittance(alpha, cells);
    if (after <= 0.5) {
      const double x = alpha >= 1 ? 0 : std::log(0.5 / trans) / std::log(1 - alpha);
      return s.t0 + std::clamp(x, 0.0, cells) * s.leaf->edge;
    }
    trans = after;
  }
  return -1;
}

TEST(Surface, MatchesTheBruteForceOnRandomTrees) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  int hits = 0, misses = 0;
  for (int scene = 0; scene < 4; ++scene) {
    auto tree = random_tree(100 + scene, 60, 7);
    const auto leaves = leaf_boxes(*tree);
    const PoolView pools = pool_view_of(*tree);
    const double half = pools.edge_m * 0.5;
    for (int i = 0; i < 200; ++i) {
      // From outside the canvas toward a random point in it, and from inside it.
      const bool inside = i % 2 == 1;
      const DVec3 eye = inside ? DVec3{u(rng), u(rng), u(rng)} * (half * 0.9)
                               : DVec3{u(rng), u(rng), u(rng)} * (half * 3);
      const DVec3 target = DVec3{u(rng), u(rng), u(rng)} * (half * 0.5);
      DVec3 d = target - eye;
      d = d * (1.0 / client_core::length(d));
      auto origin = client_core::make_ray_origin(pools, eye);
      ASSERT_TRUE(origin.ok());
      const auto r = client_core::trace_ray(pools, *origin, d, client_core::RenderOptions{});
      const double want = brute_force_surface(leaves, eye, d);
      if (want < 0) {
        EXPECT_LT(r.surface_m, 0) << "scene " << scene << " ray " << i;
        ++misses;
      } else {
        EXPECT_NEAR(r.surface_m, want, 1e-9 * (half * 4)) << "scene " << scene << " ray " << i;
        ++hits;
      }
    }
  }
  // Both cases are exercised.
  EXPECT_GT(hits, 50);
  EXPECT_GT(misses, 3);
}

}  // namespace
}  // namespace deepcanvas::render_test
