#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "deepcanvas/paintings/apa.hpp"
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

Stroke line(BrushMode mode, const float rgba[4], double x0, double y0, double x1, double y1,
            double z, float radius, int n, float opacity = 1.0f, float hardness = 0.5f) {
  Stroke s;
  s.brush.mode = mode;
  for (int i = 0; i < 4; ++i) s.brush.colour[i] = rgba[i];
  s.brush.opacity = opacity;
  s.brush.hardness = hardness;
  for (int i = 0; i < n; ++i) {
    const double t = n > 1 ? static_cast<double>(i) / (n - 1) : 0.0;
    StrokeSample p;
    p.x = x0 + (x1 - x0) * t;
    p.y = y0 + (y1 - y0) * t;
    p.z = z + 0.01 * std::sin(7 * t);
    p.radius = radius;
    p.pressure = static_cast<float>(0.6 + 0.4 * std::cos(5 * t) * std::cos(5 * t));
    s.samples.push_back(p);
  }
  return s;
}

using painting_test::random_stroke;

void expect_same_canvas(const Octree& a, const Octree& b, const std::string& what) {
  EXPECT_LE(painting_test::max_canvas_diff(a, b), 1) << what;
  EXPECT_EQ(a.canvas_hash(), b.canvas_hash()) << what;
}

TEST(Painter, MultiStepEqualsOneShotOnRandomStrokes) {
  PainterConfig small;
  small.max_cells_per_step = 64;  // many bounded steps
  Canvas multi(small), ref;
  std::mt19937 rng(11);
  for (int i = 0; i < 40; ++i) {
    const Stroke s = random_stroke(rng, i >= 10);
    auto a = multi.painter->apply_stroke(s);
    ASSERT_TRUE(a) << a.error().message;
    auto b = ref.painter->paint_one_shot(s);
    ASSERT_TRUE(b) << b.error().message;
    if (i % 8 == 7) {
      ASSERT_TRUE(multi.tree->check_invariants()) << multi.tree->check_invariants().error().message;
      ASSERT_TRUE(ref.tree->check_invariants());
    }
    expect_same_canvas(*multi.tree, *ref.tree, "after stroke " + std::to_string(i));
    if (HasFailure()) return;
  }
  EXPECT_GT(multi.tree->stats().max_depth, 15);
}

// Every interior cell carries protocol::density::filter_rgba of its children once the dirty
// blocks are taken (octree.hpp, "Interior cells"): checked on every cell, by brute force, after
// random strokes of every mode, merges and undos, with takes at random points in between; and
// the blocks a refresh changes are in the list taken. A zeros_exact take may leave a value
// lagging, but only a nonzero one over a nonempty subtree, and the next exact take writes it.
TEST(Painter, InteriorCellsCarryTheFilteredValueOfTheirChildren) {
  using Refresh = server_core::Octree::InteriorRefresh;
  server_core::PainterConfig pc;
  pc.record_diffs = true;
  Canvas c(pc);
  std::mt19937 rng(21);
  std::vector<server_core::CellDiff> diffs;
  std::size_t interior_checked = 0, lagging_seen = 0, zero_interiors_seen = 0;
  for (int i = 0; i < 90; ++i) {
    protocol::Stroke s = painting_test::random_stroke(rng, true);
    s.id = static_cast<std::uint64_t>(i + 1);
    auto d = c.painter->apply_stroke(s);
    ASSERT_TRUE(d.ok()) << d.error().message;
    if (auto diff = c.painter->take_stroke_diff(s.id)) diffs.push_back(std::move(*diff));
    if (i % 7 == 3 && !diffs.empty()) {
      auto r = c.painter->revert(diffs[rng() % diffs.size()]);
      ASSERT_TRUE(r.ok()) << r.error().message;
    }
    if (rng() % 3 == 0) continue;
    const Refresh refresh = rng() % 3 == 0 ? Refresh::exact : Refresh::zeros_exact;
    const auto fc = c.tree->first_child_pool();
    const auto before = std::vector<std::uint32_t>(c.tree->colour_pool().begin(),
                                                   c.tree->colour_pool().end());
    const auto taken = c.tree->take_dirty_blocks(refresh);
    const auto col = c.tree->colour_pool();
    const auto depth = c.tree->group_depth_flags_pool();
    std::size_t lagging = 0;
    for (std::size_t cell = 0; cell < fc.size(); ++cell) {
      if (depth[cell / 8] & 0x80) continue;  // a free group
      if (col[cell] != before[cell]) {
        EXPECT_NE(std::find(taken.begin(), taken.end(), c.tree->block_of(cell)), taken.end())
            << "cell " << cell << " changed in a block not taken";
      }
      if (fc[cell] == server_core::kNoCell) continue;
      const std::uint32_t filtered = protocol::density::filter_rgba(&col[fc[cell]]);
      ++interior_checked;
      zero_interiors_seen += filtered == 0;
      if (refresh == Refresh::exact) {
        ASSERT_EQ(col[cell], filtered) << "cell " << cell << " after an exact take";
        continue;
      }
      ASSERT_EQ(col[cell] == 0, filtered == 0) << "cell " << cell << ": 0 must be exact";
      lagging += col[cell] != filtered;
    }
    ASSERT_TRUE(c.tree->interior_colours_current());
    if (refresh == Refresh::exact) {
      ASSERT_FALSE(c.tree->interior_colours_lag());
    }
    if (lagging > 0) {
      ASSERT_TRUE(c.tree->interior_colours_lag());
    }
    lagging_seen += lagging;
  }
  EXPECT_GT(interior_checked, 1000u);
  EXPECT_GT(lagging_seen, 0u);         // the zeros_exact takes did leave values lagging
  EXPECT_GT(zero_interiors_seen, 0u);  // and erasing made interiors over empty subtrees
}

TEST(Painter, StepsAreBoundedAndPublishDirtyBlocks) {
  PainterConfig pc;
  pc.max_cells_per_step = 256;
  Canvas c(pc);
  const float red[4] = {1, 0, 0, 1};
  const Stroke s = line(BrushMode::paint, red, -0.3, 0, 0.3, 0.1, 0.2, 0.01f, 20);
  (void)c.tree->take_dirty_blocks();
  ASSERT_TRUE(c.painter->begin_stroke(s.brush, 1, s.samples));
  ASSERT_TRUE(c.painter->end_stroke());
  int steps = 0;
  std::uint64_t last_created = 0;
  for (;;) {
    auto more = c.painter->step();
    ASSERT_TRUE(more) << more.error().message;
    const std::uint64_t created = c.painter->stroke_stats().cells_created;
    // A step stops once it has spent `cap` work units; a split started under the cap may end
    // kStepWorkSlack over it.
    EXPECT_LE(created - last_created, pc.max_cells_per_step + server_core::kStepWorkSlack);
    last_created = created;
    if (!*more) break;
    ++steps;
    if (steps == 1) {
      EXPECT_FALSE(c.tree->take_dirty_blocks().empty());
    }
  }
  EXPECT_GT(steps, 20);  // one level per step from the roots down, several steps per level
  ASSERT_TRUE(c.tree->check_invariants());
}

// Steps a started stroke to its end; after every step the tree must be valid (balanced,
// consistent links, free lists) and the step must have stayed within its budget, measured both
// by the painter's own work count and by what the octree saw change.
void step_checked(Canvas& c, std::uint64_t cap, bool check_tree, const std::string& what) {
  const std::uint64_t bound = cap + server_core::kStepWorkSlack;
  for (int n = 0;; ++n) {
    const auto before = c.painter->stroke_stats();
    auto more = c.painter->step();
    ASSERT_TRUE(more) << more.error().message << " " << what;
    const auto& after = c.painter->stroke_stats();
    if (*more) {
      ASSERT_LE(after.work - before.work, bound) << what << " step " << n;
      ASSERT_LE(after.cells_created - before.cells_created, bound) << what << " step " << n;
      ASSERT_LE(after.cells_freed - before.cells_freed, bound) << what << " step " << n;
      // A recolour is a touched leaf (1 unit), a new child (1 of a split's 8) or a split or
      // merged parent (one per 8 units).
      ASSERT_LE(after.cells_recoloured - before.cells_recoloured, 2 * bound) << what;
    }
    if (check_tree) {
      auto inv = c.tree->check_invariants();
      ASSERT_TRUE(inv) << inv.error().message << " " << what << " after step " << n;
    }
    if (!*more) break;
  }
  EXPECT_LE(c.painter->stroke_stats().max_step_work, bound) << what;
}

TEST(Painter, InvariantsHoldAfterEveryStep) {
  // Whole strokes given at once (the first paint pass alone is many steps) and streamed strokes
  // with steps between the batches; the tree is checked at every step boundary, and the result
  // must still equal the one-shot reference.
  // A 16 m canvas and 4 cells across a stamp: target depths of ~8 rather than ~20 and ~60 cells
  // per stamp rather than ~500, so that the trees stay small enough to check in full after
  // every one of the many steps.
  OctreeConfig small_canvas;
  small_canvas.edge_m = 16;
  for (const std::uint64_t cap : {32u, 256u}) {
    PainterConfig pc;
    pc.max_cells_per_step = cap;
    pc.stamps.cells_across = 4;
    PainterConfig pc_ref = pc;
    pc_ref.max_cells_per_step = PainterConfig{}.max_cells_per_step;
    Canvas multi(pc, small_canvas), ref(pc_ref, small_canvas);
    std::mt19937 rng(static_cast<unsigned>(31 + cap));
    for (int i = 0; i < 8; ++i) {
      const Stroke s = random_stroke(rng, i >= 3);
      const std::string what = "cap " + std::to_string(cap) + " stroke " + std::to_string(i);
      if (i % 2 == 0) {
        ASSERT_TRUE(multi.painter->begin_stroke(s.brush, 1, s.samples)) << what;
        ASSERT_TRUE(multi.painter->end_stroke());
      } else {
        ASSERT_TRUE(multi.painter->begin_stroke(s.brush, 1, std::span(s.samples).subspan(0, 1)));
        for (std::size_t k = 1; k < s.samples.size(); k += 3) {
          const auto n = std::min<std::size_t>(3, s.samples.size() - k);
          ASSERT_TRUE(multi.painter->add_samples(std::span(s.samples).subspan(k, n)));
          for (int j = 0; j < 2; ++j) {
            ASSERT_TRUE(multi.painter->step());
            auto inv = multi.tree->check_invariants();
            ASSERT_TRUE(inv) << inv.error().message << " " << what;
          }
        }
        ASSERT_TRUE(multi.painter->end_stroke());
      }
      step_checked(multi, cap, true, what);
      if (HasFailure()) return;
      ASSERT_TRUE(ref.painter->paint_one_shot(s));
      expect_same_canvas(*multi.tree, *ref.tree, what);
    }
  }
}

TEST(Painter, WholeStrokeFirstStepIsSmallAndPublishes) {
  // A long stroke arriving at once: the first step does at most `cap` units of work (the
  // paint pass is cut into pieces), already changes the tree, and leaves dirty blocks to
  // publish; no later step exceeds the cap either.
  PainterConfig pc;
  pc.max_cells_per_step = 512;
  Canvas c(pc), ref;
  const float col[4] = {0.9f, 0.4f, 0.1f, 0.9f};
  const Stroke s = line(BrushMode::paint, col, -0.4, -0.2, 0.4, 0.3, 0.05, 0.01f, 400);
  ASSERT_TRUE(c.painter->apply_stroke(line(BrushMode::paint, col, -0.3, 0, 0.3, 0, 0, 0.05f, 8)));
  ASSERT_TRUE(ref.painter->apply_stroke(line(BrushMode::paint, col, -0.3, 0, 0.3, 0, 0, 0.05f, 8)));
  (void)c.tree->take_dirty_blocks();
  ASSERT_TRUE(c.painter->begin_stroke(s.brush, 2, s.samples));
  ASSERT_TRUE(c.painter->end_stroke());
  EXPECT_TRUE(c.tree->take_dirty_blocks().empty());  // begin/end only build stamps
  EXPECT_GT(c.painter->stroke_stats().stamps, 100u);
  auto more = c.painter->step();
  ASSERT_TRUE(more && *more);
  const auto first = c.painter->stroke_stats();
  EXPECT_LE(first.work, pc.max_cells_per_step + server_core::kStepWorkSlack);
  EXPECT_GT(first.cells_created + first.cells_recoloured, 0u);  // the tree changed
  EXPECT_FALSE(c.tree->take_dirty_blocks().empty());
  step_checked(c, pc.max_cells_per_step, false, "long stroke");
  EXPECT_GT(c.painter->stroke_stats().steps, 20u);
  EXPECT_GT(c.painter->stroke_stats().work, 20 * pc.max_cells_per_step);
  ASSERT_TRUE(c.tree->check_invariants());
  ASSERT_TRUE(ref.painter->paint_one_shot(s));
  expect_same_canvas(*c.tree, *ref.tree, "long stroke vs one-shot");
}

TEST(Painter, StreamedSamplesWithInterleavedStepsEqualWholeStroke) {
  Canvas streamed, whole;
  const float col[4] = {0.2f, 0.5f, 0.9f, 0.8f};
  const Stroke s = line(BrushMode::paint, col, -0.2, -0.1, 0.25, 0.2, 0.0, 0.02f, 30, 0.7f);
  ASSERT_TRUE(streamed.painter->begin_stroke(s.brush, 1, std::span(s.samples).subspan(0, 1)));
  for (std::size_t i = 1; i < s.samples.size(); i += 4) {
    auto n = std::min<std::size_t>(4, s.samples.size() - i);
    ASSERT_TRUE(streamed.painter->add_samples(std::span(s.samples).subspan(i, n)));
    for (int k = 0; k < 3; ++k) ASSERT_TRUE(streamed.painter->step());
  }
  ASSERT_TRUE(streamed.painter->end_stroke());
  for (;;) {
    auto more = streamed.painter->step();
    ASSERT_TRUE(more);
    if (!*more) break;
  }
  ASSERT_TRUE(whole.painter->apply_stroke(s));
  expect_same_canvas(*streamed.tree, *whole.tree, "streamed vs whole");
}

TEST(Painter, ExactShortcutsChangeNothing) {
  // PainterConfig::exact_shortcuts only skips evaluations whose outcome is known: the pools must
  // be byte-identical with and without it, for every mode, for opaque brushes (infinite
  // strengths, the bound's equality case, the hard core) and for broad strokes over finely
  // painted regions (cells wholly within a stamp's reach).
  PainterConfig off;
  off.exact_shortcuts = false;
  Canvas with, without(off);
  std::mt19937 rng(17);
  for (int i = 0; i < 60; ++i) {
    Stroke s = random_stroke(rng, i >= 20);
    if (i % 3 == 0) s.brush.colour[3] = s.brush.opacity = 1.0f;
    if (i % 10 == 9) {  // broad, over what the earlier strokes refined
      for (auto& p : s.samples) p.radius *= 8.0f;
    }
    auto a = with.painter->apply_stroke(s);
    ASSERT_TRUE(a) << a.error().message;
    auto b = without.painter->apply_stroke(s);
    ASSERT_TRUE(b) << b.error().message;
    ASSERT_EQ(with.tree->pool_hash(), without.tree->pool_hash()) << "after stroke " << i;
    // The same cells touched, refined and merged back: the same work and the same steps (so
    // the same epochs), not only the same end state.
    EXPECT_EQ(a->cells_recoloured, b->cells_recoloured) << "after stroke " << i;
    EXPECT_EQ(a->cells_created, b->cells_created) << "after stroke " << i;
    EXPECT_EQ(a->cells_freed, b->cells_freed) << "after stroke " << i;
    EXPECT_EQ(a->work, b->work) << "after stroke " << i;
    EXPECT_EQ(a->steps, b->steps) << "after stroke " << i;
  }
  EXPECT_GT(with.tree->stats().max_depth, 15);
}

TEST(Painter, FineBrushNextToCoarseRegion) {
  Canvas multi, ref;
  const float a[4] = {0.9f, 0.8f, 0.1f, 1};
  const float b[4] = {0.1f, 0.2f, 0.9f, 1};
  const Stroke broad = line(BrushMode::paint, a, -1, 0, 1, 0, 0, 0.5f, 5);
  const Stroke fine = line(BrushMode::paint, b, 0, 0.3, 0, 0.8, 0, 0.002f, 40);  // crosses the edge
  for (const Stroke* s : {&broad, &fine}) {
    ASSERT_TRUE(multi.painter->apply_stroke(*s));
    ASSERT_TRUE(ref.painter->paint_one_shot(*s));
  }
  ASSERT_TRUE(multi.tree->check_invariants());
  expect_same_canvas(*multi.tree, *ref.tree, "fine next to coarse");
  // The fine stroke reached its target depth (~10 cells across 4 mm * pressure).
  const server_core::CanvasGeometry g = server_core::CanvasGeometry::of(multi.tree->config());
  EXPECT_GE(multi.tree->stats().max_depth, server_core::target_depth(g, 2 * 0.002 * 0.6, 10));
  auto pick = multi.painter->pick({0, 0.7, std::sin(7 * 0.8) * 0.01});
  ASSERT_TRUE(pick);
  EXPECT_NEAR(pick->rgb[2], 0.9f, 0.02f);
}

TEST(Painter, BroadBrushOverFinelyRefinedRegionMergesBack) {
  Canvas multi, ref;
  std::mt19937 rng(5);
  const float f[4] = {0.3f, 0.3f, 0.3f, 1};
  for (int i = 0; i < 6; ++i) {
    const double y = -0.05 + 0.02 * i;
    const Stroke s = line(BrushMode::paint, f, -0.05, y, 0.05, y, 0, 0.003f, 10);
    ASSERT_TRUE(multi.painter->apply_stroke(s));
    ASSERT_TRUE(ref.painter->paint_one_shot(s));
  }
  const auto fine_leaves = multi.tree->stats().leaves;
  const float g[4] = {0.0f, 0.9f, 0.2f, 1};
  Stroke broad = line(BrushMode::paint, g, -0.02, 0, 0.02, 0, 0, 0.4f, 3, 1.0f, 0.9f);
  ASSERT_TRUE(multi.painter->apply_stroke(broad));
  ASSERT_TRUE(ref.painter->paint_one_shot(broad));
  ASSERT_TRUE(multi.tree->check_invariants());
  expect_same_canvas(*multi.tree, *ref.tree, "broad over fine");
  EXPECT_LT(multi.tree->stats().leaves, fine_leaves);  // the opaque interior merged back
  auto pick = multi.painter->pick({0, 0, 0});
  ASSERT_TRUE(pick);
  EXPECT_NEAR(pick->rgb[1], 0.9f, 0.01f);
  EXPECT_EQ(pick->alpha, 1.0f);
}

TEST(Painter, ErasingEverythingReturnsToTheRoots) {
  Canvas c;
  const std::uint64_t empty_hash = c.tree->canvas_hash();
  std::mt19937 rng(9);
  for (int i = 0; i < 15; ++i) ASSERT_TRUE(c.painter->apply_stroke(random_stroke(rng, false)));
  EXPECT_GT(c.tree->stats().live_cells, 64u);
  const float any[4] = {0, 0, 0, 1};
  Stroke erase = line(BrushMode::erase, any, -0.1, 0, 0.1, 0, 0, 3.0f, 2, 1.0f, 1.0f);
  auto r = c.painter->apply_stroke(erase);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_EQ(c.tree->stats().live_cells, c.tree->root_count());
  EXPECT_EQ(c.tree->canvas_hash(), empty_hash);
  ASSERT_TRUE(c.tree->check_invariants());
}

TEST(Painter, DeterministicPoolsAndHashes) {
  Canvas a, b;
  std::mt19937 r1(21), r2(21);
  for (int i = 0; i < 25; ++i) {
    ASSERT_TRUE(a.painter->apply_stroke(random_stroke(r1, true)));
    ASSERT_TRUE(b.painter->apply_stroke(random_stroke(r2, true)));
  }
  EXPECT_EQ(a.tree->pool_hash(), b.tree->pool_hash());
  EXPECT_EQ(a.tree->canvas_hash(), b.tree->canvas_hash());
}

TEST(Painter, StrokeOpacityDoesNotBuildUp) {
  Canvas once, zigzag;
  const float col[4] = {1, 1, 1, 1};
  Stroke s = line(BrushMode::paint, col, -0.1, 0, 0.1, 0, 0, 0.02f, 10, 0.5f, 1.0f);
  for (auto& p : s.samples) p.pressure = 1, p.z = 0;
  Stroke z = s;
  for (int k = 0; k < 3; ++k) {  // back and forth over the same path
    auto rev = s.samples;
    std::reverse(rev.begin(), rev.end());
    z.samples.insert(z.samples.end(), rev.begin(), rev.end());
    z.samples.insert(z.samples.end(), s.samples.begin(), s.samples.end());
  }
  ASSERT_TRUE(once.painter->apply_stroke(s));
  ASSERT_TRUE(zigzag.painter->apply_stroke(z));
  EXPECT_EQ(once.tree->canvas_hash(), zigzag.tree->canvas_hash());
  // A second stroke does build up (stroke-level, not canvas-level, opacity).
  const auto p1 = once.painter->pick({0, 0, 0});
  ASSERT_TRUE(once.painter->apply_stroke(s));
  const auto p2 = once.painter->pick({0, 0, 0});
  ASSERT_TRUE(p1 && p2);
  EXPECT_GT(p2->alpha, p1->alpha);
}

TEST(Painter, ScaleCorrectTransparency) {
  // The same stroke at 1/64 and at 64 times its size: cells exactly 2^12 apart in size, so the
  // same alpha per cell, and a ray across the stroke sees the same opacity at both scales.
  const float col[4] = {0.5f, 0.5f, 1.0f, 0.5f};
  double alphas[2];
  int depths[2];
  const double scales[2] = {1.0 / 64, 64};
  for (int i = 0; i < 2; ++i) {
    Canvas c;
    const double k = scales[i];
    Stroke s = line(BrushMode::paint, col, -0.5 * k, 0.1 * k, 0.5 * k, 0.1 * k, 0,
                    0.2f * static_cast<float>(k), 8, 0.8f, 1.0f);
    for (auto& p : s.samples) p.pressure = 1, p.z = 0;
    ASSERT_TRUE(c.painter->apply_stroke(s));
    auto p = c.painter->pick({0.01 * k, 0.1 * k, 0.0001 * k});
    ASSERT_TRUE(p);
    alphas[i] = p->alpha;
    depths[i] = p->depth;
    // Across the diameter, the stroke transmits 1 - A*O = 0.6 (within quantisation).
    const double cells = 2 * 0.2 * k / p->cell_edge_m;
    EXPECT_NEAR(std::pow(1.0 - p->alpha, cells), 0.6, 0.03) << "scale " << k;
  }
  EXPECT_EQ(alphas[0], alphas[1]);
  EXPECT_EQ(depths[0], depths[1] + 12);
}

TEST(Painter, PickUpChangesNothing) {
  Canvas c;
  const float col[4] = {0.25f, 0.5f, 0.75f, 1};
  ASSERT_TRUE(
      c.painter->apply_stroke(line(BrushMode::paint, col, -0.1, 0, 0.1, 0, 0, 0.05f, 5, 1, 1)));
  const auto pool = c.tree->pool_hash();
  Stroke pick;
  pick.brush.mode = BrushMode::pick_up;
  StrokeSample p;
  p.radius = 0.01f;
  pick.samples.push_back(p);
  ASSERT_TRUE(c.painter->apply_stroke(pick));
  EXPECT_EQ(c.tree->pool_hash(), pool);
  ASSERT_TRUE(c.painter->last_pick());
  EXPECT_NEAR(c.painter->last_pick()->rgb[0], 0.25f, 0.01f);
  EXPECT_NEAR(c.painter->last_pick()->rgb[2], 0.75f, 0.01f);
  EXPECT_EQ(c.painter->last_pick()->alpha, 1.0f);
}

TEST(Painter, RecolorKeepsDensityAndSmudgeDragsColour) {
  Canvas c;
  const float red[4] = {1, 0, 0, 0.6f}, blue[4] = {0, 0, 1, 1};
  ASSERT_TRUE(
      c.painter->apply_stroke(line(BrushMode::paint, red, -0.2, 0, 0.0, 0, 0, 0.05f, 5, 1, 1)));
  ASSERT_TRUE(
      c.painter->apply_stroke(line(BrushMode::paint, blue, 0.0, 0, 0.2, 0, 0, 0.05f, 5, 1, 1)));
  const auto before = c.painter->pick({-0.1, 0, 0.0});
  ASSERT_TRUE(before);
  const float green[4] = {0, 1, 0, 1};
  ASSERT_TRUE(c.painter->apply_stroke(
      line(BrushMode::recolor, green, -0.15, 0, -0.05, 0, 0, 0.05f, 3, 1, 1)));
  const auto after = c.painter->pick({-0.1, 0, 0.0});
  ASSERT_TRUE(after);
  EXPECT_EQ(after->alpha, before->alpha);
  EXPECT_GT(after->rgb[1], 0.9f);
  // Smudge from the blue part into the green part: blue arrives where it was not.
  const auto g0 = c.painter->pick({-0.12, 0, 0});
  Stroke sm = line(BrushMode::smudge, green, 0.15, 0, -0.12, 0, 0, 0.03f, 30, 1, 1);
  for (auto& p : sm.samples) p.pressure = 1, p.z = 0;
  ASSERT_TRUE(c.painter->apply_stroke(sm));
  const auto g1 = c.painter->pick({-0.12, 0, 0});
  ASSERT_TRUE(g0 && g1);
  EXPECT_GT(g1->rgb[2], g0->rgb[2] + 0.05f);
  // Density kept: compare extinction per metre (the smudge may have refined the cell).
  EXPECT_NEAR(g1->sigma_per_m, g0->sigma_per_m, 0.05 * g0->sigma_per_m);
}

TEST(Painter, BadStrokesChangeNothing) {
  Canvas c;
  const float col[4] = {1, 1, 1, 1};
  ASSERT_TRUE(c.painter->apply_stroke(line(BrushMode::paint, col, 0, 0, 0.1, 0, 0, 0.02f, 3)));
  const auto pool = c.tree->pool_hash();
  Stroke bad = line(BrushMode::paint, col, 0, 0, 0.1, 0, 0, 0.02f, 3);
  bad.samples[1].y = std::nan("");
  EXPECT_FALSE(c.painter->apply_stroke(bad));
  bad.samples[1].y = 2e4;  // outside the canvas
  EXPECT_FALSE(c.painter->apply_stroke(bad));
  bad = line(BrushMode::paint, col, 0, 0, 0.1, 0, 0, 0.02f, 3);
  bad.brush.opacity = 2;
  EXPECT_FALSE(c.painter->apply_stroke(bad));
  EXPECT_FALSE(c.painter->paint_one_shot(bad));
  EXPECT_EQ(c.tree->pool_hash(), pool);
  EXPECT_FALSE(c.painter->stroke_active());
  // Samples for no stroke are refused; a bad batch in a live stroke is refused and changes nothing.
  EXPECT_FALSE(c.painter->add_samples(std::span(bad.samples)));
  const Stroke good = line(BrushMode::paint, col, 0, 0, 0.1, 0, 0, 0.02f, 3);
  ASSERT_TRUE(c.painter->begin_stroke(good.brush, 7, good.samples));
  std::vector<StrokeSample> nan_batch{good.samples[0]};
  nan_batch[0].x = std::nan("");
  EXPECT_FALSE(c.painter->add_samples(nan_batch));
  EXPECT_FALSE(c.painter->begin_stroke(good.brush, 8, good.samples));  // one at a time
  ASSERT_TRUE(c.painter->end_stroke());
  while (*c.painter->step()) {
  }
}

// ---- several open strokes (painter.hpp, "Concurrent strokes") ----

// One piece of work for one stroke, as the server's turns give it.
struct Turn {
  enum Kind { begin, samples, end } kind;
  std::size_t stroke;
  std::size_t first, count;  // samples [first, first + count) of the stroke
};

// A random interleaving of the strokes' turns: each stroke begins (with a random number of its
// first samples), gets its remaining samples in random pieces, then ends; at any time a random
// open stroke takes the next turn, so up to all of them are open at once.
std::vector<Turn> random_turns(const std::vector<Stroke>& strokes, std::mt19937& rng) {
  std::vector<Turn> turns;
  std::vector<std::size_t> next(strokes.size(), 0);
  std::vector<bool> begun(strokes.size(), false), ended(strokes.size(), false);
  std::size_t done = 0;
  while (done < strokes.size()) {
    const std::size_t k = rng() % strokes.size();
    if (ended[k]) continue;
    const std::size_t left = strokes[k].samples.size() - next[k];
    const std::size_t n = left == 0 ? 0 : 1 + rng() % left;
    if (!begun[k]) {
      turns.push_back({Turn::begin, k, 0, n});
      begun[k] = true;
    } else if (n > 0 && rng() % 4 != 0) {
      turns.push_back({Turn::samples, k, next[k], n});
    } else if (left == 0) {
      turns.push_back({Turn::end, k, 0, 0});
      ended[k] = true;
      ++done;
      continue;
    } else {
      continue;
    }
    next[k] += n;
  }
  return turns;
}

// Gives each turn to the painter and steps it to completion, checking the tree after each.
void run_turns(Painter& p, const Octree& tree, const std::vector<Stroke>& strokes,
               const std::vector<Turn>& turns) {
  for (const Turn& t : turns) {
    const auto id = static_cast<std::uint64_t>(t.stroke + 1);
    const auto piece = std::span(strokes[t.stroke].samples).subspan(t.first, t.count);
    const auto r = t.kind == Turn::begin     ? p.begin_stroke(strokes[t.stroke].brush, id, piece)
                   : t.kind == Turn::samples ? p.add_samples(id, piece)
                                             : p.end_stroke(id);
    ASSERT_TRUE(r) << r.error().message;
    for (;;) {
      auto more = p.step();
      ASSERT_TRUE(more) << more.error().message;
      if (!*more) break;
    }
    ASSERT_TRUE(tree.check_invariants()) << tree.check_invariants().error().message;
  }
  EXPECT_EQ(p.open_strokes(), 0u);
}

// Strokes far apart (each around its own point, 100 m from the others) give the same canvas
// whether painted one after another or interleaved turn by turn in any order.
TEST(Painter, DisjointStrokesInterleavedEqualThemOneAfterAnother) {
  PainterConfig small;
  small.max_cells_per_step = 256;
  std::mt19937 rng(21);
  for (int trial = 0; trial < 6; ++trial) {
    std::vector<Stroke> strokes;
    for (int k = 0; k < 4; ++k) {
      Stroke s = random_stroke(rng, trial >= 2);
      for (auto& p : s.samples) {
        p.x += 100.0 * (k & 1);
        p.y += 100.0 * (k >> 1);
      }
      strokes.push_back(s);
    }
    Canvas interleaved(small), sequential(small);
    run_turns(*interleaved.painter, *interleaved.tree, strokes, random_turns(strokes, rng));
    for (const Stroke& s : strokes) ASSERT_TRUE(sequential.painter->apply_stroke(s));
    expect_same_canvas(*interleaved.tree, *sequential.tree, "trial " + std::to_string(trial));
    if (HasFailure()) return;
  }
}

// Strokes that overlap while open layer in the order of their turns: the tree stays valid after
// every turn, every stroke finishes, and the same turns give the same pools.
TEST(Painter, OverlappingStrokesInterleavedKeepTheTreeValidAndAreDeterministic) {
  PainterConfig small;
  small.max_cells_per_step = 256;
  std::mt19937 rng(5);
  for (int trial = 0; trial < 6; ++trial) {
    std::vector<Stroke> strokes;
    for (int k = 0; k < 4; ++k) {
      Stroke s = random_stroke(rng, trial >= 2);
      for (auto& p : s.samples) p.x *= 0.2, p.y *= 0.2, p.z *= 0.2;  // crowded together
      strokes.push_back(s);
    }
    const auto turns = random_turns(strokes, rng);
    Canvas a(small), b(small);
    run_turns(*a.painter, *a.tree, strokes, turns);
    run_turns(*b.painter, *b.tree, strokes, turns);
    if (HasFailure()) return;
    EXPECT_EQ(a.tree->pool_hash(), b.tree->pool_hash()) << "trial " << trial;
  }
}

// Only the stroke with work may be given more: the others wait until step() has finished it.
TEST(Painter, AnotherStrokeWaitsWhileOneIsBusy) {
  Canvas c;
  const float col[4] = {1, 0, 0, 1};
  const Stroke a = line(BrushMode::paint, col, -0.2, 0, 0.2, 0, 0, 0.05f, 8);
  const Stroke b = line(BrushMode::paint, col, -0.2, 0.3, 0.2, 0.3, 0, 0.05f, 8);
  ASSERT_TRUE(c.painter->begin_stroke(a.brush, 1, std::span(a.samples).subspan(0, 4)));
  EXPECT_EQ(c.painter->busy_stroke(), std::optional<std::uint64_t>(1));
  auto refused = c.painter->begin_stroke(b.brush, 2, b.samples);
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code, Errc::refused);
  while (*c.painter->step()) {
  }
  EXPECT_FALSE(c.painter->busy_stroke());
  ASSERT_TRUE(c.painter->begin_stroke(b.brush, 2, b.samples));
  EXPECT_FALSE(c.painter->begin_stroke(b.brush, 2, b.samples));  // already open
  while (*c.painter->step()) {
  }
  EXPECT_EQ(c.painter->open_strokes(), 2u);
  EXPECT_FALSE(c.painter->end_stroke());  // two are open: which?
  ASSERT_TRUE(c.painter->add_samples(1, std::span(a.samples).subspan(4)));
  while (*c.painter->step()) {
  }
  ASSERT_TRUE(c.painter->end_stroke(2));
  while (*c.painter->step()) {
  }
  ASSERT_TRUE(c.painter->end_stroke());  // only stroke 1 is left
  while (*c.painter->step()) {
  }
  EXPECT_FALSE(c.painter->stroke_active());
}

// Two strokes over the same cells taking turns sample by sample, as the server interleaves its
// artists (a heavy stroke's turns hold one sample: stroke_scheduler::turn_samples), give the
// same canvas whatever the step sizes: the server steps each turn with a small first step and
// full ones after it, a replay (deepcanvas-server replay, a restart) with full steps. A stroke
// taking back cells the other took must weigh the same stamps when it refines them as when its
// paint reaches them (Impl::TurnSeq); before it did not, and a replay of the server's stroke
// log gave another canvas (StrokeOrderReplay.InterleavedStrokesReplayToTheSameCanvasHash).
TEST(Painter, StrokesTakingTurnsOverTheSameCellsDoNotDependOnStepSizes) {
  std::mt19937 rng(77);
  int changed = 0;
  for (int trial = 0; trial < 40; ++trial) {
    Stroke a = random_stroke(rng, trial % 2 == 1);
    while (a.samples.size() < 6) a = random_stroke(rng, trial % 2 == 1);
    // Radii that change along the stroke: a later, finer stamp refines cells an earlier one
    // painted (and the other stroke took over in between).
    for (auto& p : a.samples) p.radius *= static_cast<float>(0.25 + 1.5 * (rng() % 1000) / 1000.0);
    Stroke b = random_stroke(rng, trial % 2 == 1);
    b.samples = a.samples;
    const double d = 0.3 * a.samples[0].radius;
    for (auto& p : b.samples) p.x += d, p.y -= d / 2, p.z += d / 3;
    const std::vector<Stroke> strokes{a, b};
    std::vector<Turn> turns{{Turn::begin, 0, 0, 2}, {Turn::begin, 1, 0, 2}};
    for (std::size_t i = 2; i < a.samples.size(); ++i) {
      turns.push_back({Turn::samples, 0, i, 1});
      turns.push_back({Turn::samples, 1, i, 1});
    }
    turns.push_back({Turn::end, trial % 3 == 0 ? 1u : 0u, 0, 0});
    turns.push_back({Turn::end, trial % 3 == 0 ? 0u : 1u, 0, 0});
    PainterConfig full;
    full.max_cells_per_step = 1u << 20;
    Canvas whole(full), stepped(full);
    run_turns(*whole.painter, *whole.tree, strokes, turns);
    for (const Turn& t : turns) {
      const auto id = static_cast<std::uint64_t>(t.stroke + 1);
      const auto piece = std::span(strokes[t.stroke].samples).subspan(t.first, t.count);
      Painter& p = *stepped.painter;
      const auto r = t.kind == Turn::begin     ? p.begin_stroke(strokes[t.stroke].brush, id, piece)
                     : t.kind == Turn::samples ? p.add_samples(id, piece)
                                               : p.end_stroke(id);
      ASSERT_TRUE(r) << r.error().message;
      for (bool first = true;; first = false) {
        auto more = p.step(first ? 64 : 8 + rng() % 512);
        ASSERT_TRUE(more) << more.error().message;
        if (!*more) break;
      }
    }
    if (HasFailure()) return;
    ASSERT_TRUE(stepped.tree->check_invariants());
    EXPECT_EQ(whole.tree->canvas_hash(), stepped.tree->canvas_hash()) << "trial " << trial;
    Canvas serial(full);  // the same strokes one after the other: overlapping, so another canvas
    for (const Stroke& s : strokes) ASSERT_TRUE(serial.painter->apply_stroke(s));
    changed += serial.tree->canvas_hash() != whole.tree->canvas_hash();
  }
  EXPECT_GT(changed, 20) << "the strokes hardly overlap: the test would not see an order effect";
}

}  // namespace
}  // namespace deepcanvas
