// The StreamingReplica's content box step (see "Content box" in streaming_replica.hpp), internal
// to client_gpu: what a batch changes and the box after it, computed from the batch's rows laid
// over the mirror BEFORE the batch is applied, so that it runs outside the GPU lock (the mirror
// is written only by the upload thread, which is the one calling this).
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/pool_view.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"

namespace deepcanvas::client_gpu::detail {

struct ContentStep {
  std::optional<client_core::DAabb> box;  // the box after the batch (unless fallback)
  // The state after the batch is not a tree somewhere (see the header): recompute the box
  // exactly with painted_bounds once the batch is in the mirror.
  bool fallback = false;
  // Paint was removed where it reached the faces of the box before: the box may now be loose.
  bool loose = false;
  std::uint64_t changed_cells = 0;  // cells whose first_child, or colour as a leaf, changed
};

// Keeps per-group scratch (positions memoised per group, walked groups) between batches, so a
// step costs O(changed cells + their ancestors), not O(cells): about 4.5 bytes per cell.
class ContentTracker {
 public:
  // `mirror`: the state before the batch; `box_before`: its box (contains its painted leaves);
  // `batch`: the batch's epochs, all of width 2^width_log2, their rows sorted; `rows`: the union
  // of their rows. The last epoch carrying a row wins, as in StreamingReplica::apply_to_mirror.
  ContentStep step(const client_core::PoolView& mirror,
                   const std::optional<client_core::DAabb>& box_before,
                   const std::vector<EpochUpload>& batch, std::span<const std::uint32_t> rows,
                   std::uint32_t width_log2);

  // Scratch memo of a group's parent position, stamped per use (no clearing per batch).
  struct GroupMemo {
    struct Entry {
      std::uint32_t x = 0, y = 0, z = 0;  // the parent cell's coordinates at its depth
      std::uint8_t depth = 0;             // the parent's depth
      std::uint8_t reach = 0;             // Reach (streaming_replica_content.cpp)
      std::uint16_t stamp = 0;
    };
    std::vector<Entry> entries;
    std::uint16_t now = 0;
    void begin(std::uint64_t groups);
  };

 private:
  GroupMemo before_, after_;
  std::vector<std::uint16_t> walked_;  // stamp per group: walked in this step
  std::uint16_t walk_now_ = 0;
};

}  // namespace deepcanvas::client_gpu::detail
