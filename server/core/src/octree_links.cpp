// Octree: blocks (dirty flags, versions), neighbour masks and link recomputation.
#include <bit>
#include <cstring>

#include "octree_impl.hpp"

namespace deepcanvas::server_core {

namespace pl = pool_layout;

std::uint32_t Octree::block_count() const noexcept {
  const Impl& m = *impl_;
  return static_cast<std::uint32_t>((m.hw_cells() + m.cfg.block_cells - 1) >> m.block_shift);
}

const BlockState& Octree::block_state(BlockId b) const noexcept {
  static const BlockState kNone{};
  return b < impl_->block_capacity ? impl_->blocks[b] : kNone;
}

std::vector<BlockId> Octree::take_dirty_blocks() {
  Impl& m = *impl_;
  std::vector<BlockId> out;
  out.swap(m.dirty_list);
  for (BlockId b : out) m.blocks[b].dirty = false;
  m.dirty_list.reserve(out.capacity());
  return out;
}

std::span<const BlockId> Octree::dirty_blocks() const noexcept {
  return impl_->dirty_list;
}

std::span<const std::uint64_t> Octree::neighbour_mask(BlockId b) const noexcept {
  const Impl& m = *impl_;
  if (b >= m.block_capacity) return {};
  return {m.mask.data() + std::size_t{b} * m.mask_words_per_block, m.mask_words_per_block};
}

void Octree::clear_neighbour_mask(BlockId b) noexcept {
  Impl& m = *impl_;
  if (b >= m.block_capacity) return;
  std::memset(m.mask.data() + std::size_t{b} * m.mask_words_per_block, 0,
              m.mask_words_per_block * sizeof(std::uint64_t));
}

void Octree::clear_all_neighbour_masks() noexcept {
  Impl& m = *impl_;
  std::memset(m.mask.data(), 0, ((m.hw_groups + 63) / 64) * sizeof(std::uint64_t));
}

void Octree::recompute_masked_links_into(std::span<std::uint32_t> out) const {
  const Impl& m = *impl_;
  if (out.size() < m.hw_groups * pl::kFaceCount) return;
  // Bucket the masked groups by depth so that a group's parent's group (whose links it reads)
  // is recomputed first when it is masked too.
  std::vector<GroupIndex> by_depth[kMaxSupportedDepth + 1];
  const std::uint64_t words = (m.hw_groups + 63) / 64;
  for (std::uint64_t w = 0; w < words; ++w) {
    std::uint64_t bits = m.mask[w];
    while (bits) {
      const GroupIndex g = static_cast<GroupIndex>(w * 64 + std::countr_zero(bits));
      bits &= bits - 1;
      if (g >= m.hw_groups) break;
      if (g < m.root_groups || m.is_free_group(g)) {
        for (int f = 0; f < kFaces; ++f) out[pl::dc_link_index(g, f)] = kNoCell;
      } else {
        by_depth[pl::dc_depth_of(m.gdepth[g])].push_back(g);
      }
    }
  }
  for (const auto& bucket : by_depth)
    for (GroupIndex g : bucket)
      m.compute_group_links(g, out.data(), &out[pl::dc_link_index(g, 0)]);
}

void Octree::recompute_masked_links() {
  Impl& m = *impl_;
  recompute_masked_links_into({m.links.data(), m.hw_groups * pl::kFaceCount});
  clear_all_neighbour_masks();
}

void Octree::recompute_all_links() {
  Impl& m = *impl_;
  // Counting sort of every group by depth, then compute parents' depths first.
  std::uint64_t start[kMaxSupportedDepth + 2] = {};
  for (GroupIndex g = 0; g < m.hw_groups; ++g)
    if (!m.is_free_group(g)) ++start[pl::dc_depth_of(m.gdepth[g]) + 1];
  for (int d = 1; d <= kMaxSupportedDepth + 1; ++d) start[d] += start[d - 1];
  std::vector<GroupIndex> order(start[kMaxSupportedDepth + 1]);
  for (GroupIndex g = 0; g < m.hw_groups; ++g) {
    std::uint32_t* l = m.links_of(g);
    if (m.is_free_group(g)) {
      for (int f = 0; f < kFaces; ++f) l[f] = kNoCell;
      continue;
    }
    order[start[pl::dc_depth_of(m.gdepth[g])]++] = g;
  }
  for (GroupIndex g : order) m.compute_group_links(g, m.links.data(), m.links_of(g));
}

}  // namespace deepcanvas::server_core
