// Face neighbours of every cell read from the pool textures of pool_layout.h: roots by root
// arithmetic, inner faces by sibling arithmetic, outer faces through the group links and one
// first_child fetch. The test compares every cell with a brute-force coordinate search on the CPU
// (GpuPools.FaceNeighboursMatchBruteForce).
#version 450
#extension GL_GOOGLE_include_directive : require
#include "pool_layout.h"

layout(local_size_x = 64) in;
layout(push_constant) uniform Push {
  DcPoolInfo pool;
  DcDispatchRange range;
} pc;

layout(binding = 0) uniform usampler2D first_child_tex;
layout(binding = 1) uniform usampler2D group_depth_tex;
layout(binding = 2) uniform usampler2DArray group_links_tex;
layout(std430, binding = 3) writeonly buffer Out { uint v[]; } outp;

const uint kWords = 8u;  // 6 neighbours, depth flags, first_child

uint first_child(uint cell) {
  uint w = pc.pool.width_log2;
  ivec2 texel = ivec2(dc_cell_texel_x(cell, w), dc_cell_texel_y(cell, w));
  return texelFetch(first_child_tex, texel, 0).r;
}

uint depth_flags(uint group) {
  uint w = pc.pool.width_log2;
  return texelFetch(group_depth_tex, ivec2(dc_group_texel_x(group, w), dc_group_texel_y(group, w)),
                    0).r;
}

uint group_link(uint group, uint face) {
  uint w = pc.pool.width_log2;
  return texelFetch(group_links_tex,
                    ivec3(dc_group_texel_x(group, w), dc_group_texel_y(group, w), face), 0).r;
}

uint face_neighbour(uint cell, uint face) {
  if (cell < pc.pool.root_count) return dc_root_neighbour(cell, face, pc.pool.roots_per_axis);
  if (dc_face_is_inner(cell, face)) return dc_sibling_across(cell, face);
  uint link = group_link(dc_group_of(cell), face);
  uint link_first_child = link == kNoCell ? kNoCell : first_child(link);
  return dc_resolve_link(cell, face, link, link_first_child);
}

void main() {
  uint k = gl_GlobalInvocationID.x;
  if (k >= pc.range.count) return;
  uint cell = pc.range.first + k;
  if (cell >= pc.pool.cell_count) return;
  uint base = cell * kWords;
  for (uint f = 0u; f < kFaceCount; ++f) outp.v[base + f] = face_neighbour(cell, f);
  outp.v[base + 6u] = depth_flags(dc_group_of(cell));
  outp.v[base + 7u] = first_child(cell);
}
