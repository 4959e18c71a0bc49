// Octree: checkpoints. A block's bytes and the allocator's state out (save_block,
// save_allocator), and a whole tree back in (restore), with every field of the untrusted bytes
// checked before the tree is handed out. Layouts in octree.hpp.
#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <string>

#include "octree_impl.hpp"

namespace deepcanvas::server_core {

namespace pl = pool_layout;

namespace {

constexpr std::uint32_t kBlockMagic = 0x4B424344u;  // "DCBK" little-endian
constexpr std::uint32_t kAllocMagic = 0x4C414344u;  // "DCAL"
constexpr std::uint32_t kSnapshotVersion = 1;
constexpr std::size_t kBlockHeaderBytes = 32;

class Writer {
 public:
  explicit Writer(std::size_t reserve) { out_.reserve(reserve); }
  template <class T>
  void put(T v) {
    static_assert(std::endian::native == std::endian::little, "little-endian hosts only");
    const auto* p = reinterpret_cast<const std::uint8_t*>(&v);
    out_.insert(out_.end(), p, p + sizeof(T));
  }
  template <class T>
  void put_array(const T* data, std::size_t n) {
    if (n == 0) return;
    const auto* p = reinterpret_cast<const std::uint8_t*>(data);
    out_.insert(out_.end(), p, p + n * sizeof(T));
  }
  std::vector<std::uint8_t> take() { return std::move(out_); }

 private:
  std::vector<std::uint8_t> out_;
};

class Reader {
 public:
  explicit Reader(std::span<const std::uint8_t> in) : in_(in) {}
  template <class T>
  bool get(T& v) {
    if (in_.size() - pos_ < sizeof(T)) return false;
    std::memcpy(&v, in_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return true;
  }
  template <class T>
  bool get_array(T* out, std::size_t n) {
    if (n == 0) return true;
    if ((in_.size() - pos_) / sizeof(T) < n) return false;
    std::memcpy(out, in_.data() + pos_, n * sizeof(T));
    pos_ += n * sizeof(T);
    return true;
  }
  bool at_end() const { return pos_ == in_.size(); }

 private:
  std::span<const std::uint8_t> in_;
  std::size_t pos_ = 0;
};

Error malformed(std::string what) {
  return make_error(Errc::malformed, "octree checkpoint: " + std::move(what));
}

}  // namespace

std::vector<std::uint8_t> Octree::save_block(BlockId b) const {
  const Impl& m = *impl_;
  const std::uint32_t cells = m.cfg.block_cells;
  const std::uint32_t groups = m.groups_per_block;
  Writer w(kBlockHeaderBytes + std::size_t{cells} * 8 + std::size_t{groups} * 5);
  w.put(kBlockMagic);
  w.put(kSnapshotVersion);
  w.put(cells);
  w.put(m.free_count[b]);
  w.put(m.blocks[b].version);
  w.put(m.free_head[b]);
  w.put(m.block_flags[b]);
  w.put(std::uint8_t{0});
  w.put(std::uint16_t{0});
  const std::size_t c0 = std::size_t{b} << m.block_shift;
  const std::size_t g0 = std::size_t{b} << m.gblock_shift;
  w.put_array(m.first_child.data() + c0, cells);
  w.put_array(m.colour.data() + c0, cells);
  w.put_array(m.gparent.data() + g0, groups);
  w.put_array(m.gdepth.data() + g0, groups);
  return w.take();
}

std::vector<std::uint8_t> Octree::save_allocator() const {
  const Impl& m = *impl_;
  Writer w(256 + m.avail.size() * 4);
  w.put(kAllocMagic);
  w.put(kSnapshotVersion);
  w.put(m.hw_groups);
  w.put(m.open_block);
  w.put(block_count());
  w.put(m.live_groups);
  w.put(m.free_groups);
  for (std::uint64_t n : m.groups_at_depth) w.put(n);
  w.put(static_cast<std::uint32_t>(m.avail.size()));
  w.put_array(m.avail.data(), m.avail.size());
  return w.take();
}

Result<std::unique_ptr<Octree>> Octree::restore(
    const OctreeConfig& config, std::span<const std::uint8_t> allocator,
    const std::function<std::span<const std::uint8_t>(BlockId)>& block) {
  auto fresh = Octree::create(config);
  if (!fresh) return std::move(fresh).error();
  std::unique_ptr<Octree> tree = std::move(*fresh);
  Impl& m = *tree->impl_;
  (void)tree->take_dirty_blocks();

  // The allocator.
  Reader a(allocator);
  std::uint32_t magic = 0, version = 0, open_block = 0, blocks = 0, avail_n = 0;
  std::uint64_t hw_groups = 0, live_groups = 0, free_groups = 0;
  std::array<std::uint64_t, kMaxSupportedDepth + 1> at_depth{};
  if (!a.get(magic) || !a.get(version) || !a.get(hw_groups) || !a.get(open_block) ||
      !a.get(blocks) || !a.get(live_groups) || !a.get(free_groups))
    return malformed("allocator: truncated");
  if (magic != kAllocMagic) return malformed("allocator: bad magic");
  if (version != kSnapshotVersion)
    return make_error(Errc::unsupported,
                      "octree checkpoint: allocator layout version " + std::to_string(version));
  for (auto& n : at_depth)
    if (!a.get(n)) return malformed("allocator: truncated");
  if (!a.get(avail_n)) return malformed("allocator: truncated");
  if (hw_groups < m.root_groups || hw_groups > m.group_capacity)
    return malformed("allocator: high-water mark outside the canvas's capacity");
  m.hw_groups = hw_groups;
  if (blocks != tree->block_count()) return malformed("allocator: block count does not match");
  if (open_block != kNoBlock && open_block >= blocks)
    return malformed("allocator: open block beyond the high-water mark");
  if (avail_n > blocks) return malformed("allocator: more available blocks than blocks");
  std::vector<BlockId> avail(avail_n);
  if (!a.get_array(avail.data(), avail_n) || !a.at_end())
    return malformed("allocator: wrong length");
  for (BlockId b : avail)
    if (b >= blocks) return malformed("allocator: available block beyond the high-water mark");

  // The blocks.
  const std::uint32_t cells = m.cfg.block_cells;
  const std::uint32_t groups = m.groups_per_block;
  const std::size_t want = kBlockHeaderBytes + std::size_t{cells} * 8 + std::size_t{groups} * 5;
  for (BlockId b = 0; b < blocks; ++b) {
    const std::string where = "block " + std::to_string(b) + ": ";
    const std::span<const std::uint8_t> bytes = block(b);
    if (bytes.empty()) return malformed(where + "missing");
    if (bytes.size() != want)
      return malformed(where + std::to_string(bytes.size()) + " bytes, expected " +
                       std::to_string(want));
    Reader r(bytes);
    std::uint32_t bmagic = 0, bversion = 0, bcells = 0, free_count = 0, free_head = 0;
    std::uint64_t block_version = 0;
    std::uint8_t flags = 0, pad8 = 0;
    std::uint16_t pad16 = 0;
    (void)(r.get(bmagic) && r.get(bversion) && r.get(bcells) && r.get(free_count) &&
           r.get(block_version) && r.get(free_head) && r.get(flags) && r.get(pad8) &&
           r.get(pad16));
    if (bmagic != kBlockMagic) return malformed(where + "bad magic");
    if (bversion != kSnapshotVersion)
      return make_error(Errc::unsupported, "octree checkpoint: " + where + "layout version " +
                                               std::to_string(bversion));
    if (bcells != cells) return malformed(where + "block size differs from the canvas's");
    if (free_count > groups || free_head > groups * std::uint64_t{blocks} ||
        (flags & ~Impl::kInAvail) != 0)
      return malformed(where + "bad free-list header");
    const std::size_t c0 = std::size_t{b} << m.block_shift;
    const std::size_t g0 = std::size_t{b} << m.gblock_shift;
    (void)(r.get_array(m.first_child.data() + c0, cells) &&
           r.get_array(m.colour.data() + c0, cells) &&
           r.get_array(m.gparent.data() + g0, groups) && r.get_array(m.gdepth.data() + g0, groups));
    m.free_count[b] = free_count;
    m.free_head[b] = free_head;
    m.block_flags[b] = flags;
    m.blocks[b].version = block_version;
  }
  m.open_block = open_block;
  m.live_groups = live_groups;
  m.free_groups = free_groups;
  m.groups_at_depth = at_depth;
  m.avail = std::move(avail);

  // Structure: every live group's parent is a live cell beyond-or-within the high water, one
  // level up, whose first_child points back; every live cell's children are a live group.
  const std::uint64_t hw_cells = m.hw_cells();
  std::uint64_t live = 0, free = 0;
  std::array<std::uint64_t, kMaxSupportedDepth + 1> per_depth{};
  for (GroupIndex g = 0; g < hw_groups; ++g) {
    const std::string where = "group " + std::to_string(g) + ": ";
    if (g < m.root_groups) {
      if (m.is_free_group(g) || pl::dc_depth_of(m.gdepth[g]) != 0 || m.gparent[g] != kNoCell)
        return malformed(where + "a root group is not a live depth-0 group");
      continue;
    }
    if (m.is_free_group(g)) {
      if (m.gdepth[g] != kGroupFreeFlag) return malformed(where + "free group with depth bits");
      for (CellIndex c = g * pl::kCellsPerGroup; c < (g + 1) * pl::kCellsPerGroup; ++c)
        if (m.first_child[c] != kNoCell || m.colour[c] != 0)
          return malformed(where + "free group not clean");
      ++free;
      continue;
    }
    ++live;
    if ((m.gdepth[g] & ~kDepthMask) != 0) return malformed(where + "unknown flag bits");
    const CellIndex p = m.gparent[g];
    const std::uint32_t d = pl::dc_depth_of(m.gdepth[g]);
    ++per_depth[std::min<std::uint32_t>(d, kMaxSupportedDepth)];
    if (p >= hw_cells || m.is_free_group(pl::dc_group_of(p)) ||
        pl::dc_depth_of(m.gdepth[pl::dc_group_of(p)]) + 1 != d ||
        static_cast<int>(d) > m.cfg.max_depth || m.first_child[p] != g * pl::kCellsPerGroup)
      return malformed(where + "parent link broken");
  }
  if (live != live_groups || free != free_groups)
    return malformed("allocator: group counts do not match the blocks");
  if (per_depth != at_depth) return malformed("allocator: per-depth counts do not match");
  // Free lists: each block's chain (through the group parent pool) runs over free groups of
  // that block only, free_count long, and ends; the blocks with room are flagged once each.
  for (BlockId b = 0; b < blocks; ++b) {
    std::uint32_t steps = 0;
    for (GroupIndex g = m.head(b); g != kNoGroup; g = m.gparent[g]) {
      if (steps++ == m.free_count[b] || g >= hw_groups || (g >> m.gblock_shift) != b ||
          !m.is_free_group(g))
        return malformed("block " + std::to_string(b) + ": free list broken");
    }
    if (steps != m.free_count[b])
      return malformed("block " + std::to_string(b) + ": free count does not match its list");
  }
  {
    std::vector<bool> listed(blocks, false);
    for (BlockId b : m.avail) {
      if (listed[b] || !(m.block_flags[b] & Impl::kInAvail))
        return malformed("allocator: available block " + std::to_string(b) + " listed wrongly");
      listed[b] = true;
    }
    for (BlockId b = 0; b < blocks; ++b)
      if ((m.block_flags[b] & Impl::kInAvail) && !listed[b])
        return malformed("block " + std::to_string(b) + ": flagged available but not listed");
  }
  for (CellIndex c = 0; c < hw_cells; ++c) {
    if (m.is_free_group(pl::dc_group_of(c))) continue;
    const CellIndex fc = m.first_child[c];
    if (fc == kNoCell) continue;
    if (fc >= hw_cells || fc % pl::kCellsPerGroup != 0 ||
        m.is_free_group(pl::dc_group_of(fc)) || m.gparent[pl::dc_group_of(fc)] != c)
      return malformed("cell " + std::to_string(c) + ": child link broken");
  }

  tree->recompute_all_links();
  m.refilter_all = true;
  for (BlockId b = 0; b < blocks; ++b) {
    m.dirty_list.push_back(b);
    m.blocks[b].dirty = true;
  }
  // Full neighbour masks up to the high-water mark: a replica given this tree computes every
  // group's links.
  std::memset(m.mask.data(), 0xFF, (hw_groups / 64) * sizeof(std::uint64_t));
  if (hw_groups % 64) m.mask[hw_groups / 64] = (std::uint64_t{1} << (hw_groups % 64)) - 1;
  return tree;
}

}  // namespace deepcanvas::server_core
