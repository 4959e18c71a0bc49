// Importing volumes and meshes into a canvas (issue: export, import and time-lapse): a file
// becomes a CellPaste (server_core/cell_paste.hpp), the one operation the canvas applies,
// records and can undo.
//
// Files:
//   vdb        an OpenVDB file with a float grid: `density` if there is one, else the first float
//              grid. A fog volume's values are extinction per file unit (times density_scale);
//              a level set (signed distance) is solid inside. Colour from a Vec3f grid named
//              `Cd`, `color` or `colour` where there is one (0..1), else options.colour.
//              Transforms must be linear with uniform voxels (no rotation, no taper).
//   gltf, glb  the first mesh's first primitive (triangles, POSITION, COLOR_0), through tinygltf;
//   ply        binary little-endian PLY (vertex x y z, red green blue; faces): meshes are made
//              solid with OpenVDB's mesh-to-volume (closed meshes; the inside is filled), their
//              surface cells coloured by the nearest triangle's vertex colours.
// Placement: a file point p (file units) lands at canvas metres `at + scale * p`. The cells are
// at one octree level: the one whose edge is nearest voxel_size_m, or with 0 the file's own voxel
// size (vdb), or 1/128 of the mesh's largest extent. A voxel becomes the cells of that level
// whose centres it holds (exact when the voxels line up with the canvas's cells, as an exported
// file's do); a tile, or a voxel larger than the level's cells, becomes the coarsest cells that
// fit inside it. Each cell gets alpha = 1 - exp(-sigma * edge) from the extinction sigma (the
// density model: the same paint at every level) or, for solids, the solid's coverage.
//
// Untrusted input: the file bytes. Every failure is an error and nothing is made: malformed (not
// a readable file of the format: truncated, corrupt), invalid_argument (no float grid, a grid of
// the wrong type, a transform that is not linear and uniform, cells that fall outside the
// canvas, a non-finite or absurd option), limit_exceeded (more cells than max_cells: choose a
// coarser voxel_size_m). OpenVDB's own exceptions are caught here.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/server_core/cell_paste.hpp"

namespace deepcanvas::exporting {

struct ImportOptions {
  std::string format = "vdb";  // vdb, gltf, glb, ply
  std::array<double, 3> at{};  // canvas metres
  double scale = 1;            // metres per file unit
  double voxel_size_m = 0;     // 0: the file's own (vdb) or 1/128 of the mesh
  std::array<float, 3> colour{1, 1, 1};
  double density_scale = 1;
  std::uint64_t max_cells = server_core::kMaxPastedCells;
};

struct ImportSummary {
  int depth = 0;            // the level of the cells
  double cell_edge_m = 0;   // its edge
  std::uint64_t cells = 0;  // cells made (coarser ones for tiles included)
  std::string source;       // what was read, e.g. "grid density (fog volume) + Cd" or "mesh: N triangles"
};

// The cells of `file` for `canvas` (normalised: ready for Painter::paste / encode_cell_paste).
Result<server_core::CellPaste> import_cells(std::span<const std::uint8_t> file,
                                            const server_core::OctreeConfig& canvas,
                                            const ImportOptions& options,
                                            ImportSummary* summary = nullptr);

}  // namespace deepcanvas::exporting
