// G3 on the GPU: recomputes the six links of the listed groups (the groups the neighbour
// computation mask marks, or every group for a full rebuild). A group's links are its parent P's
// six same-depth face neighbours by pool_layout.h's neighbour rule (root array, sibling, or
// through the link of P's own group); root groups and free groups get kNoCell. The server's
// Octree and the client's CPU Replica apply the same functions of the same header, so the
// result is bit-identical to theirs. Indices read from the textures are checked against
// cell_count before they are followed (the pools come from the network).
//
// Ordering: a group reads the links of its parent's group, which may be in the list too. The
// host sorts the list by depth and issues one dispatch per depth (range = that depth's slice),
// with a barrier between, so parents' groups are always final before their children read them.
#version 450
#extension GL_GOOGLE_include_directive : require
#include "pool_layout.h"

layout(local_size_x = 64) in;
layout(push_constant) uniform Push {
  DcPoolInfo pool;
  DcDispatchRange range;  // slice of the group list
} pc;

layout(binding = 0) uniform usampler2D first_child_tex;
layout(binding = 1) uniform usampler2D group_parent_tex;
layout(binding = 2) uniform usampler2D group_depth_tex;
layout(binding = 3, r32ui) uniform coherent uimage2DArray links_img;
layout(std430, binding = 4) readonly buffer Groups { uint g[]; } groups;

uint fetch_first_child(uint cell) {
  uint w = pc.pool.width_log2;
  return texelFetch(first_child_tex, ivec2(dc_cell_texel_x(cell, w), dc_cell_texel_y(cell, w)), 0).r;
}
uint fetch_group(usampler2D tex, uint group) {
  uint w = pc.pool.width_log2;
  return texelFetch(tex, ivec2(dc_group_texel_x(group, w), dc_group_texel_y(group, w)), 0).r;
}
ivec3 link_texel(uint group, uint face) {
  uint w = pc.pool.width_log2;
  return ivec3(dc_group_texel_x(group, w), dc_group_texel_y(group, w), face);
}

uint same_depth_neighbour(uint p, uint face) {
  if (p < pc.pool.root_count) return dc_root_neighbour(p, face, pc.pool.roots_per_axis);
  if (dc_face_is_inner(p, face)) return dc_sibling_across(p, face);
  uint q = imageLoad(links_img, link_texel(dc_group_of(p), face)).r;
  if (q == kNoCell || q >= pc.pool.cell_count) return kNoCell;
  return dc_resolve_link(p, face, q, fetch_first_child(q));
}

void main() {
  uint k = gl_GlobalInvocationID.x;
  if (k >= pc.range.count) return;
  uint g = groups.g[pc.range.first + k];
  if (dc_group_first_cell(g) >= pc.pool.cell_count) return;
  uint out_links[6];
  bool dead = g < dc_group_of(pc.pool.root_count) ||
              dc_group_is_free(fetch_group(group_depth_tex, g));
  uint parent = dead ? kNoCell : fetch_group(group_parent_tex, g);
  if (parent >= pc.pool.cell_count) dead = true;
  for (uint f = 0u; f < kFaceCount; ++f) {
    out_links[f] = dead ? kNoCell : same_depth_neighbour(parent, f);
  }
  for (uint f = 0u; f < kFaceCount; ++f) imageStore(links_img, link_texel(g, f), uvec4(out_links[f]));
}
