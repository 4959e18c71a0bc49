#include "deepcanvas/server_core/cell_paste.hpp"

#include <algorithm>
#include <cstring>
#include <string>
#include <unordered_set>

#include "column_frame.hpp"
#include "deepcanvas/server_core/cell_diff.hpp"

namespace deepcanvas::server_core {

namespace {

constexpr std::uint32_t kMagic = 0x53504344;  // "DCPS"
constexpr std::uint32_t kVersion = 1;
constexpr std::size_t kHeader = 16;
constexpr std::size_t kPerCell = 1 + 4 * 4;

using detail::get32;
using detail::put32;
Error bad(const std::string& what) { return Error{Errc::malformed, "cell paste: " + what}; }

// Every check but the order (the cells are in address order when this is called).
Result<void> check_cells(const std::vector<PastedCell>& cells, const OctreeConfig& canvas) {
  std::uint32_t depths = 0;  // bit d: some cell has depth d
  std::unordered_set<CellCoord, CellCoordHash> seen;
  seen.reserve(cells.size());
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const CellCoord& k = cells[i].cell;
    const std::string at = "cell " + std::to_string(i);
    if (k.depth < 0 || k.depth > canvas.max_depth) return bad(at + ": depth past the canvas's");
    const std::uint64_t per_axis = std::uint64_t{canvas.roots_per_axis} << k.depth;
    if (k.x >= per_axis || k.y >= per_axis || k.z >= per_axis)
      return bad(at + ": outside the canvas");
    if (i > 0 && !cell_order(cells[i - 1].cell, k)) return bad(at + ": out of order or repeated");
    // Inside another cell: an ancestor at one of the depths the paste holds.
    for (CellCoord up = k; up.depth > 0;) {
      up = parent_coord(up);
      if ((depths >> up.depth) & 1u)
        if (seen.count(up)) return bad(at + ": inside another cell of the paste");
    }
    depths |= 1u << k.depth;
    seen.insert(k);
  }
  return {};
}

}  // namespace

Result<void> normalise_cell_paste(CellPaste& paste, const OctreeConfig& canvas,
                                  std::uint64_t max_cells) {
  if (paste.cells.size() > max_cells)
    return make_error(Errc::limit_exceeded, "cell paste: " + std::to_string(paste.cells.size()) +
                                                " cells, more than " + std::to_string(max_cells));
  std::sort(paste.cells.begin(), paste.cells.end(),
            [](const PastedCell& a, const PastedCell& b) { return cell_order(a.cell, b.cell); });
  return check_cells(paste.cells, canvas);
}

std::vector<std::uint8_t> encode_cell_paste(const CellPaste& paste) {
  const std::size_t n = paste.cells.size();
  std::vector<std::uint8_t> raw(kHeader + n * kPerCell);
  std::uint8_t* p = raw.data();
  put32(p, kMagic);
  put32(p + 4, kVersion);
  put32(p + 8, static_cast<std::uint32_t>(n));
  put32(p + 12, static_cast<std::uint32_t>(std::uint64_t{n} >> 32));
  std::uint8_t* depth = p + kHeader;
  std::uint8_t* xs = depth + n;
  std::uint8_t* ys = xs + 4 * n;
  std::uint8_t* zs = ys + 4 * n;
  std::uint8_t* cs = zs + 4 * n;
  for (std::size_t i = 0; i < n; ++i) {
    const PastedCell& c = paste.cells[i];
    depth[i] = static_cast<std::uint8_t>(c.cell.depth);
    put32(xs + 4 * i, c.cell.x);
    put32(ys + 4 * i, c.cell.y);
    put32(zs + 4 * i, c.cell.z);
    put32(cs + 4 * i, c.rgba);
  }
  return detail::compress_columns(raw);
}

Result<CellPaste> decode_cell_paste(std::span<const std::uint8_t> bytes, const OctreeConfig& canvas,
                                    std::uint64_t max_cells) {
  const unsigned long long most = kHeader + static_cast<unsigned long long>(max_cells) * kPerCell;
  auto frame = detail::decompress_columns(bytes, most, kMagic, kVersion, "cell paste",
                                          Errc::limit_exceeded);
  if (!frame) return std::move(frame).error();
  const std::vector<std::uint8_t>& raw = *frame;
  const std::uint8_t* p = raw.data();
  const std::uint64_t n = std::uint64_t{get32(p + 8)} | (std::uint64_t{get32(p + 12)} << 32);
  if (n > max_cells || raw.size() != kHeader + n * kPerCell)
    return bad("size " + std::to_string(raw.size()) + " does not match " + std::to_string(n) +
               " cells");
  const std::uint8_t* depth = p + kHeader;
  const std::uint8_t* xs = depth + n;
  const std::uint8_t* ys = xs + 4 * n;
  const std::uint8_t* zs = ys + 4 * n;
  const std::uint8_t* cs = zs + 4 * n;
  CellPaste out;
  out.cells.resize(static_cast<std::size_t>(n));
  for (std::size_t i = 0; i < n; ++i) {
    PastedCell& c = out.cells[i];
    c.cell.depth = depth[i];
    c.cell.x = get32(xs + 4 * i);
    c.cell.y = get32(ys + 4 * i);
    c.cell.z = get32(zs + 4 * i);
    c.rgba = get32(cs + 4 * i);
  }
  if (auto ok = check_cells(out.cells, canvas); !ok) return std::move(ok).error();
  return out;
}

}  // namespace deepcanvas::server_core
