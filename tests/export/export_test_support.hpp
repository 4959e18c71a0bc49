// Helpers shared by the export and import tests: a canvas with its painter, a small canvas's
// shape, the canvas's value at a cell (finer cells merged by the density model, as the export's
// grids hold it), and temporary files.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <string>
#include <vector>

#include "deepcanvas/protocol/density_model.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas::export_test {

struct Canvas {
  std::unique_ptr<server_core::Octree> tree;
  std::unique_ptr<server_core::Painter> painter;
  explicit Canvas(server_core::OctreeConfig oc = {}) {
    auto t = server_core::Octree::create(oc);
    EXPECT_TRUE(t);
    tree = std::move(*t);
    auto p = server_core::Painter::create(*tree);
    EXPECT_TRUE(p);
    painter = std::move(*p);
  }
};

// 2 m, 2 roots per axis, 8 levels.
inline server_core::OctreeConfig small_canvas() {
  server_core::OctreeConfig oc;
  oc.roots_per_axis = 2;
  oc.edge_m = 2.0;
  oc.max_depth = 8;
  oc.block_cells = 512;
  return oc;
}

inline std::uint32_t merged_value(const server_core::Octree& t, server_core::CellIndex c) {
  const auto fc = t.first_child(c);
  if (fc == server_core::kNoCell) return t.colour(c);
  std::uint32_t ch[8];
  for (std::uint32_t i = 0; i < 8; ++i) ch[i] = merged_value(t, fc + i);
  return protocol::density::coarsen_rgba(ch);
}

// The canvas's value at cell k: the cell's own (finer cells merged), or its leaf ancestor's
// refined down to k's depth.
inline std::uint32_t value_at(const server_core::Octree& t, const server_core::CellCoord& k) {
  const auto loc = t.find(k);
  if (loc.coord == k) return merged_value(t, loc.cell);
  std::uint32_t v = t.colour(loc.cell);
  for (int d = loc.coord.depth; d < k.depth; ++d) v = protocol::density::refine_rgba(v);
  return v;
}

// The value at point p at depth `depth` (0 outside the canvas).
inline std::uint32_t merged_at(const server_core::Octree& t, const server_core::Vec3d& p, int depth) {
  auto at = t.locate(p, depth);
  return at ? merged_value(t, at->cell) : 0;
}

inline std::filesystem::path temp_file(const std::string& name) {
  return std::filesystem::temp_directory_path() /
         ("deepcanvas_export_test_" + std::to_string(::getpid()) + "_" + name);
}

inline std::vector<std::uint8_t> file_bytes(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

}  // namespace deepcanvas::export_test
