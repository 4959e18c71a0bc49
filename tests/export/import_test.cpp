// exporting::import_cells: an exported OpenVDB file imported into an empty canvas gives the same
// canvas within 1/255 per channel at the exported level (synthetic strokes and real paintings),
// a mesh imports as the solid it bounds, and bad files and placements are refused with nothing
// made.
#include <gtest/gtest.h>

#include "export_test_support.hpp"

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <vector>

#include "deepcanvas/export/mesh_export.hpp"
#include "deepcanvas/export/vdb_export.hpp"
#include "deepcanvas/export/volume_import.hpp"
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
using server_core::CellCoord;
using server_core::Octree;

// The painted units of t at voxel level D: leaves at depth <= D and cells at D (merged).
template <class F>
void for_each_unit(const Octree& t, int D, F&& f) {
  const std::uint32_t r = t.config().roots_per_axis;
  std::vector<std::pair<server_core::CellIndex, CellCoord>> stack;
  for (std::uint32_t z = 0; z < r; ++z)
    for (std::uint32_t y = 0; y < r; ++y)
      for (std::uint32_t x = 0; x < r; ++x) stack.push_back({x + r * (y + r * z), {0, x, y, z}});
  while (!stack.empty()) {
    const auto [c, k] = stack.back();
    stack.pop_back();
    const auto fc = t.first_child(c);
    if (fc == server_core::kNoCell || k.depth == D) {
      const std::uint32_t v = merged_value(t, c);
      if ((v >> 24) != 0) f(k, v);
      continue;
    }
    for (std::uint32_t i = 0; i < 8; ++i) stack.push_back({fc + i, server_core::child_coord(k, i)});
  }
}

int channel_diff(std::uint32_t a, std::uint32_t b) {
  int m = 0;
  for (int s = 0; s < 32; s += 8)
    m = std::max(m, std::abs(static_cast<int>((a >> s) & 0xFF) - static_cast<int>((b >> s) & 0xFF)));
  return m;
}

struct RoundTrip {
  int worst = 0;            // max channel difference over both canvases' units
  std::size_t units = 0;    // units compared
  std::uint64_t cells = 0;  // cells imported
};

// Exports `a` at level D, imports the file into an empty canvas of the same shape, compares.
RoundTrip round_trip(const Octree& a, int D) {
  RoundTrip rt;
  const fs::path p = temp_file("rt_" + std::to_string(D) + ".vdb");
  exporting::VdbExportOptions xo;
  xo.voxel_depth = D;
  auto written = exporting::export_vdb(a, xo, p.string());
  EXPECT_TRUE(written) << written.error().message;
  if (!written) return rt;
  exporting::ImportSummary s;
  auto cells = exporting::import_cells(file_bytes(p), a.config(), {}, &s);
  fs::remove(p);
  EXPECT_TRUE(cells) << cells.error().message;
  if (!cells) return rt;
  EXPECT_EQ(s.depth, D);
  rt.cells = cells->size();
  Canvas b(a.config());
  auto pasted = b.painter->paste(*cells);
  EXPECT_TRUE(pasted) << pasted.error().message;
  EXPECT_TRUE(b.tree->check_invariants());
  // Both ways: every painted unit of each canvas against the other's value there.
  for_each_unit(a, D, [&](const CellCoord& k, std::uint32_t v) {
    const int d = channel_diff(v, value_at(*b.tree, k));
    rt.worst = std::max(rt.worst, d);
    ++rt.units;
  });
  for_each_unit(*b.tree, D, [&](const CellCoord& k, std::uint32_t v) {
    rt.worst = std::max(rt.worst, channel_diff(v, value_at(a, k)));
  });
  return rt;
}

void paint_random(Canvas& c, int strokes, unsigned seed, double spread = 0.6) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-spread, spread);
  for (int s = 0; s < strokes; ++s) {
    protocol::Stroke st;
    for (int k = 0; k < 3; ++k) st.brush.colour[k] = static_cast<float>((rng() % 256) / 255.0);
    st.brush.colour[3] = static_cast<float>(0.2 + 0.8 * (rng() % 100) / 100.0);
    st.brush.hardness = static_cast<float>((rng() % 100) / 100.0);
    const double x = u(rng), y = u(rng), z = u(rng);
    const float r = 0.01f + 0.15f * static_cast<float>(rng() % 100) / 100.0f;
    for (int i = 0; i < 6; ++i)
      st.samples.push_back({x + 0.3 * r * i, y, z + 0.1 * r * i, r, 1.0f, 0});
    ASSERT_TRUE(c.painter->apply_stroke(st));
  }
}

TEST(Import, VdbRoundTripGivesTheSameCanvasAtTheExportedLevel) {
  for (unsigned seed : {1u, 2u, 3u}) {
    Canvas a(small_canvas());
    paint_random(a, 8, seed);
    for (int D : {5, 7, 8}) {
      const RoundTrip rt = round_trip(*a.tree, D);
      EXPECT_GT(rt.units, 0u);
      EXPECT_LE(rt.worst, 1) << "seed " << seed << " level " << D;
    }
  }
}

TEST(Import, RealPaintingsRoundTripWithinOneQuantum) {
  const char* dir = std::getenv("DEEPCANVAS_PAINTINGS");
  if (dir == nullptr || *dir == 0) GTEST_SKIP() << "DEEPCANVAS_PAINTINGS is not set";
  for (const char* name : {"demo.apa", "mozfest.apa"}) {
    auto painting = paintings::read_apa_file(std::string(dir) + "/" + name, {});
    ASSERT_TRUE(painting) << painting.error().message;
    Canvas a;
    for (const auto& s : painting->strokes) ASSERT_TRUE(a.painter->apply_stroke(s));
    // A level where the paintings have detail (~1 cm cells) and one of their finest (~2.4 mm).
    for (int D : {19, 21}) {
      const RoundTrip rt = round_trip(*a.tree, D);
      EXPECT_GT(rt.units, 1000u) << name;
      EXPECT_LE(rt.worst, 1) << name << " level " << D;
    }
  }
}

TEST(Import, PlacementAndScaleMoveTheVolume) {
  Canvas a(small_canvas());
  paint_random(a, 3, 7, 0.2);
  const fs::path p = temp_file("moved.vdb");
  exporting::VdbExportOptions xo;
  xo.voxel_depth = 6;
  ASSERT_TRUE(exporting::export_vdb(*a.tree, xo, p.string()));
  const auto bytes = file_bytes(p);
  fs::remove(p);
  exporting::ImportOptions o;
  const double h = a.tree->cell_edge_m(6);
  o.at = {4 * h, -2 * h, 0};  // whole cells: the same cells, moved
  auto moved = exporting::import_cells(bytes, a.tree->config(), o);
  ASSERT_TRUE(moved) << moved.error().message;
  auto same = exporting::import_cells(bytes, a.tree->config(), {});
  ASSERT_TRUE(same);
  Canvas cs(a.tree->config()), cm(a.tree->config());
  ASSERT_TRUE(cs.painter->paste(*same));
  ASSERT_TRUE(cm.painter->paste(*moved));
  int worst = 0, painted = 0;
  const std::uint32_t n = a.tree->config().roots_per_axis << 6;
  for (std::uint32_t z = 0; z < n; ++z)
    for (std::uint32_t y = 2; y < n; ++y)
      for (std::uint32_t x = 0; x + 4 < n; ++x) {
        const std::uint32_t v = value_at(*cs.tree, {6, x, y, z});
        painted += (v >> 24) != 0;
        worst = std::max(worst, channel_diff(v, value_at(*cm.tree, {6, x + 4, y - 2, z})));
      }
  EXPECT_GT(painted, 100);
  EXPECT_LE(worst, 1);
  // Scale 2 at a level one coarser: about the same number of cells, twice the size.
  o.at = {0, 0, 0};
  o.scale = 2;
  exporting::ImportSummary s;
  auto doubled = exporting::import_cells(bytes, a.tree->config(), o, &s);
  ASSERT_TRUE(doubled) << doubled.error().message;
  EXPECT_EQ(s.depth, 5);
}

TEST(Import, MeshImportsAsTheSolidItBounds) {
  // A painted blob exported as a mesh, imported back: the solid covers the blob's opaque cells.
  Canvas a(small_canvas());
  protocol::Stroke st;
  st.brush.colour[0] = 1.0f;
  st.brush.colour[1] = 0.5f;
  st.brush.colour[2] = 0.0f;
  st.brush.colour[3] = 1.0f;
  st.brush.hardness = 1.0f;
  for (int i = 0; i < 4; ++i) st.samples.push_back({-0.1 + 0.06 * i, 0.0, 0.0, 0.15f, 1.0f, 0});
  ASSERT_TRUE(a.painter->apply_stroke(st));
  exporting::MeshExportOptions mo;
  mo.volume.voxel_depth = 6;
  mo.max_triangles = 0;
  mo.iso_alpha = 0.5;
  const fs::path p = temp_file("solid.ply");
  ASSERT_TRUE(exporting::export_mesh(*a.tree, mo, exporting::MeshFormat::ply, p.string()));
  exporting::ImportOptions o;
  o.format = "ply";
  o.voxel_size_m = a.tree->cell_edge_m(6);
  exporting::ImportSummary s;
  auto cells = exporting::import_cells(file_bytes(p), a.tree->config(), o, &s);
  fs::remove(p);
  ASSERT_TRUE(cells) << cells.error().message;
  EXPECT_EQ(s.depth, 6);
  Canvas b(a.tree->config());
  ASSERT_TRUE(b.painter->paste(*cells));
  // Intersection over union of the cells at least half opaque at level 6.
  std::size_t both = 0, either = 0, orange = 0, checked = 0;
  const std::uint32_t n = a.tree->config().roots_per_axis << 6;
  for (std::uint32_t z = 0; z < n; ++z)
    for (std::uint32_t y = 0; y < n; ++y)
      for (std::uint32_t x = 0; x < n; ++x) {
        const CellCoord k{6, x, y, z};
        const std::uint32_t va = value_at(*a.tree, k), vb = value_at(*b.tree, k);
        const bool ia = (va >> 24) >= 128, ib = (vb >> 24) >= 128;
        both += ia && ib;
        either += ia || ib;
        if (ib) {
          ++checked;
          orange += channel_diff(vb & 0xFFFFFF, 0x0080FF) <= 3;
        }
      }
  ASSERT_GT(either, 100u);
  EXPECT_GT(static_cast<double>(both) / static_cast<double>(either), 0.8);
  EXPECT_EQ(orange, checked) << "the mesh's vertex colour on every imported cell";
}

TEST(Import, BadFilesAndPlacementsAreRefusedWithNothingMade) {
  Canvas a(small_canvas());
  paint_random(a, 2, 9);
  const fs::path p = temp_file("bad.vdb");
  exporting::VdbExportOptions xo;
  xo.voxel_depth = 5;
  ASSERT_TRUE(exporting::export_vdb(*a.tree, xo, p.string()));
  const auto bytes = file_bytes(p);
  fs::remove(p);
  const auto& oc = a.tree->config();
  // The reads leave no temporary file behind: the importer's copy for OpenVDB to map is made in
  // TMPDIR, here a folder of this test's, and must be gone afterwards, cut-short files included.
  const fs::path tmp = temp_file("import_tmpdir");
  fs::create_directories(tmp);
  const char* old_tmpdir = std::getenv("TMPDIR");
  const std::string saved = old_tmpdir != nullptr ? old_tmpdir : "";
  ::setenv("TMPDIR", tmp.c_str(), 1);
  // Every cut on a grid of 64, and those the test had: refused as malformed, with a message a
  // client can be sent (OpenVDB's own text for a cut-short file can quote 32 KB of the bytes
  // it read: the message keeps a short printable part of it).
  std::vector<std::size_t> cuts{0, 10, bytes.size() / 3, bytes.size() / 2, bytes.size() - 1};
  for (std::size_t k = 1; k < 64; ++k) cuts.push_back(bytes.size() * k / 64);
  for (std::size_t cut : cuts) {
    auto r = exporting::import_cells(std::span(bytes.data(), cut), oc, {});
    EXPECT_FALSE(r) << "cut at " << cut;
    if (!r) {
      EXPECT_EQ(r.error().code, Errc::malformed) << r.error().message;
      EXPECT_LE(r.error().message.size(), 300u) << "cut at " << cut;
      for (const char c : r.error().message)
        ASSERT_TRUE(c >= 0x20 && c < 0x7f) << "cut at " << cut << ": " << r.error().message;
    }
  }
  EXPECT_TRUE(exporting::import_cells(bytes, oc, {})) << "the whole file imports";
  if (old_tmpdir != nullptr)
    ::setenv("TMPDIR", saved.c_str(), 1);
  else
    ::unsetenv("TMPDIR");
  std::vector<std::string> left;
  for (const auto& e : fs::directory_iterator(tmp)) left.push_back(e.path().filename().string());
  EXPECT_TRUE(left.empty()) << left.size() << " temporary files left, the first " << left[0];
  fs::remove_all(tmp);
  std::vector<std::uint8_t> noise(4096);
  std::mt19937 rng(1);
  for (auto& b : noise) b = static_cast<std::uint8_t>(rng());
  EXPECT_EQ(exporting::import_cells(noise, oc, {}).error().code, Errc::malformed);
  // A grid of the wrong type only.
  {
    openvdb::initialize();
    auto g = openvdb::Int32Grid::create(0);
    g->tree().setValue(openvdb::Coord(1, 2, 3), 7);
    g->setName("labels");
    const fs::path q = temp_file("int.vdb");
    openvdb::io::File f(q.string());
    f.write({g});
    f.close();
    auto r = exporting::import_cells(file_bytes(q), oc, {});
    fs::remove(q);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, Errc::invalid_argument);
    EXPECT_NE(r.error().message.find("labels"), std::string::npos) << r.error().message;
  }
  exporting::ImportOptions o;
  o.at = {0.9, 0, 0};  // the volume reaches past the 1 m half-edge
  auto outside = exporting::import_cells(bytes, oc, o);
  ASSERT_FALSE(outside);
  EXPECT_EQ(outside.error().code, Errc::invalid_argument);
  EXPECT_NE(outside.error().message.find("outside the canvas"), std::string::npos);
  o = {};
  o.scale = std::nan("");
  EXPECT_EQ(exporting::import_cells(bytes, oc, o).error().code, Errc::invalid_argument);
  o = {};
  o.max_cells = 5;
  EXPECT_EQ(exporting::import_cells(bytes, oc, o).error().code, Errc::limit_exceeded);
  o = {};
  o.format = "ply";
  EXPECT_EQ(exporting::import_cells(bytes, oc, o).error().code, Errc::malformed);
}

// Damaged mesh files (bytes flipped anywhere, as a hostile client could send): an error or a
// result, never a crash. (OpenVDB's reader does crash on damaged .vdb files: the server converts
// imports in a child process, import_worker.cpp, tested in tests/cli/export_import.py.)
TEST(Import, FlippedMeshBytesNeverCrash) {
  Canvas a(small_canvas());
  paint_random(a, 2, 11, 0.3);
  const fs::path glb = temp_file("flip.glb"), ply = temp_file("flip.ply");
  exporting::MeshExportOptions mo;
  mo.volume.voxel_depth = 6;
  mo.max_triangles = 0;
  mo.iso_alpha = 0.05;
  auto m1 = exporting::export_mesh(*a.tree, mo, exporting::MeshFormat::glb, glb.string());
  ASSERT_TRUE(m1) << m1.error().message;
  ASSERT_TRUE(exporting::export_mesh(*a.tree, mo, exporting::MeshFormat::ply, ply.string()));
  std::mt19937 rng(21);
  int errors = 0, results = 0;
  for (auto [path, format] : {std::pair{glb, "glb"}, std::pair{ply, "ply"}}) {
    const auto good = file_bytes(path);
    fs::remove(path);
    exporting::ImportOptions o;
    o.format = format;
    o.voxel_size_m = a.tree->cell_edge_m(5);
    for (int trial = 0; trial < 150; ++trial) {
      auto bytes = good;
      const int flips = 1 + static_cast<int>(rng() % 4);
      for (int f = 0; f < flips; ++f) bytes[rng() % bytes.size()] ^= static_cast<std::uint8_t>(1 + rng() % 255);
      auto r = exporting::import_cells(bytes, a.tree->config(), o);
      (r ? results : errors)++;
    }
  }
  EXPECT_EQ(errors + results, 300);
  EXPECT_GT(errors, 0);
}

}  // namespace
}  // namespace deepcanvas
