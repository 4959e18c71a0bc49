#include "deepcanvas/export/mesh_export.hpp"

#include <openvdb/tools/VolumeToMesh.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>

#include "canvas_grids.hpp"

namespace deepcanvas::exporting {

namespace {

// The colour of a surface vertex: the mean Cd of the painted voxels around it that lie inside
// the surface (opacity >= iso); where none does, the most opaque painted one around it.
std::array<std::uint8_t, 3> vertex_colour(const openvdb::Vec3d& index_pos,
                                          const openvdb::FloatGrid::ConstAccessor& opacity,
                                          const openvdb::Vec3SGrid::ConstAccessor& colour,
                                          double iso) {
  const openvdb::Coord base(static_cast<int>(std::floor(index_pos.x())),
                            static_cast<int>(std::floor(index_pos.y())),
                            static_cast<int>(std::floor(index_pos.z())));
  openvdb::Vec3d sum(0.0);
  int inside = 0;
  float best = 0;
  openvdb::Vec3s best_rgb(0.0f);
  for (int r = 1; r <= 2 && inside == 0 && best == 0; ++r) {
    // r = 1: the 8 voxels whose centres surround the vertex; r = 2: the 4^3 around them.
    const int lo = r == 1 ? 0 : -1, hi = r == 1 ? 1 : 2;
    for (int dz = lo; dz <= hi; ++dz)
      for (int dy = lo; dy <= hi; ++dy)
        for (int dx = lo; dx <= hi; ++dx) {
          const openvdb::Coord c = base.offsetBy(dx, dy, dz);
          const float a = opacity.getValue(c);
          if (a <= 0) continue;
          const openvdb::Vec3s rgb = colour.getValue(c);
          if (a >= iso) {
            sum += openvdb::Vec3d(rgb);
            ++inside;
          } else if (a > best) {
            best = a;
            best_rgb = rgb;
          }
        }
  }
  const openvdb::Vec3d v = inside > 0 ? sum / inside : openvdb::Vec3d(best_rgb);
  std::array<std::uint8_t, 3> out{};
  for (int i = 0; i < 3; ++i)
    out[static_cast<std::size_t>(i)] =
        static_cast<std::uint8_t>(std::clamp(std::lround(v[i] * 255.0), 0L, 255L));
  return out;
}

Mesh mesh_at(const openvdb::FloatGrid& surface, const detail::CanvasGrids& g, double iso,
             double adaptivity) {
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> tris;
  std::vector<openvdb::Vec4I> quads;
  // The field is -opacity (inside negative, a level set's convention) so that OpenVDB's winding
  // makes normals point out of the paint.
  openvdb::tools::volumeToMesh(surface, points, tris, quads, -iso, adaptivity);
  Mesh m;
  m.positions.reserve(points.size());
  m.colours.reserve(points.size());
  const auto op = g.opacity->getConstAccessor();
  const auto cd = g.colour->getConstAccessor();
  const auto& xf = surface.transform();
  for (const auto& p : points) {
    m.positions.push_back({p.x(), p.y(), p.z()});
    m.colours.push_back(vertex_colour(xf.worldToIndex(openvdb::Vec3d(p)), op, cd, iso));
  }
  auto tri = [&](std::uint32_t a, std::uint32_t b, std::uint32_t c) {
    if (a == b || b == c || a == c) return;  // collapsed by adaptivity
    m.indices.insert(m.indices.end(), {a, b, c});
  };
  m.indices.reserve(3 * tris.size() + 6 * quads.size());
  // With the field negative inside, OpenVDB's polygons wind counter-clockwise seen from outside.
  for (const auto& q : quads) {
    tri(q[0], q[1], q[2]);
    tri(q[0], q[2], q[3]);
  }
  for (const auto& t : tris) tri(t[0], t[1], t[2]);
  return m;
}

}  // namespace

namespace {

struct Meshed {
  Mesh mesh;
  MeshExportSummary summary;
};

// The mesh at one voxel level, adaptivity raised in steps until it fits the budget.
Result<Meshed> mesh_level(const server_core::Octree& tree, const MeshExportOptions& options) {
  auto g = detail::build_grids(tree, options.volume, /*with_opacity=*/true);
  if (!g) return std::move(g).error();
  if (g->summary.voxels == 0)
    return make_error(Errc::not_found, "nothing painted in the export box: no surface to write");
  auto surface = g->opacity->deepCopy();
  for (auto it = surface->beginValueOn(); it; ++it) it.setValue(-*it);
  double adaptivity = options.adaptivity;
  Meshed out;
  out.mesh = mesh_at(*surface, *g, options.iso_alpha, adaptivity);
  while (options.max_triangles != 0 && out.mesh.triangles() > options.max_triangles &&
         adaptivity < 1) {
    adaptivity = std::min(1.0, adaptivity + 0.2);
    out.mesh = mesh_at(*surface, *g, options.iso_alpha, adaptivity);
  }
  out.summary.volume = g->summary;
  out.summary.adaptivity = adaptivity;
  out.summary.vertices = out.mesh.positions.size();
  out.summary.triangles = out.mesh.triangles();
  return out;
}

bool fits(const Meshed& m, const MeshExportOptions& o) {
  return o.max_triangles == 0 || m.mesh.triangles() <= o.max_triangles;
}

}  // namespace

Result<Mesh> mesh_canvas(const server_core::Octree& tree, const MeshExportOptions& options,
                         MeshExportSummary* summary) {
  if (!(options.iso_alpha > 0 && options.iso_alpha < 1))
    return make_error(Errc::invalid_argument, "the iso level must lie in (0, 1)");
  if (!(options.adaptivity >= 0 && options.adaptivity <= 1))
    return make_error(Errc::invalid_argument, "adaptivity must lie in [0, 1]");
  std::optional<Meshed> best;
  if (options.volume.voxel_depth < 0 && options.max_triangles != 0) {
    // No level given: the finest level whose mesh fits the budget, found from coarse levels up
    // (each finer level has about four times the triangles, so the coarse tries cost little).
    auto deepest = estimate_vdb(tree, options.volume);
    if (!deepest) return std::move(deepest).error();
    // The search keeps the given adaptivity (no raising): each level as it is.
    MeshExportOptions o = options;
    o.max_triangles = 0;
    for (int d = std::max(0, deepest->voxel_depth - 12); d <= deepest->voxel_depth; ++d) {
      o.volume.voxel_depth = d;
      auto m = mesh_level(tree, o);
      if (!m) return std::move(m).error();
      if (!fits(*m, options)) break;
      if (!m->mesh.indices.empty()) best = std::move(*m);
    }
    if (!best)
      return make_error(Errc::limit_exceeded,
                        "no voxel level gives a surface within " +
                            std::to_string(options.max_triangles) + " triangles");
  } else {
    auto m = mesh_level(tree, options);
    if (!m) return std::move(m).error();
    if (!fits(*m, options))
      return make_error(Errc::limit_exceeded,
                        "the surface has " + std::to_string(m->mesh.triangles()) +
                            " triangles at full adaptivity, more than the budget of " +
                            std::to_string(options.max_triangles) +
                            ": choose a coarser --voxel-size or a smaller --box; nothing written");
    best = std::move(*m);
  }
  if (best->mesh.indices.empty())
    return make_error(Errc::not_found, "no surface at opacity " + std::to_string(options.iso_alpha) +
                                           ": the paint is fainter (try a lower --iso)");
  if (summary != nullptr) *summary = best->summary;
  return std::move(best->mesh);
}

Result<MeshExportSummary> export_mesh(const server_core::Octree& tree,
                                      const MeshExportOptions& options, MeshFormat format,
                                      const std::string& path) {
  MeshExportSummary s;
  auto m = mesh_canvas(tree, options, &s);
  if (!m) return std::move(m).error();
  auto bytes = write_mesh(*m, format, path);
  if (!bytes) return std::move(bytes).error();
  s.file_bytes = *bytes;
  return s;
}

}  // namespace deepcanvas::exporting
