// Undo at the painter: Painter::revert() of recorded stroke diffs (painter.hpp, "undo"), against
// a brute-force reference (every finest cell of a small canvas) and against replays without the
// stroke on real paintings.
#include <gtest/gtest.h>

#include <map>
#include <random>
#include <unordered_set>

#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/cell_diff.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/server_core/undo_history.hpp"
#include "test_support.hpp"

namespace deepcanvas {
namespace {

using protocol::BrushMode;
using protocol::Stroke;
using server_core::CellCoord;
using server_core::CellCoordHash;
using server_core::CellDiff;
using server_core::Octree;
using server_core::OctreeConfig;
using server_core::PainterConfig;
using server_core::RevertStats;
using painting_test::Canvas;
using painting_test::channel_diff;
using painting_test::random_stroke;

PainterConfig recording() {
  PainterConfig pc;
  pc.record_diffs = true;
  pc.max_cells_per_step = 512;  // many steps: the diff must not depend on them
  return pc;
}

using painting_test::finest_cells;
using painting_test::small_canvas;

CellDiff take_diff(server_core::Painter& p, std::uint64_t id) {
  auto d = p.take_stroke_diff(id);
  EXPECT_TRUE(d.has_value()) << "no diff for stroke " << id;
  return d ? std::move(*d) : CellDiff{};
}

// Undoing the last stroke gives exactly the canvas before it, and redoing the undo exactly the
// canvas after it, in every brush mode.
TEST(Undo, LastStrokeComesBackExactlyAndRedoRestoresIt) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 24; ++trial) {
    Canvas c(recording());
    for (int i = 0; i < 6; ++i) ASSERT_TRUE(c.painter->apply_stroke(random_stroke(rng, true)));
    for (int i = 1; i <= 6; ++i) (void)c.painter->take_stroke_diff(static_cast<std::uint64_t>(i));
    const std::uint64_t before = c.tree->canvas_hash();
    Stroke s = random_stroke(rng, false);
    s.brush.mode = static_cast<BrushMode>(trial % 4);
    s.id = 100;
    ASSERT_TRUE(c.painter->apply_stroke(s));
    const std::uint64_t after = c.tree->canvas_hash();
    const CellDiff d = take_diff(*c.painter, 100);
    RevertStats st;
    auto undo = c.painter->revert(d, &st);
    ASSERT_TRUE(undo) << undo.error().message;
    EXPECT_EQ(c.tree->canvas_hash(), before) << "trial " << trial;
    EXPECT_EQ(st.kept, 0u);
    ASSERT_TRUE(c.tree->check_invariants()) << c.tree->check_invariants().error().message;
    auto redo = c.painter->revert(*undo);
    ASSERT_TRUE(redo) << redo.error().message;
    EXPECT_EQ(c.tree->canvas_hash(), after) << "trial " << trial;
    ASSERT_TRUE(c.tree->check_invariants());
    // And undo again after the redo: the redo's own diff takes it back.
    ASSERT_TRUE(c.painter->revert(*redo));
    EXPECT_EQ(c.tree->canvas_hash(), before) << "trial " << trial;
  }
}

// The reference, cell by cell at the finest level: where the canvas still holds what stroke S
// left, the cell gets what it had before S; elsewhere it keeps what it holds. Allowed slack: one
// quantum per channel where a restored region merged back (density-model coarsening).
TEST(Undo, MatchesTheFinestCellReferenceOnRandomStrokesOfSeveralArtists) {
  std::mt19937 rng(11);
  std::uint64_t restored = 0, kept = 0, mismatches = 0, cells = 0;
  for (int trial = 0; trial < 48; ++trial) {
    Canvas c(recording(), small_canvas());
    const int n = 10;
    const int undone = static_cast<int>(rng() % (n - 2));
    std::vector<std::uint32_t> before_s, after_s;
    CellDiff ds;
    for (int i = 0; i < n; ++i) {
      Stroke s = random_stroke(rng, true);
      for (auto& p : s.samples) p.x *= 0.1, p.y *= 0.1, p.z *= 0.1;  // crowded: overlaps
      s.id = static_cast<std::uint64_t>(i + 1);
      if (i == undone) before_s = finest_cells(*c.tree);
      ASSERT_TRUE(c.painter->apply_stroke(s));
      CellDiff d = take_diff(*c.painter, s.id);
      if (i == undone) {
        after_s = finest_cells(*c.tree);
        ds = std::move(d);
      }
    }
    const auto now = finest_cells(*c.tree);
    const std::uint64_t now_hash = c.tree->canvas_hash();
    RevertStats st;
    auto undo = c.painter->revert(ds, &st);
    ASSERT_TRUE(undo) << undo.error().message;
    ASSERT_TRUE(c.tree->check_invariants()) << c.tree->check_invariants().error().message;
    restored += st.restored;
    kept += st.kept;
    const auto got = finest_cells(*c.tree);
    for (std::size_t v = 0; v < got.size(); ++v) {
      const std::uint32_t want = now[v] == after_s[v] ? before_s[v] : now[v];
      if (channel_diff(got[v], want) > 1) ++mismatches;
      ++cells;
    }
    // Redo right away gives back the canvas as it was before the undo, exactly.
    auto redo = c.painter->revert(*undo);
    ASSERT_TRUE(redo) << redo.error().message;
    EXPECT_EQ(c.tree->canvas_hash(), now_hash) << "trial " << trial;
  }
  EXPECT_GT(restored, 0u);
  EXPECT_GT(kept, 0u) << restored << " restored; no stroke was painted over: the reference's other branch is untested";
  EXPECT_EQ(mismatches, 0u) << "of " << cells << " finest cells";
}

// A stroke still open keeps the cells it touched: an undo under it changes none of them and
// the tree stays valid; the open stroke then ends normally.
TEST(Undo, CellsOfAnOpenStrokeAreKept) {
  Canvas c(recording(), small_canvas());
  const float red[4] = {1, 0, 0, 1}, blue[4] = {0, 0, 1, 1};
  Stroke a;
  a.brush.mode = BrushMode::paint;
  std::copy(red, red + 4, a.brush.colour);
  for (int i = 0; i < 6; ++i) a.samples.push_back({-0.3 + 0.1 * i, 0, 0, 0.12f, 1.0f, 0});
  a.id = 1;
  ASSERT_TRUE(c.painter->apply_stroke(a));
  const CellDiff da = take_diff(*c.painter, 1);
  Stroke b = a;
  std::copy(blue, blue + 4, b.brush.colour);
  ASSERT_TRUE(c.painter->begin_stroke(b.brush, 2, b.samples));
  while (*c.painter->step()) {
  }
  ASSERT_TRUE(c.painter->stroke_open(2));
  const std::uint64_t h = c.tree->canvas_hash();
  RevertStats st;
  auto undo = c.painter->revert(da, &st);
  ASSERT_TRUE(undo) << undo.error().message;
  EXPECT_GT(st.kept, 0u);
  ASSERT_TRUE(c.tree->check_invariants());
  ASSERT_TRUE(c.painter->end_stroke(2));
  while (*c.painter->step()) {
  }
  ASSERT_TRUE(c.tree->check_invariants());
  (void)h;
}

TEST(Undo, RevertIsRefusedWhileAStrokeIsBusy) {
  Canvas c(recording(), small_canvas());
  std::mt19937 rng(3);
  Stroke s = random_stroke(rng, false);
  ASSERT_TRUE(c.painter->begin_stroke(s.brush, 1, s.samples));
  auto r = c.painter->revert(CellDiff{});
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, Errc::refused);
}

// The encoded form round-trips, and damaged bytes are refused with malformed, never a crash.
TEST(Undo, DiffEncodingRoundTripsAndRefusesDamage) {
  Canvas c(recording());
  std::mt19937 rng(5);
  Stroke s = random_stroke(rng, false);
  s.id = 1;
  ASSERT_TRUE(c.painter->apply_stroke(s));
  CellDiff d = take_diff(*c.painter, 1);
  ASSERT_GT(d.size(), 0u);
  const auto bytes = server_core::encode_cell_diff(d);
  // The encoded form lists each depth's cells in address order.
  std::stable_sort(d.changes.begin(), d.changes.end(), [](const auto& a, const auto& b) {
    return server_core::cell_order(a.cell, b.cell);
  });
  auto back = server_core::decode_cell_diff(bytes, c.tree->config());
  ASSERT_TRUE(back) << back.error().message;
  ASSERT_EQ(back->size(), d.size());
  for (std::size_t i = 0; i < d.size(); ++i) {
    EXPECT_EQ(back->changes[i].cell, d.changes[i].cell);
    EXPECT_EQ(back->changes[i].before, d.changes[i].before);
    EXPECT_EQ(back->changes[i].after, d.changes[i].after);
  }
  for (std::size_t cut : {std::size_t{0}, std::size_t{5}, bytes.size() / 2, bytes.size() - 1}) {
    auto r = server_core::decode_cell_diff(std::span(bytes).first(cut), c.tree->config());
    ASSERT_FALSE(r) << "cut at " << cut;
    EXPECT_EQ(r.error().code, Errc::malformed);
  }
  for (int i = 0; i < 200; ++i) {
    auto damaged = bytes;
    damaged[rng() % damaged.size()] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
    (void)server_core::decode_cell_diff(damaged, c.tree->config());  // must not crash
  }
  OctreeConfig tiny = c.tree->config();
  tiny.max_depth = 2;
  auto shallow = server_core::decode_cell_diff(bytes, tiny);
  EXPECT_FALSE(shallow);  // cells deeper than that canvas has
}

// Memory stays bounded: past its record limit a recorder keeps nothing and says too_large, and
// the history keeps such a stroke as a marker that refuses its undo.
TEST(Undo, ARecorderPastItsLimitSaysTooLargeAndTheHistoryRefusesIt) {
  std::vector<std::uint32_t> slots(64, 0);
  server_core::CellDiffRecorder rec(slots.data(), 4);
  rec.refine(1, {1, 0, 0, 0}, 0xFF0000FFu, 0xFF0000FFu, 8);  // 9 records
  const CellDiff d = rec.take();
  EXPECT_TRUE(d.too_large);
  EXPECT_TRUE(d.empty());
  rec.colour(2, {1, 1, 0, 0}, true, 1, 2);  // recording again after take()
  EXPECT_FALSE(rec.take().too_large);
  server_core::UndoHistory h;
  h.stroke_done(5, 1, {1, 2, 3});
  h.stroke_too_large(5, 2);
  auto next = h.next(5, false);
  ASSERT_FALSE(next);
  EXPECT_EQ(next.error().code, Errc::limit_exceeded);
}

// The open strokes' recordings share one budget (CellDiffBudget), against a model of its rule
// (arrays doubling from 256 records of 36 bytes; a growth past the budget drops the largest
// holder, the growing recorder itself when it holds at least as much as any other), over
// random records into several recorders sharing one slot array, as a painter's do (a slot
// another recorder overwrote makes a second record of the cell, which take() merges; the model
// keeps the same slots): the budget never holds more
// than its maximum and counts what its recorders hold, the recorders dropped are the model's,
// every recorder kept gives the same diff as a twin recording without a budget, and a recorder
// gone gives its bytes back.
TEST(Undo, RecordersSharingABudgetStayWithinItAndDropTheLargest) {
  using server_core::CellDiffRecorder;
  constexpr std::uint64_t kRecordBytes = 36;
  constexpr std::uint32_t kCells = 1u << 14;
  int dropped = 0, others_dropped = 0, kept = 0;
  for (std::uint32_t seed = 1; seed <= 40; ++seed) {
    std::mt19937 rng(seed);
    const std::size_t n = 2 + rng() % 4;
    const std::uint64_t max_bytes = (256 + rng() % 6000) * kRecordBytes;
    server_core::CellDiffBudget budget(max_bytes);
    std::vector<std::uint32_t> slots(kCells, ~0u), twin_slots(kCells, ~0u);
    std::vector<std::unique_ptr<CellDiffRecorder>> recs, twins;
    struct Model {
      std::uint64_t cap = 0;
      bool dropped = false;
      std::vector<std::uint32_t> cells;  // each record's cell
    };
    std::vector<Model> model(n);
    std::vector<std::uint32_t> model_slots(kCells, ~0u);
    std::uint64_t model_bytes = 0;
    for (std::size_t i = 0; i < n; ++i) {
      recs.push_back(std::make_unique<CellDiffRecorder>(
          slots.data(), CellDiffRecorder::kDefaultMaxRecords, &budget));
      twins.push_back(std::make_unique<CellDiffRecorder>(twin_slots.data()));
    }
    for (int op = 0; op < 6000; ++op) {
      const std::size_t i = std::min(rng() % n, rng() % n);  // the first recorders grow most
      const std::uint32_t c = rng() % kCells;
      const server_core::CellCoord k{16, c, static_cast<std::uint32_t>(i), 0};
      const std::uint32_t old_rgba = c, new_rgba = c + 1 + static_cast<std::uint32_t>(op);
      recs[i]->colour(c, k, true, old_rgba, new_rgba);
      twins[i]->colour(c, k, true, old_rgba, new_rgba);
      Model& m = model[i];
      const std::uint32_t slot = model_slots[c];
      const bool recorded = slot < m.cells.size() && m.cells[slot] == c;
      if (!m.dropped && !recorded) {
        if (m.cells.size() == m.cap) {
          const std::uint64_t grown = std::max<std::uint64_t>(256, 2 * m.cap);
          const std::uint64_t need = (grown - m.cap) * kRecordBytes;
          while (model_bytes + need > max_bytes && !m.dropped) {
            std::size_t most = i;
            for (std::size_t j = 0; j < n; ++j)
              if (model[j].cap > model[most].cap) most = j;
            model_bytes -= model[most].cap * kRecordBytes;
            model[most].cap = 0;
            model[most].dropped = true;
            ++dropped;
            others_dropped += most != i;
          }
          if (!m.dropped) {
            model_bytes += need;
            m.cap = grown;
          }
        }
        if (!m.dropped) {
          model_slots[c] = static_cast<std::uint32_t>(m.cells.size());
          m.cells.push_back(c);
        }
      }
      ASSERT_EQ(budget.bytes(), model_bytes) << "seed " << seed << " op " << op;
      ASSERT_LE(budget.bytes(), max_bytes);
      for (std::size_t j = 0; j < n; ++j)
        ASSERT_EQ(recs[j]->dropped(), model[j].dropped) << "seed " << seed << " op " << op;
    }
    EXPECT_LE(budget.peak_bytes(), max_bytes);
    for (std::size_t i = 0; i < n; ++i) {
      const CellDiff got = recs[i]->take();
      const CellDiff want = twins[i]->take();
      EXPECT_EQ(got.too_large, model[i].dropped);
      if (model[i].dropped) continue;
      ++kept;
      ASSERT_EQ(got.size(), want.size());
      for (std::size_t j = 0; j < got.size(); ++j) {
        EXPECT_TRUE(got.changes[j].cell == want.changes[j].cell);
        EXPECT_TRUE(got.changes[j].before == want.changes[j].before);
        EXPECT_TRUE(got.changes[j].after == want.changes[j].after);
      }
    }
    recs.clear();
    EXPECT_EQ(budget.bytes(), 0u);
  }
  EXPECT_GT(dropped, 20);
  EXPECT_GT(others_dropped, 5) << "a growing recorder never made room by dropping a larger one";
  EXPECT_GT(kept, 40);
}

// Through the painter (PainterConfig::max_recording_bytes): a wide stroke and a thin one taking
// turns under a budget that holds the thin one's recording but not both: the wide one is
// dropped (its diff says too_large), the thin one's diff is exactly what it is without a
// budget, and the outcome does not depend on the step sizes.
TEST(Undo, OpenStrokesRecordingsStayWithinTheirBudget) {
  const auto make = [](float radius, double y, int n) {
    Stroke s;
    s.brush.mode = BrushMode::paint;
    s.brush.colour[0] = 0.8f, s.brush.colour[3] = 1.0f;
    for (int i = 0; i < n; ++i)
      s.samples.push_back({-0.3 + 0.6 * i / (n - 1), y, 0, radius, 1.0f, 0});
    return s;
  };
  const std::vector<Stroke> strokes{make(0.08f, 0, 24), make(0.01f, 0.2, 24)};
  // Paints strokes `ids` (of 1, 2) taking turns of 4 samples; full steps, or random ones.
  const auto run = [&](std::vector<std::uint64_t> ids, std::uint64_t max_bytes, std::mt19937* rng,
                       std::uint64_t* peak) {
    PainterConfig pc = recording();
    pc.max_cells_per_step = 1u << 20;
    pc.max_recording_bytes = max_bytes;
    Canvas c(pc, small_canvas());
    server_core::Painter& p = *c.painter;
    const auto finish = [&] {
      for (bool first = true;; first = false) {
        auto more = rng != nullptr ? p.step(first ? 64 : 8 + (*rng)() % 512) : p.step();
        EXPECT_TRUE(more);
        if (!more || !*more) break;
      }
    };
    for (std::size_t i = 0; i < 24; i += 4)
      for (std::uint64_t id : ids) {
        const auto piece = std::span(strokes[id - 1].samples).subspan(i, 4);
        EXPECT_TRUE(i == 0 ? p.begin_stroke(strokes[id - 1].brush, id, piece)
                           : p.add_samples(id, piece));
        finish();
      }
    for (std::uint64_t id : ids) {
      EXPECT_TRUE(p.end_stroke(id));
      finish();
    }
    *peak = p.recording_budget().peak_bytes();
    std::vector<CellDiff> out;
    for (std::uint64_t id : ids) out.push_back(take_diff(p, id));
    return out;
  };
  constexpr std::uint64_t kFree = std::uint64_t{1} << 40;
  std::uint64_t wide_alone = 0, thin_alone = 0, both = 0;
  (void)run({1}, kFree, nullptr, &wide_alone);
  (void)run({2}, kFree, nullptr, &thin_alone);
  const auto free = run({1, 2}, kFree, nullptr, &both);
  ASSERT_FALSE(free[0].too_large);
  ASSERT_FALSE(free[1].too_large);
  ASSERT_GE(wide_alone, 4 * thin_alone) << "the strokes are not different enough";
  // Room for the thin stroke's arrays twice over, not for the wide one's: once the wide one
  // holds as much as the thin one, its next doubling does not fit, and it holds the most.
  const std::uint64_t budget = thin_alone * 5 / 2;
  std::mt19937 rng(5);
  for (std::mt19937* steps : {static_cast<std::mt19937*>(nullptr), &rng}) {
    std::uint64_t peak = 0;
    const auto got = run({1, 2}, budget, steps, &peak);
    EXPECT_TRUE(got[0].too_large);
    ASSERT_FALSE(got[1].too_large);
    EXPECT_LE(peak, budget);
    EXPECT_EQ(server_core::encode_cell_diff(got[1]), server_core::encode_cell_diff(free[1]));
  }
}

// The canvas-wide byte budget (UndoLimits::max_bytes), against a reference history without
// one, over random strokes, undos and redos of several artists: the history never holds more
// than the budget, counts exactly what it holds, and what it dropped is always what entered it
// first (every dropped entry, undo or redo side, came before every kept one); an artist whose
// undo entries were dropped is told limit_exceeded.
TEST(Undo, TheHistoryKeepsItsByteBudgetByDroppingWhatCameFirst) {
  struct Ref {
    std::uint64_t id;
    std::size_t size;
    std::uint64_t came;  // the order of the entries' arrival on their side
  };
  for (std::uint32_t seed = 1; seed <= 30; ++seed) {
    std::mt19937 rng(seed);
    server_core::UndoLimits lim;
    lim.depth = 1000;
    lim.max_stroke_bytes = 400;
    lim.max_bytes = 1000 + rng() % 2000;
    server_core::UndoHistory h(lim);
    std::map<std::uint64_t, std::pair<std::vector<Ref>, std::vector<Ref>>> ref;  // undo, redo
    std::uint64_t next_id = 1, came = 0;
    const auto bytes_of = [](std::size_t n) { return std::vector<std::uint8_t>(n, 7); };
    for (int op = 0; op < 400; ++op) {
      const std::uint64_t artist = 1 + rng() % 4;
      auto& [undo, redo] = ref[artist];
      const int kind = static_cast<int>(rng() % 10);
      if (kind < 5) {
        const std::size_t n = 1 + rng() % 400;
        h.stroke_done(artist, next_id, bytes_of(n));
        undo.push_back({next_id++, n, came++});
        redo.clear();
      } else {
        const bool is_redo = kind >= 8;
        auto& from = is_redo ? redo : undo;
        auto& to = is_redo ? undo : redo;
        auto r = h.next(artist, is_redo);
        if (!r) {
          if (is_redo) {
            EXPECT_EQ(r.error().code, Errc::not_found);
          } else if (!from.empty()) {
            EXPECT_EQ(r.error().code, Errc::limit_exceeded) << "its strokes were dropped";
          }
          continue;
        }
        ASSERT_FALSE(from.empty()) << seed;
        ASSERT_EQ((*r)->stroke_id, from.back().id) << "the newest entry is the one taken";
        const std::size_t n = 1 + rng() % 400;
        const std::uint64_t id = from.back().id;
        h.moved(artist, id, is_redo, bytes_of(n));
        from.pop_back();
        to.push_back({id, n, came++});
      }
      // What the history holds, by the reference's entries it still finds.
      std::uint64_t held = 0, last_dropped = 0, first_kept = ~std::uint64_t{0};
      bool dropped_any = false;
      for (const auto& [a, sides] : ref)
        for (const bool redo_side : {false, true})
          for (const Ref& e : redo_side ? sides.second : sides.first) {
            if (h.find(e.id, redo_side)) {
              held += e.size;
              first_kept = std::min(first_kept, e.came);
            } else {
              dropped_any = true;
              last_dropped = std::max(last_dropped, e.came);
            }
          }
      ASSERT_LE(h.bytes(), lim.max_bytes) << seed;
      ASSERT_EQ(h.bytes(), held) << "seed " << seed << " op " << op;
      if (dropped_any) {
        ASSERT_LT(last_dropped, first_kept) << "seed " << seed << ": a later entry was dropped";
      }
    }
  }
  // A server restarted with a smaller budget drops the oldest at once.
  server_core::UndoHistory h;
  for (std::uint64_t id = 1; id <= 10; ++id)
    h.stroke_done(1 + id % 2, id, std::vector<std::uint8_t>(100, 1));
  auto loaded = server_core::UndoHistory::load(h.save());
  ASSERT_TRUE(loaded);
  EXPECT_EQ(loaded->bytes(), 1000u);
  server_core::UndoLimits smaller;
  smaller.max_bytes = 450;
  smaller.max_stroke_bytes = 100;
  loaded->set_limits(smaller);
  EXPECT_EQ(loaded->bytes(), 400u);
  for (std::uint64_t id = 1; id <= 10; ++id) EXPECT_EQ(loaded->find(id, false).has_value(), id > 6);
  auto newest = loaded->next(2, false);
  ASSERT_TRUE(newest);  // artist 2 (odd ids) keeps strokes 7 and 9
  EXPECT_EQ((*newest)->stroke_id, 9u);
}

// ---- real paintings ----

std::unordered_set<CellCoord, CellCoordHash> cells_of(const CellDiff& d) {
  std::unordered_set<CellCoord, CellCoordHash> s;
  for (const auto& c : d.changes) s.insert(c.cell);
  return s;
}
// The cells and all their ancestors.
std::unordered_set<CellCoord, CellCoordHash> footprint(const CellDiff& d) {
  std::unordered_set<CellCoord, CellCoordHash> s;
  for (const auto& c : d.changes)
    for (CellCoord k = c.cell;; k = server_core::parent_coord(k)) {
      if (!s.insert(k).second || k.depth == 0) break;
    }
  return s;
}
bool meets(const std::unordered_set<CellCoord, CellCoordHash>& a,
           const std::unordered_set<CellCoord, CellCoordHash>& b) {
  for (const auto& k : a)
    if (b.count(k)) return true;
  return false;
}

std::uint64_t replay_hash(const std::vector<Stroke>& strokes, std::size_t skip) {
  Canvas c;
  for (std::size_t i = 0; i < strokes.size(); ++i)
    if (i != skip) {
      EXPECT_TRUE(c.painter->apply_stroke(strokes[i]));
    }
  return c.tree->canvas_hash();
}

// On real paintings: undoing the last stroke, and strokes deep in the history that no later
// stroke painted over, gives exactly the canvas_hash of a replay without that stroke; an
// erase, recolor and smudge stroke across the painting too; redo gives back the canvas.
TEST(Undo, RealPaintingsUndoEqualsReplayWithoutTheStroke) {
  DEEPCANVAS_PAINTINGS_OR_SKIP(dir);
  int deep_checked = 0;
  for (const char* name : {"demo.apa", "mozfest.apa", "mozilla.apa", "palmtree.apa"}) {
    auto painting = paintings::read_apa_file(dir + "/" + name, {});
    ASSERT_TRUE(painting) << painting.error().message;
    std::vector<Stroke> strokes = painting->strokes;
    for (std::size_t i = 0; i < strokes.size(); ++i) strokes[i].id = i + 1;
    Canvas c(recording());
    std::vector<CellDiff> diffs;
    for (const Stroke& s : strokes) {
      ASSERT_TRUE(c.painter->apply_stroke(s));
      diffs.push_back(take_diff(*c.painter, s.id));
    }
    const std::uint64_t full = c.tree->canvas_hash();
    // Deep strokes: those whose cells no later stroke changed (nor an ancestor of them).
    std::vector<std::size_t> deep;
    for (std::size_t i = strokes.size() / 4; i + 1 < strokes.size() && deep.size() < 2; i += 7) {
      const auto own = cells_of(diffs[i]), own_fp = footprint(diffs[i]);
      bool alone = !diffs[i].empty();
      for (std::size_t j = i + 1; j < strokes.size() && alone; ++j)
        alone = !meets(own, footprint(diffs[j])) && !meets(cells_of(diffs[j]), own_fp);
      if (alone) deep.push_back(i);
    }
    deep.push_back(strokes.size() - 1);  // the last stroke
    for (std::size_t i : deep) {
      Canvas u(recording());
      for (const Stroke& s : strokes) ASSERT_TRUE(u.painter->apply_stroke(s));
      ASSERT_EQ(u.tree->canvas_hash(), full);
      RevertStats st;
      auto undo = u.painter->revert(diffs[i], &st);
      ASSERT_TRUE(undo) << undo.error().message;
      EXPECT_EQ(u.tree->canvas_hash(), replay_hash(strokes, i))
          << name << " stroke " << i + 1 << " of " << strokes.size();
      EXPECT_EQ(st.kept, 0u) << name << " stroke " << i + 1;
      ASSERT_TRUE(u.painter->revert(*undo));
      EXPECT_EQ(u.tree->canvas_hash(), full) << name << " redo of stroke " << i + 1;
      if (i + 1 < strokes.size()) ++deep_checked;
    }
    // Every other mode, once across the painting: undone exactly.
    for (BrushMode mode : {BrushMode::erase, BrushMode::recolor, BrushMode::smudge}) {
      Stroke s = strokes[strokes.size() / 2];
      s.brush.mode = mode;
      s.brush.colour[0] = 0.1f;
      s.brush.colour[1] = 0.9f;
      s.brush.opacity = 0.7f;
      for (auto& p : s.samples) p.radius *= 3.0f;
      s.id = 100000 + static_cast<std::uint64_t>(mode);
      const std::uint64_t before = c.tree->canvas_hash();
      ASSERT_TRUE(c.painter->apply_stroke(s));
      EXPECT_NE(c.tree->canvas_hash(), before) << name << " mode " << static_cast<int>(mode);
      auto undo = c.painter->revert(take_diff(*c.painter, s.id));
      ASSERT_TRUE(undo) << undo.error().message;
      EXPECT_EQ(c.tree->canvas_hash(), before) << name << " mode " << static_cast<int>(mode);
      ASSERT_TRUE(c.tree->check_invariants());
    }
  }
  EXPECT_GT(deep_checked, 0) << "no stroke deep in a history was left alone by later strokes";
}

}  // namespace
}  // namespace deepcanvas
