#include "deepcanvas/client_core/replica.hpp"

#include <algorithm>
#include <bit>
#include <cstring>

#include "deepcanvas/protocol/pool_hash.hpp"

namespace deepcanvas::client_core {

namespace pl = pool_layout;

namespace {
constexpr std::uint32_t kNoCell = pl::kNoCell;
}

// The pools reserve room for the largest canvas up front (address space only; PoolArray): the
// replica then grows without copying or moving what it holds.
Replica::Replica(const ReplicaGeometry& geometry)
    : geometry_(geometry),
      first_child_(kMaxCells),
      colour_(kMaxCells),
      group_parent_(kMaxCells / 8),
      links_(kMaxCells / 8 * pl::kFaceCount),
      depth_flags_(kMaxCells / 8),
      mask_((kMaxCells / 8 + 63) / 64),
      links_set_((kMaxCells / 8) >> kLinkChunkLog2, 0) {
  const std::uint32_t n = geometry_.roots_per_axis;
  root_count_ = pl::dc_root_count(n);
}

Result<void> Replica::stage(protocol::BlockFrame frame) {
  const auto& h = frame.header;
  const std::uint64_t bc = geometry_.block_cells;
  const std::uint64_t first = h.first_cell, count = h.cell_count;
  if (count == 0 || first % 8 || count % 8)
    return make_error(Errc::invalid_argument, "block frame range is not whole groups");
  if (first + count > kMaxCells)
    return make_error(Errc::invalid_argument, "block frame range past the largest canvas");
  if (bc == 0 || first / bc != h.block_id || (first + count - 1) / bc != h.block_id)
    return make_error(Errc::invalid_argument,
                      "block frame range outside block " + std::to_string(h.block_id));
  if (frame.is_delta())
    if (auto r = resolve_delta(frame); !r) return r;
  staged_.push_back(std::move(frame));
  return {};
}

namespace {
constexpr std::uint16_t kPoolFields = protocol::kFieldFirstChild | protocol::kFieldColour |
                                      protocol::kFieldGroupParent | protocol::kFieldDepthFlags;
}

// The base is the block as it will be when this frame is applied: its newest staged frame with
// pools (frames of one batch apply in order), else the committed pools.
Result<void> Replica::resolve_delta(protocol::BlockFrame& frame) const {
  const auto& h = frame.header;
  for (auto it = staged_.rbegin(); it != staged_.rend(); ++it) {
    const protocol::BlockFrame& s = *it;
    if (s.header.block_id != h.block_id || !(s.header.fields & kPoolFields)) continue;
    return protocol::apply_block_delta(frame, protocol::view_of(s));
  }
  if (h.block_id >= held_.size() || !held_[h.block_id].valid)
    return make_error(Errc::invalid_argument,
                      "delta frame for block " + std::to_string(h.block_id) +
                          " needs base version " + std::to_string(h.base_version) +
                          ", but the replica holds no version of that block");
  const BlockHeld& held = held_[h.block_id];
  protocol::BlockView base;
  base.block_id = h.block_id;
  base.version = held.version;
  base.first_cell = held.first_cell;
  base.cell_count = held.cell_count;
  // The held range was committed, so the pools cover it (grow() never shrinks).
  const std::size_t c0 = held.first_cell, n = held.cell_count;
  base.first_child = {first_child_.data() + c0, n};
  base.colour = {colour_.data() + c0, n};
  base.group_parent = {group_parent_.data() + c0 / 8, n / 8};
  base.depth_flags = {depth_flags_.data() + c0 / 8, n / 8};
  return protocol::apply_block_delta(frame, base);
}

std::optional<std::uint64_t> Replica::block_version(std::uint32_t block) const noexcept {
  if (block >= held_.size() || !held_[block].valid) return std::nullopt;
  return held_[block].version;
}

void Replica::grow(std::uint64_t groups) {
  if (groups <= hw_groups_) return;
  if (groups * 8 > first_child_.size()) {
    // Whole blocks. Growth neither copies nor moves (PoolArray), so it need not be geometric.
    const std::uint64_t bc = std::max<std::uint32_t>(geometry_.block_cells, 8);
    std::uint64_t cap = (groups * 8 + bc - 1) / bc * bc;
    cap = std::min<std::uint64_t>(cap, kMaxCells);
    // New cells are zero (nothing written); links too, until set (set_links_of).
    first_child_.resize(cap);
    colour_.resize(cap);
    group_parent_.resize(cap / 8);
    depth_flags_.resize(cap / 8);
    links_.resize(cap / 8 * pl::kFaceCount);
    mask_.resize((cap / 8 + 63) / 64);
  }
  hw_groups_ = groups;
}

std::vector<std::uint32_t> Replica::apply_staged() {
  std::vector<std::uint32_t> blocks;
  for (const protocol::BlockFrame& f : staged_) {
    const std::uint64_t first = f.header.first_cell, count = f.header.cell_count;
    const std::uint64_t g0 = first / 8, groups = count / 8;
    grow(g0 + groups);
    if (f.header.fields & kPoolFields) set_links_of(g0, groups);
    if (f.has(protocol::kFieldFirstChild) && f.first_child.size() == count)
      std::memcpy(&first_child_[first], f.first_child.data(), count * 4);
    if (f.has(protocol::kFieldColour) && f.colour.size() == count)
      std::memcpy(&colour_[first], f.colour.data(), count * 4);
    if (f.has(protocol::kFieldGroupParent) && f.group_parent.size() == groups)
      std::memcpy(&group_parent_[g0], f.group_parent.data(), groups * 4);
    if (f.has(protocol::kFieldDepthFlags) && f.depth_flags.size() == groups)
      std::memcpy(&depth_flags_[g0], f.depth_flags.data(), groups);
    if (f.header.fields & kPoolFields) {
      if (f.header.block_id >= held_.size()) held_.resize(std::size_t{f.header.block_id} + 1);
      held_[f.header.block_id] = {true, f.header.version, f.header.first_cell, f.header.cell_count};
      blocks.push_back(f.header.block_id);
    }
    if (f.has(protocol::kFieldNeighbourMask)) {
      for (std::uint64_t i = 0; i < groups; ++i) {
        const std::size_t w = i / 64;
        if (w >= f.neighbour_mask.size()) break;
        if ((f.neighbour_mask[w] >> (i % 64)) & 1u) {
          const std::uint64_t g = g0 + i;
          mask_[g / 64] |= std::uint64_t{1} << (g % 64);
        }
      }
    }
  }
  staged_.clear();
  return blocks;
}

std::size_t Replica::commit() {
  const std::size_t n = staged_.size();
  (void)apply_staged();
  changed_cells_.clear();
  const bool was_partial = partial_;
  if (partial_) {
    // The snapshot is complete: every hidden cell gets its first_child back (a block that never
    // came leaves its pointer as the server sent it: the replica equals the server's bytes).
    for (auto& [block, cells] : hidden_)
      for (const auto& [cell, fc] : cells)
        if (first_child_[cell] == kNoCell) {
          first_child_[cell] = fc;
          changed_cells_.push_back(cell);
        }
    hidden_.clear();
    partial_ = false;
    std::sort(changed_cells_.begin(), changed_cells_.end());
  }
  recompute_links(was_partial);
  return n;
}

std::size_t Replica::commit_partial() {
  // Nothing can be shown before the roots' block (block 0) has come: until then unreceived
  // roots would read as cells pointing at group 0.
  const bool roots = holds_block(0) || std::any_of(staged_.begin(), staged_.end(), [](const auto& f) {
                       return f.header.block_id == 0 && (f.header.fields & kPoolFields);
                     });
  if (!roots) return 0;
  const std::size_t n = staged_.size();
  const std::vector<std::uint32_t> blocks = apply_staged();
  changed_cells_.clear();
  partial_ = true;
  const std::uint64_t bc = geometry_.block_cells;
  // Un-hide the cells whose children's block came; then hide, in the blocks that came, the
  // cells whose children's block has not.
  for (const std::uint32_t b : blocks) {
    const auto it = hidden_.find(b);
    if (it == hidden_.end()) continue;
    for (const auto& [cell, fc] : it->second)
      if (first_child_[cell] == kNoCell) {
        first_child_[cell] = fc;
        changed_cells_.push_back(cell);
      }
    hidden_.erase(it);
  }
  for (const std::uint32_t b : blocks) {
    const BlockHeld& h = held_[b];
    for (std::uint64_t c = h.first_cell; c < std::uint64_t{h.first_cell} + h.cell_count; ++c) {
      const std::uint32_t fc = first_child_[c];
      if (fc == kNoCell || holds_block(fc / bc)) continue;
      hidden_[static_cast<std::uint32_t>(fc / bc)].emplace_back(static_cast<std::uint32_t>(c), fc);
      first_child_[c] = kNoCell;
      changed_cells_.push_back(static_cast<std::uint32_t>(c));
    }
  }
  std::sort(changed_cells_.begin(), changed_cells_.end());
  recompute_links(true);
  return n;
}

std::vector<std::uint32_t> Replica::received_groups() const {
  std::vector<std::uint32_t> out;
  for (const BlockHeld& h : held_) {
    if (!h.valid) continue;
    for (std::uint64_t g = h.first_cell / 8; g < (std::uint64_t{h.first_cell} + h.cell_count) / 8; ++g)
      out.push_back(static_cast<std::uint32_t>(g));
  }
  return out;
}

void Replica::recompute_links(bool all) {
  // Masked groups (`all`: every group received) in depth order: a group reads its parent's
  // group's links.
  std::vector<std::uint32_t> by_depth[pl::kMaxDepth + 1];
  auto add = [&](std::uint64_t g) {
    const pl::uint d = std::min(pl::dc_depth_of(depth_flags_[g]), pl::kMaxDepth);
    by_depth[d].push_back(static_cast<std::uint32_t>(g));
  };
  const std::uint64_t words = (hw_groups_ + 63) / 64;
  if (all) {
    std::fill(mask_.begin(), mask_.begin() + static_cast<std::ptrdiff_t>(words), 0);
    for (const std::uint32_t g : received_groups())
      if (g < hw_groups_) add(g);
  } else {
    for (std::uint64_t w = 0; w < words; ++w) {
      std::uint64_t bits = mask_[w];
      mask_[w] = 0;
      while (bits) {
        const std::uint64_t g = w * 64 + static_cast<std::uint64_t>(std::countr_zero(bits));
        bits &= bits - 1;
        if (g >= hw_groups_) break;
        add(g);
      }
    }
  }
  for (auto& bucket : by_depth)
    for (std::uint32_t g : bucket) compute_group_links(g);
}

// The same-depth face neighbour of cell p (or the coarser leaf there), from the links of p's
// group: pool_layout.h's rule as the server's Octree applies it, with every index read from the
// (untrusted) pools bounds-checked first.
std::uint32_t Replica::same_depth_neighbour(std::uint32_t p, pl::uint face) const noexcept {
  const std::uint64_t cells = hw_groups_ * pl::kCellsPerGroup;
  if (p < root_count_) return pl::dc_root_neighbour(p, face, geometry_.roots_per_axis);
  if (p >= cells) return kNoCell;
  if (pl::dc_face_is_inner(p, face)) return pl::dc_sibling_across(p, face);
  const std::uint32_t q = links_[pl::dc_link_index(pl::dc_group_of(p), face)];
  if (q == kNoCell || q >= cells) return kNoCell;
  const std::uint32_t fc = first_child_[q];
  if (fc != kNoCell && std::uint64_t{fc} + pl::kCellsPerGroup > cells) return kNoCell;
  return pl::dc_resolve_link(p, face, q, fc);
}

void Replica::set_links_of(std::uint64_t g0, std::uint64_t groups) noexcept {
  const std::uint64_t end = std::min<std::uint64_t>(g0 + groups, links_.size() / pl::kFaceCount);
  for (std::uint64_t c = g0 >> kLinkChunkLog2; (c << kLinkChunkLog2) < end; ++c) {
    if (links_set_[c]) continue;
    links_set_[c] = 1;
    const std::uint64_t a = c << kLinkChunkLog2;
    const std::uint64_t b = std::min<std::uint64_t>(a + (1u << kLinkChunkLog2), end);
    std::fill(&links_[pl::dc_link_index(static_cast<std::uint32_t>(a), 0)],
              &links_[pl::dc_link_index(static_cast<std::uint32_t>(b - 1), 0)] + pl::kFaceCount,
              kNoCell);
  }
}

void Replica::compute_group_links(std::uint32_t g) noexcept {
  ++links_recomputed_;
  set_links_of(g, 1);
  std::uint32_t* out = &links_[pl::dc_link_index(g, 0)];
  if (g < root_count_ / pl::kCellsPerGroup || pl::dc_group_is_free(depth_flags_[g])) {
    for (pl::uint f = 0; f < pl::kFaceCount; ++f) out[f] = kNoCell;
    return;
  }
  const std::uint32_t p = group_parent_[g];
  std::uint32_t tmp[pl::kFaceCount];
  for (pl::uint f = 0; f < pl::kFaceCount; ++f) tmp[f] = same_depth_neighbour(p, f);
  std::memcpy(out, tmp, sizeof tmp);
}

std::uint64_t Replica::pool_hash() const noexcept {
  const auto span = [](const auto& a) { return std::span(a.data(), a.size()); };
  return protocol::pool_hash(hw_groups_, span(first_child_), span(colour_), span(group_parent_),
                             span(depth_flags_));
}

std::uint64_t Replica::links_hash() const noexcept {
  protocol::PoolHasher h;
  h.add(hw_groups_);
  h.add_bytes(links_.data(), hw_groups_ * pl::kFaceCount * 4);
  return h.finish();
}

PoolView Replica::view() const noexcept {
  PoolView v;
  const std::size_t cells = hw_groups_ * 8;
  v.first_child = {first_child_.data(), cells};
  v.colour = {colour_.data(), cells};
  v.group_parent = {group_parent_.data(), hw_groups_};
  v.group_depth_flags = {depth_flags_.data(), hw_groups_};
  v.group_links = {links_.data(), hw_groups_ * pl::kFaceCount};
  v.roots_per_axis = geometry_.roots_per_axis;
  v.edge_m = geometry_.edge_m;
  v.filtered_interiors = true;  // the server's values: 0 exactly over empty subtrees (4.4)
  return v;
}

}  // namespace deepcanvas::client_core
