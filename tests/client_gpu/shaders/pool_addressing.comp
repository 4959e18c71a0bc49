// Every addressing function of pool_layout.h evaluated on the GPU for a range of indices; the
// test compares each output word with the same function evaluated by the C++ compiler and with
// brute-force references (GpuLayout.AddressingFunctionsMatchCpu).
#version 450
#extension GL_GOOGLE_include_directive : require
#include "pool_layout.h"

layout(local_size_x = 64) in;
layout(push_constant) uniform Push {
  DcPoolInfo pool;
  DcDispatchRange range;
} pc;
layout(std430, binding = 0) writeonly buffer Out { uint v[]; } outp;

const uint kWords = 26u;  // words per index, see the C++ side

void main() {
  uint k = gl_GlobalInvocationID.x;
  if (k >= pc.range.count) return;
  uint i = pc.range.first + k;
  uint w = pc.pool.width_log2;
  uint b = pc.pool.block_log2;
  uint base = k * kWords;
  outp.v[base + 0u] = dc_cell_texel_x(i, w);
  outp.v[base + 1u] = dc_cell_texel_y(i, w);
  outp.v[base + 2u] = dc_group_texel_x(dc_group_of(i), w);
  outp.v[base + 3u] = dc_group_texel_y(dc_group_of(i), w);
  outp.v[base + 4u] = dc_block_of(i, b);
  outp.v[base + 5u] = dc_block_x0(dc_block_of(i, b), b, w);
  outp.v[base + 6u] = dc_block_y0(dc_block_of(i, b), b, w);
  outp.v[base + 7u] = dc_block_w(b, w) | (dc_block_h(b, w) << 16);
  uint inner = 0u;
  for (uint f = 0u; f < kFaceCount; ++f) inner |= dc_face_is_inner(i, f) ? (1u << f) : 0u;
  outp.v[base + 8u] = inner;
  outp.v[base + 9u] = dc_sibling_across(i, i % 6u);
  outp.v[base + 10u] = dc_resolve_link(i, i % 6u, (i & 1u) != 0u ? i * 3u : kNoCell,
                                       (i & 2u) != 0u ? i * 5u : kNoCell);
  outp.v[base + 11u] = dc_root_neighbour(i % pc.pool.root_count, i % 6u, pc.pool.roots_per_axis);
  outp.v[base + 12u] = dc_depth_of(i) | (dc_group_is_free(i) ? 0x100u : 0u);
  outp.v[base + 13u] = dc_pack_rgba8(i, i >> 3, i >> 7, i >> 11);
  outp.v[base + 14u] = dc_colour_channel(i * 2654435761u, i & 3u);
  outp.v[base + 15u] = dc_texture_height(i, w);
  uint n = pc.pool.roots_per_axis;
  outp.v[base + 16u] = dc_face(i % 3u, (i & 8u) != 0u);
  outp.v[base + 17u] = dc_outer_face(i, i % 3u);
  outp.v[base + 18u] = dc_mirror_child(i, i % 6u, i * 8u);
  outp.v[base + 19u] = dc_link_index(dc_group_of(i), i % 6u);
  outp.v[base + 20u] = dc_group_first_cell(dc_group_of(i));
  outp.v[base + 21u] = dc_slot(i, i >> 1u, i >> 2u);
  outp.v[base + 22u] = dc_root_index(i % n, (i / n) % n, (i / (n * n)) % n, n);
  outp.v[base + 23u] = dc_root_count(n) + dc_slot_of(i);
  outp.v[base + 24u] = dc_face_axis(i % 6u) | (dc_face_positive(i % 6u) ? 0x100u : 0u) |
                       (dc_group_width(w) << 12u);
  outp.v[base + 25u] = dc_width(w) ^ dc_group_of(i);
}
