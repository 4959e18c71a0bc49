// Octree: creation, pool access, allocation, refine / coarsen with 2:1 balance, navigation.
// Links, blocks and masks: octree_links.cpp. Checker, hashes, field pools: octree_check.cpp.
#include <bit>
#include <cmath>
#include <cstring>

#include "octree_impl.hpp"

namespace deepcanvas::server_core {

namespace pl = pool_layout;

namespace {

Error bad(std::string msg) {
  return make_error(Errc::invalid_argument, std::move(msg));
}

}  // namespace

Octree::Octree(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {
  config_block_cells_ = impl_->cfg.block_cells;
  first_child_ptr_ = impl_->first_child.data();
  colour_ptr_ = impl_->colour.data();
}

Octree::~Octree() = default;

Result<std::unique_ptr<Octree>> Octree::create(const OctreeConfig& config) {
  const OctreeConfig& c = config;
  if (c.roots_per_axis < pl::kMinRootsPerAxis || c.roots_per_axis > pl::kMaxRootsPerAxis ||
      c.roots_per_axis % 2 != 0)
    return bad("octree: roots_per_axis must be even and in 2..64");
  if (!std::isfinite(c.edge_m) || c.edge_m <= 0.0)
    return bad("octree: edge_m must be a positive finite number of metres");
  if (c.max_depth < 1 || c.max_depth > kMaxSupportedDepth)
    return bad("octree: max_depth must be in 1..24");
  if (c.block_cells < 512 || !std::has_single_bit(c.block_cells) || c.block_cells > (1u << 24))
    return bad("octree: block_cells must be a power of two in 512..2^24");
  const std::uint64_t roots = pl::dc_root_count(c.roots_per_axis);
  if (c.max_cells > (std::uint64_t{1} << pl::kMaxCellsLog2))
    return bad("octree: max_cells must be at most 2^28 (the GPU texture limit)");
  if (c.max_cells < roots + pl::kCellsPerGroup)
    return bad("octree: max_cells must leave room for the roots and one group");

  auto impl = std::make_unique<Impl>();
  Impl& m = *impl;
  m.cfg = c;
  m.cfg.max_cells = c.max_cells / pl::kCellsPerGroup * pl::kCellsPerGroup;
  m.n = c.roots_per_axis;
  m.root_count = static_cast<std::uint32_t>(roots);
  m.root_groups = m.root_count / pl::kCellsPerGroup;
  m.block_shift = static_cast<std::uint32_t>(std::countr_zero(c.block_cells));
  m.gblock_shift = m.block_shift - 3;
  m.groups_per_block = c.block_cells / pl::kCellsPerGroup;
  m.mask_words_per_block = m.groups_per_block / 64;
  m.avail_threshold = m.groups_per_block / 4;
  m.group_capacity = m.cfg.max_cells / pl::kCellsPerGroup;
  m.block_capacity =
      static_cast<std::uint32_t>((m.cfg.max_cells + c.block_cells - 1) / c.block_cells);
  m.half_edge = c.edge_m / 2;
  m.fixed_scale = static_cast<double>(std::uint64_t{m.n} << kFixedBits) / c.edge_m;

  const std::uint64_t cells = m.group_capacity * pl::kCellsPerGroup;
  const std::uint64_t mask_words = (m.group_capacity + 63) / 64 + 1;
  bool ok = m.first_child.reserve(cells) && m.colour.reserve(cells) &&
            m.gparent.reserve(m.group_capacity) && m.gdepth.reserve(m.group_capacity) &&
            m.links.reserve(m.group_capacity * pl::kFaceCount) && m.mask.reserve(mask_words) &&
            m.blocks.reserve(m.block_capacity) && m.free_head.reserve(m.block_capacity) &&
            m.free_count.reserve(m.block_capacity) && m.block_flags.reserve(m.block_capacity);
  if (!ok)
    return make_error(Errc::out_of_memory, "octree: cannot reserve the pools' address space");

  m.dirty_list.reserve(1024);
  m.avail.reserve(1024);
  m.refine_stack.reserve(64);

  for (CellIndex r = 0; r < m.root_count; ++r) {
    m.first_child[r] = kNoCell;
    m.colour[r] = 0;
  }
  for (GroupIndex g = 0; g < m.root_groups; ++g) {
    m.gparent[g] = kNoCell;
    m.gdepth[g] = 0;
    std::uint32_t* l = m.links_of(g);
    for (int f = 0; f < kFaces; ++f) l[f] = kNoCell;
  }
  m.hw_groups = m.root_groups;
  for (BlockId b = 0; b <= (m.root_count - 1) >> m.block_shift; ++b) m.mark_dirty(b);
  return std::unique_ptr<Octree>(new Octree(std::move(impl)));
}

const OctreeConfig& Octree::config() const noexcept {
  return impl_->cfg;
}
std::uint32_t Octree::root_count() const noexcept {
  return impl_->root_count;
}
double Octree::cell_edge_m(int depth) const noexcept {
  return impl_->cfg.edge_m / static_cast<double>(std::uint64_t{impl_->n} << depth);
}

CellIndex Octree::parent(CellIndex c) const noexcept {
  return impl_->gparent[pl::dc_group_of(c)];
}
int Octree::depth(CellIndex c) const noexcept {
  return impl_->depth(c);
}
bool Octree::is_live(CellIndex c) const noexcept {
  return c < impl_->hw_cells() && !impl_->is_free_group(pl::dc_group_of(c));
}
CellIndex Octree::group_link(GroupIndex g, int face) const noexcept {
  return impl_->links[pl::dc_link_index(g, static_cast<pl::uint>(face))];
}
std::uint64_t Octree::high_water_cells() const noexcept {
  return impl_->hw_cells();
}
std::uint64_t Octree::live_cells() const noexcept {
  return impl_->root_count + impl_->live_groups * pl::kCellsPerGroup;
}

std::span<const std::uint32_t> Octree::first_child_pool() const noexcept {
  return {impl_->first_child.data(), impl_->hw_cells()};
}
std::span<const std::uint32_t> Octree::colour_pool() const noexcept {
  return {impl_->colour.data(), impl_->hw_cells()};
}
std::span<const std::uint32_t> Octree::group_parent_pool() const noexcept {
  return {impl_->gparent.data(), impl_->hw_groups};
}
std::span<const std::uint8_t> Octree::group_depth_flags_pool() const noexcept {
  return {impl_->gdepth.data(), impl_->hw_groups};
}
std::span<const std::uint32_t> Octree::group_link_pool() const noexcept {
  return {impl_->links.data(), impl_->hw_groups * pl::kFaceCount};
}

// ---------------------------------------------------------------------------------------------
// Allocation

GroupIndex Octree::Impl::take_from_block(BlockId b) noexcept {
  const GroupIndex h = head(b);
  if (h != kNoGroup) {
    set_head(b, gparent[h]);
    --free_count[b];
    --free_groups;
    return h;
  }
  // Bump only inside the block that holds the high-water mark.
  if ((hw_groups >> gblock_shift) == b && hw_groups < group_capacity) {
    return static_cast<GroupIndex>(hw_groups++);
  }
  return kNoGroup;
}

GroupIndex Octree::Impl::alloc_group(CellIndex parent_cell) noexcept {
  const BlockId pb = parent_cell >> block_shift;
  GroupIndex g = take_from_block(pb);
  if (g != kNoGroup) return g;
  if (open_block != kNoBlock && open_block != pb) {
    g = take_from_block(open_block);
    if (g != kNoGroup) return g;
  }
  // A block with plenty of free groups (entries are validated lazily).
  while (!avail.empty()) {
    const BlockId b = avail.back();
    avail.pop_back();
    block_flags[b] &= static_cast<std::uint8_t>(~kInAvail);
    if (free_count[b] >= avail_threshold) {
      open_block = b;
      return take_from_block(b);
    }
  }
  // Fresh memory at the high-water mark.
  if (hw_groups < group_capacity) {
    open_block = static_cast<BlockId>(hw_groups >> gblock_shift);
    return take_from_block(open_block);
  }
  // Last resort before reporting out of memory: any block with a free group.
  if (free_groups > 0) {
    const BlockId nb = static_cast<BlockId>((hw_groups + groups_per_block - 1) >> gblock_shift);
    for (BlockId b = 0; b < nb; ++b) {
      if (free_count[b] > 0) {
        open_block = b;
        return take_from_block(b);
      }
    }
  }
  return kNoGroup;
}

void Octree::Impl::free_group(GroupIndex g) noexcept {
  const CellIndex base = pl::dc_group_first_cell(g);
  for (CellIndex i = 0; i < pl::kCellsPerGroup; ++i) {
    first_child[base + i] = kNoCell;
    colour[base + i] = 0;
  }
  std::uint32_t* l = links_of(g);
  for (int f = 0; f < kFaces; ++f) l[f] = kNoCell;
  const int d = static_cast<int>(pl::dc_depth_of(gdepth[g]));
  --groups_at_depth[d];
  gdepth[g] = kGroupFreeFlag;
  const BlockId b = g >> gblock_shift;
  gparent[g] = head(b);
  set_head(b, g);
  ++free_count[b];
  ++free_groups;
  --live_groups;
  set_mask(g);
  mark_dirty(b);
  if (free_count[b] == avail_threshold && !(block_flags[b] & kInAvail) && b != open_block) {
    block_flags[b] |= kInAvail;
    avail.push_back(b);
  }
}

// Creates the children of leaf c (balance is the caller's business). False: out of memory.
bool Octree::Impl::split(CellIndex c) noexcept {
  const GroupIndex g = alloc_group(c);
  if (g == kNoGroup) return false;
  const CellIndex base = pl::dc_group_first_cell(g);
  const std::uint32_t col = colour[c];
  for (CellIndex i = 0; i < pl::kCellsPerGroup; ++i) {
    first_child[base + i] = kNoCell;
    colour[base + i] = col;
  }
  const int d = depth(c) + 1;
  gparent[g] = c;
  gdepth[g] = static_cast<std::uint8_t>(d);
  // The new group's links are its parent c's face neighbours.
  std::uint32_t* l = links_of(g);
  const std::uint32_t* src = links.data();
  for (int f = 0; f < kFaces; ++f) l[f] = same_depth_neighbour(c, f, src);
  first_child[c] = base;
  filter_stale(c);
  ++groups_at_depth[d];
  ++live_groups;
  set_mask(g);
  const BlockId cb = c >> block_shift;
  const BlockId gb = base >> block_shift;
  mark_dirty(cb);
  if (gb != cb) mark_dirty(gb);
  return true;
}

Result<void> Octree::refine(CellIndex c, std::uint64_t* created) {
  Impl& m = *impl_;
  if (created) *created = 0;
  if (c >= m.hw_cells() || m.is_free_group(pl::dc_group_of(c)))
    return bad("refine: not a live cell");
  if (m.first_child[c] != kNoCell) return bad("refine: not a leaf");
  if (m.depth(c) >= m.cfg.max_depth)
    return make_error(Errc::refused, "refine: the cell is at the maximum depth");

  // Iterative balance: before splitting x, every coarser face-neighbour leaf of x is split
  // first. Only faces across the parent can hold a coarser leaf, and each such leaf is one level
  // coarser than x, so the stack holds a strictly shallower chain (at most 25 entries).
  auto& stack = m.refine_stack;
  stack.clear();
  stack.push_back(c);
  std::uint64_t made = 0;
  while (!stack.empty()) {
    const CellIndex x = stack.back();
    if (m.first_child[x] != kNoCell) {  // already split on the way
      stack.pop_back();
      continue;
    }
    bool pushed = false;
    if (x >= m.root_count) {
      const std::uint32_t* l = m.links_of(pl::dc_group_of(x));
      for (pl::uint axis = 0; axis < 3; ++axis) {
        const CellIndex q = l[pl::dc_outer_face(x, axis)];
        if (q != kNoCell && m.first_child[q] == kNoCell) {
          stack.push_back(q);
          pushed = true;
          break;
        }
      }
    }
    if (pushed) continue;
    if (!m.split(x)) {
      if (created) *created = made;
      return make_error(Errc::out_of_memory, "refine: the octree's cell capacity is exhausted");
    }
    made += pl::kCellsPerGroup;
    stack.pop_back();
  }
  if (created) *created = made;
  return {};
}

bool Octree::Impl::can_coarsen(CellIndex c) const noexcept {
  if (c >= hw_cells() || is_free_group(pl::dc_group_of(c))) return false;
  const CellIndex fc = first_child[c];
  if (fc == kNoCell) return false;
  for (CellIndex i = 0; i < pl::kCellsPerGroup; ++i)
    if (first_child[fc + i] != kNoCell) return false;
  // The children's group links are c's six same-depth neighbours. A neighbour's children that
  // touch c must be leaves: a deeper cell there would face c two levels apart.
  const std::uint32_t* l = links_of(pl::dc_group_of(fc));
  for (pl::uint f = 0; f < pl::kFaceCount; ++f) {
    const CellIndex nb = l[f];
    if (nb == kNoCell) continue;
    const CellIndex nfc = first_child[nb];
    if (nfc == kNoCell) continue;
    // c's face f is positive: the neighbour's children on its negative side touch c.
    const pl::uint axis = pl::dc_face_axis(f);
    const pl::uint want = pl::dc_face_positive(f) ? 0u : 1u;
    for (CellIndex i = 0; i < pl::kCellsPerGroup; ++i) {
      if (((i >> axis) & 1u) != want) continue;
      if (first_child[nfc + i] != kNoCell) return false;
    }
  }
  return true;
}

bool Octree::can_coarsen(CellIndex c) const noexcept {
  return impl_->can_coarsen(c);
}

Result<void> Octree::coarsen(CellIndex c) {
  Impl& m = *impl_;
  if (!m.can_coarsen(c)) {
    if (c >= m.hw_cells() || m.is_free_group(pl::dc_group_of(c)))
      return bad("coarsen: not a live cell");
    return make_error(Errc::refused,
                      "coarsen: the cell is a leaf, has internal children, or coarsening "
                      "would break 2:1 balance");
  }
  const CellIndex fc = m.first_child[c];
  std::uint32_t sum[4] = {0, 0, 0, 0};
  for (CellIndex i = 0; i < pl::kCellsPerGroup; ++i) {
    const std::uint32_t v = m.colour[fc + i];
    for (pl::uint k = 0; k < 4; ++k) sum[k] += pl::dc_colour_channel(v, k);
  }
  const std::uint32_t avg =
      pl::dc_pack_rgba8((sum[0] + 4) / 8, (sum[1] + 4) / 8, (sum[2] + 4) / 8, (sum[3] + 4) / 8);
  m.first_child[c] = kNoCell;
  m.colour[c] = avg;
  m.parent_filter_stale(c);
  m.mark_dirty(c >> m.block_shift);
  m.free_group(pl::dc_group_of(fc));
  return {};
}

void Octree::set_colour(CellIndex c, std::uint32_t rgba) noexcept {
  Impl& m = *impl_;
  if (c >= m.hw_cells() || m.colour[c] == rgba) return;
  m.colour[c] = rgba;
  m.parent_filter_stale(c);
  if (m.first_child[c] != kNoCell) m.filter_stale(c);  // an interior value is derived
  m.mark_dirty(c >> m.block_shift);
}

// ---------------------------------------------------------------------------------------------
// Navigation

Result<LocateResult> Octree::locate(const Vec3d& p, int max_depth) const {
  const Impl& m = *impl_;
  if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
    return bad("locate: the point is not finite");
  if (max_depth < 0) return bad("locate: negative depth");
  const double h = m.half_edge;
  if (p.x < -h || p.x > h || p.y < -h || p.y > h || p.z < -h || p.z > h)
    return bad("locate: the point is outside the canvas");
  const std::uint64_t lim = (std::uint64_t{m.n} << kFixedBits) - 1;
  auto fix = [&](double v) {
    const double u = std::floor((v + h) * m.fixed_scale);
    const std::uint64_t i = u <= 0 ? 0 : static_cast<std::uint64_t>(u);
    return i > lim ? lim : i;  // the canvas's max faces belong to the last cell
  };
  const std::uint64_t ux = fix(p.x), uy = fix(p.y), uz = fix(p.z);
  const int dmax = max_depth < m.cfg.max_depth ? max_depth : m.cfg.max_depth;
  CellIndex c = pl::dc_root_index(static_cast<pl::uint>(ux >> kFixedBits),
                                  static_cast<pl::uint>(uy >> kFixedBits),
                                  static_cast<pl::uint>(uz >> kFixedBits), m.n);
  int d = 0;
  const std::uint32_t* fcp = m.first_child.data();
  while (d < dmax) {
    const CellIndex fc = fcp[c];
    if (fc == kNoCell) break;
    ++d;
    const int s = kFixedBits - d;
    c = fc + pl::dc_slot(static_cast<pl::uint>(ux >> s), static_cast<pl::uint>(uy >> s),
                         static_cast<pl::uint>(uz >> s));
  }
  const int s = kFixedBits - d;
  LocateResult r;
  r.cell = c;
  r.coord = CellCoord{d, static_cast<std::uint32_t>(ux >> s), static_cast<std::uint32_t>(uy >> s),
                      static_cast<std::uint32_t>(uz >> s)};
  return r;
}

LocateResult Octree::find(const CellCoord& k) const noexcept {
  const Impl& m = *impl_;
  LocateResult r;
  r.coord = k;
  if (k.depth < 0 || k.depth > m.cfg.max_depth) return r;
  const std::uint64_t lim = std::uint64_t{m.n} << k.depth;
  if (k.x >= lim || k.y >= lim || k.z >= lim) return r;
  const int d0 = k.depth;
  CellIndex c = pl::dc_root_index(k.x >> d0, k.y >> d0, k.z >> d0, m.n);
  int d = 0;
  while (d < d0) {
    const CellIndex fc = m.first_child[c];
    if (fc == kNoCell) break;
    ++d;
    const int s = d0 - d;
    c = fc + pl::dc_slot(k.x >> s, k.y >> s, k.z >> s);
  }
  r.cell = c;
  const int s = d0 - d;
  r.coord = CellCoord{d, k.x >> s, k.y >> s, k.z >> s};
  return r;
}

CellCoord Octree::coord(CellIndex c) const noexcept {
  const Impl& m = *impl_;
  CellCoord k;
  k.depth = m.depth(c);
  int bit = 0;
  while (c >= m.root_count) {
    const std::uint32_t i = pl::dc_slot_of(c);
    k.x |= (i & 1u) << bit;
    k.y |= ((i >> 1) & 1u) << bit;
    k.z |= ((i >> 2) & 1u) << bit;
    ++bit;
    c = m.gparent[pl::dc_group_of(c)];
  }
  k.x |= (c % m.n) << bit;
  k.y |= ((c / m.n) % m.n) << bit;
  k.z |= (c / (m.n * m.n)) << bit;
  return k;
}

Aabb Octree::bounds_m(const CellCoord& k) const noexcept {
  const double e = cell_edge_m(k.depth);
  const double h = impl_->half_edge;
  Aabb b;
  b.min = {-h + k.x * e, -h + k.y * e, -h + k.z * e};
  b.max = {-h + (k.x + 1.0) * e, -h + (k.y + 1.0) * e, -h + (k.z + 1.0) * e};
  return b;
}

CellIndex Octree::face_neighbour(CellIndex c, int face) const noexcept {
  return impl_->face_neighbour(c, face);
}

CellIndex Octree::g3(CellIndex c, int axis) const noexcept {
  if (c < impl_->root_count) return kNoCell;  // roots use root-array arithmetic
  return impl_->face_neighbour(c, static_cast<int>(pl::dc_outer_face(c, static_cast<pl::uint>(axis))));
}

}  // namespace deepcanvas::server_core
