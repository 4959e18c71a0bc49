#include "deepcanvas/client_core/pool_view.hpp"

#include <cmath>
#include <string>

namespace deepcanvas::client_core {

namespace pl = pool_layout;

double PoolView::cell_edge_m(int depth) const noexcept {
  return std::ldexp(root_edge_m(), -depth);
}

Result<void> PoolView::validate() const {
  if (roots_per_axis < pl::kMinRootsPerAxis || roots_per_axis > pl::kMaxRootsPerAxis ||
      roots_per_axis % 2 != 0) {
    return make_error(Errc::invalid_argument, "roots_per_axis must be even in 2..64, got " +
                                                  std::to_string(roots_per_axis));
  }
  if (!std::isfinite(edge_m) || edge_m <= 0.0) {
    return make_error(Errc::invalid_argument, "canvas edge must be finite and positive");
  }
  const std::uint64_t cells = first_child.size();
  if (cells < root_count() || cells % pl::kCellsPerGroup != 0) {
    return make_error(Errc::invalid_argument, "first_child pool holds " + std::to_string(cells) +
                                                  " cells: needs all roots and a multiple of 8");
  }
  if (colour.size() != cells) {
    return make_error(Errc::invalid_argument, "colour pool size differs from first_child");
  }
  const std::uint64_t groups = cells / pl::kCellsPerGroup;
  if (group_parent.size() != groups || group_depth_flags.size() != groups) {
    return make_error(Errc::invalid_argument, "group pools must hold cells / 8 entries");
  }
  if (group_links.size() != groups * pl::kFaceCount) {
    return make_error(Errc::invalid_argument, "group links must hold 6 entries per group");
  }
  return {};
}

// pool_layout.h's neighbour rule, with every index read from the pools checked first.
std::uint32_t PoolView::face_neighbour(std::uint32_t c, int face) const noexcept {
  if (!in_range(c) || face < 0 || face >= static_cast<int>(pl::kFaceCount)) return kNoCell;
  const auto f = static_cast<pl::uint>(face);
  if (c < root_count()) return pl::dc_root_neighbour(c, f, roots_per_axis);
  if (pl::dc_face_is_inner(c, f)) return pl::dc_sibling_across(c, f);
  const std::uint32_t link_cell = link(pl::dc_group_of(c), face);
  if (!in_range(link_cell)) return kNoCell;
  const std::uint32_t fc = first_child[link_cell];
  if (fc != kNoCell && (pl::dc_slot_of(fc) != 0 || !in_range(fc))) return kNoCell;
  return pl::dc_resolve_link(c, f, link_cell, fc);
}

}  // namespace deepcanvas::client_core
