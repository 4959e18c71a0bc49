// exporting::mesh_canvas / write_mesh / read_mesh: the surface is closed and manifold with
// consistent outward winding, its vertex colours are the paint's near the surface, the budget
// picks the level, the files read back (tinygltf for glTF), and bad files are refused.
#include <gtest/gtest.h>

#include "export_test_support.hpp"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>

#include "deepcanvas/export/mesh_export.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/protocol/density_model.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas {
namespace {

namespace fs = std::filesystem;
using export_test::Canvas;
using export_test::file_bytes;
using export_test::merged_at;
using export_test::merged_value;
using export_test::small_canvas;
using export_test::temp_file;
using export_test::value_at;
using exporting::Mesh;
using server_core::Octree;

// A short opaque stroke of one colour around `at`.
void blob(Canvas& c, double x, double y, double z, float r, float g, float b) {
  protocol::Stroke st;
  st.brush.colour[0] = r;
  st.brush.colour[1] = g;
  st.brush.colour[2] = b;
  st.brush.colour[3] = 1.0f;
  for (int i = 0; i < 4; ++i) st.samples.push_back({x + 0.04 * i, y, z, 0.12f, 1.0f, 0});
  ASSERT_TRUE(c.painter->apply_stroke(st));
}

struct EdgeReport {
  std::size_t edges = 0, boundary = 0, non_manifold = 0, same_direction = 0;
};

// Every undirected edge should be used by exactly two triangles, once in each direction.
EdgeReport edges_of(const Mesh& m) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::pair<int, int>> uses;  // (fwd, back)
  for (std::size_t t = 0; t < m.triangles(); ++t)
    for (int e = 0; e < 3; ++e) {
      const std::uint32_t a = m.indices[3 * t + static_cast<std::size_t>(e)];
      const std::uint32_t b = m.indices[3 * t + static_cast<std::size_t>((e + 1) % 3)];
      if (a < b)
        ++uses[{a, b}].first;
      else
        ++uses[{b, a}].second;
    }
  EdgeReport r;
  r.edges = uses.size();
  for (const auto& [e, u] : uses) {
    if (u.first + u.second == 1) ++r.boundary;
    if (u.first + u.second > 2) ++r.non_manifold;
    if (u.first == 2 || u.second == 2) ++r.same_direction;
  }
  return r;
}

// The enclosed volume (positive when the triangles wind counter-clockwise seen from outside).
double signed_volume(const Mesh& m) {
  double v = 0;
  for (std::size_t t = 0; t < m.triangles(); ++t) {
    const auto& a = m.positions[m.indices[3 * t]];
    const auto& b = m.positions[m.indices[3 * t + 1]];
    const auto& c = m.positions[m.indices[3 * t + 2]];
    v += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) +
          a[2] * (b[0] * c[1] - b[1] * c[0])) /
         6.0;
  }
  return v;
}

// The canvas's value at p at depth `depth`: the leaf's colour, or the cell at that depth with its
// finer cells merged by the density model (what the export's grids hold).
TEST(MeshExport, TwoBlobsGiveClosedManifoldOutwardSurfacesInTheirColours) {
  Canvas c(small_canvas());
  blob(c, -0.4, 0.0, 0.0, 1.0f, 0.0f, 0.0f);  // red on the left
  blob(c, 0.4, 0.1, 0.0, 0.0f, 0.0f, 1.0f);   // blue on the right
  exporting::MeshExportOptions o;
  o.volume.voxel_depth = 6;  // 2 m / 2 / 64: 15.6 mm voxels
  o.max_triangles = 0;
  exporting::MeshExportSummary s;
  auto m = exporting::mesh_canvas(*c.tree, o, &s);
  ASSERT_TRUE(m) << m.error().message;
  EXPECT_GT(m->triangles(), 500u);
  EXPECT_EQ(s.triangles, m->triangles());
  const EdgeReport e = edges_of(*m);
  EXPECT_EQ(e.boundary, 0u) << "a closed surface has no open edges";
  EXPECT_EQ(e.non_manifold, 0u);
  EXPECT_EQ(e.same_direction, 0u) << "neighbouring triangles wind alike";
  // Outward: the enclosed volume is positive, and within 15% of the volume of the voxels at
  // least as opaque as the iso level (brute force over every voxel of the level).
  const double h = c.tree->cell_edge_m(6);
  double reference = 0;
  for (int z = 0; z < 128; ++z)
    for (int y = 0; y < 128; ++y)
      for (int x = 0; x < 128; ++x) {
        const std::uint32_t a = merged_at(*c.tree, {-1 + (x + 0.5) * h, -1 + (y + 0.5) * h,
                                                    -1 + (z + 0.5) * h}, 6) >> 24;
        if (a / 255.0 >= o.iso_alpha) reference += h * h * h;
      }
  const double v = signed_volume(*m);
  EXPECT_GT(v, 0.85 * reference);
  EXPECT_LT(v, 1.15 * reference);
  int red = 0, blue = 0;
  for (std::size_t i = 0; i < m->positions.size(); ++i) {
    const auto& p = m->positions[i];
    const auto& col = m->colours[i];
    ASSERT_GE(p[0] < 0 ? col[0] : col[2], 253) << "vertex " << i << " at x " << p[0];
    ASSERT_LE(p[0] < 0 ? col[2] : col[0], 2) << "vertex " << i << " at x " << p[0];
    (p[0] < 0 ? red : blue)++;
  }
  EXPECT_GT(red, 100);
  EXPECT_GT(blue, 100);
}

TEST(MeshExport, FilesReadBackEqualAndBadFilesAreRefused) {
  Canvas c(small_canvas());
  blob(c, 0.0, 0.0, 0.0, 0.2f, 0.8f, 0.4f);
  exporting::MeshExportOptions o;
  o.volume.voxel_depth = 5;
  auto m = exporting::mesh_canvas(*c.tree, o);
  ASSERT_TRUE(m) << m.error().message;
  for (auto [fmt, ext] : {std::pair{exporting::MeshFormat::gltf, ".gltf"},
                          std::pair{exporting::MeshFormat::glb, ".glb"},
                          std::pair{exporting::MeshFormat::ply, ".ply"}}) {
    const fs::path p = temp_file(std::string("blob") + ext);
    auto bytes = exporting::write_mesh(*m, fmt, p.string());
    ASSERT_TRUE(bytes) << bytes.error().message;
    EXPECT_EQ(*bytes, fs::file_size(p));
    EXPECT_NEAR(static_cast<double>(exporting::estimate_mesh_bytes(*m, fmt)),
                static_cast<double>(*bytes), 2000.0)
        << ext;
    EXPECT_FALSE(fs::exists(p.string() + ".part"));
    auto back = exporting::read_mesh(p.string());  // tinygltf for .gltf and .glb
    ASSERT_TRUE(back) << ext << ": " << back.error().message;
    EXPECT_EQ(back->indices, m->indices) << ext;
    EXPECT_EQ(back->positions, m->positions) << ext;
    EXPECT_EQ(back->colours, m->colours) << ext;
    // Truncated and corrupted copies are refused, never crash.
    std::string bytes_in;
    {
      std::ifstream in(p, std::ios::binary);
      bytes_in.assign(std::istreambuf_iterator<char>(in), {});
    }
    for (std::size_t cut : {bytes_in.size() / 2, bytes_in.size() - 7, std::size_t{20}}) {
      const fs::path q = temp_file(std::string("cut") + ext);
      std::ofstream(q, std::ios::binary).write(bytes_in.data(), static_cast<std::streamsize>(cut));
      auto r = exporting::read_mesh(q.string());
      EXPECT_FALSE(r) << ext << " cut at " << cut;
      if (!r) {
        EXPECT_EQ(r.error().code, Errc::malformed) << r.error().message;
      }
      fs::remove(q);
    }
    fs::remove(p);
  }
  EXPECT_EQ(exporting::read_mesh("/nonexistent/x.ply").error().code, Errc::not_found);
  const fs::path obj = temp_file("x.obj");
  std::ofstream(obj) << "v 0 0 0\n";
  EXPECT_EQ(exporting::read_mesh(obj.string()).error().code, Errc::unsupported);
  fs::remove(obj);
}

TEST(MeshExport, TheBudgetPicksTheLevelAndBadOptionsAreRefused) {
  Canvas c(small_canvas());
  blob(c, 0.0, 0.0, 0.0, 1.0f, 1.0f, 1.0f);
  exporting::MeshExportOptions o;
  o.max_triangles = 60;
  exporting::MeshExportSummary s;
  auto m = exporting::mesh_canvas(*c.tree, o, &s);
  ASSERT_TRUE(m) << m.error().message;
  EXPECT_LE(m->triangles(), 60u);
  // The finest fitting level: one level finer does not fit (the blob is painted finer still).
  auto deepest = exporting::estimate_vdb(*c.tree, {});
  ASSERT_TRUE(deepest);
  ASSERT_LT(s.volume.voxel_depth, deepest->voxel_depth);
  o.volume.voxel_depth = s.volume.voxel_depth + 1;
  o.max_triangles = 0;
  auto finer = exporting::mesh_canvas(*c.tree, o);
  ASSERT_TRUE(finer);
  EXPECT_GT(finer->triangles(), 60u);
  // A fixed level the budget cannot hold even at full adaptivity.
  o.volume.voxel_depth = 8;
  o.max_triangles = 10;
  auto refused = exporting::mesh_canvas(*c.tree, o);
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code, Errc::limit_exceeded);
  o.max_triangles = 0;
  o.iso_alpha = 1.5;
  EXPECT_EQ(exporting::mesh_canvas(*c.tree, o).error().code, Errc::invalid_argument);
  o.iso_alpha = 0.5;
  o.volume.box = server_core::Aabb{{0.8, 0.8, 0.8}, {0.9, 0.9, 0.9}};  // away from the paint
  EXPECT_EQ(exporting::mesh_canvas(*c.tree, o).error().code, Errc::not_found);
}

// On a real painting: the surface at the budget's level is closed and consistently wound (a
// rare non-manifold edge where two voxels touch only along an edge is allowed), outward, and
// its vertices carry the colours of painted cells beside them.
TEST(MeshExport, RealPaintingSurfaceIsClosedAndOutward) {
  const char* dir = std::getenv("DEEPCANVAS_PAINTINGS");
  if (dir == nullptr || *dir == 0) GTEST_SKIP() << "DEEPCANVAS_PAINTINGS is not set";
  auto painting = paintings::read_apa_file(std::string(dir) + "/demo.apa", {});
  ASSERT_TRUE(painting) << painting.error().message;
  Canvas c;
  for (const auto& s : painting->strokes) ASSERT_TRUE(c.painter->apply_stroke(s));
  exporting::MeshExportOptions o;
  o.max_triangles = 200'000;
  exporting::MeshExportSummary s;
  auto m = exporting::mesh_canvas(*c.tree, o, &s);
  ASSERT_TRUE(m) << m.error().message;
  EXPECT_LE(m->triangles(), 200'000u);
  EXPECT_GT(m->triangles(), 20'000u);
  const EdgeReport e = edges_of(*m);
  EXPECT_EQ(e.boundary, 0u);
  EXPECT_EQ(e.same_direction, 0u);
  EXPECT_LE(e.non_manifold, e.edges / 1000) << e.non_manifold << " of " << e.edges;
  EXPECT_GT(signed_volume(*m), 0.0);
  // Vertex colours: within the colours of the painted leaves around the vertex (the eight
  // points half a voxel away on each axis), per channel, 2/255 slack.
  const double h = s.volume.voxel_size_m;
  std::size_t checked = 0, outside = 0;
  for (std::size_t i = 0; i < m->positions.size(); i += 7) {
    int lo[3] = {255, 255, 255}, hi[3] = {0, 0, 0};
    bool any = false;
    for (int corner = 0; corner < 8; ++corner) {
      server_core::Vec3d p{m->positions[i][0] + ((corner & 1) ? h : -h) * 0.5,
              m->positions[i][1] + ((corner & 2) ? h : -h) * 0.5,
              m->positions[i][2] + ((corner & 4) ? h : -h) * 0.5};
      const std::uint32_t v = merged_at(*c.tree, p, s.volume.voxel_depth);
      if ((v >> 24) == 0) continue;
      any = true;
      for (int k = 0; k < 3; ++k) {
        lo[k] = std::min(lo[k], static_cast<int>((v >> (8 * k)) & 0xFF));
        hi[k] = std::max(hi[k], static_cast<int>((v >> (8 * k)) & 0xFF));
      }
    }
    if (!any) continue;
    ++checked;
    for (int k = 0; k < 3; ++k)
      if (m->colours[i][static_cast<std::size_t>(k)] + 2 < lo[k] ||
          m->colours[i][static_cast<std::size_t>(k)] > hi[k] + 2) {
        ++outside;
        break;
      }
  }
  EXPECT_GT(checked, m->positions.size() / 14);
  EXPECT_LE(outside, checked / 100) << outside << " of " << checked << " vertices";
}

}  // namespace
}  // namespace deepcanvas
