// Painter::paste() and the cell paste's encoded form: against a brute-force reference over every
// finest cell of a small canvas (pasted cells hold their value, every other cell what it held),
// exact undo through revert(), the encoded form's round trip and its refusals, and capacity.
#include <gtest/gtest.h>

#include <random>

#include "deepcanvas/server_core/cell_paste.hpp"
#include "test_support.hpp"

namespace deepcanvas {
namespace {

using painting_test::Canvas;
using painting_test::channel_diff;
using painting_test::finest_cells;
using painting_test::small_canvas;
using server_core::CellCoord;
using server_core::CellPaste;
using server_core::PastedCell;

// Random disjoint cells: each at a random depth, inside the middle of the canvas, none inside
// another (a candidate meeting an earlier one is skipped).
CellPaste random_paste(std::mt19937& rng, const server_core::OctreeConfig& oc, int count) {
  CellPaste p;
  std::vector<CellCoord> taken;
  auto inside = [](CellCoord a, const CellCoord& b) {  // a inside or equal to b
    while (a.depth > b.depth) a = server_core::parent_coord(a);
    return a == b;
  };
  for (int tries = 0; static_cast<int>(p.cells.size()) < count && tries < 50 * count; ++tries) {
    CellCoord k;
    k.depth = 1 + static_cast<int>(rng() % static_cast<std::uint32_t>(oc.max_depth));
    const std::uint32_t n = oc.roots_per_axis << k.depth;
    k.x = n / 4 + rng() % (n / 2);
    k.y = n / 4 + rng() % (n / 2);
    k.z = n / 4 + rng() % (n / 2);
    bool free = true;
    for (const auto& t : taken) free = free && !inside(k, t) && !inside(t, k);
    if (!free) continue;
    taken.push_back(k);
    const std::uint32_t a = rng() % 4 == 0 ? 0u : static_cast<std::uint32_t>(1 + rng() % 255);  // some erase
    p.cells.push_back({k, static_cast<std::uint32_t>((a << 24) | (rng() & 0xFFFFFF))});
  }
  return p;
}

TEST(Paste, PastedCellsHoldTheirValueEverythingElseIsKeptAndUndoIsExact) {
  std::mt19937 rng(11);
  const auto oc = small_canvas();
  const int D = oc.max_depth;
  const std::uint32_t n = oc.roots_per_axis << D;
  for (int trial = 0; trial < 24; ++trial) {
    Canvas c({}, oc);
    for (int s = 0; s < 6; ++s) ASSERT_TRUE(c.painter->apply_stroke(painting_test::random_stroke(rng, true)));
    const auto before = finest_cells(*c.tree);
    const std::uint64_t hash_before = c.tree->canvas_hash();
    CellPaste paste = random_paste(rng, oc, 1 + trial % 12);
    ASSERT_TRUE(server_core::normalise_cell_paste(paste, oc));
    server_core::PasteStats st;
    auto diff = c.painter->paste(paste, &st);
    ASSERT_TRUE(diff) << diff.error().message;
    ASSERT_TRUE(c.tree->check_invariants()) << "trial " << trial;
    EXPECT_EQ(st.cells, paste.size());
    // The reference: every finest cell inside a pasted cell holds its value refined down.
    std::vector<std::int64_t> expected(before.begin(), before.end());
    for (const PastedCell& pc : paste.cells) {
      std::uint32_t v = pc.rgba;
      for (int d = pc.cell.depth; d < D; ++d) v = protocol::density::refine_rgba(v);
      const int s = D - pc.cell.depth;
      const std::uint32_t e = 1u << s;
      for (std::uint32_t z = 0; z < e; ++z)
        for (std::uint32_t y = 0; y < e; ++y)
          for (std::uint32_t x = 0; x < e; ++x)
            expected[((pc.cell.z << s) + z) * std::size_t{n} * n +
                     ((pc.cell.y << s) + y) * std::size_t{n} + (pc.cell.x << s) + x] = v;
    }
    const auto after = finest_cells(*c.tree);
    int worst = 0;
    for (std::size_t i = 0; i < after.size(); ++i)
      worst = std::max(worst, channel_diff(after[i], static_cast<std::uint32_t>(expected[i])));
    // Merging uniform siblings (and refining again) may move a value by a quantum.
    EXPECT_LE(worst, 1) << "trial " << trial;
    // Pasted cells that are leaves hold exactly their value.
    for (const PastedCell& pc : paste.cells) {
      const auto loc = c.tree->find(pc.cell);
      if (loc.coord == pc.cell && c.tree->is_leaf(loc.cell)) {
        EXPECT_EQ(c.tree->colour(loc.cell), pc.rgba);
      }
    }
    // Undo: exactly the canvas before; redo: exactly the canvas after.
    const std::uint64_t hash_after = c.tree->canvas_hash();
    auto undo = c.painter->revert(*diff);
    ASSERT_TRUE(undo);
    EXPECT_EQ(c.tree->canvas_hash(), hash_before) << "trial " << trial;
    ASSERT_TRUE(c.painter->revert(*undo));
    EXPECT_EQ(c.tree->canvas_hash(), hash_after) << "trial " << trial;
  }
}

TEST(Paste, EncodedFormRoundTripsAndBadBytesAreRefused) {
  std::mt19937 rng(5);
  const auto oc = small_canvas();
  CellPaste p = random_paste(rng, oc, 40);
  ASSERT_TRUE(server_core::normalise_cell_paste(p, oc));
  const auto bytes = server_core::encode_cell_paste(p);
  auto back = server_core::decode_cell_paste(bytes, oc);
  ASSERT_TRUE(back) << back.error().message;
  ASSERT_EQ(back->size(), p.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    EXPECT_EQ(back->cells[i].cell, p.cells[i].cell);
    EXPECT_EQ(back->cells[i].rgba, p.cells[i].rgba);
  }
  for (std::size_t cut = 0; cut < bytes.size(); cut += 3)
    EXPECT_FALSE(server_core::decode_cell_paste(std::span(bytes.data(), cut), oc)) << cut;
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    auto flipped = bytes;
    flipped[i] ^= 0x10;
    (void)server_core::decode_cell_paste(flipped, oc);  // never crashes; may decode
  }
  EXPECT_EQ(server_core::decode_cell_paste(bytes, oc, 10).error().code, Errc::limit_exceeded);
  // A cell inside another; a repeated cell; a cell outside the canvas; a depth past it.
  auto refused = [&](std::vector<PastedCell> cells) {
    CellPaste q{std::move(cells)};
    EXPECT_FALSE(server_core::normalise_cell_paste(q, oc));
    // Encoded in the given order, decode refuses it too.
    auto r = server_core::decode_cell_paste(server_core::encode_cell_paste(q), oc);
    EXPECT_FALSE(r);
    if (!r) {
      EXPECT_EQ(r.error().code, Errc::malformed);
    }
  };
  refused({{{2, 3, 3, 3}, 1}, {{4, 12, 12, 13}, 2}});
  refused({{{2, 3, 3, 3}, 1}, {{2, 3, 3, 3}, 2}});
  refused({{{1, 4, 0, 0}, 1}});
  refused({{{6, 0, 0, 0}, 1}});
}

TEST(Paste, PastTheCapacityNothingChanges) {
  auto oc = small_canvas();
  oc.max_cells = 600;
  Canvas c({}, oc);
  const std::uint64_t hash = c.tree->canvas_hash();
  CellPaste p;
  for (std::uint32_t i = 0; i < 30; ++i) p.cells.push_back({{5, 2 * i, 7, 9}, 0xFF0000FFu});
  ASSERT_TRUE(server_core::normalise_cell_paste(p, oc));
  auto r = c.painter->paste(p);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, Errc::out_of_memory);
  EXPECT_EQ(c.tree->canvas_hash(), hash);
}

}  // namespace
}  // namespace deepcanvas
