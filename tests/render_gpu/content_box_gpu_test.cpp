// The streaming content box (StreamingReplica's "Content box", RenderLoop's "Content cull"),
// label gpu. Random strokes, erases among them, are painted by the server's Painter and streamed
// epoch by epoch through the upload thread under an adversarial schedule (random batching and
// delays, rows in random chunks) while the render loop renders culled frames in bands. For every
// band, against the CPU state of the epoch it claims:
//  * the box it was culled with contains painted_bounds of that epoch (the box never misses
//    paint) and lies inside the hull of painted_bounds over the epochs up to it (the box is not
//    simply huge: the property has teeth);
//  * its pixels equal a render of that epoch without the cull (a separate replica uploaded whole).
// Between frames the same is checked on the resident state directly. After the stream, once
// idle, the box shrinks to the exact painted_bounds. The negative control skips one batch's
// growth (UploadChaos::skip_content_growth_batch) and must be caught by both checks. Hand-made
// pools cover what the server never sends (a moved subtree, a state that is not a tree).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <thread>

#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "gpu_test_support.hpp"
#include "render_scenes.hpp"
#include "stream_test_support.hpp"

namespace deepcanvas::render_test {
namespace {

namespace cg = client_gpu;
using client_core::DAabb;

bool contains(const DAabb& outer, const DAabb& inner) {
  for (int a = 0; a < 3; ++a)
    if (inner.min[a] < outer.min[a] || inner.max[a] > outer.max[a]) return false;
  return true;
}

DAabb hull(const DAabb& a, const DAabb& b) {
  return {{std::min(a.min.x, b.min.x), std::min(a.min.y, b.min.y), std::min(a.min.z, b.min.z)},
          {std::max(a.max.x, b.max.x), std::max(a.max.y, b.max.y), std::max(a.max.z, b.max.z)}};
}

std::string str(const std::optional<DAabb>& b) {
  if (!b) return "none";
  char buf[200];
  std::snprintf(buf, sizeof buf, "[%.6g %.6g %.6g .. %.6g %.6g %.6g]", b->min.x, b->min.y, b->min.z,
                b->max.x, b->max.y, b->max.z);
  return buf;
}

// A stroke of `samples` samples from (x0, y0, z0) along +x.
protocol::Stroke make_stroke(bool erase, double x0, double y0, double z0, float radius,
                             int samples) {
  protocol::Stroke s;
  s.brush.mode = erase ? protocol::BrushMode::erase : protocol::BrushMode::paint;
  s.brush.colour[0] = 0.9f;
  s.brush.colour[1] = 0.3f;
  s.brush.colour[3] = 0.85f;
  for (int k = 0; k < samples; ++k) {
    protocol::StrokeSample smp;
    smp.x = x0 + 0.03 * k;
    smp.y = y0 + 0.01 * k;
    smp.z = z0;
    smp.radius = radius;
    s.samples.push_back(smp);
  }
  return s;
}

// The epochs of one scenario: uploads, the state of each epoch, its painted_bounds and the hull
// of painted_bounds up to it.
struct Scenario {
  std::vector<cg::EpochUpload> uploads;
  std::map<std::uint64_t, Snapshot> snaps;
  std::map<std::uint64_t, std::optional<DAabb>> exact, hull_upto;
  std::unique_ptr<Octree> tree;
};

void record(Scenario& sc, std::uint64_t epoch, bool all) {
  sc.uploads.push_back(capture_tree_epoch(*sc.tree, epoch, 10, all));
  sc.snaps[epoch] = snapshot_of(*sc.tree);
  auto b = client_core::painted_bounds(sc.snaps[epoch].view());
  ASSERT_TRUE(b.ok());
  sc.exact[epoch] = *b;
  std::optional<DAabb> h = epoch > 0 ? sc.hull_upto[epoch - 1] : std::nullopt;
  if (*b) h = h ? hull(*h, **b) : **b;
  sc.hull_upto[epoch] = h;
}

// Random strokes in [-1, 1]^3, a third of them erases placed on earlier paint (so that erasing
// at the edges shrinks the exact box), 1-3 strokes per epoch.
void random_strokes(Scenario& sc, std::uint64_t seed, int epochs) {
  auto created = Octree::create({});
  ASSERT_TRUE(created.ok());
  sc.tree = std::move(*created);
  auto painter = server_core::Painter::create(*sc.tree);
  ASSERT_TRUE(painter.ok());
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<std::array<double, 3>> painted_at;
  record(sc, 0, true);
  for (int e = 1; e <= epochs; ++e) {
    const int strokes = 1 + static_cast<int>(rng() % 3);
    for (int s = 0; s < strokes; ++s) {
      const bool erase = !painted_at.empty() && rng() % 3 == 0;
      std::array<double, 3> at{u(rng), u(rng), u(rng)};
      if (erase) {
        at = painted_at[rng() % painted_at.size()];
        at[0] -= 0.05;
      } else {
        painted_at.push_back(at);
      }
      const float radius = erase ? 0.12f : 0.02f + 0.03f * static_cast<float>(rng() % 3);
      ASSERT_TRUE(
          (*painter)->apply_stroke(make_stroke(erase, at[0], at[1], at[2], radius, 8)).ok());
    }
    record(sc, static_cast<std::uint64_t>(e), false);
  }
}

struct Outcome {
  std::size_t bands = 0, bad_boxes = 0, too_big_boxes = 0, bad_images = 0, loose_bands = 0;
  std::size_t resident_checks = 0, bad_resident = 0, epochs_seen = 0, culled_pixels_differ = 0;
  std::string first_bad;
  cg::StreamingStats stats;
  bool shrank_to_exact = false;
};

// Renders reference frames of an epoch's snapshot without the cull.
class Reference {
 public:
  Reference(cg::Context& ctx, const Octree& tree, const Camera& cam) : cam_(cam) {
    auto rep = cg::GpuReplica::create(ctx, config_of(tree, 10, 1u << 10));
    EXPECT_TRUE(rep.ok());
    rep_ = std::move(*rep);
    auto rc = cg::GpuRaycaster::create(*rep_);
    EXPECT_TRUE(rc.ok());
    rc_ = std::move(*rc);
  }
  const std::vector<std::uint32_t>& image(const Scenario& sc, std::uint64_t epoch,
                                          const cg::RenderLoopOptions& lo) {
    auto it = images_.find(epoch);
    if (it != images_.end()) return it->second;
    const PoolView v = sc.snaps.at(epoch).view();
    EXPECT_TRUE(rep_->upload_all(v).ok());
    EXPECT_TRUE(rep_->compute_all_links(v).ok());
    auto origin = client_core::make_ray_origin(v, cam_.position());
    EXPECT_TRUE(origin.ok());
    client_core::RenderOptions ro = lo.render;
    ro.content_bounds.reset();  // the uncull reference
    EXPECT_TRUE(rc_->set_frame(cam_, *origin, ro).ok());
    EXPECT_TRUE(rc_->render().ok());
    auto px = rc_->read_pixels();
    EXPECT_TRUE(px.ok());
    return images_[epoch] = std::move(*px);
  }

 private:
  Camera cam_;
  std::unique_ptr<cg::GpuReplica> rep_;
  std::unique_ptr<cg::GpuRaycaster> rc_;
  std::map<std::uint64_t, std::vector<std::uint32_t>> images_;
};

constexpr std::uint32_t kW = 64, kH = 36, kBands = 6;

// Checks one rendered frame's bands (box and pixels) against the scenario.
void check_frame(const Scenario& sc, const cg::FrameRecord& f, const std::vector<std::uint32_t>& px,
                 Reference& ref, const cg::RenderLoopOptions& lo, Outcome& out) {
  for (const auto& b : f.band_list) {
    ++out.bands;
    const auto& want = sc.exact.at(b.epoch);
    const std::string where = "band rows " + std::to_string(b.row0) + "+" + std::to_string(b.rows) +
                              " at epoch " + std::to_string(b.epoch);
    if (want && (!b.content_bounds || !contains(*b.content_bounds, *want))) {
      ++out.bad_boxes;
      if (out.first_bad.empty())
        out.first_bad =
            where + ": box " + str(b.content_bounds) + " misses painted_bounds " + str(want);
    }
    const auto& upper = sc.hull_upto.at(b.epoch);
    if (b.content_bounds && (!upper || !contains(*upper, *b.content_bounds))) ++out.too_big_boxes;
    if (b.content_bounds && want &&
        (b.content_bounds->min != want->min || b.content_bounds->max != want->max))
      ++out.loose_bands;
    const auto& img = ref.image(sc, b.epoch, lo);
    for (std::uint32_t y = b.row0; y < b.row0 + b.rows; ++y) {
      if (!std::equal(px.begin() + y * kW, px.begin() + (y + 1) * kW, img.begin() + y * kW)) {
        ++out.bad_images;
        if (out.first_bad.empty())
          out.first_bad = where + ": pixels differ from the uncull render of that epoch, row " +
                          std::to_string(y) + " (box " + str(b.content_bounds) + ")";
        break;
      }
    }
  }
}

// The resident state's box against painted_bounds of the mirror itself.
void check_resident(cg::StreamingReplica& sr, Outcome& out) {
  ASSERT_TRUE(sr.with_gpu([&](const cg::ResidentState& st) -> Result<void> {
                  if (!st.any) return {};
                  auto exact = client_core::painted_bounds(st.pools);
                  if (!exact) return std::move(exact).error();
                  ++out.resident_checks;
                  if (*exact && (!st.content_bounds || !contains(*st.content_bounds, **exact))) {
                    ++out.bad_resident;
                    if (out.first_bad.empty())
                      out.first_bad = "resident epoch " + std::to_string(st.epoch) + ": box " +
                                      str(st.content_bounds) + " misses painted_bounds " +
                                      str(*exact);
                  }
                  return {};
                }).ok());
}

// The whole scenario in view, from one side.
auto scenario_camera() {
  return Camera::frame_box({{-1.3, -1.3, -1.3}, {1.3, 1.3, 1.3}}, kW, kH, 45.0,
                           {-0.45, -0.35, -0.82}, {0, 1, 0});
}

// The loop both streaming tests render with: kBands fixed bands, checked one by one.
cg::RenderLoopOptions loop_options(const Camera& cam) {
  cg::RenderLoopOptions lo;
  lo.width = kW;
  lo.height = kH;
  lo.camera = cam;
  lo.fixed_bands = kBands;
  lo.render.background = {0.1, 0.2, 0.3};
  return lo;
}

// Streams the scenario with `chaos` while the loop renders culled frames; checks every band.
void run_stream(cg::Context& ctx, const Scenario& sc, const cg::UploadChaos& chaos, Outcome& out) {
  const std::uint64_t last = sc.uploads.back().epoch;
  auto streaming = cg::StreamingReplica::create(ctx, config_of(*sc.tree, 10, 1u << 10), {}, chaos);
  ASSERT_TRUE(streaming.ok()) << streaming.error().message;
  cg::StreamingReplica& sr = **streaming;
  auto cam = scenario_camera();
  ASSERT_TRUE(cam.ok());
  const cg::RenderLoopOptions lo = loop_options(*cam);
  ASSERT_TRUE(lo.content_cull);  // the default
  auto loop = cg::RenderLoop::create(sr, lo);
  ASSERT_TRUE(loop.ok()) << loop.error().message;
  Reference ref(ctx, *sc.tree, *cam);

  // The producer: random pauses, and two idle spells long enough for a shrink.
  std::vector<cg::EpochUpload> uploads = sc.uploads;
  std::thread producer([&] {
    std::mt19937_64 prng(chaos.seed + 1);
    for (std::size_t i = 0; i < uploads.size(); ++i) {
      const bool idle = i == uploads.size() / 3 || i == 2 * uploads.size() / 3;
      std::this_thread::sleep_for(idle ? std::chrono::milliseconds(900)
                                       : std::chrono::milliseconds(prng() % 15));
      sr.push(std::move(uploads[i]));
    }
  });
  std::set<std::uint64_t> seen;
  for (int i = 0; i < 2000; ++i) {
    auto f = (*loop)->render_frame(true);
    ASSERT_TRUE(f.ok()) << f.error().message;
    if (f->empty) {
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
      continue;
    }
    auto px = (*loop)->read_pixels();
    ASSERT_TRUE(px.ok());
    check_frame(sc, *f, *px, ref, lo, out);
    for (const auto& b : f->band_list) seen.insert(b.epoch);
    check_resident(sr, out);
    if (f->min_epoch == last) break;
  }
  producer.join();
  ASSERT_TRUE(sr.wait_resident(last, std::chrono::seconds(60)));
  ASSERT_TRUE(sr.status().ok()) << sr.status().error().message;
  out.epochs_seen = seen.size();
  // Idle now: the box shrinks to the exact one (the wait bounds a liveness property; no
  // timing is measured).
  const auto& final_exact = sc.exact.at(last);
  for (int i = 0; i < 300 && !out.shrank_to_exact; ++i) {
    ASSERT_TRUE(sr.with_gpu([&](const cg::ResidentState& st) -> Result<void> {
                    out.shrank_to_exact =
                        st.content_bounds.has_value() == final_exact.has_value() &&
                        (!final_exact || (st.content_bounds->min == final_exact->min &&
                                          st.content_bounds->max == final_exact->max));
                    return {};
                  }).ok());
    if (!out.shrank_to_exact) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  out.stats = sr.stats();
}

TEST(ContentBox, EveryBandsBoxHoldsItsEpochsPaintAndTheCullChangesNoPixel) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  std::size_t loose_total = 0;
  for (std::uint64_t seed : {3u, 41u, 2024u}) {
    Scenario sc;
    random_strokes(sc, seed, 36);
    // The scenario has teeth: erases shrink the exact box at some epochs.
    std::size_t shrinking = 0;
    for (const auto& [e, b] : sc.exact)
      if (e > 0 && b && sc.exact.at(e - 1) && !contains(*b, *sc.exact.at(e - 1))) ++shrinking;
    EXPECT_GT(shrinking, 0u) << "seed " << seed;
    cg::UploadChaos chaos;
    chaos.seed = seed;
    Outcome out;
    run_stream(*ctx, sc, chaos, out);
    EXPECT_EQ(out.bad_boxes, 0u) << "seed " << seed << ": " << out.first_bad;
    EXPECT_EQ(out.bad_resident, 0u) << "seed " << seed << ": " << out.first_bad;
    EXPECT_EQ(out.bad_images, 0u) << "seed " << seed << ": " << out.first_bad;
    EXPECT_EQ(out.too_big_boxes, 0u) << "seed " << seed;
    EXPECT_GT(out.bands, 60u) << "seed " << seed;
    EXPECT_GT(out.epochs_seen, 5u) << "seed " << seed;
    EXPECT_GT(out.resident_checks, 10u) << "seed " << seed;
    // The incremental path did the work (server states are trees: no fallback), and the box
    // was shrunk exactly at least once besides the first batch.
    EXPECT_EQ(out.stats.content_fallbacks, 0u) << "seed " << seed;
    EXPECT_GE(out.stats.content_exact, 2u) << "seed " << seed;
    EXPECT_TRUE(out.shrank_to_exact) << "seed " << seed;
    loose_total += out.loose_bands;
    std::printf(
        "seed %llu: %zu bands (%zu with a loose box), %zu resident checks, %zu epochs "
        "seen, %llu batches, %llu exact recomputes (longest %.2f ms)\n",
        static_cast<unsigned long long>(seed), out.bands, out.loose_bands, out.resident_checks,
        out.epochs_seen, static_cast<unsigned long long>(out.stats.batches),
        static_cast<unsigned long long>(out.stats.content_exact), out.stats.max_content_exact_ms);
  }
  // Erases left the box loose for a while somewhere (the loose path was exercised).
  EXPECT_GT(loose_total, 0u);
}

// The negative control: epochs one batch each (pushed after the previous one is resident), and
// the batch of the epoch that paints far outside everything else does not grow the box. Both
// the box check and the pixel check must catch it.
TEST(ContentBox, SkippingOneBatchsGrowthIsCaught) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  Scenario sc;
  auto created = Octree::create({});
  ASSERT_TRUE(created.ok());
  sc.tree = std::move(*created);
  auto painter = server_core::Painter::create(*sc.tree);
  ASSERT_TRUE(painter.ok());
  record(sc, 0, true);
  const double xs[] = {-0.6, 0.2, 1.0, -0.2};  // epoch 3 paints at x = 1.0, past the others
  for (int e = 1; e <= 4; ++e) {
    ASSERT_TRUE((*painter)->apply_stroke(make_stroke(false, xs[e - 1], 0.1, 0.0, 0.06f, 6)).ok());
    record(sc, static_cast<std::uint64_t>(e), false);
  }
  cg::UploadChaos chaos;
  chaos.skip_content_growth_batch = 4;  // batch 4 = epoch 3
  auto streaming = cg::StreamingReplica::create(*ctx, config_of(*sc.tree, 10, 1u << 10), {}, chaos);
  ASSERT_TRUE(streaming.ok());
  auto cam = scenario_camera();
  ASSERT_TRUE(cam.ok());
  const cg::RenderLoopOptions lo = loop_options(*cam);
  auto loop = cg::RenderLoop::create(**streaming, lo);
  ASSERT_TRUE(loop.ok());
  Reference ref(*ctx, *sc.tree, *cam);
  Outcome out;
  for (auto& u : sc.uploads) {
    const std::uint64_t e = u.epoch;
    (*streaming)->push(std::move(u));
    ASSERT_TRUE((*streaming)->wait_resident(e, std::chrono::seconds(60)));
    auto f = (*loop)->render_frame(true);
    ASSERT_TRUE(f.ok());
    auto px = (*loop)->read_pixels();
    ASSERT_TRUE(px.ok());
    check_frame(sc, *f, *px, ref, lo, out);
    check_resident(**streaming, out);
  }
  EXPECT_GT(out.bad_boxes, 0u);
  EXPECT_GT(out.bad_resident, 0u);
  EXPECT_GT(out.bad_images, 0u);
  std::printf(
      "skipped growth: %zu of %zu bands with a box missing paint, %zu with wrong pixels "
      "(first: %s)\n",
      out.bad_boxes, out.bands, out.bad_images, out.first_bad.c_str());
}

// Pools the server never produces, uploaded by hand: (1) a painted subtree moved to a cell far
// away by re-pointing one first_child (its cells keep their values, only the two parents and
// the group's parent change): the walk from the new parent must grow the box, without a
// fallback; (2) then a live group whose parent does not point to it, holding a leaf painted in
// the same epoch: not a tree, so that batch falls back to the exact box. Both times the
// resident box must contain painted_bounds of the resident pools.
TEST(ContentBox, MovedSubtreesAreWalkedAndNonTreesFallBackToTheExactBox) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto created = Octree::create({});
  ASSERT_TRUE(created.ok());
  Octree& tree = **created;
  auto painter = server_core::Painter::create(tree);
  ASSERT_TRUE(painter.ok());
  ASSERT_TRUE((*painter)->apply_stroke(make_stroke(false, -0.55, 0.0, 0.0, 0.05f, 4)).ok());
  constexpr int kDepth = 14;  // cells of ~0.3 m
  refine_around(tree, {{0.7, 0.0, 0.0}}, kDepth);
  auto y = tree.locate({-0.5, 0.0, 0.0}, kDepth);
  auto x = tree.locate({0.7, 0.0, 0.0}, kDepth);
  ASSERT_TRUE(y.ok() && x.ok());
  ASSERT_EQ(y->coord.depth, kDepth);
  ASSERT_EQ(x->coord.depth, kDepth);
  ASSERT_FALSE(tree.is_leaf(y->cell));  // the painted subtree
  ASSERT_TRUE(tree.is_leaf(x->cell));
  ASSERT_EQ(tree.colour(x->cell) >> 24, 0u);
  const cg::EpochUpload e0 = capture_tree_epoch(tree, 0, 10, true);
  const Snapshot s0 = snapshot_of(tree);

  // (1) The subtree under Y moves under X.
  Snapshot s1 = s0;
  const std::uint32_t g = s0.fc[y->cell] / 8;
  s1.fc[x->cell] = s0.fc[y->cell];
  s1.fc[y->cell] = PoolView::kNoCell;
  s1.col[y->cell] = 0;
  s1.par[g] = x->cell;
  const std::vector<cg::ChangedRange> moved{{x->cell, 1}, {y->cell, 1}, {std::uint64_t{g} * 8, 8}};
  const cg::EpochUpload e1 = cg::capture_epoch(s1.view(), 1, 10, moved, {});
  auto exact1 = client_core::painted_bounds(s1.view());
  ASSERT_TRUE(exact1.ok() && exact1->has_value());
  ASSERT_GT((*exact1)->max.x, 0.6);  // the paint is now near x = 0.7

  // (2) A leaf of a live group is painted and the group's parent is made wrong.
  Snapshot s2 = s1;
  std::uint32_t leaf = PoolView::kNoCell;
  for (std::uint32_t c = 64; c < s2.fc.size() && leaf == PoolView::kNoCell; ++c)
    if (s2.fc[c] == PoolView::kNoCell && !(s2.dep[c / 8] & PoolView::kFreeFlag) &&
        s2.fc[0] != c / 8 * 8)
      leaf = c;
  ASSERT_NE(leaf, PoolView::kNoCell);
  s2.col[leaf] = 0xC0204080u;
  s2.par[leaf / 8] = 0;  // root 0 does not point to this group
  const std::vector<cg::ChangedRange> bad{{leaf / 8 * 8, 8}};
  const cg::EpochUpload e2 = cg::capture_epoch(s2.view(), 2, 10, bad, {});

  auto sr = cg::StreamingReplica::create(*ctx, config_of(tree, 10, 1u << 12));
  ASSERT_TRUE(sr.ok());
  auto check = [&](std::uint64_t epoch, const Snapshot& want_state) {
    ASSERT_TRUE((*sr)->wait_resident(epoch, std::chrono::seconds(60)));
    auto want = client_core::painted_bounds(want_state.view());
    ASSERT_TRUE(want.ok() && want->has_value());
    ASSERT_TRUE((*sr)
                    ->with_gpu([&](const cg::ResidentState& st) -> Result<void> {
                      EXPECT_EQ(st.epoch, epoch);
                      auto exact = client_core::painted_bounds(st.pools);
                      EXPECT_TRUE(exact.ok() && exact->has_value());
                      EXPECT_TRUE(st.content_bounds && contains(*st.content_bounds, **exact))
                          << "epoch " << epoch << ": box " << str(st.content_bounds)
                          << " misses painted_bounds " << str(*exact);
                      EXPECT_TRUE(st.content_bounds && contains(*st.content_bounds, **want));
                      return {};
                    })
                    .ok());
  };
  (*sr)->push(e0);
  check(0, s0);
  (*sr)->push(e1);
  check(1, s1);
  EXPECT_EQ((*sr)->stats().content_fallbacks, 0u);  // the walk, not the fallback, grew it
  (*sr)->push(e2);
  check(2, s2);
  EXPECT_EQ((*sr)->stats().content_fallbacks, 1u);
}

}  // namespace
}  // namespace deepcanvas::render_test
