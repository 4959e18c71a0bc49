#include "deepcanvas/client_core/content_boxes.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace deepcanvas::client_core {
namespace {

// A cell and its integer address at `depth` (as for_each_painted_leaf).
struct Cell {
  std::uint32_t cell;
  int depth;
  std::uint32_t x, y, z;
  // Child `slot` (0..7) of this cell, whose first child is `first_child`.
  Cell child(std::uint32_t first_child, std::uint32_t slot) const {
    return {first_child + slot, depth + 1, 2 * x + (slot & 1), 2 * y + ((slot >> 1) & 1),
            2 * z + ((slot >> 2) & 1)};
  }
};

struct Subtree {
  Cell at;
  DAabb box;  // its cube clipped to the content box
};

DAabb intersect(const DAabb& a, const DAabb& b) {
  return {{std::max(a.min.x, b.min.x), std::max(a.min.y, b.min.y), std::max(a.min.z, b.min.z)},
          {std::min(a.max.x, b.max.x), std::min(a.max.y, b.max.y), std::min(a.max.z, b.max.z)}};
}
bool is_empty(const DAabb& b) {
  return b.min.x > b.max.x || b.min.y > b.max.y || b.min.z > b.max.z;
}
DAabb unite(const DAabb& a, const DAabb& b) {
  return {{std::min(a.min.x, b.min.x), std::min(a.min.y, b.min.y), std::min(a.min.z, b.min.z)},
          {std::max(a.max.x, b.max.x), std::max(a.max.y, b.max.y), std::max(a.max.z, b.max.z)}};
}
double half_perimeter(const DAabb& b) {
  return (b.max.x - b.min.x) + (b.max.y - b.min.y) + (b.max.z - b.min.z);
}

// The camera's view pyramid as four side planes and the plane through the eye: a point v
// (relative to the eye) that some ray reaches has dot(n, v) <= 0 for each normal n. A box is
// outside when one plane has the whole box strictly on its far side, with slack for the
// rounding of the ray directions (the GPU computes them in float).
class ViewPyramid {
 public:
  explicit ViewPyramid(const Camera& c) : eye_(c.position()) {
    // Widened by 1e-4: pixel centres lie strictly inside the edges, and float directions stray
    // by far less.
    const double th = c.tan_half_h() * (1 + 1e-4), tv = c.tan_half_v() * (1 + 1e-4);
    const DVec3 f = c.forward(), r = c.right(), u = c.up();
    normals_[0] = r - f * th;
    normals_[1] = r * -1.0 - f * th;
    normals_[2] = u - f * tv;
    normals_[3] = u * -1.0 - f * tv;
    normals_[4] = f * -1.0;
  }
  bool may_see(const DAabb& b) const {
    const DVec3 centre = (b.min + b.max) * 0.5 - eye_;
    const DVec3 half = (b.max - b.min) * 0.5;
    for (const DVec3& n : normals_) {
      const double reach = std::abs(n.x) * half.x + std::abs(n.y) * half.y + std::abs(n.z) * half.z;
      const double c = dot(n, centre);
      // The nearest point of the box to the plane is still beyond it, by more than rounding.
      if (c - reach > 1e-9 * (std::abs(c) + reach) + 1e-12) return false;
    }
    return true;
  }

 private:
  DVec3 eye_;
  DVec3 normals_[5];
};

}  // namespace

ContentBoxes content_boxes_for_view(const PoolView& pools, const Camera& camera,
                                    const DAabb& bounds, std::size_t max_boxes) {
  max_boxes = std::clamp<std::size_t>(max_boxes, 1, kMaxContentBoxes);
  ContentBoxes whole;
  whole.push_back(bounds);
  if (!pools.filtered_interiors || !pools.validate()) return whole;
  const ViewPyramid view(camera);
  const double lo = -pools.edge_m * 0.5;
  const auto cube = [&](const Cell& c) {
    const double e = pools.cell_edge_m(c.depth);
    const DVec3 mn{lo + c.x * e, lo + c.y * e, lo + c.z * e};
    return DAabb{mn, mn + DVec3{e, e, e}};
  };
  // A leaf is painted when its alpha is not 0; an interior cell's filtered colour is 0 exactly
  // when nothing below it is painted.
  const auto may_hold_paint = [&](std::uint32_t cell) {
    const std::uint32_t colour = pools.colour[cell];
    return pools.first_child[cell] == PoolView::kNoCell ? (colour >> 24) != 0 : colour != 0;
  };
  // A good first child index of `cell`'s children (kNoCell for a leaf too).
  const auto children_of = [&](const Cell& c) {
    const std::uint32_t fc = pools.first_child[c.cell];
    const bool good = fc % 8 == 0 && pools.in_range(fc) && pools.in_range(fc + 7) &&
                      c.depth < PoolView::kMaxDepth;
    return good ? fc : PoolView::kNoCell;
  };
  // A subtree that may hold paint in view, with its box; false when it does not.
  const auto keep = [&](Subtree& s) {
    if (!may_hold_paint(s.at.cell)) return false;
    s.box = intersect(cube(s.at), bounds);
    return !is_empty(s.box) && view.may_see(s.box);
  };

  std::vector<Subtree> kept;
  const std::uint32_t n = pools.roots_per_axis;
  for (std::uint32_t c = 0; c < pools.root_count(); ++c) {
    Subtree s{{c, 0, c % n, (c / n) % n, c / (n * n)}, {}};
    if (keep(s)) kept.push_back(s);
  }
  // Split the largest subtree (the shallowest) while the children fit in the candidates.
  std::vector<Subtree> children;
  for (;;) {
    std::size_t pick = kept.size();
    for (std::size_t i = 0; i < kept.size(); ++i) {
      if (pools.first_child[kept[i].at.cell] == PoolView::kNoCell ||
          kept[i].at.depth >= PoolView::kMaxDepth)
        continue;
      if (pick == kept.size() || kept[i].at.depth < kept[pick].at.depth) pick = i;
    }
    if (pick == kept.size()) break;  // only leaves left
    const Cell parent = kept[pick].at;
    const std::uint32_t fc = children_of(parent);
    if (fc == PoolView::kNoCell) return whole;  // corrupt
    children.clear();
    for (std::uint32_t s = 0; s < 8; ++s) {
      Subtree ch{parent.child(fc, s), {}};
      if (keep(ch)) children.push_back(ch);
    }
    if (kept.size() - 1 + children.size() > kContentBoxCandidates) break;
    kept.erase(kept.begin() + static_cast<std::ptrdiff_t>(pick));
    kept.insert(kept.end(), children.begin(), children.end());
  }

  std::vector<DAabb> boxes;
  std::vector<std::vector<std::size_t>> members;  // the subtrees in each box
  boxes.reserve(kept.size());
  for (std::size_t i = 0; i < kept.size(); ++i) {
    boxes.push_back(kept[i].box);
    members.push_back({i});
  }
  // Merge while over max_boxes, and past that while two boxes are as good as one: their union's
  // half perimeter is under the sum of theirs (neighbouring pieces of one painting; each box
  // costs every ray of the frame a slab test).
  while (boxes.size() > 1) {
    std::size_t bi = 0, bj = 1;
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < boxes.size(); ++i) {
      for (std::size_t j = i + 1; j < boxes.size(); ++j) {
        const double h = half_perimeter(unite(boxes[i], boxes[j]));
        if (h < best) {
          best = h;
          bi = i;
          bj = j;
        }
      }
    }
    if (boxes.size() <= max_boxes && best >= half_perimeter(boxes[bi]) + half_perimeter(boxes[bj]))
      break;
    boxes[bi] = unite(boxes[bi], boxes[bj]);
    boxes.erase(boxes.begin() + static_cast<std::ptrdiff_t>(bj));
    members[bi].insert(members[bi].end(), members[bj].begin(), members[bj].end());
    members.erase(members.begin() + static_cast<std::ptrdiff_t>(bj));
  }

  // Each face pulled in to the paint (the subtrees' cubes stick out past it): per face, a
  // best-first search over the box's subtrees by how far a cell's cube reaches out of that face.
  // The first painted leaf taken reaches furthest of all painted leaves below them; where the
  // search stops early (kTightenSteps cells taken), the cube taken last bounds what is left.
  constexpr int kTightenSteps = 256;
  struct Reach {
    double key;  // how far the cube reaches along the face's direction
    Cell at;
    bool operator<(const Reach& o) const { return key < o.key; }
  };
  std::vector<Reach> heap;
  for (std::size_t b = 0; b < boxes.size(); ++b) {
    for (int face = 0; face < 6; ++face) {
      const int axis = face / 2;
      const double sign = face % 2 == 1 ? 1.0 : -1.0;  // odd faces: the max side
      const auto reach = [&](const Cell& c) {
        const DAabb q = cube(c);
        return Reach{sign > 0 ? q.max[axis] : -q.min[axis], c};
      };
      heap.clear();
      for (std::size_t m : members[b]) heap.push_back(reach(kept[m].at));
      std::make_heap(heap.begin(), heap.end());
      double bound = std::numeric_limits<double>::infinity();
      for (int step = 0; !heap.empty(); ++step) {
        std::pop_heap(heap.begin(), heap.end());
        const Reach r = heap.back();
        heap.pop_back();
        if (pools.first_child[r.at.cell] == PoolView::kNoCell || step >= kTightenSteps) {
          bound = r.key;  // a painted leaf (only those are queued), or out of steps
          break;
        }
        const std::uint32_t fc = children_of(r.at);
        if (fc == PoolView::kNoCell) break;  // corrupt: leave this face as it is
        for (std::uint32_t k = 0; k < 8; ++k) {
          if (!may_hold_paint(fc + k)) continue;
          heap.push_back(reach(r.at.child(fc, k)));
          std::push_heap(heap.begin(), heap.end());
        }
      }
      if (!std::isfinite(bound)) continue;
      DVec3& side = sign > 0 ? boxes[b].max : boxes[b].min;
      const double pulled = sign > 0 ? std::min(side[axis], bound) : std::max(side[axis], -bound);
      if (axis == 0) side.x = pulled;
      if (axis == 1) side.y = pulled;
      if (axis == 2) side.z = pulled;
    }
  }
  ContentBoxes out;
  for (const DAabb& b : boxes) out.push_back(b);
  return out;
}

}  // namespace deepcanvas::client_core
