#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "deepcanvas/protocol/density_model.hpp"

namespace deepcanvas {
namespace {

namespace dm = protocol::density;

TEST(DensityModel, QuantiseRoundsLikeLround) {
  // The reference: std::lround of the clamped, scaled value. Every half step, its neighbours one
  // ulp away, random values, the clamp's edges and NaN.
  auto ref = [](double v) {
    return static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0, 1.0) * 255.0));
  };
  std::vector<double> vs = {0.0,
                            1.0,
                            -0.0,
                            -1.0,
                            2.0,
                            1e-300,
                            0.49999999999999994 / 255.0,
                            0.5 / 255.0,
                            std::numeric_limits<double>::infinity(),
                            -std::numeric_limits<double>::infinity()};
  for (int k = 0; k <= 510; ++k) {
    const double v = k / 510.0;
    vs.push_back(v);
    vs.push_back(std::nextafter(v, 0.0));
    vs.push_back(std::nextafter(v, 1.0));
    const double y = k * 0.5;  // exactly on a half step of y = v * 255
    vs.push_back(y / 255.0);
    vs.push_back(std::nextafter(y / 255.0, 0.0));
    vs.push_back(std::nextafter(y / 255.0, 1.0));
  }
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-0.1, 1.1);
  for (int i = 0; i < 200000; ++i) vs.push_back(u(rng));
  for (const double v : vs) ASSERT_EQ(dm::quantise(v), ref(v)) << std::hexfloat << v;
  EXPECT_EQ(dm::quantise(std::numeric_limits<double>::quiet_NaN()), 0);
}

TEST(DensityModel, RefineMatchesTheRealModelAndKeepsDensity) {
  for (int a = 0; a < 256; ++a) {
    const double exact = dm::alpha_at_level_offset(a / 255.0, 1) * 255.0;
    const int q = dm::refine_alpha(static_cast<std::uint8_t>(a));
    EXPECT_LE(std::abs(q - exact), a > 0 && exact < 0.5 ? 1.0 : 0.5) << a;
    if (a > 0) {
      EXPECT_GT(q, 0) << "density vanished by refining " << a;
    }
  }
}

TEST(DensityModel, RefineThenCoarsenIsWithinOneQuantum) {
  for (int a = 0; a < 256; ++a) {
    const std::uint32_t c = dm::pack({200, 100, 50, static_cast<std::uint8_t>(a)});
    const std::uint32_t child = dm::refine_rgba(c);
    std::uint32_t ch[8];
    for (auto& x : ch) x = child;
    const std::uint32_t back = dm::coarsen_rgba(ch);
    EXPECT_LE(std::abs(int(back >> 24) - a), 1) << a;
    // Stable: a second round trip changes nothing (no drift from repeated refine/merge).
    for (auto& x : ch) x = dm::refine_rgba(back);
    EXPECT_EQ(dm::coarsen_rgba(ch), back) << a;
  }
}

TEST(DensityModel, CoarsenAveragesExtinction) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> d(0, 254);
  for (int it = 0; it < 2000; ++it) {
    std::uint32_t ch[8];
    double sigma = 0;  // per child edge
    for (auto& x : ch) {
      const auto a = static_cast<std::uint8_t>(d(rng));
      x = dm::pack({10, 20, 30, a});
      sigma += -std::log1p(-a / 255.0) / 8.0;
    }
    const double expect = 1.0 - std::exp(-2.0 * sigma);  // across the parent's doubled edge
    const std::uint32_t p = dm::coarsen_rgba(ch);
    EXPECT_NEAR((p >> 24) / 255.0, expect, 0.5 / 255.0 + 1e-12);
  }
}

// An interior value of 0 means an empty subtree (the ray casters skip it whole): filter_rgba is 0
// exactly when every child is, down to one child of the faintest alpha, and so at every level.
TEST(DensityModel, FilterIsZeroExactlyWhenEveryChildIsEmpty) {
  std::mt19937_64 rng(21);
  for (int k = 0; k < 20000; ++k) {
    std::uint32_t ch[8] = {};
    bool any = false;
    for (auto& c : ch) {
      if (rng() % 3 != 0) continue;
      const auto a = static_cast<std::uint8_t>(rng() % 4 == 0 ? 1 + rng() % 3 : 1 + rng() % 255);
      c = dm::pack({static_cast<std::uint8_t>(rng()), static_cast<std::uint8_t>(rng()),
                    static_cast<std::uint8_t>(rng()), a});
      any = true;
    }
    const std::uint32_t f = dm::filter_rgba(ch);
    ASSERT_EQ(f != 0, any) << "case " << k;
    ASSERT_EQ(f == 0, dm::unpack(f).a == 0) << "case " << k;  // canonical empty
    // A level up, with this cell one of eight otherwise empty children: still not 0.
    const std::uint32_t up[8] = {f, 0, 0, 0, 0, 0, 0, 0};
    ASSERT_EQ(dm::filter_rgba(up) != 0, any) << "case " << k;
  }
}

TEST(DensityModel, FilterKeepsSheetsAndFadesLinesByTheirShareOfTheVolume) {
  const std::uint32_t empty[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  EXPECT_EQ(dm::filter_rgba(empty), 0u);
  const std::uint32_t red = dm::pack({255, 0, 0, 255}), blue = dm::pack({0, 0, 255, 255});
  // A sheet one child thick (the four children on one side), opaque: the parent stays opaque,
  // where coarsen_rgba's rule would say the same and an average of alpha would say half.
  std::uint32_t sheet[8] = {red, 0, red, 0, red, 0, red, 0};
  EXPECT_EQ(dm::unpack(dm::filter_rgba(sheet)).a, 255);
  EXPECT_EQ(dm::unpack(dm::filter_rgba(sheet)).r, 255);
  // One opaque child of eight (a line's share): not opaque (coarsen_rgba would make the parent
  // opaque), 1 - exp(-2 * ln(1024) / 8) of the way.
  const std::uint32_t one[8] = {red, 0, 0, 0, 0, 0, 0, 0};
  const double want = 1.0 - std::exp(-2.0 * dm::kOpaqueOpticalDepth / 8.0);
  EXPECT_NEAR(dm::unpack(dm::filter_rgba(one)).a / 255.0, want, 0.5 / 255);
  EXPECT_EQ(dm::unpack(dm::coarsen_rgba(one)).a, 255);
  // Colour weighted by optical depth: an opaque blue child outweighs a faint red one.
  const std::uint32_t faint_red = dm::pack({255, 0, 0, 20});
  const std::uint32_t mixed[8] = {blue, faint_red, 0, 0, 0, 0, 0, 0};
  const auto m = dm::unpack(dm::filter_rgba(mixed));
  EXPECT_GT(m.b, 200);
  EXPECT_LT(m.r, 55);
  // A uniform region keeps its extinction: eight equal children give the parent whose
  // refinement is within a quantum of them (up to alpha 200: above it the parent's alpha is
  // so near 1 that one quantum there spans several of the children's).
  std::mt19937 rng(5);
  for (int i = 0; i < 200; ++i) {
    const std::uint32_t c = dm::pack({static_cast<std::uint8_t>(rng()), static_cast<std::uint8_t>(rng()),
                                      static_cast<std::uint8_t>(rng()),
                                      static_cast<std::uint8_t>(1 + rng() % 200)});
    const std::uint32_t same[8] = {c, c, c, c, c, c, c, c};
    const auto back = dm::unpack(dm::refine_rgba(dm::filter_rgba(same)));
    EXPECT_NEAR(back.a, dm::unpack(c).a, 1) << "alpha " << int(dm::unpack(c).a);
    EXPECT_NEAR(back.r, dm::unpack(c).r, 1);
  }
}

TEST(DensityModel, BrushOpacityIsScaleFree) {
  // A ray straight across a fully covered stamp transmits 1 - A*O whatever the cell count.
  for (double cells : {7.0, 10.0, 14.0, 100.0}) {
    const double a = dm::brush_cell_alpha(0.6, 1.0, 1.0 / cells);
    EXPECT_NEAR(std::pow(1.0 - a, cells), 0.4, 1e-12);
  }
}

TEST(DensityModel, PaintingCommutesWithRefinement) {
  // Painting a cell then refining it equals refining then painting each child (in alpha).
  const float rgb[3] = {0.2f, 0.9f, 0.4f};
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> d(0, 255);
  std::uniform_real_distribution<double> u(0, 1);
  for (int it = 0; it < 2000; ++it) {
    const std::uint32_t pre =
        dm::pack({static_cast<std::uint8_t>(d(rng)), 0, 0, static_cast<std::uint8_t>(d(rng))});
    const double q = u(rng);  // stroke alpha across a parent edge
    const double qc = 1.0 - std::sqrt(1.0 - q);
    const std::uint32_t a = dm::refine_rgba(dm::paint_over(pre, q, rgb));
    const std::uint32_t b = dm::paint_over(dm::refine_rgba(pre), qc, rgb);
    // Compare in the parent's frame (coarsening is well conditioned; refining near a = 1 is not).
    std::uint32_t ca[8], cb[8];
    for (int i = 0; i < 8; ++i) ca[i] = a, cb[i] = b;
    EXPECT_LE(std::abs(int(dm::coarsen_rgba(ca) >> 24) - int(dm::coarsen_rgba(cb) >> 24)), 2);
  }
}

TEST(DensityModel, EraseAndRecolor) {
  const float rgb[3] = {1, 0, 0};
  const std::uint32_t c = dm::pack({0, 0, 255, 200});
  EXPECT_EQ(dm::erase(c, 1.0), 0u);
  EXPECT_EQ(dm::erase(c, 0.0), c);
  EXPECT_LT(dm::erase(c, 0.5) >> 24, 200u);
  EXPECT_EQ(dm::erase(dm::pack({1, 2, 3, 255}), 1.0), 0u);
  const std::uint32_t r = dm::recolor(c, 1.0, rgb);
  EXPECT_EQ(r >> 24, 200u);
  EXPECT_EQ(r & 0xFF, 255u);
  EXPECT_EQ(dm::recolor(0, 1.0, rgb), 0u);  // empty stays empty
  EXPECT_EQ(dm::pack({9, 9, 9, 0}), 0u);    // canonical empty
}

TEST(DensityModel, CompositeMatchesTransmittance) {
  dm::Composite c;
  c.add(dm::pack({255, 0, 0, 128}), 2.0);
  const double t = std::pow(1.0 - 128 / 255.0, 2.0);
  EXPECT_NEAR(c.transmittance, t, 1e-12);
  EXPECT_NEAR(c.rgb[0], 1.0 - t, 1e-12);
}

}  // namespace
}  // namespace deepcanvas
