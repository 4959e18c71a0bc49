// The pool textures of pool_layout.h on a real device: a random octree (refinements focused
// around a few points, so depths differ by many levels side by side, plus coarsenings that free
// groups and reuse their indices) is uploaded block by block, in shuffled order, into the five
// textures exactly as the layout says; a compute shader derives every cell's six face
// neighbours from them (root arithmetic, sibling arithmetic, group links + first_child) and the
// test compares every live cell with a brute-force coordinate search.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <cstring>
#include <random>
#include <span>
#include <unordered_map>
#include <vector>

#include "deepcanvas/client_gpu/compute.hpp"
#include "deepcanvas/client_gpu/memory.hpp"
#include "deepcanvas/shaders/face_neighbours.spv.h"
#include "gpu_test_support.hpp"
#include "pool_layout.h"

namespace deepcanvas::client_gpu {
namespace {

namespace L = gpu_layout;

struct GpuPush {
  L::DcPoolInfo pool;
  L::DcDispatchRange range;
};

struct Coord {
  std::uint32_t d = 0, x = 0, y = 0, z = 0;
};

// A brute-force octree: pools in the layout's order plus every cell's integer coordinates and a
// coordinate -> cell map. Not balanced (the link rule works without balance).
class TestTree {
 public:
  TestTree(std::uint32_t roots_per_axis, std::uint32_t max_depth, std::uint32_t seed)
      : n_(roots_per_axis), max_depth_(max_depth), rng_(seed) {
    const std::uint32_t roots = n_ * n_ * n_;
    for (std::uint32_t i = 0; i < roots; ++i) {
      const Coord c{0, i % n_, (i / n_) % n_, i / (n_ * n_)};
      add_cell(i, c);
    }
    for (std::uint32_t g = 0; g < roots / 8; ++g) {
      parent_.push_back(L::kNoCell);
      depth_flags_.push_back(0);
    }
  }

  std::uint32_t root_count() const { return n_ * n_ * n_; }
  std::uint32_t cell_count() const { return static_cast<std::uint32_t>(first_child_.size()); }
  bool live(std::uint32_t cell) const { return !L::dc_group_is_free(depth_flags_[cell >> 3]); }

  void random_workload(std::uint32_t target_cells) {
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::array<std::array<double, 3>, 6> foci{};
    for (auto& f : foci) f = {u(rng_), u(rng_), u(rng_)};
    while (cell_count() < target_cells) {
      const double r = u(rng_);
      if (r < 0.7) {
        const auto& f = foci[rng_() % foci.size()];
        // Jitter so the refined region is a neighbourhood, not a line.
        const double j = 0.02;
        refine_at(std::clamp(f[0] + (u(rng_) - 0.5) * j, 0.0, 0.999999),
                  std::clamp(f[1] + (u(rng_) - 0.5) * j, 0.0, 0.999999),
                  std::clamp(f[2] + (u(rng_) - 0.5) * j, 0.0, 0.999999));
      } else if (r < 0.9) {
        refine_at(u(rng_) * 0.999999, u(rng_) * 0.999999, u(rng_) * 0.999999);
      } else {
        coarsen_random();
      }
    }
    // Refinement reuses freed groups first; leave some free at the end so the pools hold dead
    // groups (free flag set, stale links) between live ones, as the server's do.
    for (std::uint32_t k = 0; k < target_cells / 2000; ++k) coarsen_random();
  }

  // The same-depth face neighbour, or the coarser leaf there; kNoCell at the boundary.
  std::uint32_t brute_neighbour(std::uint32_t cell, std::uint32_t face) const {
    const Coord c = coord_[cell];
    std::int64_t p[3] = {c.x, c.y, c.z};
    p[face >> 1] += (face & 1) ? 1 : -1;
    const std::int64_t extent = static_cast<std::int64_t>(n_) << c.d;
    for (auto v : p) {
      if (v < 0 || v >= extent) return L::kNoCell;
    }
    for (std::int64_t d = c.d; d >= 0; --d) {
      const std::uint32_t s = c.d - static_cast<std::uint32_t>(d);
      auto it = by_coord_.find(
          key({static_cast<std::uint32_t>(d), static_cast<std::uint32_t>(p[0] >> s),
               static_cast<std::uint32_t>(p[1] >> s), static_cast<std::uint32_t>(p[2] >> s)}));
      if (it != by_coord_.end()) return it->second;
    }
    return L::kNoCell;  // unreachable: roots cover the canvas
  }

  // Links of every live non-root group: its parent's brute-force neighbours. Layer-major.
  std::vector<std::uint32_t> links(std::uint32_t groups_padded) const {
    std::vector<std::uint32_t> out(static_cast<std::size_t>(groups_padded) * 6, L::kNoCell);
    for (std::uint32_t g = root_count() / 8; g < parent_.size(); ++g) {
      if (L::dc_group_is_free(depth_flags_[g])) continue;
      for (std::uint32_t f = 0; f < 6; ++f)
        out[f * groups_padded + g] = brute_neighbour(parent_[g], f);
    }
    return out;
  }

  const std::vector<std::uint32_t>& first_child() const { return first_child_; }
  const std::vector<std::uint8_t>& depth_flags() const { return depth_flags_; }

 private:
  // Coordinates need up to 26 bits each (roots_per_axis 4 at depth 24): a 128-bit key.
  struct Key {
    std::uint64_t hi, lo;
    bool operator==(const Key&) const = default;
  };
  struct KeyHash {
    std::size_t operator()(const Key& k) const noexcept {
      return std::hash<std::uint64_t>()(k.hi * 0x9E3779B97F4A7C15ull ^ k.lo);
    }
  };
  static Key key(const Coord& c) {
    return {(std::uint64_t{c.d} << 32) | c.x, (std::uint64_t{c.y} << 32) | c.z};
  }
  void add_cell(std::uint32_t i, const Coord& c) {
    if (i >= first_child_.size()) {
      first_child_.resize(i + 1, L::kNoCell);
      coord_.resize(i + 1);
    }
    first_child_[i] = L::kNoCell;
    coord_[i] = c;
    by_coord_[key(c)] = i;
  }

  void refine(std::uint32_t cell) {
    std::uint32_t g;
    if (!free_groups_.empty()) {
      // Reuse a random free group, so indices are not in depth order.
      const std::size_t k = rng_() % free_groups_.size();
      g = free_groups_[k];
      free_groups_[k] = free_groups_.back();
      free_groups_.pop_back();
    } else {
      g = static_cast<std::uint32_t>(parent_.size());
      parent_.push_back(L::kNoCell);
      depth_flags_.push_back(0);
    }
    const Coord c = coord_[cell];
    for (std::uint32_t s = 0; s < 8; ++s) {
      add_cell(8 * g + s,
               {c.d + 1, 2 * c.x + (s & 1), 2 * c.y + ((s >> 1) & 1), 2 * c.z + (s >> 2)});
    }
    parent_[g] = cell;
    depth_flags_[g] = static_cast<std::uint8_t>(c.d + 1);
    first_child_[cell] = 8 * g;
  }

  void refine_at(double fx, double fy, double fz) {
    const std::uint32_t rx = static_cast<std::uint32_t>(fx * n_),
                        ry = static_cast<std::uint32_t>(fy * n_),
                        rz = static_cast<std::uint32_t>(fz * n_);
    std::uint32_t cell = rx + n_ * (ry + n_ * rz);
    double lx = fx * n_ - rx, ly = fy * n_ - ry, lz = fz * n_ - rz;
    while (first_child_[cell] != L::kNoCell) {
      const std::uint32_t s = (lx >= 0.5 ? 1u : 0u) | (ly >= 0.5 ? 2u : 0u) | (lz >= 0.5 ? 4u : 0u);
      lx = lx * 2 - (s & 1);
      ly = ly * 2 - ((s >> 1) & 1);
      lz = lz * 2 - (s >> 2);
      cell = first_child_[cell] + s;
    }
    if (coord_[cell].d < max_depth_) refine(cell);
  }

  void coarsen_random() {
    for (int attempt = 0; attempt < 64; ++attempt) {
      const std::uint32_t cell = static_cast<std::uint32_t>(rng_() % first_child_.size());
      if (!live(cell) || first_child_[cell] == L::kNoCell) continue;
      const std::uint32_t fc = first_child_[cell];
      bool leaves = true;
      for (std::uint32_t s = 0; s < 8; ++s) leaves = leaves && first_child_[fc + s] == L::kNoCell;
      if (!leaves) continue;
      for (std::uint32_t s = 0; s < 8; ++s) by_coord_.erase(key(coord_[fc + s]));
      const std::uint32_t g = fc >> 3;
      depth_flags_[g] = static_cast<std::uint8_t>(L::kGroupFreeFlag | depth_flags_[g]);
      parent_[g] = L::kNoCell;
      first_child_[cell] = L::kNoCell;
      free_groups_.push_back(g);
      return;
    }
  }

  std::uint32_t n_, max_depth_;
  std::mt19937 rng_;
  std::vector<std::uint32_t> first_child_;
  std::vector<std::uint32_t> parent_;
  std::vector<std::uint8_t> depth_flags_;
  std::vector<Coord> coord_;
  std::vector<std::uint32_t> free_groups_;
  std::unordered_map<Key, std::uint32_t, KeyHash> by_coord_;
};

constexpr VkBufferUsageFlags kStorage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT |
                                        VK_BUFFER_USAGE_TRANSFER_SRC_BIT |
                                        VK_BUFFER_USAGE_TRANSFER_DST_BIT;

// Staging, arranged per block of B cells at `block_stride` bytes: the block's first_child
// words, then its group bytes, then its links layer-major (one copy region per texture).
void stage_blocks(const std::vector<std::uint32_t>& first_child,
                  const std::vector<std::uint8_t>& depth_flags,
                  const std::vector<std::uint32_t>& links, std::uint32_t B,
                  VkDeviceSize block_stride, std::uint8_t* base) {
  const std::uint32_t gpb = B / 8;  // groups per block
  const std::size_t groups_padded = depth_flags.size();
  const std::size_t blocks = first_child.size() / B;
  for (std::uint32_t b = 0; b < blocks; ++b) {
    std::uint8_t* p = base + b * block_stride;
    std::memcpy(p, &first_child[b * B], B * 4ull);
    std::memcpy(p + B * 4ull, &depth_flags[b * gpb], gpb);
    for (std::uint32_t f = 0; f < 6; ++f) {
      std::memcpy(p + B * 4ull + gpb + f * gpb * 4ull, &links[f * groups_padded + b * gpb],
                  gpb * 4ull);
    }
  }
}

struct NeighbourCheck {
  std::uint64_t checked = 0, coarser = 0, boundary = 0, mismatches = 0, free_cells = 0;
};

// The shader's output, 8 words per cell (the six face neighbours, then the group_depth and
// first_child texels it read), against the pools and the brute-force neighbours; the first ten
// mismatches are reported. The counts say which paths the tree exercised.
NeighbourCheck compare_with_brute_force(const TestTree& tree,
                                        const std::vector<std::uint32_t>& first_child,
                                        const std::vector<std::uint8_t>& depth_flags,
                                        std::span<const std::uint32_t> v) {
  NeighbourCheck r;
  const std::uint32_t cells = static_cast<std::uint32_t>(v.size() / 8);
  for (std::uint32_t c = 0; c < cells; ++c) {
    const std::uint32_t* o = &v[c * 8ull];
    if (o[7] != first_child[c] && r.mismatches++ < 10) {
      ADD_FAILURE() << "cell " << c << ": first_child texel " << o[7] << ", pool "
                    << first_child[c];
    }
    if (o[6] != depth_flags[c >> 3] && r.mismatches++ < 10) {
      ADD_FAILURE() << "cell " << c << ": group_depth texel " << o[6] << ", pool "
                    << unsigned{depth_flags[c >> 3]};
    }
    if (!tree.live(c)) {
      ++r.free_cells;
      continue;
    }
    for (std::uint32_t f = 0; f < 6; ++f) {
      const std::uint32_t want = tree.brute_neighbour(c, f);
      ++r.checked;
      if (want == L::kNoCell) {
        ++r.boundary;
      } else if (L::dc_depth_of(depth_flags[want >> 3]) < L::dc_depth_of(depth_flags[c >> 3]) &&
                 c >= tree.root_count()) {
        ++r.coarser;
      }
      if (o[f] != want && r.mismatches++ < 10) {
        ADD_FAILURE() << "cell " << c << " face " << f << ": GPU " << o[f] << ", brute force "
                      << want;
      }
    }
  }
  return r;
}

struct PoolCase {
  std::uint32_t width_log2, block_log2, roots_per_axis, max_depth, target_cells, seed;
};

// Block b's three copy regions from its staging (stage_blocks) at `off`: the rectangle
// pool_layout.h gives it in every texture, the links' 6 layers in one region.
void copy_block(VkCommandBuffer cb, const PoolCase& pc, std::uint32_t b, const Buffer& staging,
                VkDeviceSize off, const Image& fc_tex, const Image& df_tex, const Image& ln_tex) {
  const std::uint32_t B = 1u << pc.block_log2, gpb = B / 8;
  const std::uint32_t x0 = L::dc_block_x0(b, pc.block_log2, pc.width_log2);
  const std::uint32_t y0 = L::dc_block_y0(b, pc.block_log2, pc.width_log2);
  const std::uint32_t bw = L::dc_block_w(pc.block_log2, pc.width_log2);
  const std::uint32_t bh = L::dc_block_h(pc.block_log2, pc.width_log2);
  copy_buffer_to_image(cb, staging, off, fc_tex, x0, y0, bw, bh);
  copy_buffer_to_image(cb, staging, off + B * 4ull, df_tex, x0 >> 3, y0, bw >> 3, bh);
  copy_buffer_to_image(cb, staging, off + B * 4ull + gpb, ln_tex, x0 >> 3, y0, bw >> 3, bh, 0, 6);
}

// The compute shader's storage writes, made visible to the host's read of the mapped buffer.
void shader_writes_visible_to_host(VkCommandBuffer cb) {
  VkMemoryBarrier mb{};
  mb.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
  mb.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT;
  mb.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
  vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0, 1,
                       &mb, 0, nullptr, 0, nullptr);
}

class GpuPools : public ::testing::TestWithParam<PoolCase> {};

TEST_P(GpuPools, FaceNeighboursMatchBruteForce) {
  Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  const PoolCase pc = GetParam();
  TestTree tree(pc.roots_per_axis, pc.max_depth, pc.seed);
  tree.random_workload(pc.target_cells);

  // Pools padded to whole blocks; every texture has the same height (pool_layout.h).
  const std::uint32_t B = 1u << pc.block_log2, W = 1u << pc.width_log2;
  const std::uint32_t cells = tree.cell_count();
  const std::uint32_t blocks = (cells + B - 1) / B;
  const std::uint32_t padded = blocks * B, groups_padded = padded / 8;
  const std::uint32_t height = L::dc_texture_height(padded, pc.width_log2);
  ASSERT_LE(height, ctx->limits().maxImageDimension2D);
  std::vector<std::uint32_t> first_child(padded, L::kNoCell);
  std::copy(tree.first_child().begin(), tree.first_child().end(), first_child.begin());
  std::vector<std::uint8_t> depth_flags(groups_padded,
                                        static_cast<std::uint8_t>(L::kGroupFreeFlag));
  std::copy(tree.depth_flags().begin(), tree.depth_flags().end(), depth_flags.begin());
  const std::vector<std::uint32_t> links = tree.links(groups_padded);

  // One staging region per block (stage_blocks), 16-byte aligned.
  const std::uint32_t gpb = B / 8;  // groups per block
  const VkDeviceSize block_bytes = B * 4ull + gpb + gpb * 6 * 4ull;
  const VkDeviceSize block_stride = (block_bytes + 15) / 16 * 16;
  auto staging = Buffer::create(*ctx, block_stride * blocks, VK_BUFFER_USAGE_TRANSFER_SRC_BIT,
                                MemoryUse::upload);
  ASSERT_TRUE(staging) << staging.error().message;
  stage_blocks(first_child, depth_flags, links, B, block_stride,
               static_cast<std::uint8_t*>(staging->mapped()));
  ASSERT_TRUE(staging->flush());

  const VkImageUsageFlags usage = VK_IMAGE_USAGE_SAMPLED_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT;
  auto fc_tex = Image::create(*ctx, {VK_FORMAT_R32_UINT, W, height, 1, false, usage});
  auto df_tex = Image::create(*ctx, {VK_FORMAT_R8_UINT, W / 8, height, 1, false, usage});
  auto ln_tex = Image::create(*ctx, {VK_FORMAT_R32_UINT, W / 8, height, 6, true, usage});
  ASSERT_TRUE(fc_tex) << fc_tex.error().message;
  ASSERT_TRUE(df_tex) << df_tex.error().message;
  ASSERT_TRUE(ln_tex) << ln_tex.error().message;
  auto sampler = Sampler::create_nearest(*ctx);
  ASSERT_TRUE(sampler);
  auto out = Buffer::create(*ctx, padded * 8ull * 4, kStorage, MemoryUse::readback);
  ASSERT_TRUE(out) << out.error().message;
  std::memset(out->mapped(), 0xEE, padded * 8ull * 4);
  ASSERT_TRUE(out->flush());

  auto pipe =
      ComputePipeline::create(*ctx, {.name = "face_neighbours",
                                     .spirv = deepcanvas_spv_face_neighbours,
                                     .bindings = {{0, VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER},
                                                  {1, VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER},
                                                  {2, VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER},
                                                  {3, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER}},
                                     .push_constant_bytes = sizeof(GpuPush)});
  ASSERT_TRUE(pipe) << pipe.error().message;
  auto dpool = DescriptorPool::create(*ctx, *pipe, 1);
  ASSERT_TRUE(dpool);
  auto set = dpool->allocate(*pipe);
  ASSERT_TRUE(set);
  DescriptorWriter()
      .sampled_image(0, *fc_tex, *sampler)
      .sampled_image(1, *df_tex, *sampler)
      .sampled_image(2, *ln_tex, *sampler)
      .buffer(3, *out)
      .update(*ctx, *set);

  std::vector<std::uint32_t> order(blocks);
  for (std::uint32_t b = 0; b < blocks; ++b) order[b] = b;
  std::shuffle(order.begin(), order.end(), std::mt19937(pc.seed + 1));

  auto upload = ctx->submit_once(ctx->transfer_queue(), [&](VkCommandBuffer cb) {
    for (const Image* img : {&*fc_tex, &*df_tex, &*ln_tex}) {
      image_barrier(cb, *img, VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                    VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0, VK_PIPELINE_STAGE_TRANSFER_BIT,
                    VK_ACCESS_TRANSFER_WRITE_BIT);
    }
    for (std::uint32_t b : order)
      copy_block(cb, pc, b, *staging, b * block_stride, *fc_tex, *df_tex, *ln_tex);
  });
  ASSERT_TRUE(upload) << upload.error().message;

  auto run = ctx->submit_once(ctx->compute_queue(), [&](VkCommandBuffer cb) {
    for (const Image* img : {&*fc_tex, &*df_tex, &*ln_tex}) {
      image_barrier(cb, *img, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                    VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0,
                    VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_READ_BIT);
    }
    pipe->bind(cb, *set);
    // Two dispatches over two ranges, so DcDispatchRange.first is exercised.
    const std::uint32_t half = cells / 2;
    for (auto [first, count] : {std::pair{0u, half}, std::pair{half, cells - half}}) {
      GpuPush push{};
      push.pool = {pc.width_log2,     pc.block_log2, cells,    tree.root_count(),
                   pc.roots_per_axis, pc.max_depth,  20000.0f, 0};
      push.range = {first, count, 0, 0};
      pipe->push(cb, push);
      vkCmdDispatch(cb, group_count(count, 64), 1, 1);
    }
    shader_writes_visible_to_host(cb);
  });
  ASSERT_TRUE(run) << run.error().message;
  ASSERT_TRUE(out->invalidate());

  const NeighbourCheck r =
      compare_with_brute_force(tree, first_child, depth_flags,
                               out->mapped_span<const std::uint32_t>().first(cells * 8ull));
  EXPECT_EQ(r.mismatches, 0u);
  std::printf(
      "W=%u B=%u: %u cells (%llu in free groups), %llu neighbours checked, %llu coarser, "
      "%llu at the boundary, %u blocks\n",
      W, B, cells, static_cast<unsigned long long>(r.free_cells),
      static_cast<unsigned long long>(r.checked), static_cast<unsigned long long>(r.coarser),
      static_cast<unsigned long long>(r.boundary), blocks);
  // The workload must exercise every path, or the comparison proves little.
  EXPECT_GT(r.coarser, 1000u);
  EXPECT_GT(r.boundary, 100u);
  EXPECT_GT(r.free_cells, 0u);
}

INSTANTIATE_TEST_SUITE_P(
    Layouts, GpuPools,
    ::testing::Values(PoolCase{9, 12, 4, 14, 150000, 1},    // blocks are bands of 8 rows
                      PoolCase{10, 6, 4, 12, 100000, 2},    // 16 blocks share a row
                      PoolCase{6, 6, 2, 16, 60000, 3},      // narrowest texture, block = 1 row
                      PoolCase{14, 14, 4, 20, 120000, 4}),  // widest texture, block = 1 row
    [](const ::testing::TestParamInfo<PoolCase>& param_info) {
      return "W" + std::to_string(1u << param_info.param.width_log2) + "_B" +
             std::to_string(1u << param_info.param.block_log2);
    });

}  // namespace
}  // namespace deepcanvas::client_gpu
