// A device self-check (`deepcanvas-client devices --check`): every invocation writes an integer
// hash of its index and the pool-layout texel of that index, which the CPU recomputes. Proves the
// chosen device compiles and runs this project's SPIR-V and that push constants and storage
// buffers reach it intact.
#version 450
#extension GL_GOOGLE_include_directive : require
#include "pool_layout.h"

layout(local_size_x = 64) in;
layout(push_constant) uniform Push {
  DcPoolInfo pool;
  DcDispatchRange range;
} pc;
layout(std430, binding = 0) writeonly buffer Out { uint v[]; } outp;

// The PCG output permutation (O'Neill): cheap, and every bit depends on every input bit.
uint pcg_hash(uint x) {
  uint state = x * 747796405u + 2891336453u;
  uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
  return (word >> 22u) ^ word;
}

void main() {
  uint k = gl_GlobalInvocationID.x;
  if (k >= pc.range.count) return;
  uint i = pc.range.first + k;
  outp.v[2u * k] = pcg_hash(i);
  outp.v[2u * k + 1u] = dc_cell_texel_x(i, pc.pool.width_log2) |
                        (dc_cell_texel_y(i, pc.pool.width_log2) << 16u);
}
