// The GLSL half of the layout pin (tests/client_gpu/gpu_test.cpp, GpuLayout.*). Whatever the
// GLSL compiler believes about pool_layout.h lands in buffers that the C++ side reads through
// its own struct definitions, so any disagreement on offsets, sizes, strides or constants shows.
#version 450
#extension GL_GOOGLE_include_directive : require
#include "pool_layout.h"

layout(local_size_x = 1) in;

// The same push-constant block as the C++ struct GpuPush in the test.
layout(push_constant) uniform Push {
  DcPoolInfo pool;
  DcDispatchRange range;
} pc;

// GLSL writes every field with a sentinel; C++ reads them as C++ structs (offsets + strides).
layout(std430, binding = 0) writeonly buffer Written {
  DcPoolInfo info[2];
  DcDispatchRange range[2];
} written;

// C++ wrote these as C++ structs; GLSL echoes each field in declaration order into probes.
layout(std430, binding = 1) readonly buffer Given {
  DcPoolInfo info;
  DcDispatchRange range;
} given;

layout(std430, binding = 2) writeonly buffer Probes { uint v[]; } probes;

uint sentinel(uint field, uint element) { return 0xA5000000u | (element << 16) | field; }

void write_info(uint e) {
  written.info[e].width_log2 = sentinel(0u, e);
  written.info[e].block_log2 = sentinel(1u, e);
  written.info[e].cell_count = sentinel(2u, e);
  written.info[e].root_count = sentinel(3u, e);
  written.info[e].roots_per_axis = sentinel(4u, e);
  written.info[e].max_depth = sentinel(5u, e);
  written.info[e].canvas_edge_m = 1000.5 + float(e);
  written.info[e].reserved0 = sentinel(7u, e);
}

void write_range(uint e) {
  written.range[e].first = sentinel(10u, e);
  written.range[e].count = sentinel(11u, e);
  written.range[e].reserved0 = sentinel(12u, e);
  written.range[e].reserved1 = sentinel(13u, e);
}

void main() {
  write_info(0u);
  write_info(1u);
  write_range(0u);
  write_range(1u);

  uint n = 0u;
  // [0, 12): push constants, field by field.
  probes.v[n++] = pc.pool.width_log2;
  probes.v[n++] = pc.pool.block_log2;
  probes.v[n++] = pc.pool.cell_count;
  probes.v[n++] = pc.pool.root_count;
  probes.v[n++] = pc.pool.roots_per_axis;
  probes.v[n++] = pc.pool.max_depth;
  probes.v[n++] = floatBitsToUint(pc.pool.canvas_edge_m);
  probes.v[n++] = pc.pool.reserved0;
  probes.v[n++] = pc.range.first;
  probes.v[n++] = pc.range.count;
  probes.v[n++] = pc.range.reserved0;
  probes.v[n++] = pc.range.reserved1;
  // [12, 24): the storage buffer written by C++.
  probes.v[n++] = given.info.width_log2;
  probes.v[n++] = given.info.block_log2;
  probes.v[n++] = given.info.cell_count;
  probes.v[n++] = given.info.root_count;
  probes.v[n++] = given.info.roots_per_axis;
  probes.v[n++] = given.info.max_depth;
  probes.v[n++] = floatBitsToUint(given.info.canvas_edge_m);
  probes.v[n++] = given.info.reserved0;
  probes.v[n++] = given.range.first;
  probes.v[n++] = given.range.count;
  probes.v[n++] = given.range.reserved0;
  probes.v[n++] = given.range.reserved1;
  // [24, ...): every constant, in the order of the C++ list kConstantProbes in the test.
  probes.v[n++] = kLayoutVersion;
  probes.v[n++] = kNoCell;
  probes.v[n++] = kDepthMask;
  probes.v[n++] = kGroupFreeFlag;
  probes.v[n++] = kMaxDepth;
  probes.v[n++] = kMinWidthLog2;
  probes.v[n++] = kMaxWidthLog2;
  probes.v[n++] = kMinBlockLog2;
  probes.v[n++] = kMaxCellsLog2;
  probes.v[n++] = kFaceCount;
  probes.v[n++] = kCellsPerGroupLog2;
  probes.v[n++] = kPoolFirstChild;
  probes.v[n++] = kPoolColour;
  probes.v[n++] = kPoolGroupParent;
  probes.v[n++] = kPoolGroupDepth;
  probes.v[n++] = kPoolGroupLinks;
  probes.v[n++] = kPoolCount;
  probes.v[n++] = kMinRootsPerAxis;
  probes.v[n++] = kMaxRootsPerAxis;
  probes.v[n++] = kCellsPerGroup;
  // The end marker tells C++ how many probes GLSL wrote (a missing constant shifts it).
  probes.v[n++] = 0xE0D0E0D0u;
  probes.v[n] = n;
}
