// Command-line options that shape a canvas, shared by `serve` (the live canvases) and `replay`
// (a headless canvas): a stroke log replays to the served canvas only on a canvas of the same
// shape and stroke limits, so both commands take them under the same names.
#pragma once

#include <CLI/CLI.hpp>

#include "cli_options.hpp"
#include "deepcanvas/protocol/stroke.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::server_app {

inline void add_octree_options(CLI::App& app, server_core::OctreeConfig& octree) {
  app.add_option("--edge", octree.edge_m, "canvas edge in metres (default 20000)")
      ->type_name("METRES")
      ->transform(positive());
  app.add_option("--roots", octree.roots_per_axis, "roots per axis, even (default 4)")
      ->type_name("N")
      ->transform(whole(2, 64));
  app.add_option("--max-depth", octree.max_depth, "deepest level (default 24)")
      ->type_name("D")
      ->transform(whole(1, 24));
  app.add_option("--block-cells", octree.block_cells,
                 "cells per block, a power of two (default 4096)")
      ->type_name("N")
      ->transform(whole(0, 1u << 20));
  app.add_option("--max-cells", octree.max_cells, "cell capacity per canvas (default 268435456)")
      ->type_name("N")
      ->transform(whole(0));
}

// `extent_default` names the default of --max-stroke-extent in the help.
inline void add_stroke_limit_options(CLI::App& app, protocol::StrokeLimits& limits,
                                     double& capacity_reserve, const std::string& extent_default) {
  app.add_option("--max-stroke-extent", limits.max_extent_m,
                 "largest edge of one stroke's box in metres (default " + extent_default + ")")
      ->type_name("METRES")
      ->transform(positive());
  app.add_option("--max-stroke-cells", limits.max_stroke_cells,
                 "cells one stroke may create (default 4000000)")
      ->type_name("N")
      ->transform(whole(1));
  app.add_option("--capacity-reserve", capacity_reserve,
                 "share of --max-cells kept for erase strokes (default 0.05)")
      ->type_name("F")
      ->transform(number(0, 0.5));
}

}  // namespace deepcanvas::server_app
