// GPU replica + G3 pass + ray caster against the CPU references, on a real Vulkan device.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <random>
#include <set>

#include "deepcanvas/client_core/content_boxes.hpp"
#include "deepcanvas/client_core/stereo.hpp"
#include "deepcanvas/client_gpu/errors.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/replica_gpu.hpp"
#include "deepcanvas/shaders/ray_params_probe.spv.h"
#include "gpu_test_support.hpp"
#include "raycast_layout.h"
#include "render_scenes.hpp"
#include "stream_test_support.hpp"

namespace deepcanvas::render_test {
namespace {

using client_core::RenderOptions;
using client_core::Stepping;
using client_gpu::GpuRaycaster;
using client_gpu::GpuReplica;
using client_gpu::GpuReplicaConfig;

std::unique_ptr<GpuReplica> make_replica(const client_gpu::Context& ctx, const Octree& tree,
                                         std::uint32_t width_log2 = 10,
                                         std::uint64_t initial = 1u << 12) {
  GpuReplicaConfig cfg;
  cfg.width_log2 = width_log2;
  cfg.block_log2 = static_cast<std::uint32_t>(std::countr_zero(tree.config().block_cells));
  cfg.roots_per_axis = tree.config().roots_per_axis;
  cfg.edge_m = tree.config().edge_m;
  cfg.initial_capacity_cells = initial;
  auto r = GpuReplica::create(ctx, cfg);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message);
  return r.ok() ? std::move(r).value() : nullptr;
}

// A replica of 256-cell texture rows (blocks of one row), starting `initial_rows` rows tall:
// small enough that tests grow it row by row.
constexpr std::uint32_t kNarrowWidthLog2 = 8;
GpuReplicaConfig narrow_config(std::uint64_t initial_rows) {
  GpuReplicaConfig cfg;
  cfg.width_log2 = kNarrowWidthLog2;
  cfg.block_log2 = kNarrowWidthLog2;
  cfg.initial_capacity_cells = initial_rows << kNarrowWidthLog2;
  return cfg;
}

// The tree's masks over all blocks as one bitset (bit g = group g).
std::vector<std::uint64_t> global_mask(const Octree& tree) {
  std::vector<std::uint64_t> out;
  for (server_core::BlockId b = 0; b < tree.block_count(); ++b) {
    const auto m = tree.neighbour_mask(b);
    out.insert(out.end(), m.begin(), m.end());
  }
  return out;
}

void expect_links_equal(const std::vector<std::uint32_t>& gpu, const Octree& tree,
                        const char* when) {
  const auto want = tree.group_link_pool();
  ASSERT_EQ(gpu.size(), tree.high_water_cells() / 8 * 6) << when;
  std::size_t bad = 0, first_bad = 0;
  for (std::size_t i = 0; i < gpu.size(); ++i) {
    if (gpu[i] != want[i] && bad++ == 0) first_bad = i;
  }
  EXPECT_EQ(bad, 0u) << when << ": first mismatch group " << first_bad / 6 << " face "
                     << first_bad % 6 << " gpu " << gpu[first_bad] << " cpu " << want[first_bad];
}

// Random refine / coarsen rounds; after each, only the dirty blocks are uploaded and only the
// masked groups recomputed on the GPU: the links equal the server's, bit for bit.
TEST(GpuLinks, MaskedUpdatesMatchServerAfterRandomOperations) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto tree = random_tree(101, 200, 8);
  const PoolView first = pool_view_of(*tree);
  auto replica = make_replica(*ctx, *tree);
  ASSERT_TRUE(replica);
  ASSERT_TRUE(replica->upload_all(first).ok());
  ASSERT_TRUE(replica->compute_all_links(first).ok());
  tree->clear_all_neighbour_masks();
  (void)tree->take_dirty_blocks();
  auto links = replica->read_links();
  ASSERT_TRUE(links.ok());
  expect_links_equal(*links, *tree, "full rebuild");

  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  std::uint64_t masked_total = 0, groups_total = 0;
  for (int round = 0; round < 12; ++round) {
    const int ops = 20 + static_cast<int>(rng() % 200);
    for (int i = 0; i < ops; ++i) {
      const std::uint32_t hw = static_cast<std::uint32_t>(tree->high_water_cells());
      const std::uint32_t c = static_cast<std::uint32_t>(rng() % hw);
      if (!tree->is_live(c)) continue;
      if (rng() % 3 != 0) {
        if (tree->is_leaf(c) && tree->depth(c) < 12) (void)tree->refine(c);
      } else if (!tree->is_leaf(c) && tree->can_coarsen(c)) {
        ASSERT_TRUE(tree->coarsen(c).ok());
      }
    }
    const PoolView pools = pool_view_of(*tree);
    const auto dirty = tree->take_dirty_blocks();
    ASSERT_TRUE(replica->upload_blocks(pools, dirty).ok());
    const auto mask = global_mask(*tree);
    client_gpu::LinksTiming timing;
    ASSERT_TRUE(replica->compute_links_masked(pools, mask, &timing).ok());
    tree->clear_all_neighbour_masks();
    masked_total += timing.groups;
    groups_total += tree->high_water_cells() / 8;
    auto l = replica->read_links();
    ASSERT_TRUE(l.ok());
    expect_links_equal(*l, *tree, ("round " + std::to_string(round)).c_str());
    ASSERT_TRUE(tree->check_invariants().ok());
  }
  EXPECT_GT(replica->generation(), 1u);       // the textures grew on the way
  EXPECT_LT(masked_total * 4, groups_total);  // the mask is a small part of the pools
}

// Random pools (an upload copies words, whatever they mean) changed row by row over rounds, the
// textures growing on the way: after every round the four textures read back equal the pools
// (the brute-force reference), on a replica fed by rows copied from the pools
// (upload_row_list) and on one fed by rows staged first from per-row copies (stage_rows, then
// upload_staged), the StreamingReplica's path. Staging left stale by another upload is refused
// and changes nothing (the negative control), as are unsorted rows and rows of another width.
// Growth doubles the textures' height, adding at most max_growth_cells (whole rows) beyond what
// is needed; a need past that gets exactly its rows. Reserve and the incremental growth agree.
TEST(GpuReplicaGrowth, DoublesUpToTheGrowthCapThenAddsTheCap) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  constexpr std::uint64_t W = 1u << kNarrowWidthLog2;
  GpuReplicaConfig cfg = narrow_config(2);
  cfg.max_growth_cells = 4 * W - 3;  // rounded up to 4 rows
  auto created = GpuReplica::create(*ctx, cfg);
  ASSERT_TRUE(created.ok()) << created.error().message;
  GpuReplica& r = **created;
  EXPECT_EQ(r.max_growth_cells(), 4 * W);
  EXPECT_EQ(r.capacity_cells(), 2 * W);
  // Brute force: the height after growing from `h` rows to hold `need` rows.
  const auto expected_rows = [](std::uint64_t h, std::uint64_t need) {
    return std::max(need, std::min(2 * h, h + 4));
  };
  std::uint64_t rows = 2;
  for (const std::uint64_t need : {3u, 5u, 9u, 13u, 40u, 41u}) {
    ASSERT_TRUE(r.reserve(need * W - 5).ok());
    rows = expected_rows(rows, need);
    EXPECT_EQ(r.capacity_cells(), rows * W) << "reserving " << need << " rows";
  }
  // The incremental growth ahead of need (StreamingReplica asks for one cell more) adds the cap.
  ASSERT_TRUE(r.begin_growth(r.capacity_cells() + 1).ok());
  for (;;) {
    auto done = r.growth_step(~0u);
    ASSERT_TRUE(done.ok()) << done.error().message;
    if (*done) break;
  }
  EXPECT_EQ(r.capacity_cells(), (rows + 4) * W);
}

// The rows a growth adds are written when first used, never by the growth (GpuReplica's
// header): a row reads as written exactly when it was in the first textures or uploaded since;
// a row's first upload sets its links to "no link", as does the first links computation of a
// group in it (before the row's pools were uploaded), and a later first upload keeps the
// computed links. Through reserve() and through the incremental growth. The links check is the
// discriminating one: the fresh rows of a texture hold zeros or garbage, never all ones.
TEST(GpuReplicaGrowth, RowsAGrowthAddsAreWrittenWhenFirstUsed) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  namespace L = gpu_layout;
  constexpr std::uint64_t W = 1u << kNarrowWidthLog2;
  constexpr std::uint64_t G = W / 8;  // groups per row
  GpuReplicaConfig cfg = narrow_config(2);
  auto created = GpuReplica::create(*ctx, cfg);
  ASSERT_TRUE(created.ok()) << created.error().message;
  GpuReplica& r = **created;
  // Pools of 64 rows of never-used cells past the roots; row 9's groups live at depth 1 under
  // root cell 0 (whatever their links: computed from these pools on the GPU).
  Snapshot pools;
  pools.edge_m = cfg.edge_m;
  const auto resize = [&](std::uint64_t cells) {
    pools.fc.resize(cells, L::kNoCell);
    pools.col.resize(cells, 0u);
    pools.par.resize(cells / 8, L::kNoCell);
    pools.dep.resize(cells / 8, static_cast<std::uint8_t>(L::kGroupFreeFlag));
    pools.links.resize(cells / 8 * 6, L::kNoCell);
  };
  resize(64 * W);
  std::set<std::uint32_t> written = {0, 1};  // the first textures
  const auto expect_rows = [&](const std::string& when) {
    for (std::uint32_t row = 0; row < r.capacity_cells() / W; ++row)
      EXPECT_EQ(r.row_written(row), written.contains(row)) << when << ", row " << row;
  };
  // Every link of the groups of `rows` reads "no link", but those of group 20 * G + 3, which
  // is linked below from its row's unspecified values (never uploaded).
  const auto expect_no_links = [&](std::initializer_list<std::uint32_t> rows,
                                   const std::string& when) {
    auto links = r.read_links();
    ASSERT_TRUE(links.ok()) << links.error().message;
    for (const std::uint32_t row : rows) {
      for (std::uint64_t i = row * G * 6; i < (row + 1) * G * 6; ++i) {
        if (i / 6 == 20 * G + 3) continue;
        ASSERT_EQ((*links)[i], L::kNoCell) << when << ", row " << row << ", word " << i;
      }
    }
  };

  ASSERT_TRUE(r.reserve(40 * W).ok());  // at once
  EXPECT_GE(r.capacity_cells(), 40 * W);
  expect_rows("after reserve");
  ASSERT_TRUE(r.reserve(64 * W).ok());  // from a grown height, as the pools need
  expect_rows("after reserve");
  ASSERT_TRUE(r.upload_row_list(pools.view(), std::vector<std::uint32_t>{10, 11, 30}).ok());
  written.insert({10, 11, 30});
  expect_rows("after the first uploads");
  expect_no_links({10, 11, 30}, "rows first uploaded");

  // Links of one group of row 20 first (its row not uploaded: what they are is unspecified),
  // then the rest of row 20 reads "no link".
  ASSERT_TRUE(r.compute_links(pools.view(), std::vector<std::uint32_t>{20 * G + 3}).ok());
  expect_rows("after links in row 20");
  expect_no_links({20}, "row 20 linked before its upload");
  // Row 9: depth-1 groups under root 0 (cell 0's first child is row 9's first group), linked,
  // then the row uploaded again: the computed links stay.
  for (std::uint64_t k = 0; k < G; ++k) {
    pools.par[9 * G + k] = 0;
    pools.dep[9 * G + k] = 1;
  }
  pools.fc[0] = static_cast<std::uint32_t>(9 * W);
  ASSERT_TRUE(r.upload_row_list(pools.view(), std::vector<std::uint32_t>{0, 9}).ok());
  written.insert(9);
  ASSERT_TRUE(r.compute_links(pools.view(), std::vector<std::uint32_t>{9 * G}).ok());
  auto before = r.read_links();
  ASSERT_TRUE(before.ok());
  const std::vector<std::uint32_t> group_links(before->begin() + 9 * G * 6,
                                               before->begin() + 9 * G * 6 + 6);
  EXPECT_NE(group_links, std::vector<std::uint32_t>(6, L::kNoCell))
      << "root 0's children have a neighbour across some face (root 1's cell)";
  ASSERT_TRUE(r.upload_row_list(pools.view(), std::vector<std::uint32_t>{9}).ok());
  auto after = r.read_links();
  ASSERT_TRUE(after.ok());
  EXPECT_EQ(std::vector<std::uint32_t>(after->begin() + 9 * G * 6, after->begin() + 9 * G * 6 + 6),
            group_links);

  // The incremental growth: rows written during it and before it are carried over; the rows it
  // adds are not written.
  const std::uint64_t old_rows = r.capacity_cells() / W;
  ASSERT_TRUE(r.begin_growth(r.capacity_cells() + 1).ok());
  ASSERT_TRUE(r.growth_step(1).ok());
  ASSERT_TRUE(r.upload_row_list(pools.view(), std::vector<std::uint32_t>{0, 12}).ok());
  written.insert(12);
  for (;;) {
    auto done = r.growth_step(3);
    ASSERT_TRUE(done.ok()) << done.error().message;
    if (*done) break;
  }
  EXPECT_GT(r.capacity_cells() / W, old_rows);
  expect_rows("after the incremental growth");
  expect_no_links({10, 11, 12, 20, 30}, "after the incremental growth");
  const std::uint32_t past = static_cast<std::uint32_t>(old_rows + 1);
  resize((past + 1) * W);
  ASSERT_TRUE(r.upload_row_list(pools.view(), std::vector<std::uint32_t>{past}).ok());
  written.insert(past);
  expect_rows("after a row past the old height");
  expect_no_links({past}, "a row past the old height");
  auto got = r.read_uploaded();
  ASSERT_TRUE(got.ok());
  for (const std::uint32_t row : written) {
    for (std::uint64_t c = row * W; c < (row + 1) * W && c < pools.fc.size(); ++c) {
      ASSERT_EQ(got->first_child[c], pools.fc[c]) << "cell " << c;
      ASSERT_EQ(got->colour[c], pools.col[c]) << "cell " << c;
    }
  }
}

TEST(GpuReplicaUpload, StagedRowsLandExactlyAsRowsCopiedFromThePools) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  namespace L = gpu_layout;
  constexpr std::uint64_t W = 1u << kNarrowWidthLog2;
  GpuReplicaConfig cfg = narrow_config(4);
  auto copied = GpuReplica::create(*ctx, cfg);
  auto staged = GpuReplica::create(*ctx, cfg);
  ASSERT_TRUE(copied && staged);
  std::mt19937_64 rng(2026);
  Snapshot pools;  // fc, col, par, dep, links
  pools.edge_m = cfg.edge_m;
  auto& first_child = pools.fc;
  auto& colour = pools.col;
  auto& group_parent = pools.par;
  auto& flags = pools.dep;
  auto resize = [&](std::uint64_t cells) {
    first_child.resize(cells, L::kNoCell);
    colour.resize(cells, 0u);
    group_parent.resize(cells / 8, L::kNoCell);
    flags.resize(cells / 8, static_cast<std::uint8_t>(L::kGroupFreeFlag));
    pools.links.resize(cells / 8 * 6, L::kNoCell);
  };
  auto view = [&] { return pools.view(); };
  // Row r as stage_rows takes it: W cells and W/8 groups, never-used values past the pools.
  struct Row {
    std::vector<std::uint32_t> fc, col, gp;
    std::vector<std::uint8_t> df;
  };
  auto row_copy = [&](std::uint32_t r) {
    Row out{std::vector<std::uint32_t>(W, L::kNoCell), std::vector<std::uint32_t>(W, 0u),
            std::vector<std::uint32_t>(W / 8, L::kNoCell),
            std::vector<std::uint8_t>(W / 8, static_cast<std::uint8_t>(L::kGroupFreeFlag))};
    for (std::uint64_t i = 0; i < W && r * W + i < first_child.size(); ++i) {
      out.fc[i] = first_child[r * W + i];
      out.col[i] = colour[r * W + i];
      if (i % 8 == 0) {
        out.gp[i / 8] = group_parent[(r * W + i) / 8];
        out.df[i / 8] = flags[(r * W + i) / 8];
      }
    }
    return out;
  };
  auto sources = [&](const std::vector<Row>& rows, const std::vector<std::uint32_t>& at) {
    std::vector<GpuReplica::RowSource> out;
    for (std::size_t i = 0; i < rows.size(); ++i)
      out.push_back({at[i], rows[i].fc, rows[i].col, rows[i].gp, rows[i].df});
    return out;
  };
  // Rows the test uploaded, and the rows of the first textures: written. Rows a growth added
  // and nothing uploaded since hold unspecified values (GpuReplica's header), so the textures
  // are compared with the pools on the written rows, and the replica must say exactly which
  // rows those are.
  std::set<std::uint32_t> uploaded = {0, 1, 2, 3};
  auto expect_textures_hold_pools = [&](const GpuReplica& replica, const std::string& when) {
    auto got = replica.read_uploaded();
    ASSERT_TRUE(got.ok()) << got.error().message;
    const std::uint64_t cells = first_child.size();
    for (std::uint32_t r = 0; r < replica.capacity_cells() / W; ++r) {
      ASSERT_EQ(replica.row_written(r), uploaded.contains(r)) << when << ", row " << r;
      if (!uploaded.contains(r)) continue;
      for (std::uint64_t c = r * W; c < std::min<std::uint64_t>((r + 1) * W, cells); ++c) {
        ASSERT_EQ(got->first_child[c], first_child[c]) << when << ", cell " << c;
        ASSERT_EQ(got->colour[c], colour[c]) << when << ", cell " << c;
        if (c % 8 == 0) {
          ASSERT_EQ(got->group_parent[c / 8], group_parent[c / 8]) << when << ", cell " << c;
          ASSERT_EQ(got->group_depth_flags[c / 8], flags[c / 8]) << when << ", cell " << c;
        }
      }
    }
  };

  resize(2 * W);
  ASSERT_TRUE((*copied)->upload_all(view()).ok());
  ASSERT_TRUE((*staged)->upload_all(view()).ok());
  for (int round = 0; round < 16; ++round) {
    const std::string when = "round " + std::to_string(round);
    if (rng() % 3 == 0) resize(first_child.size() + W / 2 * (1 + rng() % 5));  // grows the textures
    const std::uint64_t cells = first_child.size();
    const std::uint32_t row_count = static_cast<std::uint32_t>((cells + W - 1) / W);
    std::vector<std::uint32_t> rows;
    for (std::uint32_t k = 0, n = 1 + static_cast<std::uint32_t>(rng() % row_count); k < n; ++k)
      rows.push_back(static_cast<std::uint32_t>(rng() % row_count));
    std::ranges::sort(rows);
    rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
    for (std::uint32_t r : rows) {
      for (std::uint64_t c = r * W; c < std::min<std::uint64_t>((r + 1) * W, cells); ++c) {
        first_child[c] = static_cast<std::uint32_t>(rng());
        colour[c] = static_cast<std::uint32_t>(rng());
        if (c % 8 == 0) {
          group_parent[c / 8] = static_cast<std::uint32_t>(rng());
          flags[c / 8] = static_cast<std::uint8_t>(rng());
        }
      }
    }
    // A row past the pools now and then (never-used values both ways; read back only once the
    // pools reach it).
    if (rng() % 2 == 0) rows.push_back(row_count);
    ASSERT_TRUE((*copied)->upload_row_list(view(), rows).ok()) << when;
    for (std::uint32_t r : rows)
      if (r < (*copied)->capacity_cells() / W) uploaded.insert(r);
    std::vector<Row> copies;
    for (std::uint32_t r : rows) copies.push_back(row_copy(r));
    auto s = (*staged)->stage_rows(sources(copies, rows));
    ASSERT_TRUE(s.ok()) << s.error().message;
    ASSERT_TRUE((*staged)->upload_staged(view(), *s).ok()) << when;
    expect_textures_hold_pools(**copied, "copied, " + when);
    expect_textures_hold_pools(**staged, "staged, " + when);
    EXPECT_EQ((*staged)->cell_count(), cells);
  }
  EXPECT_GT((*staged)->generation(), 1u) << "the textures grew on the way";

  // Negative control: rows staged, then another upload (its rows unchanged) fills the staging
  // buffer: the stale staging is refused and the textures keep the pools.
  std::vector<std::uint32_t> rows = {0, 1};
  std::vector<Row> stale;
  for (std::uint32_t r : rows) {
    Row c = row_copy(r);
    std::ranges::fill(c.fc, 12345u);
    stale.push_back(std::move(c));
  }
  auto s = (*staged)->stage_rows(sources(stale, rows));
  ASSERT_TRUE(s.ok());
  ASSERT_TRUE((*staged)->upload_row_list(view(), std::vector<std::uint32_t>{2}).ok());
  auto refused = (*staged)->upload_staged(view(), *s);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(client_gpu::gpu_errc_of(refused.error()), client_gpu::GpuErrc::bad_argument);
  expect_textures_hold_pools(**staged, "after the refused stale staging");
  // The same staging, uploaded in its turn, does land (what the control would miss otherwise).
  auto fresh = (*staged)->stage_rows(sources(stale, rows));
  ASSERT_TRUE(fresh.ok());
  ASSERT_TRUE((*staged)->upload_staged(view(), *fresh).ok());
  auto got = (*staged)->read_uploaded();
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->first_child[0], 12345u);
  EXPECT_EQ(got->first_child[2 * W - 1], 12345u);
  EXPECT_EQ(got->first_child[2 * W], first_child[2 * W]);

  std::vector<std::uint32_t> backwards = {1, 0};
  std::vector<Row> two = {row_copy(1), row_copy(0)};
  auto unsorted = (*staged)->stage_rows(sources(two, backwards));
  ASSERT_FALSE(unsorted.ok());
  EXPECT_EQ(client_gpu::gpu_errc_of(unsorted.error()), client_gpu::GpuErrc::bad_argument);
  Row narrow = row_copy(0);
  narrow.fc.pop_back();
  std::vector<Row> one = {narrow};
  auto wrong_width = (*staged)->stage_rows(sources(one, std::vector<std::uint32_t>{0}));
  ASSERT_FALSE(wrong_width.ok());
  EXPECT_EQ(client_gpu::gpu_errc_of(wrong_width.error()), client_gpu::GpuErrc::bad_argument);
}

// The pin between the two languages for the ray casting parameter buffer (DcRayParamsBuffer,
// raycast_layout.h): all its fields are 32-bit, so in declaration order they are words 0..95 on
// both sides exactly when the layouts agree. GLSL echoes every field, read by name, into probes[k]
// and writes sentinel k into every field of a second struct (ray_params_probe.comp).
TEST(GpuLayout, RayParamsMatchCpp) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  using client_gpu::Buffer;
  using client_gpu::MemoryUse;
  namespace L = gpu_layout;
  constexpr std::size_t kWords = sizeof(L::DcRayParamsBuffer) / 4;
  static_assert(kWords == 96);
  const VkBufferUsageFlags storage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
  auto given = Buffer::create(*ctx, sizeof(L::DcRayParamsBuffer), storage, MemoryUse::upload);
  auto written = Buffer::create(*ctx, sizeof(L::DcRayParamsBuffer), storage, MemoryUse::readback);
  auto probes = Buffer::create(*ctx, kWords * 4, storage, MemoryUse::readback);
  ASSERT_TRUE(given && written && probes);
  std::uint32_t words[kWords];
  for (std::uint32_t k = 0; k < kWords; ++k) words[k] = 0x5A000000u | (k << 8) | k;
  std::memcpy(given->mapped(), words, sizeof words);
  std::memset(written->mapped(), 0xCD, sizeof words);
  std::memset(probes->mapped(), 0xCD, sizeof words);
  ASSERT_TRUE(given->flush() && written->flush() && probes->flush());
  auto pipe = client_gpu::ComputePipeline::create(
      *ctx, {.name = "ray_params_probe",
             .spirv = deepcanvas_spv_ray_params_probe,
             .bindings = {{0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER},
                          {1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER},
                          {2, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER}}});
  ASSERT_TRUE(pipe) << pipe.error().message;
  auto pool = client_gpu::DescriptorPool::create(*ctx, *pipe, 1);
  ASSERT_TRUE(pool);
  auto set = pool->allocate(*pipe);
  ASSERT_TRUE(set);
  client_gpu::DescriptorWriter()
      .buffer(0, *given)
      .buffer(1, *written)
      .buffer(2, *probes)
      .update(*ctx, *set);
  auto run = ctx->submit_once(ctx->compute_queue(), [&](VkCommandBuffer cb) {
    pipe->bind(cb, *set);
    vkCmdDispatch(cb, 1, 1, 1);
    VkMemoryBarrier b{};
    b.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
    b.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT;
    b.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0, 1,
                         &b, 0, nullptr, 0, nullptr);
  });
  ASSERT_TRUE(run) << run.error().message;
  ASSERT_TRUE(written->invalidate() && probes->invalidate());
  std::uint32_t echoed[kWords], sentinels[kWords];
  std::memcpy(echoed, probes->mapped(), sizeof echoed);
  std::memcpy(sentinels, written->mapped(), sizeof sentinels);
  for (std::uint32_t k = 0; k < kWords; ++k) {
    EXPECT_EQ(echoed[k], words[k]) << "GLSL field " << k << " reads another C++ word";
    EXPECT_EQ(sentinels[k], 0xA5000000u | k) << "GLSL field " << k << " lands elsewhere in C++";
  }
  // And the C++ names sit at the words the GLSL declaration order gives them.
  L::DcRayParamsBuffer named{};
  std::memcpy(&named, words, sizeof named);
  EXPECT_EQ(named.p.origin_cell, words[3]);
  EXPECT_EQ(named.p.max_steps, words[29]);
  EXPECT_EQ(named.p.skip_empty, words[30]);
  EXPECT_EQ(named.p.cull, words[35]);
  EXPECT_EQ(named.p.cull_count, words[39]);
  EXPECT_EQ(named.more_boxes[0].reserved0, words[43]);
  EXPECT_EQ(named.more_boxes[6].reserved1, words[95]);
}

// GPU image vs the CPU reference (double): max channel difference <= 2/255.
int max_rgba8_diff(const std::vector<std::uint8_t>& a, const std::vector<std::uint8_t>& b) {
  EXPECT_EQ(a.size(), b.size());
  int m = 0;
  for (std::size_t i = 0; i < std::min(a.size(), b.size()); ++i) {
    m = std::max(m, std::abs(int{a[i]} - int{b[i]}));
  }
  return m;
}

// The raycaster's last frame as bytes (r, g, b, a per pixel); empty if reading it back failed.
std::vector<std::uint8_t> last_frame_rgba8(const GpuRaycaster& raycaster) {
  auto px = raycaster.read_pixels();
  EXPECT_TRUE(px.ok());
  if (!px.ok()) return {};
  std::vector<std::uint8_t> out(px->size() * 4);
  std::memcpy(out.data(), px->data(), out.size());  // little-endian: r is the low byte
  return out;
}

struct GpuScene {
  std::unique_ptr<GpuReplica> replica;
  std::unique_ptr<GpuRaycaster> raycaster;
};

GpuScene upload_scene(client_gpu::Context& ctx, const Octree& tree) {
  GpuScene s;
  s.replica = make_replica(ctx, tree);
  if (!s.replica) return s;
  const PoolView pools = pool_view_of(tree);
  EXPECT_TRUE(s.replica->upload_all(pools).ok());
  EXPECT_TRUE(s.replica->compute_all_links(pools).ok());
  auto rc = GpuRaycaster::create(*s.replica);
  EXPECT_TRUE(rc.ok()) << (rc.ok() ? "" : rc.error().message);
  if (rc.ok()) s.raycaster = std::move(rc).value();
  return s;
}

// The GPU image (with `opt`, content cull included when set) against the double-precision
// reference without the cull: max channel difference in 8-bit steps.
int gpu_vs_reference(GpuScene& s, const Octree& tree, const Camera& cam, RenderOptions opt,
                     std::vector<std::uint8_t>* gpu_out = nullptr) {
  const PoolView pools = pool_view_of(tree);
  auto origin = client_core::make_ray_origin(pools, cam.position());
  EXPECT_TRUE(origin.ok());
  auto gpu = s.raycaster->render_rgba8(cam, *origin, opt);
  EXPECT_TRUE(gpu.ok()) << (gpu.ok() ? "" : gpu.error().message);
  opt.content_bounds.reset();
  opt.content_boxes.reset();
  auto cpu = client_core::render_reference(pools, cam, opt);
  EXPECT_TRUE(cpu.ok());
  if (!gpu.ok() || !cpu.ok()) return 256;
  if (gpu_out) *gpu_out = *gpu;
  // Not a trivial picture: some pixel sees paint (alpha above 1/4).
  int max_alpha = 0;
  for (std::size_t i = 3; i < gpu->size(); i += 4) max_alpha = std::max(max_alpha, int{(*gpu)[i]});
  EXPECT_GT(max_alpha, 64);
  const int diff = max_rgba8_diff(*gpu, cpu->to_rgba8());
  std::printf("gpu vs reference: max channel difference %d/255 (%dx%d)\n", diff, cam.width(),
              cam.height());
  return diff;
}

client_core::DAabb painted_box(const Octree& tree) {
  auto b = client_core::painted_bounds(pool_view_of(tree));
  EXPECT_TRUE(b.ok() && b->has_value());
  return b.ok() && b->has_value() ? **b : client_core::DAabb{};
}

Camera scene_camera(std::mt19937_64& rng, bool inside, std::uint32_t w, std::uint32_t h) {
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  for (;;) {
    const double reach = inside ? 19000.0 : 50000.0;
    DVec3 eye{u(rng) * reach, u(rng) * reach, u(rng) * reach};
    if (!inside && std::max({std::abs(eye.x), std::abs(eye.y), std::abs(eye.z)}) <= 10000) {
      continue;
    }
    auto cam =
        Camera::look_at(eye, {u(rng) * 8000, u(rng) * 8000, u(rng) * 8000}, {0, 0, 1}, 60, w, h);
    if (cam.ok()) return *cam;
  }
}

TEST(GpuRender, MatchesReferenceOnRandomScenes) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  std::mt19937_64 rng(17);
  for (std::uint64_t seed = 1; seed <= 3; ++seed) {
    auto tree = random_tree(seed, 300, 9);
    GpuScene s = upload_scene(*ctx, *tree);
    ASSERT_TRUE(s.raycaster);
    for (int k = 0; k < 3; ++k) {
      const Camera cam = scene_camera(rng, k != 2, 64, 48);
      RenderOptions opt;
      opt.background = {0.2, 0.25, 0.3};
      EXPECT_LE(gpu_vs_reference(s, *tree, cam, opt), 2) << "seed " << seed << " camera " << k;
      opt.content_bounds = painted_box(*tree);
      EXPECT_LE(gpu_vs_reference(s, *tree, cam, opt), 2) << "culled, seed " << seed;
    }
  }
}

// RenderOptions::content_empty on the GPU (DcRayParams::cull = 2): a canvas with no painted
// leaf gives the reference's image (background), bit for bit, inside and outside the canvas.
TEST(GpuRender, EmptyCanvasWithContentEmptyIsTheReferenceBackground) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto tree = random_tree(4, 300, 9);
  for (std::uint32_t c = 0; c < tree->high_water_cells(); ++c)
    if (tree->is_live(c)) tree->set_colour(c, 0);
  GpuScene s = upload_scene(*ctx, *tree);
  ASSERT_TRUE(s.raycaster);
  const PoolView pools = pool_view_of(*tree);
  std::mt19937_64 rng(4);
  for (int k = 0; k < 3; ++k) {
    const Camera cam = scene_camera(rng, k != 2, 48, 32);
    auto origin = client_core::make_ray_origin(pools, cam.position());
    ASSERT_TRUE(origin.ok());
    RenderOptions opt;
    opt.background = {0.2, 0.25, 0.3};
    auto cpu = client_core::render_reference(pools, cam, opt);
    ASSERT_TRUE(cpu.ok());
    opt.content_empty = true;
    auto gpu = s.raycaster->render_rgba8(cam, *origin, opt);
    ASSERT_TRUE(gpu.ok()) << gpu.error().message;
    EXPECT_EQ(*gpu, cpu->to_rgba8()) << "camera " << k;
  }
}

TEST(GpuRender, MatchesReferenceOnMultiScaleScene) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  MultiScaleScene scene = multiscale_scene(4, 64, 48);
  ASSERT_TRUE(scene.tree);
  GpuScene s = upload_scene(*ctx, *scene.tree);
  ASSERT_TRUE(s.raycaster);
  for (const Camera* cam : {&scene.wide, &scene.close}) {
    EXPECT_LE(gpu_vs_reference(s, *scene.tree, *cam, {}), 2);
    RenderOptions culled;
    culled.content_bounds = painted_box(*scene.tree);
    EXPECT_LE(gpu_vs_reference(s, *scene.tree, *cam, culled), 2);
  }
}

// Content boxes for the view (RenderOptions::content_boxes: several boxes, DcRayParamsBuffer):
// the GPU image within 2/255 of the reference without any cull, on a canvas painted in separate
// clusters (from cameras that see several of them, so that rays test several boxes) and on the
// multi-scale scene.
TEST(GpuRender, MatchesReferenceWithContentBoxes) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto tree = clustered_tree(2, 6);
  GpuScene s = upload_scene(*ctx, *tree);
  ASSERT_TRUE(s.raycaster);
  const PoolView pools = pool_view_of(*tree);
  const client_core::DAabb bounds = painted_box(*tree);
  std::vector<Camera> cams;
  cams.push_back(*Camera::frame_box(bounds, 64, 48));
  const DVec3 c = (bounds.min + bounds.max) * 0.5;
  cams.push_back(*Camera::look_at(c + (bounds.max - c) * 1.5, c, {0, 0, 1}, 70, 64, 48));
  cams.push_back(*Camera::look_at(c + (bounds.min - c) * 0.4, c + (bounds.max - c) * 0.3, {0, 0, 1},
                                  90, 64, 48));
  std::size_t most = 0;
  for (std::size_t k = 0; k < cams.size(); ++k) {
    RenderOptions opt;
    opt.background = {0.1, 0.15, 0.2};
    opt.content_bounds = bounds;
    opt.content_boxes = client_core::content_boxes_for_view(pools, cams[k], bounds);
    most = std::max(most, opt.content_boxes->count);
    EXPECT_LE(gpu_vs_reference(s, *tree, cams[k], opt), 2)
        << "camera " << k << ", " << opt.content_boxes->count << " boxes";
  }
  EXPECT_GT(most, 1u) << "no camera saw separate clusters: one box tells nothing new";
  MultiScaleScene scene = multiscale_scene(4, 64, 48);
  ASSERT_TRUE(scene.tree);
  scene.tree->refresh_interior_colours();
  GpuScene ms = upload_scene(*ctx, *scene.tree);
  ASSERT_TRUE(ms.raycaster);
  const PoolView ms_pools = pool_view_of(*scene.tree);
  for (const Camera* cam : {&scene.wide, &scene.close}) {
    RenderOptions opt;
    opt.content_bounds = painted_box(*scene.tree);
    opt.content_boxes = client_core::content_boxes_for_view(ms_pools, *cam, *opt.content_bounds);
    EXPECT_LE(gpu_vs_reference(ms, *scene.tree, *cam, opt), 2);
  }
}

TEST(GpuRender, PrecisionSceneMatchesReference) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  PrecisionSceneData scene = precision_scene(64, 48);
  ASSERT_TRUE(scene.tree);
  GpuScene s = upload_scene(*ctx, *scene.tree);
  ASSERT_TRUE(s.raycaster);
  RenderOptions opt;
  opt.background = {0.2, 0.3, 0.4};
  EXPECT_LE(gpu_vs_reference(s, *scene.tree, scene.camera, opt), 2);
  opt.content_bounds = painted_box(*scene.tree);
  EXPECT_LE(gpu_vs_reference(s, *scene.tree, scene.camera, opt), 2);
}

// Real paintings (A-Painter files, painted by the server's Painter at scale 1): the GPU image
// within 2/255 of the reference, with and without the content cull, from a camera framing the
// painting, one inside it and one 50 m away zoomed in. Small images keep the suite fast.
// (Not from outside the canvas zoomed onto the painting's millimetre detail: there the float
// ray direction alone, 6e-8 rad, moves a ray by ~1 mm at 15 km, so sub-pixel strokes land in
// different pixels; a float limit of any float ray caster, not of the cell-local frame.)
TEST(GpuRender, MatchesReferenceOnPaintings) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  for (const char* file : {"demo.apa", "dancer.apa"}) {
    DEEPCANVAS_REQUIRE_PAINTING(path, file);
    PaintingScene scene = painting_scene(path, 1000);
    ASSERT_TRUE(scene.tree);
    GpuScene s = upload_scene(*ctx, *scene.tree);
    ASSERT_TRUE(s.raycaster);
    const client_core::DAabb& b = scene.bounds;
    const DVec3 centre = (b.min + b.max) * 0.5;
    std::vector<Camera> cams;
    cams.push_back(*Camera::frame_box(b, 96, 54));
    cams.push_back(*Camera::look_at(centre + (b.min - centre) * 0.3,
                                    centre + (b.max - centre) * 0.5, {0, 0, 1}, 80, 64, 48));
    // From 50 m with a 2 degree field: long rays through empty space to the detail.
    cams.push_back(*Camera::look_at(centre + DVec3{-40, 30, 15}, centre, {0, 0, 1}, 2, 64, 48));
    for (std::size_t k = 0; k < cams.size(); ++k) {
      RenderOptions opt;
      opt.background = {0.1, 0.1, 0.12};
      EXPECT_LE(gpu_vs_reference(s, *scene.tree, cams[k], opt), 2) << file << " camera " << k;
      opt.content_bounds = b;
      EXPECT_LE(gpu_vs_reference(s, *scene.tree, cams[k], opt), 2)
          << file << " camera " << k << ", culled";
    }
  }
}

// Headset stereo: both eyes of an artist's pose, each within 2/255 of the reference renderer
// from its own eye (so the pair's disparity is the reference's), and the two images differ by
// that disparity. At room scale on a real painting (eyes 63 mm apart, a 1.5 m world) and at
// cell scale in the precision scene (0.3 mm cells 10 km from the centre: eyes 63 um apart at
// world scale 1e-3, and 63 nm apart at 1e-6, where the eyes see the same picture).
int differing_pixels(const std::vector<std::uint8_t>& a, const std::vector<std::uint8_t>& b) {
  int n = 0;
  for (std::size_t i = 0; i + 3 < std::min(a.size(), b.size()); i += 4)
    n += std::max({std::abs(a[i] - b[i]), std::abs(a[i + 1] - b[i + 1]), std::abs(a[i + 2] - b[i + 2])}) > 8;
  return n;
}

TEST(GpuStereo, BothEyesMatchTheReferenceAtRoomAndCellScale) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  client_core::EyeSetup eyes;
  eyes.width = 64;
  eyes.height = 48;
  eyes.vfov_deg = 90;
  struct Case {
    const Octree* tree;
    DVec3 look_at;
    double world_scale, distance_m;  // canvas metres from the eyes to `look_at`
    bool expect_disparity;
  };
  PrecisionSceneData precision = precision_scene(8, 8);
  ASSERT_TRUE(precision.tree);
  const DVec3 cell_centre = precision.camera.position();
  std::vector<Case> cases = {
      {precision.tree.get(), cell_centre, 1e-3, 0.6e-3, true},
      {precision.tree.get(), cell_centre, 1e-6, 0.6e-3, false},
  };
  std::unique_ptr<Octree> painting;
  if (const char* dir = std::getenv("DEEPCANVAS_PAINTINGS")) {
    PaintingScene scene = painting_scene(std::string(dir) + "/demo.apa", 1000);
    if (scene.tree) {
      const auto& b = scene.bounds;
      const DVec3 size = b.max - b.min;
      const double scale = std::max({size.x, size.y, size.z}) / 1.5;
      painting = std::move(scene.tree);
      cases.push_back({painting.get(), (b.min + b.max) * 0.5, scale, 1.2 * scale, true});
    }
  }
  for (const Case& c : cases) {
    GpuScene s = upload_scene(*ctx, *c.tree);
    ASSERT_TRUE(s.raycaster);
    // The head 1.6 m up in the room, looking down -z at the point, `distance_m` away.
    client_core::ArtistPose pose;
    pose.head = {0, 1.6, 0};
    pose.world_scale = c.world_scale;
    pose.world_origin = c.look_at + DVec3{0, 0, c.distance_m} - pose.head * c.world_scale;
    auto cams = client_core::eye_cameras(pose, eyes);
    ASSERT_TRUE(cams) << cams.error().message;
    std::vector<std::uint8_t> img[2];
    for (int e = 0; e < 2; ++e) {
      RenderOptions opt;
      opt.background = {0.1, 0.1, 0.12};
      EXPECT_LE(gpu_vs_reference(s, *c.tree, (*cams)[static_cast<std::size_t>(e)], opt, &img[e]), 2)
          << "world scale " << c.world_scale << " eye " << e;
    }
    const int differ = differing_pixels(img[0], img[1]);
    std::printf("world scale %g: eyes %.3g m apart, %d of %u pixels differ between them\n",
                c.world_scale, eyes.ipd_m * c.world_scale, differ, eyes.width * eyes.height);
    if (c.expect_disparity) {
      EXPECT_GT(differ, 20) << "world scale " << c.world_scale;
    } else {
      EXPECT_LT(differ, 10) << "world scale " << c.world_scale;
    }
  }
}

// One painting at 1000x next to one at 0.001x (six orders of magnitude apart on one canvas):
// cameras framing both, the tiny one close up, and inside the big one.
TEST(GpuRender, MatchesReferenceOnMultiScalePaintings) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  DEEPCANVAS_REQUIRE_PAINTING(big, "demo.apa");
  DEEPCANVAS_REQUIRE_PAINTING(tiny, "palmtree.apa");
  MultiScalePaintingScene scene = multiscale_painting_scene(big, tiny, 64, 36);
  ASSERT_TRUE(scene.tree);
  ASSERT_EQ(scene.cameras.size(), 3u);
  GpuScene s = upload_scene(*ctx, *scene.tree);
  ASSERT_TRUE(s.raycaster);
  for (std::size_t k = 0; k < scene.cameras.size(); ++k) {
    RenderOptions opt;
    opt.background = {0.2, 0.2, 0.25};
    EXPECT_LE(gpu_vs_reference(s, *scene.tree, scene.cameras[k], opt), 2) << "camera " << k;
    opt.content_bounds = scene.bounds;
    EXPECT_LE(gpu_vs_reference(s, *scene.tree, scene.cameras[k], opt), 2)
        << "camera " << k << ", culled";
  }
}

// G3 stepping and descent from the root produce the same pixels on the GPU too; rendering in
// row bands gives the same image as one dispatch.
TEST(GpuRender, DescentAndBandsGiveTheSameImage) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto tree = random_tree(5, 300, 9);
  GpuScene s = upload_scene(*ctx, *tree);
  ASSERT_TRUE(s.raycaster);
  std::mt19937_64 rng(3);
  const Camera cam = scene_camera(rng, true, 61, 37);
  auto origin = client_core::make_ray_origin(pool_view_of(*tree), cam.position());
  ASSERT_TRUE(origin.ok());
  RenderOptions opt;
  auto a = s.raycaster->render_rgba8(cam, *origin, opt);
  ASSERT_TRUE(a.ok());
  opt.stepping = Stepping::descent;
  auto b = s.raycaster->render_rgba8(cam, *origin, opt);
  ASSERT_TRUE(b.ok());
  EXPECT_EQ(*a, *b);
  opt.stepping = Stepping::g3;
  ASSERT_TRUE(s.raycaster->set_frame(cam, *origin, opt).ok());
  ASSERT_TRUE(s.raycaster->render(5).ok());
  EXPECT_EQ(*a, last_frame_rgba8(*s.raycaster));
}

// Paints the raycaster's whole output with a frame of another background and an earlier
// termination than `opt`: a pixel the next frame skips keeps a colour far from the reference.
void paint_over(GpuRaycaster& rc, const Camera& cam, const client_core::RayOrigin& origin,
                const RenderOptions& opt) {
  RenderOptions other = opt;
  other.background = {1.0, 0.0, 1.0};
  other.termination_transmittance = 0.5;
  ASSERT_TRUE(rc.set_frame(cam, origin, other).ok());
  ASSERT_TRUE(rc.render().ok());
}

// Every pixel of every band is rendered, for image sizes that are not multiples of the 8x8
// workgroup tile, single rows and columns, a large frame, any number of bands, and the three
// loop budgets of the work-item scheduler (raycast.comp "Scheduling", "Loop limiter"): the
// default, 1 (every subgroup takes one item) and none (on lavapipe subgroups then take items
// until the loop limiter cuts them short, and the retry pass must render what they gave up;
// the test checks that it had to). Before each banded frame the whole output is painted by a
// frame with another background and an earlier termination, so a pixel the banded frame
// skipped keeps that colour and differs from the CPU reference by far more than 2/255. (A
// subgroup whose item loop ends early, as lavapipe's loop limiter makes it without the loop
// budget and the retry pass, leaves whole runs of pixels unrendered: this test catches it.)
TEST(GpuRender, EveryPixelOfEveryBandIsRendered) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto tree = random_tree(7, 300, 9);
  GpuScene s = upload_scene(*ctx, *tree);
  ASSERT_TRUE(s.raycaster);
  const PoolView pools = pool_view_of(*tree);
  std::mt19937_64 rng(11);
  const std::pair<std::uint32_t, std::uint32_t> sizes[] = {{1, 1},    {7, 1},  {1, 9},    {61, 37},
                                                           {130, 17}, {8, 64}, {960, 540}};
  for (const auto& [w, h] : sizes) {
    const Camera cam = scene_camera(rng, true, w, h);
    auto origin = client_core::make_ray_origin(pools, cam.position());
    ASSERT_TRUE(origin.ok());
    RenderOptions opt;
    opt.background = {0.1, 0.7, 0.2};
    auto cpu = client_core::render_reference(pools, cam, opt);
    ASSERT_TRUE(cpu.ok());
    const std::vector<std::uint8_t> want = cpu->to_rgba8();
    for (std::uint32_t budget : {0u, 1u, ~0u}) {
      s.raycaster->set_loop_budget(budget);
      const std::uint64_t retried_before = s.raycaster->retried_items();
      for (std::uint32_t bands : {1u, 2u, 3u, h}) {
        paint_over(*s.raycaster, cam, *origin, opt);
        ASSERT_TRUE(s.raycaster->set_frame(cam, *origin, opt).ok());
        ASSERT_TRUE(s.raycaster->render(bands).ok());
        EXPECT_LE(max_rgba8_diff(last_frame_rgba8(*s.raycaster), want), 2)
            << w << "x" << h << ", " << bands << " bands, loop budget " << budget;
      }
      // Without a budget, lavapipe's limiter must have cut subgroups short at 960x540 (a
      // subgroup then takes far more items than 65535 loop iterations allow).
      if (budget == ~0u && w == 960 && ctx->info().type == VK_PHYSICAL_DEVICE_TYPE_CPU) {
        EXPECT_GT(s.raycaster->retried_items(), retried_before) << "the retry pass never ran";
      }
    }
    s.raycaster->set_loop_budget(0);
  }
}

// Several views in one submission (GpuRaycaster::render_together, a headset's two eyes) give
// each view the pixels of the CPU reference for its own camera: views of different sizes, so
// of different dispatch counts (960x540 takes several), and the three loop budgets, so retry
// passes of several views are recorded side by side. Each view's output is painted first by a
// frame with another background, so a pixel the shared submission skipped or took from another
// view differs by far more than 2/255.
TEST(GpuRender, ViewsRenderedTogetherEachMatchTheReference) {
  client_gpu::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto tree = random_tree(7, 300, 9);
  GpuScene s = upload_scene(*ctx, *tree);
  ASSERT_TRUE(s.raycaster);
  const PoolView pools = pool_view_of(*tree);
  std::mt19937_64 rng(29);
  const std::pair<std::uint32_t, std::uint32_t> sizes[] = {{61, 37}, {960, 540}, {7, 1}};
  std::vector<std::unique_ptr<GpuRaycaster>> views;
  std::vector<GpuRaycaster*> raw;
  std::vector<Camera> cams;
  std::vector<std::vector<std::uint8_t>> want;
  RenderOptions opt;
  opt.background = {0.1, 0.7, 0.2};
  for (const auto& [w, h] : sizes) {
    auto rc = GpuRaycaster::create(*s.replica);
    ASSERT_TRUE(rc.ok());
    views.push_back(std::move(*rc));
    raw.push_back(views.back().get());
    cams.push_back(scene_camera(rng, true, w, h));
    auto cpu = client_core::render_reference(pools, cams.back(), opt);
    ASSERT_TRUE(cpu.ok());
    want.push_back(cpu->to_rgba8());
  }
  for (std::uint32_t budget : {0u, 1u, ~0u}) {
    for (std::size_t v = 0; v < views.size(); ++v) {
      auto origin = client_core::make_ray_origin(pools, cams[v].position());
      ASSERT_TRUE(origin.ok());
      paint_over(*views[v], cams[v], *origin, opt);
      ASSERT_TRUE(views[v]->set_frame(cams[v], *origin, opt).ok());
      views[v]->set_loop_budget(budget);
    }
    client_gpu::FrameTiming timing;
    ASSERT_TRUE(GpuRaycaster::render_together(raw, &timing).ok());
    EXPECT_GT(timing.wall_ms, 0);
    for (std::size_t v = 0; v < views.size(); ++v)
      EXPECT_LE(max_rgba8_diff(last_frame_rgba8(*views[v]), want[v]), 2)
          << "view " << v << " (" << sizes[v].first << "x" << sizes[v].second
          << "), loop budget " << budget;
  }
}

}  // namespace
}  // namespace deepcanvas::render_test
