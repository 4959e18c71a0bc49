// The studio's orbit view (client_core/navigation.hpp): wheel zoom keeps the point under the
// pointer in place and twenty notches in and out return to the starting view, at every scale
// from the whole canvas to its finest cells and anywhere on the 20 km canvas; orbit, pan,
// framing and another artist's view.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "deepcanvas/client_core/navigation.hpp"

namespace deepcanvas::client_core {
namespace {

constexpr std::uint32_t kW = 1280, kH = 720;

// Where `p` projects in the view's image (pixels, continuous).
std::pair<double, double> project(const OrbitView& v, const DVec3& p) {
  auto cam = v.camera(kW, kH);
  EXPECT_TRUE(cam.ok());
  const DVec3 d = p - cam->position();
  const double z = dot(d, cam->forward());
  const double sx = dot(d, cam->right()) / (z * cam->tan_half_h());
  const double sy = dot(d, cam->up()) / (z * cam->tan_half_v());
  return {(sx + 1) * 0.5 * kW, (1 - sy) * 0.5 * kH};
}

// The same view to within `px` of a pixel at the focus (positions near 9 km round to ~2e-12 m,
// which is a visible fraction of nothing but the smallest views).
void expect_same_view(const OrbitView& a, const OrbitView& b, double px) {
  const double tol = px * b.metres_per_pixel(b.distance, kH);
  EXPECT_NEAR(a.distance, b.distance, tol);
  EXPECT_NEAR(length(a.focus - b.focus), 0.0, tol);
  EXPECT_DOUBLE_EQ(a.yaw_rad, b.yaw_rad);
  EXPECT_DOUBLE_EQ(a.pitch_rad, b.pitch_rad);
}

TEST(Navigation, TwentyNotchesInAndOutReturnToTheStartAtEveryScale) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-1, 1), px(0, kW), py(0, kH);
  // 20 notches of 0.8 scale the distance by 0.0115: the smallest start stays above kMinDistance.
  for (double distance : {3e4, 300.0, 1.0, 1e-2}) {
    for (int i = 0; i < 20; ++i) {
      OrbitView v;
      v.focus = DVec3{u(rng), u(rng), u(rng)} * 9000.0;  // anywhere on the canvas
      v.distance = distance;
      v.yaw_rad = u(rng) * 3;
      v.pitch_rad = u(rng) * 1.2;
      const OrbitView start = v;
      auto cam = v.camera(kW, kH);
      ASSERT_TRUE(cam.ok());
      const double x = px(rng), y = py(rng);
      // The point under the pointer, somewhere between the eye and twice the focus depth.
      const DVec3 point = cam->position() + ray_direction_at(*cam, x, y) * (distance * (0.3 + u(rng) * 0.2 + 0.5));
      for (int n = 0; n < 20; ++n) {
        v.zoom_toward(point, 1);
        const auto [qx, qy] = project(v, point);
        // The point stays under the pointer (to the rounding of metres near 9 km: 2e-12 m is
        // a few micro-pixels when a pixel covers a micrometre).
        EXPECT_NEAR(qx, x, 1e-4);
        EXPECT_NEAR(qy, y, 1e-4);
      }
      for (int n = 0; n < 20; ++n) v.zoom_toward(point, -1);
      expect_same_view(v, start, 1e-3);
    }
  }
}

TEST(Navigation, ZoomsFromTheWholeCanvasToItsFinestCellAndBack) {
  OrbitView v;
  v.focus = {7000.123456, -3000.5, 2000.25};
  v.distance = 4e4;  // the whole 20 km canvas, small
  const OrbitView start = v;
  const DVec3 point = v.focus + DVec3{0.000123, -0.000045, 0.000067};  // a 0.3 mm cell's corner
  // 88 notches of 0.8: 4e4 m * 0.8^88 = 1.2e-4 m, just above kMinDistance (a clamped notch
  // would not be undone by a notch out).
  const int notches = 88;
  for (int n = 0; n < notches; ++n) v.zoom_toward(point, 1);
  EXPECT_LT(v.distance, 2e-4);
  // At the closest, one pixel covers far less than a finest cell (20 km / 2^26 = 0.3 mm).
  EXPECT_LT(v.metres_per_pixel(v.distance, kH), 20000.0 / (1 << 26) / 100);
  for (int n = 0; n < notches; ++n) v.zoom_toward(point, -1);
  expect_same_view(v, start, 1e-3);
}

TEST(Navigation, OrbitAndPanAreUndoneByTheOppositeMove) {
  OrbitView v;
  v.focus = {1, 2, 3};
  const OrbitView start = v;
  v.orbit(37, -12, kH);
  v.orbit(-37, 12, kH);
  expect_same_view(v, start, 1e-6);
  v.pan(100, -40, kH);
  EXPECT_GT(length(v.focus - start.focus), 0.1);
  v.pan(-100, 40, kH);
  expect_same_view(v, start, 1e-6);
}

TEST(Navigation, PanMovesTheFocusPointWithThePointer) {
  OrbitView v;
  v.focus = {0.5, 0.25, -0.75};
  const DVec3 focus = v.focus;
  v.pan(50, 20, kH);
  const auto [x, y] = project(v, focus);
  EXPECT_NEAR(x, kW / 2.0 + 50, 1e-6);
  EXPECT_NEAR(y, kH / 2.0 + 20, 1e-6);
}

TEST(Navigation, FrameShowsTheWholeBox) {
  OrbitView v;
  const DAabb box{{-3, 1, 2}, {5, 2, 2.5}};
  v.frame(box, kW, kH);
  for (int c = 0; c < 8; ++c) {
    const DVec3 p{(c & 1) ? box.max.x : box.min.x, (c & 2) ? box.max.y : box.min.y,
                  (c & 4) ? box.max.z : box.min.z};
    const auto [x, y] = project(v, p);
    EXPECT_GE(x, 0);
    EXPECT_LE(x, kW);
    EXPECT_GE(y, 0);
    EXPECT_LE(y, kH);
  }
}

TEST(Navigation, AnotherArtistsViewIsTakenExactly) {
  OrbitView v;
  v.focus = {10, -20, 30};
  v.distance = 0.5;
  v.yaw_rad = -2.1;
  v.pitch_rad = 0.4;
  auto copy = OrbitView::looking_at(v.eye(), v.focus, v.vfov_deg);
  ASSERT_TRUE(copy.has_value());
  EXPECT_NEAR(copy->yaw_rad, v.yaw_rad, 1e-9);
  EXPECT_NEAR(copy->pitch_rad, v.pitch_rad, 1e-9);
  EXPECT_NEAR(copy->distance, v.distance, 1e-12);
  EXPECT_FALSE(OrbitView::looking_at({1, 1, 1}, {1, 1, 1}, 45).has_value());
  EXPECT_FALSE(OrbitView::looking_at({0, 0, 0}, {1, 1, 1}, 0).has_value());
}

}  // namespace
}  // namespace deepcanvas::client_core
