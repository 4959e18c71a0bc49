// Soak: every real painting, multi-step (small step cap, whole strokes at once) against the
// one-shot reference; every step within the cap.
#include <gtest/gtest.h>

#include <filesystem>

#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "test_support.hpp"

namespace deepcanvas {
namespace {

TEST(PainterSoak, AllPaintingsMultiStepEqualsOneShot) {
  DEEPCANVAS_PAINTINGS_OR_SKIP(dir);
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    if (e.path().extension() != ".apa") continue;
    ++n;
    auto painting = paintings::read_apa_file(e.path().string(), {});
    ASSERT_TRUE(painting) << painting.error().message;
    auto ta = server_core::Octree::create({});
    auto tb = server_core::Octree::create({});
    ASSERT_TRUE(ta && tb);
    server_core::PainterConfig pc;
    pc.max_cells_per_step = 1024;
    auto pa = server_core::Painter::create(**ta, pc);
    auto pb = server_core::Painter::create(**tb, {});
    ASSERT_TRUE(pa && pb);
    for (const auto& s : painting->strokes) {
      // apply_stroke gives the whole stroke at once: every step must still be bounded.
      auto st = (*pa)->apply_stroke(s);
      ASSERT_TRUE(st) << st.error().message;
      EXPECT_LE(st->max_step_work, pc.max_cells_per_step + server_core::kStepWorkSlack) << e.path();
      ASSERT_TRUE((*pb)->paint_one_shot(s));
    }
    ASSERT_TRUE((*ta)->check_invariants()) << e.path();
    EXPECT_LE(painting_test::max_canvas_diff(**ta, **tb), 1) << e.path();
    EXPECT_EQ((*ta)->canvas_hash(), (*tb)->canvas_hash()) << e.path();
  }
  EXPECT_EQ(n, 17);
}

}  // namespace
}  // namespace deepcanvas
