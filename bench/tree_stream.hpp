// A server Octree streamed into the client's GPU replica in one process, without a network:
// each epoch captured as a client would receive it, and the replica's GPU links read back. The
// render suite (render_stream.cpp) measures frames this way; the e2e suite and the streaming
// GPU tests (tests/render_gpu/stream_test_support.hpp) use the same pieces, so that what the
// tests check is what the suites measure.
//
// Not product code: a real client gets its epochs from block frames (client_core::Client and
// client_gpu::stream_client_into); only a test or a benchmark holds the server's tree.
#pragma once

#include <bit>
#include <cstdint>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/bridge/pool_view_of_octree.hpp"
#include "deepcanvas/client_gpu/replica_gpu.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::bench {

// The epoch's upload as a client would capture it: the dirty blocks' rows and the masked groups
// (`all`: every cell and group, the snapshot a joining client gets). Takes the tree's dirty
// blocks and clears its neighbour masks, as the server's staging does.
inline client_gpu::EpochUpload capture_tree_epoch(server_core::Octree& tree, std::uint64_t epoch,
                                                  std::uint32_t width_log2, bool all) {
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
  return client_gpu::capture_epoch(bridge::pool_view_of(tree), epoch, width_log2, ranges, groups);
}

// The GPU links (G3) of the resident epoch, read back under the GPU lock.
inline Result<std::vector<std::uint32_t>> resident_links(client_gpu::StreamingReplica& sr) {
  std::vector<std::uint32_t> links;
  auto r = sr.with_gpu([&](const client_gpu::ResidentState& s) -> Result<void> {
    auto l = s.replica.read_links();
    if (!l) return std::move(l).error();
    links = std::move(*l);
    return {};
  });
  if (!r) return std::move(r).error();
  return links;
}

}  // namespace deepcanvas::bench
