// Shared by the streaming tests (label gpu): pool snapshots of a server Octree and epochs
// captured from it as a client would receive them (bench/tree_stream.hpp).
#pragma once

#include <bit>
#include <cstdint>
#include <vector>

#include "../../bench/tree_stream.hpp"
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

// Epochs captured from a server Octree and the replica's GPU links read back: the same pieces
// the render and e2e benchmarks stream and check with.
using bench::capture_tree_epoch;
using bench::resident_links;

}  // namespace deepcanvas::render_test
