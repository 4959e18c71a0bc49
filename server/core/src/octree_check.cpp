// Octree: invariant checker, statistics, hashes and extra field pools.
#include <cstring>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "deepcanvas/protocol/pool_hash.hpp"
#include "octree_impl.hpp"

namespace deepcanvas::server_core {

namespace {

Error broken(std::string msg) {
  return make_error(Errc::internal, "octree invariant: " + std::move(msg));
}

std::string cell_str(CellIndex c) {
  return "cell " + std::to_string(c);
}

using Hasher = protocol::PoolHasher;

struct Visit {
  CellIndex cell;
  CellCoord coord;
};

// The checks below are templates over the pool state (Octree::Impl, private to Octree, deduced
// at the one call in check_invariants()) so that each can be a function of its own.

// Root groups have no parent, depth 0, no flags and no links.
template <class Pools>
Result<void> check_root_groups(const Pools& m) {
  for (GroupIndex g = 0; g < m.root_groups; ++g) {
    if (m.gparent[g] != kNoCell) return broken("root group " + std::to_string(g) + " has a parent");
    if (m.gdepth[g] != 0) return broken("root group " + std::to_string(g) + " has depth/flags");
    for (int f = 0; f < kFaces; ++f)
      if (m.links_of(g)[f] != kNoCell)
        return broken("root group " + std::to_string(g) + " has a link");
  }
  return {};
}

// A freed group is clean: the free flag only, no children, no colour, no links.
template <class Pools>
Result<void> check_free_group(const Pools& m, GroupIndex g) {
  if (m.gdepth[g] != kGroupFreeFlag) return broken("free group with depth bits");
  for (int i = 0; i < 8; ++i)
    if (m.first_child[g * 8 + i] != kNoCell || m.colour[g * 8 + i] != 0)
      return broken("free " + cell_str(g * 8 + i) + " is not clean");
  for (int f = 0; f < kFaces; ++f)
    if (m.links_of(g)[f] != kNoCell) return broken("free group with links");
  return {};
}

// Every live group: its parent is live, points back at it, and is one level shallower; the
// live, free and per-depth counters match the pools. Returns the number of live groups.
template <class Pools>
Result<std::uint64_t> check_group_parents_and_counters(const Pools& m) {
  std::uint64_t live = 0, freed = 0;
  std::uint64_t per_depth[kMaxSupportedDepth + 1] = {};
  for (GroupIndex g = m.root_groups; g < m.hw_groups; ++g) {
    if (m.is_free_group(g)) {
      ++freed;
      if (auto r = check_free_group(m, g); !r) return std::move(r).error();
      continue;
    }
    ++live;
    const CellIndex p = m.gparent[g];
    const int d = m.gdepth[g] & kDepthMask;
    if ((m.gdepth[g] & ~kDepthMask) != 0) return broken("group with unknown flag bits");
    if (p >= m.hw_cells()) return broken("group " + std::to_string(g) + " has a bad parent");
    if (m.is_free_group(p >> 3))
      return broken("group " + std::to_string(g) + " has a freed parent");
    if (m.first_child[p] != g * 8)
      return broken("parent " + cell_str(p) + " does not point back at group " + std::to_string(g));
    if (d < 1 || d > m.cfg.max_depth || d != m.depth(p) + 1)
      return broken("group " + std::to_string(g) + " has an inconsistent depth");
    ++per_depth[d];
  }
  if (live != m.live_groups || freed != m.free_groups)
    return broken("live/free group counters disagree with the pools");
  for (int d = 0; d <= kMaxSupportedDepth; ++d)
    if (per_depth[d] != m.groups_at_depth[d]) return broken("per-depth counters disagree");
  return live;
}

// Free lists: each free group on exactly one list (its own block's), nothing else on them.
template <class Pools>
Result<void> check_free_lists(const Pools& m) {
  const std::uint64_t hw = m.hw_groups;
  std::vector<std::uint8_t> seen(hw, 0);
  const BlockId nb = static_cast<BlockId>((hw + m.groups_per_block - 1) >> m.gblock_shift);
  std::uint64_t listed = 0;
  for (BlockId b = 0; b < m.block_capacity; ++b) {
    std::uint64_t n = 0;
    for (GroupIndex g = m.head(b); g != kNoGroup; g = m.gparent[g]) {
      if (b >= nb || g >= hw)
        return broken("free list of block " + std::to_string(b) + " leaves the pool");
      if ((g >> m.gblock_shift) != b)
        return broken("free list of block " + std::to_string(b) + " crosses blocks");
      if (!m.is_free_group(g)) return broken("live group " + std::to_string(g) + " on a free list");
      if (seen[g]) return broken("group " + std::to_string(g) + " twice on free lists (cycle?)");
      seen[g] = 1;
      if (++n > m.groups_per_block) return broken("free list too long");
    }
    if (n != m.free_count[b])
      return broken("free count of block " + std::to_string(b) + " is wrong");
    listed += n;
    if (b >= nb && m.free_count[b] != 0) return broken("free count beyond the high-water mark");
  }
  if (listed != m.free_groups) return broken("a free group is on no free list");
  return {};
}

// The coordinate of k's face neighbour across face f, or nullopt at the canvas border
// (lim: cells per axis at k's depth).
std::optional<CellCoord> across_face(CellCoord k, int f, std::uint64_t lim) {
  std::uint32_t* a = f < 2 ? &k.x : f < 4 ? &k.y : &k.z;
  if (f & 1) {
    if (*a + 1ull >= lim) return std::nullopt;
    ++*a;
  } else {
    if (*a == 0) return std::nullopt;
    --*a;
  }
  return k;
}

// Leaf: no face-adjacent leaf two or more levels coarser (the finer side sees every violation,
// so leaves only need to look for coarser ones), and face_neighbour() agrees with find().
template <class Pools>
Result<void> check_leaf_balance(const Octree& tree, const Pools& m, const Visit& v,
                                std::uint64_t lim) {
  for (int f = 0; f < kFaces; ++f) {
    const auto nk = across_face(v.coord, f, lim);
    if (!nk) continue;
    const LocateResult nr = tree.find(*nk);
    if (nr.coord.depth + 1 < v.coord.depth)
      return broken("2:1 balance: leaf " + cell_str(v.cell) + " at depth " +
                    std::to_string(v.coord.depth) + " faces a leaf at depth " +
                    std::to_string(nr.coord.depth));
    if (m.face_neighbour(v.cell, f) != nr.cell)
      return broken("face_neighbour of " + cell_str(v.cell) + " disagrees with brute force");
  }
  return {};
}

// Links of the child group g of internal cell v: v's same-depth face neighbours, brute force.
template <class Pools>
Result<void> check_group_links(const Octree& tree, const Pools& m, const Visit& v, GroupIndex g,
                               std::uint64_t lim) {
  for (int f = 0; f < kFaces; ++f) {
    CellIndex want = kNoCell;
    if (const auto nk = across_face(v.coord, f, lim)) {
      const LocateResult nr = tree.find(*nk);
      if (nr.coord.depth != v.coord.depth)
        return broken("internal " + cell_str(v.cell) + " lacks a same-depth neighbour (balance)");
      want = nr.cell;
    }
    if (m.links_of(g)[f] != want)
      return broken("link " + std::to_string(f) + " of group " + std::to_string(g) +
                    " disagrees with brute force");
  }
  return {};
}

// Traversal from the roots: reaches every live group exactly once and no freed cell; checks
// 2:1 balance and links against a brute-force search (find()) on the way.
template <class Pools>
Result<void> check_reachability(const Octree& tree, const Pools& m, std::uint64_t live) {
  std::vector<Visit> stack;
  std::uint64_t reached = 0;
  for (CellIndex r = 0; r < m.root_count; ++r)
    stack.push_back({r, CellCoord{0, r % m.n, (r / m.n) % m.n, r / (m.n * m.n)}});
  while (!stack.empty()) {
    const Visit v = stack.back();
    stack.pop_back();
    const CellIndex c = v.cell;
    const CellCoord k = v.coord;
    const std::uint64_t lim = std::uint64_t{m.n} << k.depth;
    const CellIndex fc = m.first_child[c];
    if (fc == kNoCell) {
      if (auto r = check_leaf_balance(tree, m, v, lim); !r) return r;
      continue;
    }
    if (fc % 8 != 0 || fc >= m.hw_cells()) return broken(cell_str(c) + " has a bad first child");
    const GroupIndex g = fc >> 3;
    if (m.is_free_group(g))
      return broken(cell_str(c) + " reaches freed group " + std::to_string(g));
    if (m.gparent[g] != c)
      return broken("group " + std::to_string(g) + " does not name its parent");
    if (++reached > live) return broken("traversal reaches more groups than are live");
    if (auto r = check_group_links(tree, m, v, g, lim); !r) return r;
    for (std::uint32_t i = 0; i < 8; ++i) {
      CellCoord ck{k.depth + 1, k.x * 2 + (i & 1u), k.y * 2 + ((i >> 1) & 1u),
                   k.z * 2 + ((i >> 2) & 1u)};
      stack.push_back({fc + i, ck});
    }
  }
  if (reached != live) return broken("some live groups are unreachable from the roots");
  return {};
}

}  // namespace

Result<void> Octree::check_invariants() const {
  const Impl& m = *impl_;
  if (m.hw_groups < m.root_groups || m.hw_groups > m.group_capacity)
    return broken("high-water mark out of range");
  if (auto r = check_root_groups(m); !r) return r;
  auto live = check_group_parents_and_counters(m);
  if (!live) return std::move(live).error();
  if (auto r = check_free_lists(m); !r) return r;
  return check_reachability(*this, m, *live);
}

OctreeStats Octree::stats() const {
  const Impl& m = *impl_;
  OctreeStats s;
  s.live_cells = live_cells();
  s.leaves = s.live_cells - m.live_groups;
  for (int d = kMaxSupportedDepth; d >= 1; --d) {
    if (m.groups_at_depth[d]) {
      s.max_depth = d;
      break;
    }
  }
  s.high_water_cells = m.hw_cells();
  s.pool_bytes = m.hw_cells() * 8 + m.hw_groups * (4 + 1 + 24);
  return s;
}

std::uint64_t Octree::allocated_bytes() const noexcept {
  const Impl& m = *impl_;
  using base::round_up_to_page;
  const std::uint64_t cells = m.hw_cells();
  const std::uint64_t nb = (cells + m.cfg.block_cells - 1) >> m.block_shift;
  std::uint64_t bytes = 2 * round_up_to_page(cells * 4) + round_up_to_page(m.hw_groups * 4) +
                        round_up_to_page(m.hw_groups) + round_up_to_page(m.hw_groups * 24) +
                        round_up_to_page((m.hw_groups + 63) / 64 * 8);
  bytes += round_up_to_page(nb * sizeof(BlockState)) + 2 * round_up_to_page(nb * 4) +
           round_up_to_page(nb);
  bytes += (m.dirty_list.capacity() + m.avail.capacity()) * sizeof(BlockId) +
           m.refine_stack.capacity() * sizeof(CellIndex) + sizeof(Impl);
  return bytes;
}

std::uint64_t Octree::pool_hash() const {
  // The wire-level definition (protocol/pool_hash.hpp), so that replicas compare directly.
  return protocol::pool_hash(impl_->hw_groups, first_child_pool(), colour_pool(),
                             group_parent_pool(), group_depth_flags_pool());
}

std::uint64_t Octree::canvas_hash() const {
  const Impl& m = *impl_;
  Hasher h;
  h.add(m.n);
  // Pre-order over the roots in index order, children in position order: each cell adds
  // (leaf?, colour), an interior cell's colour excluded (a filtered value derived from its
  // children, refreshed lazily). Structure and depths follow from the leaf flags.
  std::vector<CellIndex> stack;
  for (CellIndex r = m.root_count; r-- > 0;) stack.push_back(r);
  while (!stack.empty()) {
    const CellIndex c = stack.back();
    stack.pop_back();
    const CellIndex fc = m.first_child[c];
    h.add(fc == kNoCell ? (std::uint64_t{1} << 32) | m.colour[c] : std::uint64_t{2} << 32);
    if (fc != kNoCell)
      for (CellIndex i = 8; i-- > 0;) stack.push_back(fc + i);
  }
  return h.finish();
}

// ---------------------------------------------------------------------------------------------
// Field pools

namespace {

class MappedFieldPool final : public Octree::FieldPool {
 public:
  MappedFieldPool(std::string name, std::size_t bpc, base::ReservedArray<unsigned char> mem)
      : name_(std::move(name)), bpc_(bpc), mem_(std::move(mem)) {}
  const std::string& name() const noexcept override { return name_; }
  std::size_t bytes_per_cell() const noexcept override { return bpc_; }
  void* data() noexcept override { return mem_.data(); }
  void clear() noexcept override { mem_.discard(); }

 private:
  std::string name_;
  std::size_t bpc_;
  base::ReservedArray<unsigned char> mem_;
};

}  // namespace

Result<std::unique_ptr<Octree::FieldPool>> Octree::add_field_pool(std::string name,
                                                                  std::size_t bytes_per_cell) {
  if (bytes_per_cell != 1 && bytes_per_cell != 2 && bytes_per_cell != 4 && bytes_per_cell != 8)
    return make_error(Errc::invalid_argument, "add_field_pool: element size must be 1, 2, 4 or 8");
  base::ReservedArray<unsigned char> mem;
  if (!mem.reserve(impl_->group_capacity * 8 * bytes_per_cell))
    return make_error(Errc::out_of_memory, "add_field_pool: cannot reserve address space");
  return std::unique_ptr<FieldPool>(
      new MappedFieldPool(std::move(name), bytes_per_cell, std::move(mem)));
}

}  // namespace deepcanvas::server_core
