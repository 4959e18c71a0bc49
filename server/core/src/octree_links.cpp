// Octree: blocks (dirty flags, versions), neighbour masks and link recomputation.
#include <algorithm>
#include <bit>
#include <cstring>

#include "deepcanvas/protocol/density_model.hpp"

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

void Octree::Impl::refresh_filtered(bool zeros_exact) {
  // The cells whose value may be stale, by depth: those the tree's writes named (a refresh
  // costs what changed, not what the changed blocks hold), or after a restore every interior
  // cell of a dirty block and the parent of every group in one; an exact refresh adds the cells
  // a zeros_exact one left lagging. A recomputed cell that changes makes its parent stale in
  // turn, one level up. A lagging list too long to keep makes the refresh exact.
  if (lagging_filtered.size() >= kMaxStaleFiltered) zeros_exact = false;
  if (refilter_all) {
    refilter_all = false;
    for (const BlockId b : dirty_list) {
      const GroupIndex g0 = b << gblock_shift;
      const GroupIndex g1 = static_cast<GroupIndex>(
          std::min<std::uint64_t>(hw_groups, std::uint64_t{g0} + groups_per_block));
      for (GroupIndex g = g0; g < g1; ++g) {
        if (is_free_group(g)) continue;
        const pl::uint d = pl::dc_depth_of(gdepth[g]);
        if (g >= root_groups && d > 0) filter_queue[d - 1].push_back(gparent[g]);
        const CellIndex base = pl::dc_group_first_cell(g);
        for (CellIndex i = 0; i < pl::kCellsPerGroup; ++i)
          if (first_child[base + i] != kNoCell) filter_queue[d].push_back(base + i);
      }
    }
  }
  const auto queue = [this](std::span<const CellIndex> cells) {
    for (const CellIndex c : cells) {
      if (c >= hw_cells()) continue;
      const GroupIndex g = pl::dc_group_of(c);
      if (is_free_group(g) || first_child[c] == kNoCell) continue;
      filter_queue[pl::dc_depth_of(gdepth[g])].push_back(c);
    }
  };
  queue(stale_filtered);
  stale_filtered.clear();
  if (!zeros_exact) {
    queue(lagging_filtered);
    lagging_filtered.clear();
    lagging_unique = 0;
  }
  for (std::size_t d = filter_queue.size(); d-- > 0;) {
    auto& q = filter_queue[d];
    if (q.empty()) continue;
    std::sort(q.begin(), q.end());
    q.erase(std::unique(q.begin(), q.end()), q.end());
    for (const CellIndex c : q) {
      if (c >= hw_cells()) continue;
      const CellIndex fc = first_child[c];
      if (fc == kNoCell || std::uint64_t{fc} + pl::kCellsPerGroup > hw_cells()) continue;
      const std::uint32_t v = protocol::density::filter_rgba(&colour[fc]);
      if (v == colour[c]) continue;
      if (zeros_exact && v != 0 && colour[c] != 0) {  // stays nonzero: its parent's value too
        filter_lags(c);
        continue;
      }
      colour[c] = v;
      mark_dirty(c >> block_shift);
      const GroupIndex g = pl::dc_group_of(c);
      if (g >= root_groups && d > 0) filter_queue[d - 1].push_back(gparent[g]);
    }
    q.clear();
  }
}

void Octree::Impl::filter_lags(CellIndex c) {
  lagging_filtered.push_back(c);
  // A stroke's ancestors lag again at every take: keep each once.
  if (lagging_filtered.size() >= 2 * std::max<std::size_t>(lagging_unique, 1024)) {
    std::sort(lagging_filtered.begin(), lagging_filtered.end());
    lagging_filtered.erase(std::unique(lagging_filtered.begin(), lagging_filtered.end()),
                           lagging_filtered.end());
    lagging_unique = lagging_filtered.size();
  }
}

void Octree::refresh_interior_colours() {
  impl_->refresh_filtered();
}

bool Octree::interior_colours_current() const noexcept {
  return !impl_->refilter_all && impl_->stale_filtered.empty();
}

bool Octree::interior_colours_lag() const noexcept {
  return !impl_->lagging_filtered.empty();
}

std::vector<BlockId> Octree::take_dirty_blocks(InteriorRefresh refresh) {
  Impl& m = *impl_;
  m.refresh_filtered(refresh == InteriorRefresh::zeros_exact);
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
