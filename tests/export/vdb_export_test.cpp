// exporting::export_vdb: the grids, their transform and values against the octree they came
// from, tiles for coarse leaves, merged cells at a coarser voxel level, the size bound, and the
// file as OpenVDB's own vdb_print reads it.
#include <gtest/gtest.h>

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>

#include "deepcanvas/export/vdb_export.hpp"
#include "deepcanvas/protocol/density_model.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas {
namespace {

namespace fs = std::filesystem;
using server_core::Octree;

struct Canvas {
  std::unique_ptr<Octree> tree;
  std::unique_ptr<server_core::Painter> painter;
};

// A 2 m canvas, 2 roots, 7 levels, with a few strokes of different sizes.
Canvas painted() {
  server_core::OctreeConfig oc;
  oc.roots_per_axis = 2;
  oc.edge_m = 2.0;
  oc.max_depth = 7;
  oc.block_cells = 512;
  Canvas c;
  auto t = Octree::create(oc);
  EXPECT_TRUE(t);
  c.tree = std::move(*t);
  auto p = server_core::Painter::create(*c.tree);
  EXPECT_TRUE(p);
  c.painter = std::move(*p);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  for (int s = 0; s < 6; ++s) {
    protocol::Stroke st;
    st.brush.colour[0] = static_cast<float>(s) / 6.0f;
    st.brush.colour[1] = 0.5f;
    st.brush.colour[2] = 1.0f - static_cast<float>(s) / 6.0f;
    st.brush.colour[3] = s % 2 ? 1.0f : 0.4f;
    const double x = u(rng), y = u(rng), z = u(rng);
    for (int i = 0; i < 5; ++i)
      st.samples.push_back({x + 0.05 * i, y, z, 0.03f + 0.05f * static_cast<float>(s % 3), 1.0f, 0});
    EXPECT_TRUE(c.painter->apply_stroke(st));
  }
  return c;
}

fs::path temp_file(const std::string& name) {
  return fs::temp_directory_path() / ("deepcanvas_export_" + std::to_string(::getpid()) + "_" + name);
}

template <class GridT>
typename GridT::Ptr read_grid(const fs::path& p, const std::string& name) {
  openvdb::io::File f(p.string());
  f.open(/*delayLoad=*/false);  // a delayed load copies the file to /tmp and can leave the copy behind
  auto base = f.readGrid(name);
  f.close();
  return openvdb::gridPtrCast<GridT>(base);
}

// Every painted leaf: the grids hold its extinction and colour at its centre.
TEST(VdbExport, GridsHoldEveryLeafsExtinctionAndColour) {
  openvdb::initialize();
  Canvas c = painted();
  const fs::path out = temp_file("a.vdb");
  auto s = exporting::export_vdb(*c.tree, {}, out.string());
  ASSERT_TRUE(s) << s.error().message;
  EXPECT_GT(s->voxels, 0u);
  EXPECT_GT(s->file_bytes, 0u);
  auto density = read_grid<openvdb::FloatGrid>(out, "density");
  auto colour = read_grid<openvdb::Vec3SGrid>(out, "Cd");
  ASSERT_TRUE(density && colour);
  EXPECT_EQ(density->getGridClass(), openvdb::GRID_FOG_VOLUME);
  EXPECT_EQ(density->activeVoxelCount(), s->voxels);
  EXPECT_EQ(colour->activeVoxelCount(), s->voxels);
  EXPECT_NEAR(density->voxelSize()[0], c.tree->cell_edge_m(s->voxel_depth), 1e-12);
  // Probe leaves at their centres (world -> index through the file's own transform).
  int checked = 0;
  std::vector<std::pair<server_core::CellIndex, server_core::CellCoord>> stack;
  for (std::uint32_t z = 0; z < 2; ++z)
    for (std::uint32_t y = 0; y < 2; ++y)
      for (std::uint32_t x = 0; x < 2; ++x) stack.push_back({x + 2 * (y + 2 * z), {0, x, y, z}});
  auto dacc = density->getConstAccessor();
  auto cacc = colour->getConstAccessor();
  while (!stack.empty()) {
    const auto [cell, k] = stack.back();
    stack.pop_back();
    const auto fc = c.tree->first_child(cell);
    if (fc != server_core::kNoCell) {
      for (std::uint32_t i = 0; i < 8; ++i)
        stack.push_back({fc + i, server_core::child_coord(k, i)});
      continue;
    }
    const std::uint32_t v = c.tree->colour(cell);
    const auto b = c.tree->bounds_m(k);
    const openvdb::Vec3d centre((b.min.x + b.max.x) / 2, (b.min.y + b.max.y) / 2,
                                (b.min.z + b.max.z) / 2);
    const openvdb::Coord ijk = density->transform().worldToIndexCellCentered(centre);
    const double h = c.tree->cell_edge_m(k.depth);
    const double a = (v >> 24) / 255.0;
    const double want = a == 0 ? 0.0
                        : a >= 1 ? protocol::density::kOpaqueOpticalDepth / h
                                 : protocol::density::sigma_per_m(a, h);
    ASSERT_NEAR(dacc.getValue(ijk), want, 1e-5 * std::max(1.0, want)) << "depth " << k.depth;
    EXPECT_EQ(dacc.isValueOn(ijk), a > 0);
    if (a > 0) {
      EXPECT_NEAR(cacc.getValue(ijk)[0], (v & 0xFF) / 255.0, 1e-6);
      EXPECT_NEAR(cacc.getValue(ijk)[2], ((v >> 16) & 0xFF) / 255.0, 1e-6);
      ++checked;
    }
  }
  EXPECT_GT(checked, 100);
  fs::remove(out);
}

// Coarser voxels: fewer voxels, and a cell refined below the level is one merged voxel.
TEST(VdbExport, ACoarserLevelMergesFinerCellsAndCoarseLeavesAreTiles) {
  openvdb::initialize();
  Canvas c = painted();
  auto fine = exporting::estimate_vdb(*c.tree, {});
  ASSERT_TRUE(fine);
  EXPECT_GT(fine->tiles, 0u) << "no leaf coarser than the voxels: tiles untested";
  exporting::VdbExportOptions o;
  o.voxel_depth = fine->voxel_depth - 2;
  const fs::path out = temp_file("b.vdb");
  auto coarse = exporting::export_vdb(*c.tree, o, out.string());
  ASSERT_TRUE(coarse) << coarse.error().message;
  EXPECT_LT(coarse->leaf_voxels + coarse->tiles, fine->leaf_voxels + fine->tiles);
  auto density = read_grid<openvdb::FloatGrid>(out, "density");
  EXPECT_EQ(density->activeVoxelCount(), coarse->voxels);
  EXPECT_NEAR(density->voxelSize()[0], c.tree->cell_edge_m(o.voxel_depth), 1e-12);
  fs::remove(out);
}

TEST(VdbExport, PastMaxBytesNothingIsWrittenAndBadOptionsAreRefused) {
  openvdb::initialize();
  Canvas c = painted();
  const fs::path out = temp_file("c.vdb");
  exporting::VdbExportOptions o;
  o.max_bytes = 1000;
  auto r = exporting::export_vdb(*c.tree, o, out.string());
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, Errc::limit_exceeded);
  EXPECT_FALSE(fs::exists(out));
  o = {};
  o.voxel_depth = 30;
  EXPECT_EQ(exporting::export_vdb(*c.tree, o, out.string()).error().code, Errc::invalid_argument);
  o = {};
  o.box = server_core::Aabb{{1, 1, 1}, {0, 0, 0}};
  EXPECT_EQ(exporting::export_vdb(*c.tree, o, out.string()).error().code, Errc::invalid_argument);
  auto unwritable = exporting::export_vdb(*c.tree, {}, "/nonexistent-dir/x.vdb");
  ASSERT_FALSE(unwritable);
  EXPECT_EQ(unwritable.error().code, Errc::io_error);
  // A box around nothing painted: an empty but valid file.
  o = {};
  o.box = server_core::Aabb{{0.9, 0.9, 0.9}, {0.95, 0.95, 0.95}};
  auto empty = exporting::export_vdb(*c.tree, o, out.string());
  ASSERT_TRUE(empty) << empty.error().message;
  EXPECT_EQ(empty->voxels, 0u);
  fs::remove(out);
}

// OpenVDB's own tool reads the file and lists both grids with their voxel counts.
TEST(VdbExport, VdbPrintListsBothGrids) {
  if (std::system("command -v vdb_print >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "vdb_print is not installed (Debian libopenvdb-tools; scripts/setup.sh)";
  openvdb::initialize();
  Canvas c = painted();
  const fs::path out = temp_file("d.vdb");
  auto s = exporting::export_vdb(*c.tree, {}, out.string());
  ASSERT_TRUE(s);
  const std::string cmd = "vdb_print -l " + out.string() + " 2>&1";
  FILE* p = ::popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::string text;
  char buf[4096];
  while (std::fgets(buf, sizeof buf, p)) text += buf;
  EXPECT_EQ(::pclose(p), 0) << text;
  EXPECT_NE(text.find("Name: density"), std::string::npos) << text;
  EXPECT_NE(text.find("Name: Cd"), std::string::npos) << text;
  // vdb_print writes counts with thousands separators.
  std::string count = std::to_string(s->voxels);
  for (int i = static_cast<int>(count.size()) - 3; i > 0; i -= 3)
    count.insert(static_cast<std::size_t>(i), ",");
  EXPECT_NE(text.find("Number of active voxels:       " + count), std::string::npos)
      << count << "\n" << text;
  fs::remove(out);
}

}  // namespace
}  // namespace deepcanvas
