// The server acks a stroke in the epoch where Painter::stroke_painted() first holds (all paint
// in, only merging of uniform children left; PROTOCOL.md 3.x "ack"). That is only right if the
// merges that follow do not change the picture: render the canvas (CPU reference, double) at the
// painted point and again once the stroke is settled, for random strokes in every mode that
// changes paint, and require the two images to agree within 2/255 per channel.
#include <gtest/gtest.h>

#include <cstdio>
#include <random>

#include "deepcanvas/server_core/painter.hpp"
#include "render_scenes.hpp"

namespace deepcanvas::render_test {
namespace {

using protocol::BrushMode;

double max_channel_diff(const RenderImage& a, const RenderImage& b) {
  double m = 0;
  for (std::size_t i = 0; i < a.rgba.size(); ++i) m = std::max(m, std::abs(a.rgba[i] - b.rgba[i]));
  return m;
}

TEST(AckImage, SettlingAfterThePaintedPointDoesNotChangeThePicture) {
  constexpr std::uint32_t kW = 80, kH = 60;
  int strokes_with_merges_after_painted = 0;
  double max_alpha_seen = 0;  // the camera must see paint for the comparison to mean anything
  for (std::uint64_t seed = 1; seed <= 3; ++seed) {
    auto tree = Octree::create({});
    ASSERT_TRUE(tree.ok());
    server_core::PainterConfig pc;
    pc.max_cells_per_step = 256;  // many small steps, so the painted point falls between them
    auto painter = server_core::Painter::create(**tree, pc);
    ASSERT_TRUE(painter.ok());
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    // Strokes in a 2 m region near the centre, radii 2-20 cm: several levels of refinement.
    const client_core::DAabb region{{-1.2, -1.2, -1.2}, {1.2, 1.2, 1.2}};
    auto camera = Camera::frame_box(region, kW, kH);
    ASSERT_TRUE(camera.ok());
    client_core::RenderOptions ro;
    ro.background = {0.2, 0.3, 0.4};
    const BrushMode modes[] = {BrushMode::paint, BrushMode::paint, BrushMode::erase,
                               BrushMode::recolor, BrushMode::smudge};
    for (int k = 0; k < 8; ++k) {
      protocol::Brush brush;
      brush.mode = modes[static_cast<std::size_t>(rng() % 5)];
      brush.colour[0] = static_cast<float>(0.5 + 0.5 * u(rng));
      brush.colour[1] = static_cast<float>(0.5 + 0.5 * u(rng));
      brush.colour[2] = static_cast<float>(0.5 + 0.5 * u(rng));
      brush.colour[3] = static_cast<float>(0.3 + 0.35 * (1 + u(rng)));
      brush.opacity = static_cast<float>(0.6 + 0.2 * (1 + u(rng)));
      brush.hardness = static_cast<float>(0.5 + 0.5 * u(rng));
      std::vector<protocol::StrokeSample> samples;
      const double r = 0.02 + 0.09 * (1 + u(rng));
      double x = u(rng), y = u(rng), z = u(rng);
      for (int i = 0; i < 12; ++i) {
        samples.push_back({x, y, z, static_cast<float>(r), 1.0f, static_cast<std::uint32_t>(i)});
        x += 0.1 * u(rng);
        y += 0.1 * u(rng);
        z += 0.1 * u(rng);
      }
      ASSERT_TRUE((*painter)->begin_stroke(brush, 100 * seed + k, samples).ok());
      ASSERT_TRUE((*painter)->end_stroke().ok());
      std::optional<RenderImage> at_painted;
      int steps_after_painted = 0;
      for (;;) {
        if (!at_painted && (*painter)->stroke_painted()) {
          auto img = client_core::render_reference(pool_view_of(**tree), *camera, ro);
          ASSERT_TRUE(img.ok()) << img.error().message;
          at_painted = std::move(*img);
        } else if (at_painted) {
          ++steps_after_painted;
        }
        auto more = (*painter)->step();
        ASSERT_TRUE(more.ok()) << more.error().message;
        if (!*more) break;
      }
      ASSERT_TRUE(at_painted.has_value()) << "stroke_painted() never held before the end";
      EXPECT_FALSE((*painter)->stroke_painted());  // no active stroke any more
      auto settled = client_core::render_reference(pool_view_of(**tree), *camera, ro);
      ASSERT_TRUE(settled.ok());
      EXPECT_LE(max_channel_diff(*at_painted, *settled), 2.0 / 255.0)
          << "seed " << seed << " stroke " << k << " mode "
          << protocol::brush_mode_name(brush.mode);
      if (steps_after_painted > 1) ++strokes_with_merges_after_painted;
      for (std::size_t i = 3; i < settled->rgba.size(); i += 4)
        max_alpha_seen = std::max(max_alpha_seen, settled->rgba[i]);
    }
  }
  // The property is only tested if merging really happened after the painted point.
  EXPECT_GE(strokes_with_merges_after_painted, 6);
  EXPECT_GT(max_alpha_seen, 0.5);
  std::printf("strokes with merges after the painted point: %d of 24, max alpha %.3f\n",
              strokes_with_merges_after_painted, max_alpha_seen);
}

}  // namespace
}  // namespace deepcanvas::render_test
