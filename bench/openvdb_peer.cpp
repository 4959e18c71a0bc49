#include "openvdb_peer.hpp"

#include <openvdb/openvdb.h>
#include <openvdb/tools/Prune.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "deepcanvas/protocol/density_model.hpp"

namespace deepcanvas::bench {

namespace {

namespace dm = protocol::density;
using openvdb::Coord;
using openvdb::CoordBBox;
using protocol::BrushMode;
using server_core::CanvasGeometry;
using server_core::CellCoord;
using server_core::Stamp;

// The canvas value types. Both store colour and alpha across one voxel edge (density_model.hpp),
// both blend with the painter's formulas; rgba8 quantises exactly like the octree.
struct Rgba8Policy {
  using TreeT = openvdb::UInt32Tree;
  using ValueT = std::uint32_t;
  static ValueT paint(ValueT pre, double q, const float rgb[3]) {
    return dm::paint_over(pre, q, rgb);
  }
  static ValueT erase(ValueT pre, double e) { return dm::erase(pre, e); }
  static ValueT recolor(ValueT pre, double w, const float rgb[3]) {
    return dm::recolor(pre, w, rgb);
  }
  static bool empty(ValueT v) { return (v >> 24) == 0; }
  static VdbSample read(ValueT v) {
    const dm::Rgba8 c = dm::unpack(v);
    VdbSample s;
    s.rgb[0] = c.r / 255.0f;
    s.rgb[1] = c.g / 255.0f;
    s.rgb[2] = c.b / 255.0f;
    s.alpha = c.a / 255.0f;
    return s;
  }
};

// Real-valued versions of density::paint_over / erase / recolor (no quantisation).
struct Vec4fPolicy {
  using TreeT = openvdb::tree::Tree4<openvdb::Vec4f, 5, 4, 3>::Type;
  using ValueT = openvdb::Vec4f;
  static ValueT paint(ValueT pre, double q, const float rgb[3]) {
    if (q <= 0) return pre;
    const double ap = pre[3];
    const double an = 1.0 - (1.0 - ap) * (1.0 - q);
    if (an <= 0) return ValueT(0.0f);
    const double keep = ap * (1.0 - q);
    return ValueT(static_cast<float>((q * rgb[0] + keep * pre[0]) / an),
                  static_cast<float>((q * rgb[1] + keep * pre[1]) / an),
                  static_cast<float>((q * rgb[2] + keep * pre[2]) / an), static_cast<float>(an));
  }
  static ValueT erase(ValueT pre, double e) {
    if (e <= 0 || pre[3] <= 0) return pre;
    const double tau = pre[3] >= 1.0f ? dm::kOpaqueOpticalDepth : -std::log1p(-double{pre[3]});
    const double a = 1.0 - std::exp(-tau * (1.0 - std::clamp(e, 0.0, 1.0)));
    if (a <= 0) return ValueT(0.0f);
    return ValueT(pre[0], pre[1], pre[2], static_cast<float>(a));
  }
  static ValueT recolor(ValueT pre, double w, const float rgb[3]) {
    if (pre[3] <= 0 || w <= 0) return pre;
    w = std::clamp(w, 0.0, 1.0);
    return ValueT(static_cast<float>((1 - w) * pre[0] + w * rgb[0]),
                  static_cast<float>((1 - w) * pre[1] + w * rgb[1]),
                  static_cast<float>((1 - w) * pre[2] + w * rgb[2]), pre[3]);
  }
  static bool empty(ValueT v) { return v[3] <= 0; }
  static VdbSample read(ValueT v) {
    VdbSample s;
    for (int k = 0; k < 3; ++k) s.rgb[k] = v[k];
    s.alpha = v[3];
    return s;
  }
};

// Edge, in voxels, of the region over which a value found at `depth` (ValueAccessor::
// getValueDepth) is constant, for Tree4<T, 5, 4, 3>: -1 background and 0 root tiles cover a
// root child (4096), 1 a tile of the 32^3 node (128), 2 a tile of the 16^3 node (8), 3 a voxel.
constexpr int kLeafDepth = 3;
inline int span_of(int depth) {
  switch (depth) {
    case -1:
    case 0:
      return 4096;
    case 1:
      return 128;
    case 2:
      return 8;
    default:
      return 1;
  }
}

inline CoordBBox cube(const Coord& lo, int n) {
  return CoordBBox(lo, lo.offsetBy(n - 1));
}

// Visits an aligned cube of edge n (a power of two) split into the largest aligned pieces over
// which the tree holds one value (a tile, the background or one voxel): tile(lo, n) for those,
// and leaf(leaf node, lo, n) for pieces of at most 8^3 inside an existing leaf node.
template <class Acc, class TileF, class LeafF>
void visit_cube(Acc& acc, const Coord& lo, int n, TileF& tile, LeafF& leaf) {
  const int depth = acc.getValueDepth(lo);
  if (span_of(depth) >= n) {
    tile(lo, n);
    return;
  }
  if (depth == kLeafDepth && n <= 8) {
    leaf(*acc.probeLeaf(lo), lo, n);
    return;
  }
  const int h = n / 2;
  for (int i = 0; i < 8; ++i)
    visit_cube(acc, lo.offsetBy((i & 1) * h, ((i >> 1) & 1) * h, (i >> 2) * h), h, tile, leaf);
}

template <class Policy>
class Peer final : public OpenVdbPeer {
  using TreeT = typename Policy::TreeT;
  using ValueT = typename Policy::ValueT;
  using GridT = openvdb::Grid<TreeT>;
  using LayerGrid = openvdb::FloatGrid;

 public:
  Peer(const server_core::OctreeConfig& canvas, const VdbPeerConfig& cfg)
      : cfg_(cfg),
        geo_(CanvasGeometry::of(canvas)),
        h_(geo_.cell_edge(cfg.voxel_depth)),
        grid_(GridT::create(zero())),
        layer_(LayerGrid::create(0.0f)),
        acc_(grid_->tree()),
        lacc_(layer_->tree()) {
    // Index (i, j, k) is the octree cell (voxel_depth, i, j, k); OpenVDB puts voxel centres at
    // integer index coordinates.
    auto xf = openvdb::math::Transform::createLinearTransform(h_);
    const double t = -geo_.edge_m * 0.5 + 0.5 * h_;
    xf->postTranslate(openvdb::Vec3d(t, t, t));
    grid_->setTransform(xf);
    layer_->setTransform(xf->copy());
    grid_->setName("canvas");
  }

  Result<void> apply_stroke(const protocol::Stroke& stroke) override {
    if (auto v =
            protocol::validate_stroke(stroke, protocol::CanvasBounds{geo_.edge_m}, cfg_.limits);
        !v)
      return v;
    const BrushMode mode = stroke.brush.mode;
    if (mode == BrushMode::smudge)
      return make_error(Errc::unsupported, "openvdb peer: smudge is not implemented");
    if (mode == BrushMode::pick_up) return {};
    auto stamps = server_core::stroke_stamps(geo_, cfg_.stamps, stroke);
    if (!stamps) return std::move(stamps).error();
    brush_ = stroke.brush;
    // 1. The stroke layer: max strength per voxel over the stroke's stamps.
    for (const Stamp& s : *stamps) {
      if (s.depth > cfg_.voxel_depth)
        return make_error(Errc::invalid_argument,
                          "openvdb peer: stamp depth " + std::to_string(s.depth) +
                              " is finer than the voxel depth " + std::to_string(cfg_.voxel_depth));
    }
    for (const Stamp& s : *stamps) {
      ++stats_.stamps;
      const int shift = cfg_.voxel_depth - s.depth;
      const int n = 1 << shift;
      server_core::for_each_stamp_cell(
          geo_, s, s.depth, stroke.brush.hardness,
          [&](const CellCoord& c, const server_core::StampHit& hit) {
            const float v = strength(hit);
            if (!(v > 0)) return;
            ++stats_.cells;
            layer_max(Coord(static_cast<int>(c.x << shift), static_cast<int>(c.y << shift),
                            static_cast<int>(c.z << shift)),
                      n, v);
          });
    }
    // 2. Composite the layer onto the canvas from the pre-stroke values, once per voxel.
    for (auto it = layer_->tree().cbeginValueOn(); it; ++it) {
      ++stats_.layer_values;
      const float s = *it;
      if (it.isVoxelValue()) {
        composite(it.getCoord(), 1, s);
      } else {
        const CoordBBox b = it.getBoundingBox();
        composite(b.min(), b.dim().x(), s);
      }
    }
    layer_->tree().clear();
    lacc_.clear();
    return {};
  }

  void prune() override {
    acc_.clear();
    openvdb::tools::prune(grid_->tree(), zero(), /*threaded=*/false);
  }

  VdbMemory memory() const override {
    VdbMemory m;
    m.mem_usage = grid_->memUsage();
    m.active_voxels = grid_->tree().activeVoxelCount();
    m.leaf_nodes = grid_->tree().leafCount();
    m.active_tiles = grid_->tree().activeTileCount();
    return m;
  }

  Result<VdbSample> sample(const server_core::Vec3d& p) const override {
    const double h = geo_.edge_m * 0.5;
    if (!(std::abs(p.x) <= h && std::abs(p.y) <= h && std::abs(p.z) <= h))
      return make_error(Errc::invalid_argument, "openvdb peer: point outside the canvas");
    const double lim = std::ldexp(double(geo_.roots_per_axis), cfg_.voxel_depth) - 1.0;
    auto idx = [&](double v) {
      return static_cast<int>(std::clamp(std::floor((v + h) / h_), 0.0, lim));
    };
    const ValueT v = grid_->tree().getValue(Coord(idx(p.x), idx(p.y), idx(p.z)));
    VdbSample s = Policy::read(v);
    s.sigma_per_m = s.alpha >= 1.0f ? INFINITY : dm::sigma_per_m(s.alpha, h_);
    return s;
  }

  const VdbPeerStats& stats() const noexcept override { return stats_; }
  double voxel_edge_m() const noexcept override { return h_; }

 private:
  static ValueT zero() { return openvdb::zeroVal<ValueT>(); }

  // The painter's per-stamp strength (painter.cpp strength_at): paint keeps the optical depth
  // per metre tau = -ln(1 - A O c) / D (infinite for k >= 1), the other modes O c.
  float strength(const server_core::StampHit& hit) const {
    if (brush_.mode == BrushMode::paint) {
      const double k = double{brush_.colour[3]} * brush_.opacity * hit.coverage;
      if (k >= 1.0) return INFINITY;
      return static_cast<float>(-std::log1p(-k) / hit.diameter);
    }
    return static_cast<float>(double{brush_.opacity} * hit.coverage);
  }

  ValueT blend(ValueT pre, float s) const {
    switch (brush_.mode) {
      case BrushMode::paint:
        return Policy::paint(pre, std::isinf(s) ? 1.0 : -std::expm1(-double{s} * h_),
                             brush_.colour);
      case BrushMode::erase:
        return Policy::erase(pre, s);
      case BrushMode::recolor:
        return Policy::recolor(pre, s, brush_.colour);
      default:
        return pre;
    }
  }

  // layer = max(layer, v) over the cube.
  void layer_max(const Coord& lo, int n, float v) {
    auto tile = [&](const Coord& at, int m) {
      float u = 0;
      const bool on = lacc_.probeValue(at, u);
      if (on && u >= v) return;
      if (m == 1) {
        lacc_.setValueOn(at, v);
      } else {
        // Root-level sparse fill (Tree::fill minus its clearing of every registered accessor);
        // the fill may replace nodes by tiles, so our accessor's cache must go.
        layer_->tree().root().sparseFill(cube(at, m), v, true);
        lacc_.clear();
      }
    };
    auto leaf = [&](openvdb::FloatTree::LeafNodeType& node, const Coord& at, int m) {
      for (int z = 0; z < m; ++z)
        for (int y = 0; y < m; ++y)
          for (int x = 0; x < m; ++x) {
            const openvdb::Index off = node.coordToOffset(at.offsetBy(x, y, z));
            if (!node.isValueOn(off) || node.getValue(off) < v) node.setValueOn(off, v);
          }
    };
    visit_cube(lacc_, lo, n, tile, leaf);
  }

  // canvas = blend(canvas, s) over the cube, each voxel from its own value.
  void composite(const Coord& lo, int n, float s) {
    auto tile = [&](const Coord& at, int m) {
      ValueT u = zero();
      const bool on = acc_.probeValue(at, u);
      const ValueT nv = blend(u, s);
      if (nv == u && (on || Policy::empty(nv))) return;
      if (m == 1) {
        acc_.setValueOn(at, nv);
      } else {
        grid_->tree().root().sparseFill(cube(at, m), nv, true);
        acc_.clear();
      }
    };
    auto leaf = [&](typename TreeT::LeafNodeType& node, const Coord& at, int m) {
      for (int z = 0; z < m; ++z)
        for (int y = 0; y < m; ++y)
          for (int x = 0; x < m; ++x) {
            const openvdb::Index off = node.coordToOffset(at.offsetBy(x, y, z));
            const ValueT u = node.getValue(off);
            const ValueT nv = blend(u, s);
            if (!(nv == u) || (!node.isValueOn(off) && !Policy::empty(nv)))
              node.setValueOn(off, nv);
          }
    };
    visit_cube(acc_, lo, n, tile, leaf);
  }

  VdbPeerConfig cfg_;
  CanvasGeometry geo_;
  double h_;
  typename GridT::Ptr grid_;
  LayerGrid::Ptr layer_;
  openvdb::tree::ValueAccessor<TreeT> acc_;
  openvdb::tree::ValueAccessor<openvdb::FloatTree> lacc_;
  protocol::Brush brush_;
  VdbPeerStats stats_;
};

}  // namespace

Result<std::unique_ptr<OpenVdbPeer>> OpenVdbPeer::create(const server_core::OctreeConfig& canvas,
                                                         const VdbPeerConfig& config) {
  if (config.voxel_depth < 0 || config.voxel_depth > canvas.max_depth)
    return make_error(Errc::invalid_argument, "openvdb peer: voxel depth " +
                                                  std::to_string(config.voxel_depth) +
                                                  " outside the canvas's depth range");
  // Voxel indices run to roots_per_axis * 2^depth - 1, which must fit OpenVDB's int32 Coord.
  if (std::ldexp(double(canvas.roots_per_axis), config.voxel_depth) > 2147483647.0)
    return make_error(Errc::invalid_argument, "openvdb peer: voxel addresses at depth " +
                                                  std::to_string(config.voxel_depth) +
                                                  " exceed 32-bit coordinates");
  std::unique_ptr<OpenVdbPeer> p;
  if (config.kind == VdbValueKind::rgba8)
    p = std::make_unique<Peer<Rgba8Policy>>(canvas, config);
  else
    p = std::make_unique<Peer<Vec4fPolicy>>(canvas, config);
  return p;
}

}  // namespace deepcanvas::bench
