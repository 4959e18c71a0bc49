// Exporting a canvas as a surface mesh (issue: export, import and time-lapse): what web viewers,
// AR tools and printers read.
//
// The surface is the iso-surface of the paint's opacity at the voxel level: the canvas becomes
// the grids of vdb_export.hpp, the density becomes each voxel's alpha (1 - exp(-sigma h)), and
// OpenVDB's volume-to-mesh extracts the surface alpha = iso_alpha (quads split into triangles,
// adaptive where `adaptivity` > 0). Triangles wind counter-clockwise seen from outside (normals
// point out of the paint). Each vertex gets the colour of the painted voxels around it (those
// inside the surface; the nearest painted one where none is), as 8-bit RGB.
//
// The voxel level: the one given (volume.voxel_depth), or, with none given and a triangle budget,
// the finest level whose mesh fits the budget (a canvas painted down to 0.3 mm would otherwise
// give tens of millions of triangles). At a given level the budget raises the adaptivity step by
// step until the mesh fits; where even full adaptivity does not, limit_exceeded says so and
// nothing is written.
//
// Files: glTF 2.0 through tinygltf (.gltf with the buffer embedded, or binary .glb by the
// extension): one mesh, POSITION (float, metres, canvas axes: +y up, as glTF), COLOR_0 (float
// RGB, linear) and uint32 indices. PLY: binary little-endian, vertex x y z float, red green blue
// uchar, face list uchar int.
//
// Threading: reads the tree only; the caller keeps it from changing. Errors: those of
// export_vdb (invalid_argument, limit_exceeded), not_found (nothing painted at the iso level),
// io_error (the file).
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/export/vdb_export.hpp"

namespace deepcanvas::exporting {

struct MeshExportOptions {
  VdbExportOptions volume;             // voxel level, box, max_bytes (of the grids)
  double iso_alpha = 0.25;             // the surface: the paint's opacity, (0, 1)
  double adaptivity = 0;               // OpenVDB's adaptivity, [0, 1]
  std::uint64_t max_triangles = 1'000'000;  // 0: no budget
};

struct Mesh {
  std::vector<std::array<float, 3>> positions;   // metres
  std::vector<std::array<std::uint8_t, 3>> colours;  // per vertex, sRGB-agnostic 8-bit
  std::vector<std::uint32_t> indices;           // 3 per triangle
  std::size_t triangles() const noexcept { return indices.size() / 3; }
};

struct MeshExportSummary {
  VdbExportSummary volume;
  double adaptivity = 0;  // the adaptivity used (raised to fit max_triangles)
  std::uint64_t vertices = 0;
  std::uint64_t triangles = 0;
  std::uint64_t file_bytes = 0;
};

// The iso-surface of the canvas (see above).
Result<Mesh> mesh_canvas(const server_core::Octree& tree, const MeshExportOptions& options,
                         MeshExportSummary* summary = nullptr);

enum class MeshFormat { gltf, glb, ply };
// Writes `mesh` (beside `path` first, then renamed: a failed write leaves no half file).
Result<std::uint64_t> write_mesh(const Mesh& mesh, MeshFormat format, const std::string& path);

// The bytes write_mesh would write (exact for PLY, within a few hundred bytes for glTF).
std::uint64_t estimate_mesh_bytes(const Mesh& mesh, MeshFormat format) noexcept;

// The canvas as the bytes of a file of `format` (vdb, gltf, glb or ply; export_vdb or
// mesh_canvas with their defaults, at the level nearest voxel_size_m when it is > 0, within
// `box`), at most `max_bytes`: limit_exceeded naming the estimate, before anything is written.
// Written through a temporary file that is removed.
Result<std::vector<std::uint8_t>> export_to_bytes(const server_core::Octree& tree,
                                                  const std::string& format, double voxel_size_m,
                                                  const std::optional<server_core::Aabb>& box,
                                                  std::uint64_t max_bytes);

// mesh_canvas then write_mesh.
Result<MeshExportSummary> export_mesh(const server_core::Octree& tree,
                                      const MeshExportOptions& options, MeshFormat format,
                                      const std::string& path);

// Reads a mesh file back (glTF/glb through tinygltf: the first primitive's triangles, POSITION
// and COLOR_0; PLY as write_mesh writes it). Untrusted input: sizes and indices checked,
// malformed on any inconsistency.
Result<Mesh> read_mesh(const std::string& path);
// The same from a file's bytes; `format` is gltf, glb or ply.
Result<Mesh> read_mesh_bytes(std::span<const std::uint8_t> bytes, const std::string& format);

}  // namespace deepcanvas::exporting
