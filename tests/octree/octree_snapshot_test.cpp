// Checkpoints of the octree (octree.hpp, "checkpoints"): a tree saved block by block and
// restored equals the original in every pool byte, hash and link, and goes on allocating exactly
// as the original would; bytes that do not describe a valid tree are refused, never trusted.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <vector>

#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::server_core {
namespace {

OctreeConfig small_blocks() {
  OctreeConfig c;
  c.edge_m = 64.0;
  c.max_depth = 10;
  c.block_cells = 512;
  c.max_cells = 1u << 20;
  return c;
}

// Random refines, coarsens and recolours around a wandering focus: leaves free groups in many
// blocks, so the free lists and the list of blocks with room are exercised.
void random_ops(Octree& t, std::mt19937_64& rng, int ops) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const double half = t.config().edge_m / 2;
  Vec3d focus{u(rng) * half, u(rng) * half, u(rng) * half};
  for (int i = 0; i < ops; ++i) {
    if (i % 64 == 0) focus = {u(rng) * half, u(rng) * half, u(rng) * half};
    const double r = half * 0.05;
    const Vec3d p{std::clamp(focus.x + u(rng) * r, -half, half),
                  std::clamp(focus.y + u(rng) * r, -half, half),
                  std::clamp(focus.z + u(rng) * r, -half, half)};
    auto loc = t.locate(p, t.config().max_depth);
    ASSERT_TRUE(loc.ok());
    const int op = static_cast<int>(rng() % 10);
    if (op < 5) {
      (void)t.refine(loc->cell);
    } else if (op < 8) {
      const CellIndex parent = t.parent(loc->cell);
      if (parent != kNoCell && t.can_coarsen(parent)) {
        ASSERT_TRUE(t.coarsen(parent).ok());
      }
    } else {
      t.set_colour(loc->cell, static_cast<std::uint32_t>(rng()));
    }
  }
}

struct Saved {
  std::vector<std::uint8_t> allocator;
  std::vector<std::vector<std::uint8_t>> blocks;
};

Saved save(const Octree& t) {
  Saved s;
  s.allocator = t.save_allocator();
  for (BlockId b = 0; b < t.block_count(); ++b) s.blocks.push_back(t.save_block(b));
  return s;
}

Result<std::unique_ptr<Octree>> restore(const OctreeConfig& c, const Saved& s) {
  return Octree::restore(c, s.allocator, [&](BlockId b) -> std::span<const std::uint8_t> {
    if (b >= s.blocks.size()) return {};
    return s.blocks[b];
  });
}

std::vector<std::uint32_t> links(const Octree& t) {
  auto l = t.group_link_pool();
  return {l.begin(), l.begin() + static_cast<std::ptrdiff_t>(t.high_water_cells() / 8 * 6)};
}

TEST(OctreeSnapshot, RestoredTreeEqualsTheSavedOneAndGoesOnAllocatingTheSame) {
  for (std::uint64_t seed = 1; seed <= 6; ++seed) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    const OctreeConfig cfg = small_blocks();
    auto original = Octree::create(cfg);
    ASSERT_TRUE(original.ok());
    Octree& a = **original;
    std::mt19937_64 rng(seed);
    random_ops(a, rng, 3000);
    const Saved s = save(a);
    auto restored = restore(cfg, s);
    ASSERT_TRUE(restored.ok()) << restored.error().message;
    Octree& b = **restored;
    EXPECT_EQ(b.pool_hash(), a.pool_hash());
    EXPECT_EQ(b.canvas_hash(), a.canvas_hash());
    EXPECT_EQ(b.live_cells(), a.live_cells());
    EXPECT_EQ(links(b), links(a));
    ASSERT_TRUE(b.check_invariants().ok()) << b.check_invariants().error().message;
    for (BlockId k = 0; k < a.block_count(); ++k)
      EXPECT_EQ(b.block_state(k).version, a.block_state(k).version) << "block " << k;
    EXPECT_EQ(b.dirty_blocks().size(), a.block_count());  // a replica gets every block
    // The same operations on both: the allocator state came back too.
    std::mt19937_64 rng_a(seed * 77), rng_b(seed * 77);
    random_ops(a, rng_a, 2000);
    random_ops(b, rng_b, 2000);
    EXPECT_EQ(b.pool_hash(), a.pool_hash());
    EXPECT_EQ(b.canvas_hash(), a.canvas_hash());
  }
}

TEST(OctreeSnapshot, AFreshTreeRoundTrips) {
  const OctreeConfig cfg;  // the default canvas
  auto a = Octree::create(cfg);
  ASSERT_TRUE(a.ok());
  auto b = restore(cfg, save(**a));
  ASSERT_TRUE(b.ok()) << b.error().message;
  EXPECT_EQ((*b)->pool_hash(), (*a)->pool_hash());
  EXPECT_EQ((*b)->canvas_hash(), (*a)->canvas_hash());
}

TEST(OctreeSnapshot, BadBytesAreRefusedWithTheBlockNamed) {
  const OctreeConfig cfg = small_blocks();
  auto a = Octree::create(cfg);
  ASSERT_TRUE(a.ok());
  std::mt19937_64 rng(9);
  random_ops(**a, rng, 2000);
  const Saved good = save(**a);
  ASSERT_GT(good.blocks.size(), 2u);

  Saved s = good;
  s.blocks[1].resize(s.blocks[1].size() - 1);
  auto r = restore(cfg, s);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::malformed);
  EXPECT_NE(r.error().message.find("block 1"), std::string::npos) << r.error().message;

  s = good;
  s.blocks.pop_back();
  EXPECT_FALSE(restore(cfg, s).ok());  // a block missing

  s = good;
  s.allocator.resize(10);
  EXPECT_FALSE(restore(cfg, s).ok());

  OctreeConfig other = cfg;
  other.block_cells = 1024;
  EXPECT_FALSE(restore(other, good).ok());  // another block size
}

// Every single-byte corruption of the structure (child and parent links, depths, free lists,
// the allocator) is either refused or yields a tree that passes the full invariant check and
// can go on being edited: restore never hands out a tree that could crash later.
TEST(OctreeSnapshot, CorruptedBytesNeverYieldABrokenTree) {
  const OctreeConfig cfg = small_blocks();
  auto a = Octree::create(cfg);
  ASSERT_TRUE(a.ok());
  std::mt19937_64 rng(5);
  random_ops(**a, rng, 1500);
  const Saved good = save(**a);
  std::mt19937_64 pick(11);
  int refused = 0, accepted = 0;
  for (int trial = 0; trial < 400; ++trial) {
    Saved s = good;
    std::vector<std::uint8_t>* target = nullptr;
    if (trial % 8 == 0) {
      target = &s.allocator;
    } else {
      target = &s.blocks[pick() % s.blocks.size()];
    }
    const std::size_t at = pick() % target->size();
    (*target)[at] ^= static_cast<std::uint8_t>(1u << (pick() % 8));
    auto r = restore(cfg, s);
    if (!r.ok()) {
      ++refused;
      continue;
    }
    ++accepted;
    auto inv = (*r)->check_invariants();
    if (!inv.ok()) {
      // Colours are not structure; a flipped colour is a valid (different) tree. Anything the
      // invariant check rejects must have been refused.
      ADD_FAILURE() << "trial " << trial << " byte " << at << ": " << inv.error().message;
      continue;
    }
    std::mt19937_64 more(trial);
    random_ops(**r, more, 300);
  }
  EXPECT_GT(refused, 0);
  EXPECT_GT(accepted, 0);
}

}  // namespace
}  // namespace deepcanvas::server_core
