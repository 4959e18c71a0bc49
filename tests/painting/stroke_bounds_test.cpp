// Bounded work per stroke (painter.hpp, "Bounded strokes"; stroke.hpp, StrokeLimits): the
// extent limit refuses a stroke up front, the per-stroke cell limit and the capacity reserve
// stop one that grows too much, the tree stays valid and keeps what was painted, and a full
// canvas can still be erased.
#include <gtest/gtest.h>

#include <cmath>

#include "deepcanvas/server_core/painter.hpp"
#include "test_support.hpp"

namespace deepcanvas {
namespace {

using protocol::BrushMode;
using protocol::Stroke;
using protocol::StrokeSample;
using server_core::Octree;
using server_core::OctreeConfig;
using server_core::Painter;
using server_core::PainterConfig;

using painting_test::Canvas;

// The stroke of the issue: 2 samples, (10,10,10) to (-10000,10,10), radius 0.05 (196 bytes on
// the wire). It asks for ~10^9 cells.
Stroke attack_stroke() {
  Stroke s;
  s.brush.mode = BrushMode::paint;
  s.samples.push_back(StrokeSample{10, 10, 10, 0.05f, 1.0f, 0});
  s.samples.push_back(StrokeSample{-10000, 10, 10, 0.05f, 1.0f, 16});
  return s;
}

Stroke line(BrushMode mode, double x0, double x1, float radius, int n) {
  Stroke s;
  s.brush.mode = mode;
  s.brush.colour[0] = 0.8f;
  s.brush.colour[1] = 0.3f;
  s.brush.colour[2] = 0.1f;
  s.brush.hardness = 1.0f;
  for (int i = 0; i < n; ++i) {
    const double t = n > 1 ? static_cast<double>(i) / (n - 1) : 0.0;
    s.samples.push_back(StrokeSample{x0 + (x1 - x0) * t, 0.1, 0.1, radius, 1.0f, 0});
  }
  return s;
}

TEST(StrokeBounds, SampleBoxIsThePositionsInflatedByTheirRadius) {
  protocol::SampleBox b;
  EXPECT_TRUE(b.empty());
  EXPECT_EQ(b.extent_m(), 0.0);
  b.add(StrokeSample{1, 2, 3, 0.5f, 0.3f, 0});
  EXPECT_DOUBLE_EQ(b.extent_m(), 1.0);  // the radius, not the pressure-scaled one
  b.add(StrokeSample{-3, 2, 3, 0.25f, 1.0f, 0});
  EXPECT_DOUBLE_EQ(b.extent_m(), 4.0 + 0.5 + 0.25);
  b.add(StrokeSample{0, 2, 13, 0.25f, 1.0f, 0});
  EXPECT_DOUBLE_EQ(b.extent_m(), 10.0 + 0.5 + 0.25);
  protocol::StrokeLimits lim;
  lim.max_extent_m = 10.75;
  EXPECT_TRUE(protocol::check_extent(b, lim).ok());
  lim.max_extent_m = 10.7;
  auto r = protocol::check_extent(b, lim);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::limit_exceeded);
  EXPECT_NE(r.error().message.find("max_extent_m"), std::string::npos);
}

// Refused up front by the stroke rules (the server's decoder applies the same rules): nothing
// reaches the canvas.
TEST(StrokeBounds, TheIssuesAttackStrokeIsRefusedByItsExtent) {
  Canvas c;  // the default 20 km canvas: both samples are inside it
  const auto hash = c.tree->canvas_hash();
  const protocol::StrokeRules rules = c.painter->stroke_rules();
  auto v = protocol::ValidatedStroke::make(attack_stroke(), rules);
  ASSERT_FALSE(v.ok());
  EXPECT_EQ(v.error().code, Errc::limit_exceeded);
  EXPECT_NE(v.error().message.find("max_extent_m"), std::string::npos) << v.error().message;
  auto r = c.painter->apply_stroke(attack_stroke());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::limit_exceeded);
  EXPECT_FALSE(c.painter->stroke_active());
  EXPECT_EQ(c.tree->canvas_hash(), hash);
}

// With the extent limit lifted, the per-stroke cell limit stops the same stroke: the tree holds
// at most the limit more cells, is valid, and the next stroke paints normally.
TEST(StrokeBounds, TheCellLimitStopsTheAttackStrokeWithBoundedMemory) {
  PainterConfig pc;
  pc.limits.max_extent_m = 1e9;
  pc.limits.max_stroke_cells = 100000;
  OctreeConfig oc;
  oc.max_cells = 1u << 22;
  Canvas c(pc, oc);
  const std::uint64_t before = c.tree->live_cells();
  auto r = c.painter->apply_stroke(attack_stroke());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::limit_exceeded);
  EXPECT_NE(r.error().message.find("max_stroke_cells"), std::string::npos) << r.error().message;
  EXPECT_FALSE(c.painter->stroke_active());
  EXPECT_LE(c.tree->live_cells(), before + pc.limits.max_stroke_cells);
  EXPECT_GT(c.tree->live_cells(), before);  // it painted until it was stopped
  ASSERT_TRUE(c.tree->check_invariants().ok());
  auto next = c.painter->apply_stroke(line(BrushMode::paint, 0, 0.5, 0.05f, 4));
  ASSERT_TRUE(next.ok()) << next.error().message;
  ASSERT_TRUE(c.tree->check_invariants().ok());
}

// A streamed stroke's samples add up: a batch that would take its box past the extent limit is
// refused, the stroke stays open with what it had and goes on.
TEST(StrokeBounds, AStreamedBatchPastTheExtentIsRefusedAndTheStrokeGoesOn) {
  PainterConfig pc;
  pc.limits.max_extent_m = 1.0;
  Canvas c(pc);
  Stroke s = line(BrushMode::paint, 0, 0.5, 0.05f, 3);
  ASSERT_TRUE(c.painter->begin_stroke(s.brush, 1, s.samples).ok());
  const std::vector<StrokeSample> far = {StrokeSample{2.0, 0.1, 0.1, 0.05f, 1.0f, 0}};
  auto r = c.painter->add_samples(far);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::limit_exceeded);
  EXPECT_TRUE(c.painter->stroke_active());
  const std::vector<StrokeSample> near = {StrokeSample{0.8, 0.1, 0.1, 0.05f, 1.0f, 0}};
  ASSERT_TRUE(c.painter->add_samples(near).ok());
  ASSERT_TRUE(c.painter->end_stroke().ok());
  for (;;) {
    auto more = c.painter->step();
    ASSERT_TRUE(more.ok()) << more.error().message;
    if (!*more) break;
  }
  EXPECT_EQ(c.painter->stroke_stats().samples, 4u);
  ASSERT_TRUE(c.tree->check_invariants().ok());
}

// Paint stops at capacity less the reserve (out_of_memory naming the capacity); an erase stroke
// may use the reserve, so the full canvas can be erased, and erasing frees cells for painting.
TEST(StrokeBounds, AFullCanvasCanStillBeErased) {
  PainterConfig pc;
  pc.capacity_reserve = 0.05;
  OctreeConfig oc;
  oc.edge_m = 8.0;
  oc.max_depth = 12;
  oc.max_cells = 40000;
  Canvas c(pc, oc);
  const std::uint64_t cap = c.tree->config().max_cells;
  const auto reserve = static_cast<std::uint64_t>(static_cast<double>(cap) * 0.05);
  Result<server_core::StrokeStats> painted = server_core::StrokeStats{};
  // Fine strokes until one is stopped for capacity.
  for (int i = 0; i < 64 && painted.ok(); ++i)
    painted = c.painter->apply_stroke(line(BrushMode::paint, -3.5, 3.5, 0.004f, 20));
  ASSERT_FALSE(painted.ok());
  EXPECT_EQ(painted.error().code, Errc::out_of_memory);
  EXPECT_NE(painted.error().message.find("canvas capacity"), std::string::npos)
      << painted.error().message;
  EXPECT_LE(c.tree->live_cells(), cap - reserve);
  EXPECT_GT(c.tree->live_cells() + 8, cap - reserve);  // it got to the cap, not short of it
  ASSERT_TRUE(c.tree->check_invariants().ok());
  // Paint is refused again; erase of everything painted succeeds and frees cells.
  auto again = c.painter->apply_stroke(line(BrushMode::paint, -3.5, 3.5, 0.004f, 20));
  ASSERT_FALSE(again.ok());
  Stroke erase = line(BrushMode::erase, -3.5, 3.5, 0.2f, 20);
  auto erased = c.painter->apply_stroke(erase);
  ASSERT_TRUE(erased.ok()) << erased.error().message;
  ASSERT_TRUE(c.tree->check_invariants().ok());
  EXPECT_LT(c.tree->live_cells(), cap / 2);
  auto after = c.painter->apply_stroke(line(BrushMode::paint, -0.5, 0.5, 0.1f, 4));
  ASSERT_TRUE(after.ok()) << after.error().message;
}

TEST(StrokeBounds, CapacityReserveOutsideItsRangeIsRefused) {
  auto t = Octree::create({});
  ASSERT_TRUE(t.ok());
  PainterConfig pc;
  pc.capacity_reserve = 0.6;
  auto p = Painter::create(**t, pc);
  ASSERT_FALSE(p.ok());
  EXPECT_EQ(p.error().code, Errc::invalid_argument);
}

}  // namespace
}  // namespace deepcanvas
