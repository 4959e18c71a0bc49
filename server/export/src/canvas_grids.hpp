// The canvas as OpenVDB grids at one voxel level (vdb_export.hpp has the layout): what the VDB
// writer, the mesher and the benchmark's anchor share. Private to the export target.
#pragma once

#include <openvdb/openvdb.h>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/export/vdb_export.hpp"

namespace deepcanvas::exporting::detail {

struct CanvasGrids {
  openvdb::FloatGrid::Ptr density;  // extinction, 1/m
  openvdb::Vec3SGrid::Ptr colour;   // Cd, 0..1
  openvdb::FloatGrid::Ptr opacity;  // the stored alpha of each unit, 0..1 (when asked for)
  VdbExportSummary summary;         // voxel level, counts, the estimate
};

// Builds both grids (the estimate first: past options.max_bytes nothing is built).
// `with_opacity` adds the opacity grid (the mesher's scalar field: a painted cell's own alpha,
// the same at every voxel level, unlike the extinction's per-voxel alpha).
Result<CanvasGrids> build_grids(const server_core::Octree& tree, const VdbExportOptions& options,
                                bool with_opacity = false);

}  // namespace deepcanvas::exporting::detail
