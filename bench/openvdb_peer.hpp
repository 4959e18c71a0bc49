// The OpenVDB peer of the painter: what someone would build on OpenVDB to get the same canvas,
// used by `deepcanvas-bench paint` to measure the octree against it (issue 4).
//
// Same input, same geometry, same blending model as server_core::Painter:
// - Strokes become stamps through the same rasterizer (stamp.hpp: stroke_stamps), and every
//   cell for_each_stamp_cell() paints at the stamp's target depth becomes a cube of voxels: the
//   grid's voxel is the finest cell the octree uses for the painting (`voxel_depth`), so a cell
//   of depth d is an aligned cube of 2^(voxel_depth - d) voxels per axis. Voxel (i, j, k) is the
//   cell (voxel_depth, i, j, k) of the octree: index space = the octree's integer addresses.
// - Stroke-level opacity as in the painter: per stroke, a temporary FloatGrid (the "stroke
//   layer") keeps the stroke's strength per voxel, the maximum over its stamps (painter.hpp:
//   paint stores optical depth per metre tau = -ln(1 - A O c) / D, erase/recolor O c); at the end
//   of the stroke the layer is composited once onto the canvas grid from the pre-stroke values
//   (a voxel of edge h gets the cell alpha q = 1 - exp(-tau h), then density::paint_over).
// - Cubes are written with Tree::fill() (OpenVDB keeps an aligned 8^3 or 128^3 cube as a tile),
//   single voxels with a ValueAccessor, and where the canvas under a cube is not uniform the cube
//   is split down to tiles and leaf voxels (each voxel is blended from its own pre-stroke value).
//   prune() (tools::prune, single-threaded) collapses uniform nodes to tiles at the end.
//
// Value types (the canvas grid):
// - rgba8: openvdb::UInt32Grid holding the octree's own cell format (RGBA8, alpha = opacity across
//   one voxel edge, density_model.hpp), blended by the same density:: functions: the same result
//   at the same precision, 4 bytes a voxel. The fair peer for memory.
// - vec4f: a Tree4<Vec4f, 5, 4, 3> grid (RGB + alpha across one voxel edge, float): what an
//   OpenVDB user reaches for first (float channels, what OpenVDB samplers and renderers take),
//   16 bytes a voxel.
//
// Modes: paint, erase and recolor as in the painter; pick_up changes nothing; smudge is not
// implemented (Errc::unsupported; the .apa paintings only paint).
// Threading: an OpenVdbPeer belongs to one thread. It calls no parallel OpenVDB tool (prune runs
// with threaded = false); the benchmark also caps TBB at one thread.
// Untrusted input: strokes pass protocol::validate_stroke (canvas bounds, `limits`) first; a
// rejected stroke changes nothing.
#pragma once

#include <cstdint>
#include <memory>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/stamp.hpp"

namespace deepcanvas::bench {

enum class VdbValueKind { rgba8, vec4f };

struct VdbPeerConfig {
  VdbValueKind kind = VdbValueKind::rgba8;
  int voxel_depth = 0;  // the octree depth whose cell is one voxel
  server_core::StampParams stamps;
  protocol::StrokeLimits limits{100000, 1000.0, 1e-7};
};

struct VdbSample {
  float rgb[3] = {0, 0, 0};
  float alpha = 0;  // opacity across one voxel edge
  double sigma_per_m = 0;
};

struct VdbPeerStats {
  std::uint64_t stamps = 0;
  std::uint64_t cells = 0;         // rasterizer cells (cubes) written into stroke layers
  std::uint64_t layer_values = 0;  // stroke-layer tiles and voxels composited onto the canvas
};

struct VdbMemory {
  std::uint64_t mem_usage = 0;  // Grid::memUsage() of the canvas grid
  std::uint64_t active_voxels = 0;
  std::uint64_t leaf_nodes = 0;
  std::uint64_t active_tiles = 0;
};

class OpenVdbPeer {
 public:
  // Call openvdb::initialize() before. invalid_argument for a voxel depth outside the canvas's
  // depth range or one whose voxel addresses do not fit OpenVDB's 32-bit coordinates.
  static Result<std::unique_ptr<OpenVdbPeer>> create(const server_core::OctreeConfig& canvas,
                                                     const VdbPeerConfig& config);
  virtual ~OpenVdbPeer() = default;

  // Rasterizes and composites one stroke. invalid_argument for a bad stroke, unsupported for
  // smudge, limit_exceeded for too many stamps; nothing changes then.
  virtual Result<void> apply_stroke(const protocol::Stroke& stroke) = 0;
  // tools::prune of the canvas grid (exact values), single-threaded.
  virtual void prune() = 0;
  virtual VdbMemory memory() const = 0;
  // The voxel containing `p` (metres); invalid_argument outside the canvas.
  virtual Result<VdbSample> sample(const server_core::Vec3d& p) const = 0;
  virtual const VdbPeerStats& stats() const noexcept = 0;
  virtual double voxel_edge_m() const noexcept = 0;
};

}  // namespace deepcanvas::bench
