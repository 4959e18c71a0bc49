#include "deepcanvas/export/vdb_export.hpp"

#include "canvas_grids.hpp"

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <vector>

#include "deepcanvas/protocol/density_model.hpp"
#include "deepcanvas/server_core/stamp.hpp"

namespace deepcanvas::exporting {

namespace {

namespace dm = protocol::density;
using server_core::CellCoord;
using server_core::CellIndex;
using server_core::Octree;

// A cell's value as one cell: its own colour for a leaf, its children merged with the density
// model for an internal cell (what merging the subtree would store).
std::uint32_t merged_value(const Octree& t, CellIndex c) {
  const CellIndex fc = t.first_child(c);
  if (fc == server_core::kNoCell) return t.colour(c);
  std::uint32_t ch[8];
  for (std::uint32_t i = 0; i < 8; ++i) ch[i] = merged_value(t, fc + i);
  return dm::coarsen_rgba(ch);
}

int deepest_painted(const Octree& t) {
  int deepest = 0;
  std::vector<std::pair<CellIndex, int>> stack;
  for (CellIndex r = 0; r < t.root_count(); ++r) stack.push_back({r, 0});
  while (!stack.empty()) {
    const auto [c, d] = stack.back();
    stack.pop_back();
    const CellIndex fc = t.first_child(c);
    if (fc == server_core::kNoCell) {
      if ((t.colour(c) >> 24) != 0) deepest = std::max(deepest, d);
      continue;
    }
    for (std::uint32_t i = 0; i < 8; ++i) stack.push_back({fc + i, d + 1});
  }
  return deepest;
}

bool overlaps(const server_core::Aabb& a, const server_core::Aabb& b) {
  return a.min.x <= b.max.x && b.min.x <= a.max.x && a.min.y <= b.max.y && b.min.y <= a.max.y &&
         a.min.z <= b.max.z && b.min.z <= a.max.z;
}

// Calls f(coord, rgba) for every painted unit: a leaf at depth <= D, or a cell at depth D with
// finer cells below (merged). Cells outside `box` are skipped.
template <class F>
void for_each_unit(const Octree& t, int D, const std::optional<server_core::Aabb>& box, F&& f) {
  const std::uint32_t r = t.config().roots_per_axis;
  struct Item {
    CellIndex c;
    CellCoord k;
  };
  std::vector<Item> stack;
  for (std::uint32_t z = 0; z < r; ++z)
    for (std::uint32_t y = 0; y < r; ++y)
      for (std::uint32_t x = 0; x < r; ++x) stack.push_back({x + r * (y + r * z), {0, x, y, z}});
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    if (box && !overlaps(t.bounds_m(it.k), *box)) continue;
    const CellIndex fc = t.first_child(it.c);
    if (fc == server_core::kNoCell || it.k.depth == D) {
      const std::uint32_t v = fc == server_core::kNoCell ? t.colour(it.c) : merged_value(t, it.c);
      if ((v >> 24) != 0) f(it.k, v);
      continue;
    }
    for (std::uint32_t i = 0; i < 8; ++i)
      stack.push_back({fc + i, server_core::child_coord(it.k, i)});
  }
}

Result<int> voxel_level(const Octree& t, const VdbExportOptions& o) {
  const int D = o.voxel_depth < 0 ? deepest_painted(t) : o.voxel_depth;
  if (D > t.config().max_depth)
    return make_error(Errc::invalid_argument,
                      "voxel level " + std::to_string(D) + " is deeper than the canvas (" +
                          std::to_string(t.config().max_depth) + " levels)");
  if (o.box && !(o.box->min.x <= o.box->max.x && o.box->min.y <= o.box->max.y &&
                 o.box->min.z <= o.box->max.z))
    return make_error(Errc::invalid_argument, "the export box is empty (min past max)");
  return D;
}

}  // namespace

int voxel_depth_for(const server_core::OctreeConfig& canvas, double voxel_size_m) {
  const double root = canvas.edge_m / canvas.roots_per_axis;
  return std::clamp(static_cast<int>(std::lround(std::log2(root / voxel_size_m))), 0,
                    canvas.max_depth);
}

Result<VdbExportSummary> estimate_vdb(const Octree& tree, const VdbExportOptions& options) {
  auto D = voxel_level(tree, options);
  if (!D) return std::move(D).error();
  VdbExportSummary s;
  s.voxel_depth = *D;
  s.voxel_size_m = tree.cell_edge_m(*D);
  for_each_unit(tree, *D, options.box, [&](const CellCoord& k, std::uint32_t) {
    const int shift = *D - k.depth;
    if (shift == 0) {
      ++s.leaf_voxels;
      ++s.voxels;
    } else {
      ++s.tiles;
      s.voxels += std::uint64_t{1} << (3 * shift);
    }
  });
  // OpenVDB stores voxels in 8^3 leaf nodes (4 + 12 bytes a voxel for the two grids, plus masks)
  // and a tile in a few bytes: a generous estimate, checked against real files by the tests.
  s.estimated_bytes = 4096 + s.leaf_voxels * 20 + s.tiles * 64;
  return s;
}

namespace detail {

Result<CanvasGrids> build_grids(const Octree& tree, const VdbExportOptions& options,
                                bool with_opacity) {
  auto s = estimate_vdb(tree, options);
  if (!s) return std::move(s).error();
  if (options.max_bytes != 0 && s->estimated_bytes > options.max_bytes)
    return make_error(Errc::limit_exceeded,
                      "the export would take about " + std::to_string(s->estimated_bytes) +
                          " bytes, more than --max-bytes " + std::to_string(options.max_bytes) +
                          ": choose a coarser --voxel-size or a smaller --box; nothing written");
  const int D = s->voxel_depth;
  const double h = s->voxel_size_m;
  const double half = tree.config().edge_m * 0.5;
  openvdb::initialize();
  CanvasGrids g;
  g.summary = *s;
  g.density = openvdb::FloatGrid::create(0.0f);
  g.colour = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.0f));
  auto& density = g.density;
  auto& colour = g.colour;
  auto xf = openvdb::math::Transform::createLinearTransform(h);
  xf->postTranslate(openvdb::Vec3d(-half + 0.5 * h, -half + 0.5 * h, -half + 0.5 * h));
  density->setTransform(xf);
  colour->setTransform(xf->copy());
  density->setName("density");
  colour->setName("Cd");
  density->setGridClass(openvdb::GRID_FOG_VOLUME);
  density->insertMeta("units", openvdb::StringMetadata("1/m (extinction)"));
  if (with_opacity) {
    g.opacity = openvdb::FloatGrid::create(0.0f);
    g.opacity->setTransform(xf->copy());
    g.opacity->setName("opacity");
  }
  auto& dt = density->tree();
  auto& ct = colour->tree();
  openvdb::FloatTree* ot = with_opacity ? &g.opacity->tree() : nullptr;
  for_each_unit(tree, D, options.box, [&](const CellCoord& k, std::uint32_t v) {
    const double edge = tree.cell_edge_m(k.depth);
    const double a = static_cast<double>(v >> 24) / 255.0;
    const double sigma =
        a >= 1.0 ? dm::kOpaqueOpticalDepth / edge : dm::sigma_per_m(a, edge);
    const openvdb::Vec3s rgb(static_cast<float>((v & 0xFF) / 255.0),
                             static_cast<float>(((v >> 8) & 0xFF) / 255.0),
                             static_cast<float>(((v >> 16) & 0xFF) / 255.0));
    const int shift = D - k.depth;
    const openvdb::Coord lo(static_cast<int>(k.x << shift), static_cast<int>(k.y << shift),
                            static_cast<int>(k.z << shift));
    if (shift == 0) {
      dt.setValue(lo, static_cast<float>(sigma));
      ct.setValue(lo, rgb);
      if (ot != nullptr) ot->setValue(lo, static_cast<float>(a));
      return;
    }
    const int n = (1 << shift) - 1;
    const openvdb::CoordBBox bbox(lo, lo.offsetBy(n));
    dt.sparseFill(bbox, static_cast<float>(sigma), true);
    ct.sparseFill(bbox, rgb, true);
    if (ot != nullptr) ot->sparseFill(bbox, static_cast<float>(a), true);
  });
  return g;
}

}  // namespace detail

Result<VdbExportSummary> export_vdb(const Octree& tree, const VdbExportOptions& options,
                                    const std::string& path) {
  const auto t0 = std::chrono::steady_clock::now();
  auto g = detail::build_grids(tree, options);
  if (!g) return std::move(g).error();
  VdbExportSummary s = g->summary;
  const auto t1 = std::chrono::steady_clock::now();
  s.build_seconds = std::chrono::duration<double>(t1 - t0).count();
  auto& density = g->density;
  auto& colour = g->colour;
  // Written beside the target and renamed: a failed write leaves no half file.
  const std::string tmp = path + ".part";
  try {
    openvdb::io::File file(tmp);
    openvdb::GridPtrVec grids{density, colour};
    file.write(grids);
    file.close();
    s.write_seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  } catch (const std::exception& e) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    return make_error(Errc::io_error, "writing " + path + ": " + e.what());
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    return make_error(Errc::io_error, "writing " + path + ": " + ec.message());
  }
  s.file_bytes = std::filesystem::file_size(path, ec);
  return s;
}

}  // namespace deepcanvas::exporting
