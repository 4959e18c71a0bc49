// Exporting a canvas as an OpenVDB volume (issue: export, import and time-lapse): what Blender,
// Houdini and other volume renderers read.
//
// The file holds two grids over the same index space, at one voxel level D (a depth of the
// octree; the voxel edge is the cell edge there):
//   density  FloatGrid, class fog volume: the extinction coefficient in 1/metre from the density
//            model (-ln(1 - a) / h for a cell of edge h and stored alpha a; an opaque cell gets
//            ln(1024) / h, the model's opaque optical depth), so it renders alike elsewhere;
//   Cd       Vec3SGrid: the colour, linear 0..1 (the stored RGB bytes / 255).
// Both share one transform in metres: voxel (i, j, k) is centred at -E/2 + (i + 1/2) h (the
// canvas's own cell addressing, E its edge). Leaves coarser than D are written as tiles (a
// cube of voxels filled sparsely: OpenVDB keeps node-aligned parts as tiles), never expanded
// cell by cell; cells finer than D are merged to D with the density model (as a merge would).
// Empty cells (alpha 0) are inactive background (0).
//
// Threading: reads the tree only; the caller keeps it from changing (a replayed tree, or the
// stroke thread's lock). Errors: invalid_argument (a voxel level outside the canvas, an empty
// box), limit_exceeded (the estimate is past max_bytes: nothing written), io_error (the file).
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::exporting {

struct VdbExportOptions {
  int voxel_depth = -1;                     // -1: the deepest painted leaf's depth
  std::optional<server_core::Aabb> box;     // canvas metres; cells outside it are left out
  std::uint64_t max_bytes = 0;              // refuse when the estimate is larger; 0: no limit
};

struct VdbExportSummary {
  int voxel_depth = 0;
  double voxel_size_m = 0;
  std::uint64_t voxels = 0;     // active voxels (tiles counted by the voxels they cover)
  std::uint64_t leaf_voxels = 0;  // voxels written one by one
  std::uint64_t tiles = 0;        // coarser leaves written as filled cubes
  std::uint64_t estimated_bytes = 0;
  std::uint64_t file_bytes = 0;   // after writing (0 for an estimate)
  double build_seconds = 0;       // the grids made from the tree
  double write_seconds = 0;       // OpenVDB's own write of them (io::File), the benchmark anchor
};

// The octree level whose cell edge is nearest `voxel_size_m` (clamped to the canvas's levels).
int voxel_depth_for(const server_core::OctreeConfig& canvas, double voxel_size_m);

// What an export would write, without writing it.
Result<VdbExportSummary> estimate_vdb(const server_core::Octree& tree,
                                      const VdbExportOptions& options);
// Writes `path` (the estimate first: past max_bytes nothing is written).
Result<VdbExportSummary> export_vdb(const server_core::Octree& tree,
                                    const VdbExportOptions& options, const std::string& path);

}  // namespace deepcanvas::exporting
