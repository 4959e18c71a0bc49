// EpochUpload: one committed epoch's changes as the GPU replica takes them, whole texture rows of
// the pool textures (shaders/include/pool_layout.h) plus the groups whose links to recompute.
// capture_epoch() makes one from the client's CPU replica on the I/O thread (a copy of the
// changed rows, so the I/O thread never waits for the GPU); StreamingReplica's upload thread
// applies it. No Vulkan here.
//
// Ownership and threading: an EpochUpload is a value (it owns its rows). capture_epoch() is pure;
// the pools it reads must stay unchanged during the call.
//
// Untrusted input: the pools come from the network. capture_epoch() copies only within the pools
// it is given (ranges past the high-water mark are cut); what the rows contain is checked where
// it is followed (the GPU passes, the content box).
#pragma once

#include <chrono>
#include <cstdint>
#include <span>
#include <vector>

#include "deepcanvas/client_core/pool_view.hpp"

namespace deepcanvas::client_gpu {

using SteadyTime = std::chrono::steady_clock::time_point;

// A cell range an epoch changed (first_cell, cell_count).
struct ChangedRange {
  std::uint64_t first_cell = 0, cell_count = 0;
};

struct EpochUpload {
  std::uint64_t epoch = 0;
  std::uint64_t cell_count = 0;  // the high-water mark after the epoch
  std::uint32_t width_log2 = 12;
  std::vector<std::uint32_t> rows;  // sorted, unique
  // Per row (in `rows` order) W cells / W/8 groups; cells at or past cell_count hold the
  // never-used values (leaf, empty, free group).
  std::vector<std::uint32_t> first_child, colour, group_parent;
  std::vector<std::uint8_t> depth_flags;
  std::vector<std::uint32_t> link_groups;
  // Part of a snapshot still arriving (client_core::EpochCommit::partial): `epoch` is not
  // resident whole once this is.
  bool partial = false;
  SteadyTime committed_at{};
  std::uint64_t bytes() const noexcept;
};

// Copies the rows covering `changed` from `pools` (the state after the epoch).
EpochUpload capture_epoch(const client_core::PoolView& pools, std::uint64_t epoch,
                          std::uint32_t width_log2, std::span<const ChangedRange> changed,
                          std::span<const std::uint32_t> link_groups);

}  // namespace deepcanvas::client_gpu
