#include "deepcanvas/server_core/cell_diff.hpp"

#include "column_frame.hpp"

#include "coord_table.hpp"

#include <zstd.h>

#include <algorithm>
#include <cstring>
#include <string>
#include <unordered_map>

namespace deepcanvas::server_core {

namespace {

constexpr std::uint32_t kMagic = 0x46444344u;  // "DCDF" little-endian
constexpr std::uint32_t kVersion = 1;
constexpr std::size_t kHeader = 16;
constexpr std::size_t kPerChange = 1 + 4 * 3 + 1 + 4 + 4;  // 22 bytes

std::uint8_t flags_of(const CellChange& c) {
  return static_cast<std::uint8_t>((c.before.exists ? 1 : 0) | (c.before.leaf ? 2 : 0) |
                                   (c.after.exists ? 4 : 0) | (c.after.leaf ? 8 : 0));
}

using detail::get32;
using detail::put32;

Error bad(const std::string& what) {
  return Error{Errc::malformed, "cell diff: " + what};
}

}  // namespace

std::size_t CellCoordHash::operator()(const CellCoord& k) const noexcept {
  std::uint64_t h =
      ((std::uint64_t{static_cast<std::uint32_t>(k.depth)} << 32) | k.x) * 0x9E3779B97F4A7C15ull ^
      (((std::uint64_t{k.y} << 32) | k.z) + 0x632BE59BD9B4E019ull);
  h ^= h >> 29;
  h *= 0xBF58476D1CE4E5B9ull;
  h ^= h >> 32;
  return static_cast<std::size_t>(h);
}

bool cell_order(const CellCoord& a, const CellCoord& b) noexcept {
  if (a.depth != b.depth) return a.depth < b.depth;
  if (a.z != b.z) return a.z < b.z;
  if (a.y != b.y) return a.y < b.y;
  return a.x < b.x;
}

std::vector<std::uint8_t> encode_cell_diff(const CellDiff& diff) {
  const std::size_t n = diff.changes.size();
  std::vector<std::uint8_t> raw(kHeader + n * kPerChange);
  std::uint8_t* p = raw.data();
  put32(p, kMagic);
  put32(p + 4, kVersion);
  put32(p + 8, static_cast<std::uint32_t>(n));
  put32(p + 12, static_cast<std::uint32_t>(std::uint64_t{n} >> 32));
  std::uint8_t* depth = p + kHeader;
  std::uint8_t* xs = depth + n;
  std::uint8_t* ys = xs + 4 * n;
  std::uint8_t* zs = ys + 4 * n;
  std::uint8_t* fl = zs + 4 * n;
  std::uint8_t* bc = fl + n;
  std::uint8_t* ac = bc + 4 * n;
  // Written in address order (depth, z, y, x): neighbouring cells' coordinates and colours
  // then sit side by side in each column, which zstd packs about a quarter smaller.
  std::vector<std::uint32_t> order(n);
  for (std::uint32_t i = 0; i < n; ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
    return cell_order(diff.changes[a].cell, diff.changes[b].cell);
  });
  for (std::size_t i = 0; i < n; ++i) {
    const CellChange& c = diff.changes[order[i]];
    depth[i] = static_cast<std::uint8_t>(c.cell.depth);
    put32(xs + 4 * i, c.cell.x);
    put32(ys + 4 * i, c.cell.y);
    put32(zs + 4 * i, c.cell.z);
    fl[i] = flags_of(c);
    put32(bc + 4 * i, c.before.colour);
    put32(ac + 4 * i, c.after.colour);
  }
  return detail::compress_columns(raw);
}

Result<CellDiff> decode_cell_diff(std::span<const std::uint8_t> bytes, const OctreeConfig& canvas,
                                  std::uint64_t max_changes) {
  const unsigned long long most =
      kHeader + static_cast<unsigned long long>(max_changes) * kPerChange;
  auto frame = detail::decompress_columns(bytes, most, kMagic, kVersion, "cell diff");
  if (!frame) return std::move(frame).error();
  const std::vector<std::uint8_t>& raw = *frame;
  const std::uint8_t* p = raw.data();
  const std::uint64_t n = std::uint64_t{get32(p + 8)} | (std::uint64_t{get32(p + 12)} << 32);
  if (n > max_changes || raw.size() != kHeader + n * kPerChange)
    return bad("size " + std::to_string(raw.size()) + " does not match " + std::to_string(n) +
               " changes");
  const std::uint8_t* depth = p + kHeader;
  const std::uint8_t* xs = depth + n;
  const std::uint8_t* ys = xs + 4 * n;
  const std::uint8_t* zs = ys + 4 * n;
  const std::uint8_t* fl = zs + 4 * n;
  const std::uint8_t* bc = fl + n;
  const std::uint8_t* ac = bc + 4 * n;
  CellDiff d;
  d.changes.resize(static_cast<std::size_t>(n));
  for (std::size_t i = 0; i < n; ++i) {
    CellChange& c = d.changes[i];
    c.cell.depth = depth[i];
    c.cell.x = get32(xs + 4 * i);
    c.cell.y = get32(ys + 4 * i);
    c.cell.z = get32(zs + 4 * i);
    const std::string at = "change " + std::to_string(i);
    if (c.cell.depth > canvas.max_depth) return bad(at + ": depth past the canvas's");
    const std::uint64_t per_axis = std::uint64_t{canvas.roots_per_axis} << c.cell.depth;
    if (c.cell.x >= per_axis || c.cell.y >= per_axis || c.cell.z >= per_axis)
      return bad(at + ": outside the canvas");
    const std::uint8_t f = fl[i];
    if (f > 15) return bad(at + ": unknown flags");
    c.before = {get32(bc + 4 * i), (f & 1) != 0, (f & 2) != 0};
    c.after = {get32(ac + 4 * i), (f & 4) != 0, (f & 8) != 0};
    if ((!c.before.exists && !c.after.exists) ||
        (c.cell.depth == 0 && !(c.before.exists && c.after.exists)))
      return bad(at + ": impossible state");
    if (c.before == c.after) return bad(at + ": no change");
    if (i > 0 && d.changes[i - 1].cell.depth > c.cell.depth)
      return bad(at + ": out of depth order");
  }
  return d;
}

// ---------------------------------------------------------------------------------------------

struct CellDiffRecorder::Impl {
  std::uint32_t* slots = nullptr;
  std::size_t max_records = CellDiffRecorder::kDefaultMaxRecords;
  CellDiffBudget* budget = nullptr;
  std::uint64_t budget_bytes = 0;  // what this recorder holds of the budget
  bool overflowed = false;
  CellChange scratch;  // what the hooks write into once overflowed
  std::unordered_map<CellCoord, std::uint32_t, CellCoordHash> index;  // without slots
  std::vector<CellChange> changes;
  std::vector<std::uint32_t> last;  // the order of each record's last change
  std::uint32_t clock = 0;

  static constexpr std::uint64_t kRecordBytes = sizeof(CellChange) + sizeof(std::uint32_t);

  ~Impl() {
    if (budget == nullptr) return;
    budget->release(budget_bytes);
    budget->leave(this);
  }
  // Drops every record (past the cap or the budget): nothing more is recorded.
  void drop() {
    overflowed = true;
    changes = {};
    last = {};
    index = {};
    if (budget != nullptr) budget->release(budget_bytes);
    budget_bytes = 0;
  }
  // Room for one more record; false when the recorder was dropped instead.
  bool make_room() {
    if (changes.size() >= max_records) {
      drop();
      return false;
    }
    if (changes.size() < changes.capacity()) return true;
    const std::size_t cap = changes.capacity();
    const std::size_t grown = std::min(std::max<std::size_t>(256, 2 * cap), max_records);
    if (budget != nullptr) {
      const std::uint64_t need = (grown - cap) * kRecordBytes;
      if (!budget->grant(this, need)) {
        drop();
        return false;
      }
      budget_bytes += need;
    }
    changes.reserve(grown);
    last.reserve(grown);
    return true;
  }
  CellChange& at(CellIndex c, const CellCoord& k, const CellState& now) {
    if (overflowed) return scratch;
    const auto n = static_cast<std::uint32_t>(changes.size());
    if (slots != nullptr) {
      const std::uint32_t s = slots[c];
      if (s < n && changes[s].cell == k) {
        last[s] = ++clock;
        return changes[s];
      }
    } else {
      auto it = index.find(k);
      if (it != index.end()) {
        last[it->second] = ++clock;
        return changes[it->second];
      }
    }
    if (!make_room()) return scratch;
    if (slots != nullptr)
      slots[c] = n;
    else
      index.emplace(k, n);
    changes.push_back({k, now, now});
    last.push_back(++clock);
    return changes.back();
  }
};

bool CellDiffBudget::grant(CellDiffRecorder::Impl* asker, std::uint64_t need) {
  while (bytes_ + need > max_bytes_) {
    CellDiffRecorder::Impl* most = asker;
    for (CellDiffRecorder::Impl* r : members_)
      if (r->budget_bytes > most->budget_bytes) most = r;
    ++dropped_;
    if (most == asker) return false;
    most->drop();
  }
  bytes_ += need;
  peak_ = std::max(peak_, bytes_);
  return true;
}

void CellDiffBudget::leave(CellDiffRecorder::Impl* r) noexcept {
  std::erase(members_, r);
}

CellDiffRecorder::CellDiffRecorder(std::uint32_t* slots, std::size_t max_records,
                                   CellDiffBudget* budget)
    : impl_(std::make_unique<Impl>()) {
  impl_->slots = slots;
  impl_->max_records = max_records;
  impl_->budget = budget;
  if (budget != nullptr) budget->join(impl_.get());
}
CellDiffRecorder::~CellDiffRecorder() = default;
CellDiffRecorder::CellDiffRecorder(CellDiffRecorder&&) noexcept = default;
CellDiffRecorder& CellDiffRecorder::operator=(CellDiffRecorder&&) noexcept = default;

void CellDiffRecorder::colour(CellIndex c, const CellCoord& k, bool leaf, std::uint32_t old_rgba,
                              std::uint32_t new_rgba) {
  impl_->at(c, k, {old_rgba, true, leaf}).after = {new_rgba, true, leaf};
}

void CellDiffRecorder::refine(CellIndex c, const CellCoord& k, std::uint32_t rgba,
                              std::uint32_t child_rgba, CellIndex first_child) {
  impl_->at(c, k, {rgba, true, true}).after = {rgba, true, false};
  for (std::uint32_t i = 0; i < 8; ++i)
    impl_->at(first_child + i, child_coord(k, i), {}).after = {child_rgba, true, true};
}

void CellDiffRecorder::coarsen(CellIndex c, const CellCoord& k, std::uint32_t old_rgba,
                               const std::uint32_t children[8], std::uint32_t new_rgba,
                               CellIndex first_child) {
  for (std::uint32_t i = 0; i < 8; ++i)
    impl_->at(first_child + i, child_coord(k, i), {children[i], true, true}).after = {};
  impl_->at(c, k, {old_rgba, true, false}).after = {new_rgba, true, true};
}

CellDiff CellDiffRecorder::take() {
  Impl& m = *impl_;
  if (m.overflowed) {
    clear();
    CellDiff d;
    d.too_large = true;
    return d;
  }
  const auto n = static_cast<std::uint32_t>(m.changes.size());
  // A cell recorded twice (under two pool indices: freed and made again) is one change: the first
  // record's `before`, the last changed record's `after`. Then depth order (a counting sort, the
  // records of one depth in the order they were made: deterministic, and parents first), straight
  // into the result, which then drops the cells left as they were. Memory on top of the records'
  // 36 bytes each: 13 to 21 bytes a record here, and the result's 32.
  std::vector<std::uint32_t> newest(n);
  std::vector<std::uint8_t> keep(n, 0);
  std::uint32_t per_depth[kMaxSupportedDepth + 2] = {};
  {
    detail::CoordTable first(m.changes);
    for (std::uint32_t i = 0; i < n; ++i) {
      const std::uint32_t f = first.insert(i);
      if (f == i) {
        keep[i] = 1;
        newest[i] = i;
        ++per_depth[m.changes[i].cell.depth + 1];
      } else if (m.last[i] > m.last[newest[f]]) {
        newest[f] = i;
      }
    }
  }
  for (int d = 1; d <= kMaxSupportedDepth + 1; ++d) per_depth[d] += per_depth[d - 1];
  CellDiff d;
  d.changes.resize(per_depth[kMaxSupportedDepth + 1]);
  for (std::uint32_t i = 0; i < n; ++i) {
    if (!keep[i]) continue;
    CellChange c = m.changes[i];
    c.after = m.changes[newest[i]].after;
    if (!c.before.exists) c.before = {};
    if (!c.after.exists) c.after = {};
    d.changes[per_depth[c.cell.depth]++] = c;
  }
  std::erase_if(d.changes, [](const CellChange& c) { return c.before == c.after; });
  clear();
  return d;
}

void CellDiffRecorder::clear() {
  impl_->overflowed = false;
  impl_->index.clear();
  impl_->changes.clear();
  impl_->last.clear();
  impl_->clock = 0;
}

std::size_t CellDiffRecorder::cells() const noexcept {
  return impl_->changes.size();
}

bool CellDiffRecorder::dropped() const noexcept {
  return impl_->overflowed;
}

}  // namespace deepcanvas::server_core
