// StreamingReplica + RenderLoop (label gpu): epochs stream in through the upload thread under an
// adversarial schedule (random batching, random delays, rows uploaded in random chunks and
// order, texture growth on the way) while frames are rendered in bands. Every band must equal,
// pixel for pixel, a reference render of the server state at the epoch the band claims (a
// separate GpuReplica uploaded whole from a snapshot): a band that saw a partial epoch (a
// reachable cell whose data had not arrived, a freed group reused under a stale parent) would
// differ. The bands are culled to the replica's content box (the render loop's default), the
// references are not: a box missing paint would differ too (content_box_gpu_test has the
// dedicated checks). After the stream the GPU links equal the server's.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <future>
#include <map>
#include <random>
#include <set>
#include <string>
#include <thread>

#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_gpu/headset_loop.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/server_net/server.hpp"
#include "gpu_test_support.hpp"
#include "render_scenes.hpp"
#include "stream_test_support.hpp"

namespace deepcanvas::render_test {
namespace {

namespace cg = client_gpu;

// The resident epoch's GPU links (G3 on the GPU, masked groups only) equal `tree`'s.
::testing::AssertionResult links_equal_server(cg::StreamingReplica& sr, const Octree& tree) {
  auto links = resident_links(sr);
  if (!links)
    return ::testing::AssertionFailure() << "reading the links: " << links.error().message;
  const auto want = tree.group_link_pool();
  if (links->size() != want.size())
    return ::testing::AssertionFailure()
           << links->size() << " link words on the GPU, " << want.size() << " on the server";
  const auto diff = std::mismatch(links->begin(), links->end(), want.begin());
  if (diff.first != links->end())
    return ::testing::AssertionFailure()
           << "link word " << (diff.first - links->begin()) << " differs from the server's";
  return ::testing::AssertionSuccess();
}

// The resident epoch's four uploaded textures, read back, equal `tree`'s pools (and the mirror,
// which ResidentState says holds exactly the textures' contents).
::testing::AssertionResult textures_equal_server(cg::StreamingReplica& sr, const Octree& tree) {
  const PoolView want = pool_view_of(tree);
  ::testing::AssertionResult result = ::testing::AssertionSuccess();
  auto r = sr.with_gpu([&](const cg::ResidentState& st) -> Result<void> {
    auto got = st.replica.read_uploaded();
    if (!got) return std::move(got).error();
    auto differs = [&](const char* pool, const auto& gpu, auto cpu, auto mirror) {
      if (!std::ranges::equal(gpu, cpu))
        result = ::testing::AssertionFailure()
                 << "the " << pool << " texture differs from the server's";
      else if (!std::ranges::equal(mirror, cpu))
        result = ::testing::AssertionFailure()
                 << "the " << pool << " mirror differs from the server's";
    };
    differs("first_child", got->first_child, want.first_child, st.pools.first_child);
    differs("colour", got->colour, want.colour, st.pools.colour);
    differs("group_parent", got->group_parent, want.group_parent, st.pools.group_parent);
    differs("group_depth", got->group_depth_flags, want.group_depth_flags,
            st.pools.group_depth_flags);
    return {};
  });
  if (!r) return ::testing::AssertionFailure() << "reading the textures: " << r.error().message;
  return result;
}

// A server Octree and Painter whose epochs stream into a StreamingReplica (texture width 2^12,
// a small initial capacity so that it grows, unless `initial_cells` says otherwise), the tree's
// epoch 0 snapshot already pushed.
struct PaintedStream {
  std::unique_ptr<Octree> tree;
  std::unique_ptr<server_core::Painter> painter;
  std::unique_ptr<cg::StreamingReplica> replica;
};
Result<PaintedStream> make_painted_stream(cg::Context& ctx,
                                          std::uint64_t initial_cells = std::uint64_t{1} << 12) {
  PaintedStream out;
  auto tree = Octree::create({});
  if (!tree) return std::move(tree).error();
  out.tree = std::move(*tree);
  auto painter = server_core::Painter::create(*out.tree);
  if (!painter) return std::move(painter).error();
  out.painter = std::move(*painter);
  auto sr = cg::StreamingReplica::create(ctx, config_of(*out.tree, 12, initial_cells));
  if (!sr) return std::move(sr).error();
  out.replica = std::move(*sr);
  out.replica->push(capture_tree_epoch(*out.tree, 0, 12, true));
  return out;
}

// Random refinements, coarsenings (freeing groups that later refinements reuse) and colours.
void random_edit(Octree& tree, std::mt19937_64& rng, int max_depth) {
  const int ops = 5 + static_cast<int>(rng() % 60);
  for (int i = 0; i < ops; ++i) {
    const std::uint32_t c = static_cast<std::uint32_t>(rng() % tree.high_water_cells());
    if (!tree.is_live(c)) continue;
    const int kind = static_cast<int>(rng() % 4);
    if (kind <= 1 && tree.is_leaf(c) && tree.depth(c) < max_depth) {
      auto r = tree.refine(c);
      if (r.ok()) {
        // Colour the new children (the render must show the change).
        const std::uint32_t fc = tree.first_child_pool()[c];
        for (std::uint32_t k = 0; k < 8; ++k) {
          const std::uint64_t v = rng();
          tree.set_colour(fc + k, (v % 3 == 0)
                                      ? 0u
                                      : ((static_cast<std::uint32_t>(v >> 8) & 0xFFFFFFu) |
                                         ((40u + static_cast<std::uint32_t>(v % 200)) << 24)));
        }
      }
    } else if (kind == 2 && !tree.is_leaf(c) && tree.can_coarsen(c)) {
      ASSERT_TRUE(tree.coarsen(c).ok());
    } else if (tree.is_leaf(c)) {
      tree.set_colour(c, static_cast<std::uint32_t>(rng()) | 0x40000000u);
    }
  }
}

struct StreamOutcome {
  std::size_t frames = 0, bands_checked = 0, bad_bands = 0, mixed_frames = 0, distinguishing = 0;
  std::size_t epochs_seen = 0;
  std::string first_bad;
  cg::StreamingStats stats;
  bool links_equal = false;
};

// Streams kEpochs random epochs through a StreamingReplica with `chaos` while frames are
// rendered in bands; checks every band against the reference of the epoch it claims.
// One band of a rendered frame against the reference image of the epoch it claims. The check
// has teeth when the previous epoch's image (`prev`) differs in the band's rows: counted as
// distinguishing.
void check_band(const cg::BandRecord& b, const std::vector<std::uint32_t>& px,
                const std::vector<std::uint32_t>& ref, const std::vector<std::uint32_t>* prev,
                std::uint32_t width, StreamOutcome& out) {
  bool bad = false;
  for (std::uint32_t y = b.row0; y < b.row0 + b.rows && !bad; ++y) {
    for (std::uint32_t x = 0; x < width; ++x) {
      if (px[y * width + x] != ref[y * width + x]) {
        if (out.first_bad.empty()) {
          out.first_bad = "band rows " + std::to_string(b.row0) + "+" + std::to_string(b.rows) +
                          " claims epoch " + std::to_string(b.epoch) + ", pixel (" +
                          std::to_string(x) + ", " + std::to_string(y) +
                          ") differs from that epoch's reference";
        }
        bad = true;
        break;
      }
    }
  }
  out.bad_bands += bad ? 1 : 0;
  if (prev) {
    for (std::uint32_t y = b.row0; y < b.row0 + b.rows; ++y) {
      if (!std::equal(prev->begin() + y * width, prev->begin() + (y + 1) * width,
                      ref.begin() + y * width)) {
        ++out.distinguishing;
        break;
      }
    }
  }
}

void run_adversarial_stream(cg::Context& ctx, const cg::UploadChaos& chaos, StreamOutcome& out) {
  constexpr std::uint32_t kW = 48, kH = 36, kBands = 6;
  constexpr int kEpochs = 40, kMaxDepth = 9;
  constexpr std::uint32_t kWidthLog2 = 10;
  auto tree = random_tree(11, 150, kMaxDepth);
  std::mt19937_64 rng(5);

  // Epoch 0 is the whole canvas; then random edits. Snapshots for the references.
  std::vector<cg::EpochUpload> uploads;
  std::map<std::uint64_t, Snapshot> snaps;
  uploads.push_back(capture_tree_epoch(*tree, 0, kWidthLog2, true));
  snaps[0] = snapshot_of(*tree);
  for (int e = 1; e <= kEpochs; ++e) {
    random_edit(*tree, rng, kMaxDepth);
    ASSERT_TRUE(tree->check_invariants().ok());
    uploads.push_back(capture_tree_epoch(*tree, static_cast<std::uint64_t>(e), kWidthLog2, false));
    snaps[static_cast<std::uint64_t>(e)] = snapshot_of(*tree);
  }

  // A small initial texture so that it grows while frames are rendered.
  auto streaming =
      cg::StreamingReplica::create(ctx, config_of(*tree, kWidthLog2, 1u << 10), {}, chaos);
  ASSERT_TRUE(streaming.ok()) << streaming.error().message;
  cg::StreamingReplica& sr = **streaming;

  auto box = client_core::painted_bounds(snaps[0].view());
  ASSERT_TRUE(box.ok() && box->has_value());
  auto cam = Camera::frame_box(**box, kW, kH);
  ASSERT_TRUE(cam.ok());
  cg::RenderLoopOptions lo;
  lo.width = kW;
  lo.height = kH;
  lo.camera = *cam;
  lo.fixed_bands = kBands;
  auto loop = cg::RenderLoop::create(sr, lo);
  ASSERT_TRUE(loop.ok()) << loop.error().message;

  // The reference: a separate replica uploaded whole from the snapshot of the epoch.
  auto ref_rep = cg::GpuReplica::create(ctx, config_of(*tree, kWidthLog2, 1u << 10));
  ASSERT_TRUE(ref_rep.ok());
  auto ref_rc = cg::GpuRaycaster::create(**ref_rep);
  ASSERT_TRUE(ref_rc.ok());
  std::map<std::uint64_t, std::vector<std::uint32_t>> ref_images;
  auto reference = [&](std::uint64_t epoch) -> const std::vector<std::uint32_t>& {
    auto it = ref_images.find(epoch);
    if (it != ref_images.end()) return it->second;
    const PoolView v = snaps.at(epoch).view();
    EXPECT_TRUE((*ref_rep)->upload_all(v).ok());
    EXPECT_TRUE((*ref_rep)->compute_all_links(v).ok());
    auto origin = client_core::make_ray_origin(v, cam->position());
    EXPECT_TRUE(origin.ok());
    EXPECT_TRUE((*ref_rc)->set_frame(*cam, *origin, lo.render).ok());
    EXPECT_TRUE((*ref_rc)->render().ok());
    auto px = (*ref_rc)->read_pixels();
    EXPECT_TRUE(px.ok());
    return ref_images[epoch] = std::move(*px);
  };

  // The producer pushes epochs with random pauses while frames are rendered.
  std::thread producer([&] {
    std::mt19937_64 prng(17);
    for (auto& u : uploads) {
      std::this_thread::sleep_for(std::chrono::microseconds(prng() % 20000));
      sr.push(std::move(u));
    }
  });
  std::set<std::uint64_t> epochs_seen;
  for (int i = 0; i < 600; ++i) {
    auto f = (*loop)->render_frame(true);
    if (!f.ok()) {
      ADD_FAILURE() << f.error().message;
      break;
    }
    if (f->empty) {
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
      continue;
    }
    ++out.frames;
    if (f->min_epoch != f->max_epoch) ++out.mixed_frames;
    auto px = (*loop)->read_pixels();
    ASSERT_TRUE(px.ok());
    for (const auto& b : f->band_list) {
      epochs_seen.insert(b.epoch);
      const auto& ref = reference(b.epoch);
      check_band(b, *px, ref, b.epoch > 0 ? &reference(b.epoch - 1) : nullptr, kW, out);
      ++out.bands_checked;
    }
    if (sr.resident_epoch() == static_cast<std::uint64_t>(kEpochs) && out.frames > 3) break;
  }
  producer.join();
  ASSERT_TRUE(sr.wait_resident(kEpochs, std::chrono::seconds(60)));
  ASSERT_TRUE(sr.status().ok()) << sr.status().error().message;
  out.epochs_seen = epochs_seen.size();
  out.stats = sr.stats();

  // G3 on the GPU after the streamed edits equals the server's links.
  auto links = resident_links(sr);
  ASSERT_TRUE(links.ok());
  const auto want = tree->group_link_pool();
  out.links_equal =
      links->size() == want.size() && std::equal(links->begin(), links->end(), want.begin());
}

TEST(StreamingReplica, EveryBandShowsAWholeEpochUnderAdversarialUploads) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  for (std::uint64_t seed : {99u, 1234u, 777u}) {
    cg::UploadChaos chaos;
    chaos.seed = seed;
    // Growth in steps of one or two rows: batches (and bands) run between the steps, so rows
    // already copied into the taller textures are written again before the switch.
    chaos.growth_rows_per_step = 1 + static_cast<std::uint32_t>(seed % 2);
    StreamOutcome out;
    run_adversarial_stream(*ctx, chaos, out);
    EXPECT_EQ(out.bad_bands, 0u) << "seed " << seed << ": " << out.first_bad;
    // Frames ran while the stream was in progress and saw many epochs.
    EXPECT_GT(out.epochs_seen, 4u) << "seed " << seed;
    EXPECT_GT(out.distinguishing, 0u) << "seed " << seed;
    EXPECT_GT(out.bands_checked, 20u) << "seed " << seed;
    EXPECT_GT(out.stats.growths, 0u) << "seed " << seed;  // the textures grew while streaming
    EXPECT_GT(out.stats.growth_steps, out.stats.growths) << "seed " << seed;  // in several steps
    EXPECT_TRUE(out.links_equal) << "seed " << seed;
    // The bands were culled to the replica's content box (RenderLoopOptions::content_cull is
    // on by default), grown incrementally through refinements, coarsenings and reused groups:
    // the references above are uncull renders.
    EXPECT_EQ(out.stats.content_fallbacks, 0u) << "seed " << seed;
    std::printf(
        "seed %llu: %zu frames, %zu bands checked (%zu distinguishable from the epoch "
        "before), %zu epochs seen, %zu frames spanning epochs, %llu batches, %llu "
        "growths in %llu steps, %llu epochs joined a batch late\n",
        static_cast<unsigned long long>(seed), out.frames, out.bands_checked, out.distinguishing,
        out.epochs_seen, out.mixed_frames, static_cast<unsigned long long>(out.stats.batches),
        static_cast<unsigned long long>(out.stats.growths),
        static_cast<unsigned long long>(out.stats.growth_steps),
        static_cast<unsigned long long>(out.stats.late_epochs));
  }
}

// The negative control: with the lock released between an epoch's chunks (a deliberately
// broken upload order), the same check finds bands that saw a partial epoch.
TEST(StreamingReplica, TheBandCheckCatchesPartialEpochs) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  cg::UploadChaos chaos;
  chaos.seed = 99;
  chaos.break_atomicity = true;
  StreamOutcome out;
  run_adversarial_stream(*ctx, chaos, out);
  EXPECT_GT(out.bad_bands, 0u) << out.bands_checked << " bands checked";
  std::printf("broken order: %zu of %zu bands saw a partial epoch (first: %s)\n", out.bad_bands,
              out.bands_checked, out.first_bad.c_str());
}

// Random stroke sequences painted by the server's Painter, streamed epoch by epoch through the
// upload thread with the default (fast) schedule: the GPU links equal the server's after each.
TEST(StreamingReplica, GpuLinksEqualServerAfterStreamedStrokes) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto stream = make_painted_stream(*ctx);
  ASSERT_TRUE(stream.ok());
  auto& tree = *stream->tree;
  auto* painter = &stream->painter;
  auto* sr = &stream->replica;
  std::mt19937_64 rng(23);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int e = 1; e <= 12; ++e) {
    const int strokes = 1 + static_cast<int>(rng() % 3);
    for (int s = 0; s < strokes; ++s) {
      protocol::Stroke stroke;
      stroke.brush.colour[0] = 0.8f;
      stroke.brush.colour[3] = 0.9f;
      if (rng() % 4 == 0) stroke.brush.mode = protocol::BrushMode::erase;
      const double x0 = u(rng) * 0.5, y0 = u(rng) * 0.5, z0 = u(rng) * 0.5;
      for (int k = 0; k < 12; ++k) {
        protocol::StrokeSample smp;
        smp.x = x0 + 0.02 * k;
        smp.y = y0 + 0.01 * k;
        smp.z = z0;
        smp.radius = 0.01f + 0.04f * static_cast<float>(rng() % 4);
        stroke.samples.push_back(smp);
      }
      ASSERT_TRUE((*painter)->apply_stroke(stroke).ok());
    }
    (*sr)->push(capture_tree_epoch(tree, static_cast<std::uint64_t>(e), 12, false));
    ASSERT_TRUE((*sr)->wait_resident(static_cast<std::uint64_t>(e), std::chrono::seconds(60)));
    EXPECT_TRUE(links_equal_server(**sr, tree)) << "epoch " << e;
    EXPECT_TRUE(textures_equal_server(**sr, tree)) << "epoch " << e;
  }
}

// Frame gaps, the missed gap: a loop running late starts its next frame as soon as the last one
// ends, usually before the upload thread is scheduled, so the gap after a batch's deadline can
// pass unseen. The overdue batch must then go between the new frame's bands at once, not wait
// for that frame to end (or for another gap_wait). Frames are driven by hand here, with long
// margins: the deadline is 500 ms after the commit; a batch that waited for another gap_wait
// would go at 1000 ms.
TEST(StreamingReplica, OverdueBatchGoesAtOnceAfterAMissedGap) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto stream = make_painted_stream(*ctx);
  ASSERT_TRUE(stream.ok());
  auto* sr = &stream->replica;
  ASSERT_TRUE((*sr)->wait_resident(0, std::chrono::seconds(60)));
  (*sr)->attach_frames(true);
  const double gap_wait_ms = 500;
  (*sr)->frame_started(gap_wait_ms);  // frame 1
  protocol::Stroke stroke;
  stroke.brush.colour[2] = 0.9f;
  stroke.brush.colour[3] = 0.8f;
  stroke.samples.push_back({0.1, -0.2, 0.3, 0.05f, 1.0f, 0});
  ASSERT_TRUE(stream->painter->apply_stroke(stroke).ok());
  (*sr)->push(capture_tree_epoch(*stream->tree, 1, 12, false));
  std::this_thread::sleep_for(std::chrono::milliseconds(650));  // frame 1 overruns the deadline
  EXPECT_EQ((*sr)->resident_epoch(), 0u) << "a batch went mid-frame before its deadline";
  (*sr)->frame_finished(std::chrono::steady_clock::now());  // late: the next frame is due at once
  (*sr)->frame_started(gap_wait_ms);  // frame 2, before the upload thread has run
  EXPECT_TRUE((*sr)->wait_resident(1, std::chrono::milliseconds(300)))
      << "the overdue batch waited for the frame after the missed gap";
  (*sr)->frame_finished(std::chrono::steady_clock::now());
  (*sr)->attach_frames(false);
  ASSERT_TRUE((*sr)->wait_resident(1, std::chrono::seconds(60)));
}

// Growth without a stall: a burst of epochs queued during a frame (a large stroke streamed in
// many painter steps, as in the real paintings) that needs far taller textures than the
// replica has (1 row of 4096 cells here) must not complete a growth at once inside a batch
// (ResidentBatch::grew, a GPU lock held for the whole copy): the growth completes in steps,
// each its own turn under the lock, and the epochs that fit go first. Every epoch arrives and
// the result equals the server's. Fails without make_room(): the batch then grows at once.
TEST(StreamingReplica, BurstPastTheTexturesGrowsInStepsNotAtOnce) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto stream = make_painted_stream(*ctx);
  ASSERT_TRUE(stream.ok());
  auto& tree = *stream->tree;
  auto* sr = &stream->replica;
  ASSERT_TRUE((*sr)->wait_resident(0, std::chrono::seconds(60)));
  (void)(*sr)->take_resident_log();
  (*sr)->attach_frames(true);
  (*sr)->frame_started(60000);  // a frame in progress; no deadline comes during the test
  constexpr std::uint64_t kBurst = 10;
  for (std::uint64_t e = 1; e <= kBurst; ++e) {
    protocol::Stroke stroke;
    stroke.brush.colour[2] = 0.7f;
    stroke.brush.colour[3] = 0.9f;
    const double y = -0.5 + 0.1 * static_cast<double>(e);
    for (int k = 0; k < 6; ++k)
      stroke.samples.push_back(
          {-0.4 + 0.15 * k, y, 0.1, 0.03f, 1.0f, static_cast<std::uint32_t>(k)});
    ASSERT_TRUE(stream->painter->apply_stroke(stroke).ok());
    (*sr)->push(capture_tree_epoch(tree, e, 12, false));
  }
  ASSERT_GT(tree.high_water_cells(), 8u * 4096u) << "the burst must outgrow the textures";
  (*sr)->frame_finished(std::chrono::steady_clock::now() + std::chrono::seconds(60));
  ASSERT_TRUE((*sr)->wait_resident(kBurst, std::chrono::seconds(60)));
  (*sr)->attach_frames(false);
  for (const auto& b : (*sr)->take_resident_log())
    EXPECT_FALSE(b.grew) << "epochs " << b.first_epoch << "-" << b.last_epoch
                         << " completed a growth at once";
  const auto st = (*sr)->stats();
  EXPECT_GT(st.growths, 0u);
  EXPECT_EQ(st.max_growth_ms, 0.0);
  const PoolView want = pool_view_of(tree);
  auto r = (*sr)->with_gpu([&](const cg::ResidentState& rs) -> Result<void> {
    EXPECT_EQ(rs.epoch, kBurst);
    EXPECT_TRUE(std::ranges::equal(rs.pools.first_child, want.first_child));
    EXPECT_TRUE(std::ranges::equal(rs.pools.colour, want.colour));
    return {};
  });
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(links_equal_server(**sr, tree));
}

// Late joiners: epochs committed while a batch waits for the GPU lock (a band in progress, held
// here by hand for 400 ms) go resident with that batch, and the result is the same as one batch
// after another: the mirror equals the server's pools, the GPU links its links, and the content
// box holds every painted leaf (the late epochs' content step runs over the mirror after the
// batch they join). Fails without the late path: epochs 2 and 3 then form a batch of their own.
TEST(StreamingReplica, EpochsCommittedWhileABatchWaitsForTheLockJoinIt) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  // Textures with room for all three epochs (an epoch past them may not join: make_room()).
  auto stream = make_painted_stream(*ctx, std::uint64_t{1} << 20);
  ASSERT_TRUE(stream.ok());
  auto& tree = *stream->tree;
  auto* sr = &stream->replica;
  ASSERT_TRUE((*sr)->wait_resident(0, std::chrono::seconds(60)));
  (void)(*sr)->take_resident_log();
  auto stroke = [&](float x, protocol::BrushMode mode) {
    protocol::Stroke s;
    s.brush.mode = mode;
    s.brush.colour[0] = 0.8f;
    s.brush.colour[3] = 0.9f;
    s.samples.push_back({x, 0.1, -0.2, 0.05f, 1.0f, 0});
    s.samples.push_back({x + 0.2, 0.15, -0.2, 0.05f, 1.0f, 16});
    return s;
  };
  std::promise<void> holding, release;
  std::thread holder([&] {
    auto r = (*sr)->with_gpu([&](const cg::ResidentState&) -> Result<void> {
      holding.set_value();
      release.get_future().wait();
      return {};
    });
    EXPECT_TRUE(r.ok());
  });
  holding.get_future().wait();
  ASSERT_TRUE(stream->painter->apply_stroke(stroke(-0.3f, protocol::BrushMode::paint)).ok());
  (*sr)->push(capture_tree_epoch(tree, 1, 12, false));
  // The upload thread takes epoch 1 and waits for the lock; then epochs 2 and 3 arrive (the
  // second an erase across the first, so the box may only grow where the mirror says).
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  ASSERT_TRUE(stream->painter->apply_stroke(stroke(0.2f, protocol::BrushMode::paint)).ok());
  (*sr)->push(capture_tree_epoch(tree, 2, 12, false));
  ASSERT_TRUE(stream->painter->apply_stroke(stroke(-0.35f, protocol::BrushMode::erase)).ok());
  (*sr)->push(capture_tree_epoch(tree, 3, 12, false));
  EXPECT_EQ((*sr)->resident_epoch(), 0u);
  release.set_value();
  holder.join();
  ASSERT_TRUE((*sr)->wait_resident(3, std::chrono::seconds(60)));
  const auto log = (*sr)->take_resident_log();
  ASSERT_EQ(log.size(), 1u) << "epochs 2 and 3 did not join the waiting batch";
  EXPECT_EQ(log[0].first_epoch, 1u);
  EXPECT_EQ(log[0].last_epoch, 3u);
  EXPECT_EQ(log[0].late_epochs, 2u);
  EXPECT_GT(log[0].lock_wait_ms, 100.0);
  EXPECT_EQ(log[0].commits.size(), 3u);
  const PoolView want = pool_view_of(tree);
  auto painted = client_core::painted_bounds(want);
  ASSERT_TRUE(painted.ok());
  ASSERT_TRUE(painted->has_value());
  auto r = (*sr)->with_gpu([&](const cg::ResidentState& st) -> Result<void> {
    EXPECT_EQ(st.epoch, 3u);
    EXPECT_TRUE(std::ranges::equal(st.pools.first_child, want.first_child));
    EXPECT_TRUE(std::ranges::equal(st.pools.colour, want.colour));
    EXPECT_TRUE(std::ranges::equal(st.pools.group_parent, want.group_parent));
    EXPECT_TRUE(std::ranges::equal(st.pools.group_depth_flags, want.group_depth_flags));
    EXPECT_TRUE(st.content_bounds.has_value());
    if (st.content_bounds) {
      const auto& b = *st.content_bounds;
      const auto& p = **painted;
      for (int a = 0; a < 3; ++a) {
        EXPECT_LE(b.min[a], p.min[a]) << "axis " << a;
        EXPECT_GE(b.max[a], p.max[a]) << "axis " << a;
      }
    }
    return {};
  });
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(links_equal_server(**sr, tree));
  EXPECT_TRUE(textures_equal_server(**sr, tree))
      << "the late joiners' rows over the staged batch's";
}

// The pace rule (no GPU): the fps cap's interval until the frames need more (keeping
// upload_share free); gaps only once the median frame is slower than gaps_above x the cap's
// interval; short bands while the median frame fits in the cap's interval; an unpaced loop has
// neither.
TEST(RenderLoopPace, GapsOnlyOnceFramesAreSlowerThanTheCap) {
  cg::RenderLoopOptions o;
  o.max_fps = 50;  // 20 ms
  o.upload_share = 0.25;
  o.gaps_above = 1.0;
  for (double p50 = 0; p50 <= 60; p50 += 0.5) {
    const auto pace = cg::choose_pace(o, p50);
    EXPECT_DOUBLE_EQ(pace.interval_ms, std::max(20.0, p50 / 0.75)) << p50;
    EXPECT_EQ(pace.gaps, p50 > 20.0) << p50;
    EXPECT_EQ(pace.band_target_ms, p50 > 20.0 ? o.band_target_ms : o.capped_band_target_ms) << p50;
  }
  // Gaps later than the cap: between the cap and gaps_above x the cap, long bands, no gaps.
  o.gaps_above = 1.5;
  EXPECT_FALSE(cg::choose_pace(o, 25.0).gaps);
  EXPECT_EQ(cg::choose_pace(o, 25.0).band_target_ms, o.band_target_ms);
  EXPECT_TRUE(cg::choose_pace(o, 30.5).gaps);
  // gaps_above below 1: gaps as soon as the interval outgrows the cap (p50 > 15 ms here).
  o.gaps_above = 0.75;
  EXPECT_FALSE(cg::choose_pace(o, 15.0).gaps);
  EXPECT_TRUE(cg::choose_pace(o, 15.5).gaps);
  o.upload_share = 0;  // nothing kept free: never gaps
  EXPECT_FALSE(cg::choose_pace(o, 100.0).gaps);
  EXPECT_DOUBLE_EQ(cg::choose_pace(o, 100.0).interval_ms, 100.0);
  o.max_fps = 0;  // unpaced
  o.upload_share = 0.25;
  const auto unpaced = cg::choose_pace(o, 100.0);
  EXPECT_FALSE(unpaced.gaps);
  EXPECT_EQ(unpaced.interval_ms, 0.0);
  EXPECT_EQ(unpaced.band_target_ms, o.band_target_ms);
}

// A paced render loop keeping part of each interval free (RenderLoopOptions::max_fps,
// upload_share) running on its own thread while epochs stream in: the upload thread schedules
// batches in the gaps between frames ("Frame gaps" in streaming_replica.hpp). What must hold
// whatever the timing: every epoch becomes resident (gap scheduling shapes when, never whether),
// the GPU links end equal to the server's, the loop's frames never go back in epoch, and a batch
// that waits for a gap is released when the loop stops. Some batches are scheduled in gaps (at
// the latest at a frame's end); how many is timing (the render bench reports it).
TEST(StreamingReplica, PacedLoopUploadsInGapsAndEveryEpochArrives) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto stream = make_painted_stream(*ctx);
  ASSERT_TRUE(stream.ok());
  auto& tree = *stream->tree;
  auto* painter = &stream->painter;
  auto* sr = &stream->replica;
  ASSERT_TRUE((*sr)->wait_resident(0, std::chrono::seconds(60)));
  cg::RenderLoopOptions lo;
  lo.width = 64;
  lo.height = 36;
  // A cap the frames never reach, so the frames set the pace and a quarter of each interval
  // is kept free: uploads only in those gaps.
  lo.max_fps = 10000;
  lo.upload_share = 0.25;
  auto loop = cg::RenderLoop::create(**sr, lo);
  ASSERT_TRUE(loop.ok());
  (*loop)->start();
  std::mt19937_64 rng(41);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::uint64_t epoch = 0;
  for (int e = 1; e <= 40; ++e) {
    protocol::Stroke stroke;
    stroke.brush.colour[1] = 0.7f;
    stroke.brush.colour[3] = 0.8f;
    if (rng() % 5 == 0) stroke.brush.mode = protocol::BrushMode::erase;
    const double x0 = u(rng) * 0.5, y0 = u(rng) * 0.5, z0 = u(rng) * 0.5;
    for (int k = 0; k < 8; ++k) {
      protocol::StrokeSample smp;
      smp.x = x0 + 0.02 * k;
      smp.y = y0;
      smp.z = z0 + 0.01 * k;
      smp.radius = 0.02f + 0.02f * static_cast<float>(rng() % 3);
      stroke.samples.push_back(smp);
    }
    ASSERT_TRUE((*painter)->apply_stroke(stroke).ok());
    epoch = static_cast<std::uint64_t>(e);
    (*sr)->push(capture_tree_epoch(tree, epoch, 12, false));
    std::this_thread::sleep_for(std::chrono::microseconds(rng() % 30000));
  }
  ASSERT_TRUE((*sr)->wait_resident(epoch, std::chrono::seconds(60)));
  // Epochs pushed after the loop stops must not wait for gaps that no longer come.
  ASSERT_TRUE((*loop)->stop().ok());
  protocol::Stroke last;
  last.brush.colour[0] = 1.0f;
  last.brush.colour[3] = 1.0f;
  last.samples.push_back({0.1, 0.2, 0.3, 0.05f, 1.0f, 0});
  ASSERT_TRUE((*painter)->apply_stroke(last).ok());
  (*sr)->push(capture_tree_epoch(tree, epoch + 1, 12, false));
  ASSERT_TRUE((*sr)->wait_resident(epoch + 1, std::chrono::seconds(60)));

  std::uint64_t previous = 0, gap_batches = 0;
  const auto frames = (*loop)->frames();
  ASSERT_FALSE(frames.empty());
  for (const auto& f : frames) {
    EXPECT_GE(f.min_epoch, previous);
    EXPECT_LE(f.min_epoch, f.max_epoch);
    previous = f.max_epoch;
  }
  for (const auto& b : (*sr)->take_resident_log())
    if (b.first_epoch > 0 && b.in_gap) ++gap_batches;
  EXPECT_GT(gap_batches, 0u);
  EXPECT_TRUE(links_equal_server(**sr, tree));
}

// The headset loop while strokes stream in: every frame after the snapshot renders both eyes
// of one resident epoch (epochs never go back), and once the stream is resident the two halves
// of the side-by-side frame are the CPU reference's images from the two eyes. A headset rate
// no frame can hold counts every frame as missed.
TEST(HeadsetLoop, BothEyesOfOneEpochWhileStreamingAndMissedFramesCounted) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto stream = make_painted_stream(*ctx);
  ASSERT_TRUE(stream.ok());
  auto& tree = *stream->tree;
  auto* sr = &stream->replica;
  ASSERT_TRUE((*sr)->wait_resident(0, std::chrono::seconds(60)));
  cg::HeadsetOptions ho;
  ho.eyes.width = 40;
  ho.eyes.height = 32;
  ho.eyes.vfov_deg = 80;
  ho.hz = 60;
  ho.adapt = false;
  ho.render.background = {0.1, 0.1, 0.12};
  ho.content_cull = false;
  auto loop = cg::HeadsetLoop::create(**sr, ho);
  ASSERT_TRUE(loop.ok()) << loop.error().message;
  client_core::ArtistPose pose;  // 1.6 m up, 2 m in front of the content at the centre
  pose.head = {0, 1.6, 0};
  pose.world_origin = client_core::DVec3{0, 0, 2} - pose.head;
  std::thread painter([&] {
    std::mt19937_64 rng(43);
    std::uniform_real_distribution<double> u(-0.4, 0.4);
    for (int e = 1; e <= 15; ++e) {
      protocol::Stroke stroke;
      stroke.brush.colour[0] = 0.8f;
      stroke.brush.colour[3] = 0.9f;
      const double x0 = u(rng), y0 = u(rng);
      for (int k = 0; k < 6; ++k) stroke.samples.push_back({x0 + 0.03 * k, y0, 0.01 * k, 0.05f, 1.0f, 0});
      EXPECT_TRUE(stream->painter->apply_stroke(stroke).ok());
      (*sr)->push(capture_tree_epoch(tree, static_cast<std::uint64_t>(e), 12, false));
      std::this_thread::sleep_for(std::chrono::milliseconds(15));
    }
  });
  auto frames = (*loop)->run([&](double) { return pose; },
                             [&](const std::vector<cg::HeadsetFrame>& f) { return f.size() >= 30; });
  painter.join();
  ASSERT_TRUE(frames.ok()) << frames.error().message;
  std::uint64_t previous = 0;
  for (const auto& f : *frames) {
    EXPECT_FALSE(f.empty);
    EXPECT_GE(f.epoch, previous);
    previous = f.epoch;
    EXPECT_DOUBLE_EQ(f.render_scale, 1.0);
    EXPECT_GT(f.render_ms, 0.0);
  }
  // The finished stream: the last frame's eyes against the reference.
  ASSERT_TRUE((*sr)->wait_resident(15, std::chrono::seconds(60)));
  auto last = (*loop)->run([&](double) { return pose; },
                           [](const std::vector<cg::HeadsetFrame>& f) { return f.size() >= 1; });
  ASSERT_TRUE(last.ok());
  EXPECT_EQ(last->back().epoch, 15u);
  std::uint32_t w = 0, h = 0;
  auto px = (*loop)->read_side_by_side(w, h);
  ASSERT_TRUE(px.ok()) << px.error().message;
  ASSERT_EQ(w, 80u);
  ASSERT_EQ(h, 32u);
  auto cams = client_core::eye_cameras(pose, ho.eyes);
  ASSERT_TRUE(cams.ok());
  const PoolView pools = pool_view_of(tree);
  int worst = 0, painted = 0;
  for (int e = 0; e < 2; ++e) {
    auto ref = client_core::render_reference(pools, (*cams)[static_cast<std::size_t>(e)], ho.render);
    ASSERT_TRUE(ref.ok());
    const auto bytes = ref->to_rgba8();
    for (std::uint32_t y = 0; y < h; ++y)
      for (std::uint32_t x = 0; x < 40; ++x) {
        const std::uint32_t word = (*px)[std::size_t{y} * w + static_cast<std::uint32_t>(e) * 40 + x];
        for (int c = 0; c < 4; ++c) {
          const int got = static_cast<int>((word >> (8 * c)) & 0xFF);
          worst = std::max(worst, std::abs(got - int{bytes[(std::size_t{y} * 40 + x) * 4 + static_cast<std::size_t>(c)]}));
        }
        painted += ((word >> 24) & 0xFF) > 64;
      }
  }
  EXPECT_LE(worst, 2) << "the eyes differ from the reference";
  EXPECT_GT(painted, 20) << "the eyes see the strokes";
  // 1000 Hz: no frame fits its 1 ms slot.
  cg::HeadsetOptions fast = ho;
  fast.hz = 1000;
  auto fast_loop = cg::HeadsetLoop::create(**sr, fast);
  ASSERT_TRUE(fast_loop.ok());
  auto missed = (*fast_loop)->run([&](double) { return pose; },
                                  [](const std::vector<cg::HeadsetFrame>& f) { return f.size() >= 5; });
  ASSERT_TRUE(missed.ok());
  for (const auto& f : *missed) EXPECT_TRUE(f.missed);
}

}  // namespace
}  // namespace deepcanvas::render_test
