// EpochUpload and capture_epoch (see epoch_upload.hpp).
#include "deepcanvas/client_gpu/epoch_upload.hpp"

#include <algorithm>
#include <cstring>

#include "pool_layout.h"

namespace deepcanvas::client_gpu {

namespace pl = pool_layout;

std::uint64_t EpochUpload::bytes() const noexcept {
  return (first_child.size() + colour.size() + group_parent.size()) * 4 + depth_flags.size() +
         link_groups.size() * 4;
}

EpochUpload capture_epoch(const client_core::PoolView& pools, std::uint64_t epoch,
                          std::uint32_t width_log2, std::span<const ChangedRange> changed,
                          std::span<const std::uint32_t> link_groups) {
  EpochUpload e;
  e.epoch = epoch;
  e.cell_count = pools.cell_count();
  e.width_log2 = width_log2;
  e.committed_at = std::chrono::steady_clock::now();
  for (const ChangedRange& r : changed) {
    if (r.cell_count == 0 || r.first_cell >= e.cell_count) continue;
    const std::uint64_t last = std::min(r.first_cell + r.cell_count, e.cell_count) - 1;
    for (std::uint64_t row = r.first_cell >> width_log2; row <= last >> width_log2; ++row)
      e.rows.push_back(static_cast<std::uint32_t>(row));
  }
  std::sort(e.rows.begin(), e.rows.end());
  e.rows.erase(std::unique(e.rows.begin(), e.rows.end()), e.rows.end());
  const std::uint64_t w = std::uint64_t{1} << width_log2;
  e.first_child.resize(e.rows.size() * w, pl::kNoCell);
  e.colour.resize(e.rows.size() * w, 0u);
  e.group_parent.resize(e.rows.size() * w / 8, pl::kNoCell);
  e.depth_flags.resize(e.rows.size() * w / 8, static_cast<std::uint8_t>(pl::kGroupFreeFlag));
  for (std::size_t i = 0; i < e.rows.size(); ++i) {
    const std::uint64_t c0 = std::uint64_t{e.rows[i]} * w;
    const std::uint64_t n = std::min(w, e.cell_count - c0);
    std::memcpy(&e.first_child[i * w], pools.first_child.data() + c0, n * 4);
    std::memcpy(&e.colour[i * w], pools.colour.data() + c0, n * 4);
    std::memcpy(&e.group_parent[i * w / 8], pools.group_parent.data() + c0 / 8, n / 8 * 4);
    std::memcpy(&e.depth_flags[i * w / 8], pools.group_depth_flags.data() + c0 / 8, n / 8);
  }
  e.link_groups.assign(link_groups.begin(), link_groups.end());
  return e;
}

}  // namespace deepcanvas::client_gpu
