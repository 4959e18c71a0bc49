// pool_view_of(): a client_core::PoolView of a server_core::Octree, so that code linking both
// libraries (tests, benchmarks) renders and compares the server's canvas with the client's code.
// Both sides hold the same pools (shaders/include/pool_layout.h), so the view is the tree's
// spans and geometry, nothing copied. It lives in the header-only target
// deepcanvas::pool_view_of_octree because neither library may depend on the other.
//
// Ownership and threading: the view borrows the tree's pools. It covers the cells up to the
// high-water mark at the time it is taken (take a new view after refinements that may grow it)
// and is valid while the tree lives; reading it while another thread mutates the tree is a data
// race, as for the tree itself.
#pragma once

#include "deepcanvas/client_core/pool_view.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::bridge {

inline client_core::PoolView pool_view_of(const server_core::Octree& tree) noexcept {
  client_core::PoolView v;
  v.first_child = tree.first_child_pool();
  v.colour = tree.colour_pool();
  v.group_parent = tree.group_parent_pool();
  v.group_depth_flags = tree.group_depth_flags_pool();
  v.group_links = tree.group_link_pool();
  v.roots_per_axis = tree.config().roots_per_axis;
  v.edge_m = tree.config().edge_m;
  v.filtered_interiors = tree.interior_colours_current();
  return v;
}

}  // namespace deepcanvas::bridge
