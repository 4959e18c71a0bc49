// Shared by the streaming tests (label gpu): pool snapshots of a server Octree and epochs
// captured from it as a client would receive them.
#pragma once

#include <bit>
#include <cstdint>
#include <vector>

#include "deepcanvas/client_gpu/replica_gpu.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "render_scenes.hpp"

namespace deepcanvas::render_test {

// A copy of the pools at one epoch (the reference a band of that epoch is checked against).
struct Snapshot {
  std::vector<std::uint32_t> fc, col, par, links;
  std::vector<std::uint8_t> dep;
  std::uint32_t roots_per_axis = 4;
  double edge_m = 0;
  PoolView view() const {
    PoolView v;
    v.first_child = fc;
    v.colour = col;
    v.group_parent = par;
    v.group_depth_flags = dep;
    v.group_links = links;
    v.roots_per_axis = roots_per_axis;
    v.edge_m = edge_m;
    return v;
  }
};

inline Snapshot snapshot_of(const Octree& t) {
  const PoolView v = pool_view_of(t);
  Snapshot s;
  s.fc.assign(v.first_child.begin(), v.first_child.end());
  s.col.assign(v.colour.begin(), v.colour.end());
  s.par.assign(v.group_parent.begin(), v.group_parent.end());
  s.dep.assign(v.group_depth_flags.begin(), v.group_depth_flags.end());
  s.links.assign(v.group_links.begin(), v.group_links.end());
  s.roots_per_axis = v.roots_per_axis;
  s.edge_m = v.edge_m;
  return s;
}

inline client_gpu::GpuReplicaConfig config_of(const Octree& tree, std::uint32_t width_log2,
                                              std::uint64_t initial) {
  client_gpu::GpuReplicaConfig cfg;
  cfg.width_log2 = width_log2;
  cfg.block_log2 = static_cast<std::uint32_t>(std::countr_zero(tree.config().block_cells));
  cfg.roots_per_axis = tree.config().roots_per_axis;
  cfg.edge_m = tree.config().edge_m;
  cfg.initial_capacity_cells = initial;
  return cfg;
}

// The epoch's upload as a client would capture it: the dirty blocks' rows and the masked groups
// (`all`: every cell and group, the snapshot a joining client gets).
inline client_gpu::EpochUpload capture(Octree& tree, std::uint64_t epoch, std::uint32_t width_log2,
                                       bool all) {
  const std::uint64_t bc = tree.config().block_cells;
  std::vector<client_gpu::ChangedRange> ranges;
  std::vector<std::uint32_t> groups;
  const auto dirty = tree.take_dirty_blocks();
  if (all) {
    ranges.push_back({0, tree.high_water_cells()});
    for (std::uint32_t g = 0; g < tree.high_water_cells() / 8; ++g) groups.push_back(g);
  } else {
    for (auto b : dirty) ranges.push_back({std::uint64_t{b} * bc, bc});
    for (server_core::BlockId b = 0; b < tree.block_count(); ++b) {
      const auto m = tree.neighbour_mask(b);
      for (std::size_t w = 0; w < m.size(); ++w) {
        std::uint64_t bits = m[w];
        while (bits) {
          const std::uint64_t i = w * 64 + static_cast<std::uint64_t>(std::countr_zero(bits));
          bits &= bits - 1;
          groups.push_back(static_cast<std::uint32_t>(std::uint64_t{b} * bc / 8 + i));
        }
      }
    }
  }
  tree.clear_all_neighbour_masks();
  return client_gpu::capture_epoch(pool_view_of(tree), epoch, width_log2, ranges, groups);
}

}  // namespace deepcanvas::render_test
