#include "deepcanvas/client_core/pool_view.hpp"

#include <cmath>
#include <string>

namespace deepcanvas::client_core {

double PoolView::cell_edge_m(int depth) const noexcept {
  return std::ldexp(root_edge_m(), -depth);
}

Result<void> PoolView::validate() const {
  if (roots_per_axis < 2 || roots_per_axis > 64 || roots_per_axis % 2 != 0) {
    return make_error(Errc::invalid_argument, "roots_per_axis must be even in 2..64, got " +
                                                  std::to_string(roots_per_axis));
  }
  if (!std::isfinite(edge_m) || edge_m <= 0.0) {
    return make_error(Errc::invalid_argument, "canvas edge must be finite and positive");
  }
  const std::uint64_t cells = first_child.size();
  if (cells < root_count() || cells % 8 != 0) {
    return make_error(Errc::invalid_argument, "first_child pool holds " + std::to_string(cells) +
                                                  " cells: needs all roots and a multiple of 8");
  }
  if (colour.size() != cells) {
    return make_error(Errc::invalid_argument, "colour pool size differs from first_child");
  }
  if (group_parent.size() != cells / 8 || group_depth_flags.size() != cells / 8) {
    return make_error(Errc::invalid_argument, "group pools must hold cells / 8 entries");
  }
  if (group_links.size() != cells / 8 * 6) {
    return make_error(Errc::invalid_argument, "group links must hold 6 entries per group");
  }
  return {};
}

std::uint32_t PoolView::face_neighbour(std::uint32_t c, int face) const noexcept {
  if (!in_range(c) || face < 0 || face > 5) return kNoCell;
  const int axis = face >> 1;
  const bool positive = (face & 1) != 0;
  const std::uint32_t n = roots_per_axis;
  if (c < root_count()) {
    std::uint32_t r[3] = {c % n, (c / n) % n, c / (n * n)};
    if (positive ? r[axis] + 1 >= n : r[axis] == 0) return kNoCell;
    r[axis] = positive ? r[axis] + 1 : r[axis] - 1;
    return r[0] + n * (r[1] + n * r[2]);
  }
  const std::uint32_t slot = c & 7u;
  const bool bit = ((slot >> axis) & 1u) != 0;
  if (bit != positive) return c ^ (1u << axis);  // the face is inside the parent
  const std::uint32_t link_cell = link(c >> 3, face);
  if (!in_range(link_cell)) return kNoCell;
  const std::uint32_t fc = first_child[link_cell];
  if (fc == kNoCell) return link_cell;  // the coarser leaf
  if (fc % 8 != 0 || !in_range(fc)) return kNoCell;
  return fc + (slot ^ (1u << axis));
}

}  // namespace deepcanvas::client_core
