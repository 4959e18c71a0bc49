// The GLSL half of the DcRayParamsBuffer pin (render_gpu_test, GpuLayout.RayParamsMatchCpp):
// the fields are all 32-bit, so in declaration order they are the words 0..95 of the buffer
// (DcRayParams 0..39, then the seven DcCullBox of 8 words) on both sides exactly when the two
// layouts agree. GLSL echoes every field (by name, at GLSL's
// offset) into probes[k], and writes sentinel k into every field of `written`; C++ checks both
// against the word index of its own struct.
#version 450
#extension GL_GOOGLE_include_directive : require
#include "pool_layout.h"
#include "raycast_layout.h"

layout(local_size_x = 1) in;

layout(std430, binding = 0) readonly buffer Given {
  DcRayParams p;
  DcCullBox more_boxes[kRaycastCullBoxes - 1u];
} given;
layout(std430, binding = 1) writeonly buffer Written {
  DcRayParams p;
  DcCullBox more_boxes[kRaycastCullBoxes - 1u];
} written;
layout(std430, binding = 2) writeonly buffer Probes { uint v[]; } probes;

void main() {
  probes.v[0] = floatBitsToUint(given.p.origin_local[0]);
  probes.v[1] = floatBitsToUint(given.p.origin_local[1]);
  probes.v[2] = floatBitsToUint(given.p.origin_local[2]);
  probes.v[3] = given.p.origin_cell;
  probes.v[4] = given.p.origin_coord[0];
  probes.v[5] = given.p.origin_coord[1];
  probes.v[6] = given.p.origin_coord[2];
  probes.v[7] = given.p.origin_depth;
  probes.v[8] = floatBitsToUint(given.p.canvas_pos[0]);
  probes.v[9] = floatBitsToUint(given.p.canvas_pos[1]);
  probes.v[10] = floatBitsToUint(given.p.canvas_pos[2]);
  probes.v[11] = given.p.inside;
  probes.v[12] = floatBitsToUint(given.p.forward[0]);
  probes.v[13] = floatBitsToUint(given.p.forward[1]);
  probes.v[14] = floatBitsToUint(given.p.forward[2]);
  probes.v[15] = floatBitsToUint(given.p.tan_half_h);
  probes.v[16] = floatBitsToUint(given.p.right[0]);
  probes.v[17] = floatBitsToUint(given.p.right[1]);
  probes.v[18] = floatBitsToUint(given.p.right[2]);
  probes.v[19] = floatBitsToUint(given.p.tan_half_v);
  probes.v[20] = floatBitsToUint(given.p.up[0]);
  probes.v[21] = floatBitsToUint(given.p.up[1]);
  probes.v[22] = floatBitsToUint(given.p.up[2]);
  probes.v[23] = given.p.width;
  probes.v[24] = floatBitsToUint(given.p.background[0]);
  probes.v[25] = floatBitsToUint(given.p.background[1]);
  probes.v[26] = floatBitsToUint(given.p.background[2]);
  probes.v[27] = given.p.height;
  probes.v[28] = floatBitsToUint(given.p.termination);
  probes.v[29] = given.p.max_steps;
  probes.v[30] = given.p.skip_empty;
  probes.v[31] = given.p.reserved1;
  probes.v[32] = floatBitsToUint(given.p.cull_lo[0]);
  probes.v[33] = floatBitsToUint(given.p.cull_lo[1]);
  probes.v[34] = floatBitsToUint(given.p.cull_lo[2]);
  probes.v[35] = given.p.cull;
  probes.v[36] = floatBitsToUint(given.p.cull_hi[0]);
  probes.v[37] = floatBitsToUint(given.p.cull_hi[1]);
  probes.v[38] = floatBitsToUint(given.p.cull_hi[2]);
  probes.v[39] = given.p.cull_count;
  written.p.origin_local[0] = uintBitsToFloat(0xA5000000u | 0u);
  written.p.origin_local[1] = uintBitsToFloat(0xA5000000u | 1u);
  written.p.origin_local[2] = uintBitsToFloat(0xA5000000u | 2u);
  written.p.origin_cell = 0xA5000000u | 3u;
  written.p.origin_coord[0] = 0xA5000000u | 4u;
  written.p.origin_coord[1] = 0xA5000000u | 5u;
  written.p.origin_coord[2] = 0xA5000000u | 6u;
  written.p.origin_depth = 0xA5000000u | 7u;
  written.p.canvas_pos[0] = uintBitsToFloat(0xA5000000u | 8u);
  written.p.canvas_pos[1] = uintBitsToFloat(0xA5000000u | 9u);
  written.p.canvas_pos[2] = uintBitsToFloat(0xA5000000u | 10u);
  written.p.inside = 0xA5000000u | 11u;
  written.p.forward[0] = uintBitsToFloat(0xA5000000u | 12u);
  written.p.forward[1] = uintBitsToFloat(0xA5000000u | 13u);
  written.p.forward[2] = uintBitsToFloat(0xA5000000u | 14u);
  written.p.tan_half_h = uintBitsToFloat(0xA5000000u | 15u);
  written.p.right[0] = uintBitsToFloat(0xA5000000u | 16u);
  written.p.right[1] = uintBitsToFloat(0xA5000000u | 17u);
  written.p.right[2] = uintBitsToFloat(0xA5000000u | 18u);
  written.p.tan_half_v = uintBitsToFloat(0xA5000000u | 19u);
  written.p.up[0] = uintBitsToFloat(0xA5000000u | 20u);
  written.p.up[1] = uintBitsToFloat(0xA5000000u | 21u);
  written.p.up[2] = uintBitsToFloat(0xA5000000u | 22u);
  written.p.width = 0xA5000000u | 23u;
  written.p.background[0] = uintBitsToFloat(0xA5000000u | 24u);
  written.p.background[1] = uintBitsToFloat(0xA5000000u | 25u);
  written.p.background[2] = uintBitsToFloat(0xA5000000u | 26u);
  written.p.height = 0xA5000000u | 27u;
  written.p.termination = uintBitsToFloat(0xA5000000u | 28u);
  written.p.max_steps = 0xA5000000u | 29u;
  written.p.skip_empty = 0xA5000000u | 30u;
  written.p.reserved1 = 0xA5000000u | 31u;
  written.p.cull_lo[0] = uintBitsToFloat(0xA5000000u | 32u);
  written.p.cull_lo[1] = uintBitsToFloat(0xA5000000u | 33u);
  written.p.cull_lo[2] = uintBitsToFloat(0xA5000000u | 34u);
  written.p.cull = 0xA5000000u | 35u;
  written.p.cull_hi[0] = uintBitsToFloat(0xA5000000u | 36u);
  written.p.cull_hi[1] = uintBitsToFloat(0xA5000000u | 37u);
  written.p.cull_hi[2] = uintBitsToFloat(0xA5000000u | 38u);
  written.p.cull_count = 0xA5000000u | 39u;
  for (uint b = 0u; b + 1u < kRaycastCullBoxes; ++b) {
    uint k = 40u + 8u * b;
    probes.v[k + 0u] = floatBitsToUint(given.more_boxes[b].lo[0]);
    probes.v[k + 1u] = floatBitsToUint(given.more_boxes[b].lo[1]);
    probes.v[k + 2u] = floatBitsToUint(given.more_boxes[b].lo[2]);
    probes.v[k + 3u] = given.more_boxes[b].reserved0;
    probes.v[k + 4u] = floatBitsToUint(given.more_boxes[b].hi[0]);
    probes.v[k + 5u] = floatBitsToUint(given.more_boxes[b].hi[1]);
    probes.v[k + 6u] = floatBitsToUint(given.more_boxes[b].hi[2]);
    probes.v[k + 7u] = given.more_boxes[b].reserved1;
    written.more_boxes[b].lo[0] = uintBitsToFloat(0xA5000000u | (k + 0u));
    written.more_boxes[b].lo[1] = uintBitsToFloat(0xA5000000u | (k + 1u));
    written.more_boxes[b].lo[2] = uintBitsToFloat(0xA5000000u | (k + 2u));
    written.more_boxes[b].reserved0 = 0xA5000000u | (k + 3u);
    written.more_boxes[b].hi[0] = uintBitsToFloat(0xA5000000u | (k + 4u));
    written.more_boxes[b].hi[1] = uintBitsToFloat(0xA5000000u | (k + 5u));
    written.more_boxes[b].hi[2] = uintBitsToFloat(0xA5000000u | (k + 6u));
    written.more_boxes[b].reserved1 = 0xA5000000u | (k + 7u);
  }
}
