// raycast_layout.h: the parameters of the ray casting pass (raycast.comp), shared by C++ and
// GLSL like pool_layout.h (include that first). Only 32-bit scalars and fixed arrays of them,
// padded to a multiple of 16 bytes, so std430 (storage buffers) equals the C++ layout;
// tests/render_gpu pins the offsets (static_asserts here, a probe shader there).
//
// The camera reaches the GPU already located on the pools (client_core::make_ray_origin, in
// double on the CPU): the leaf holding it and the position in that leaf's frame as floats, so
// the shader never touches a world coordinate for cameras inside the canvas. A camera outside
// the canvas is given in canvas units (position / canvas edge), where the entry point is
// computed; that is exact enough because it is then at least a canvas away from fine detail.
#ifndef DEEPCANVAS_RAYCAST_LAYOUT_H
#define DEEPCANVAS_RAYCAST_LAYOUT_H

#include "pool_layout.h"

#ifdef __cplusplus
#include <cstddef>
#include <cstdint>
namespace deepcanvas::gpu_layout {
#define DC_RC_CONST inline constexpr
#else
#define DC_RC_CONST const
#endif

DC_RC_CONST uint kRaycastLocalSizeX = 8u;  // invocations per workgroup: X x Y pixels
DC_RC_CONST uint kRaycastLocalSizeY = 8u;  // 8 x 8: raycast.comp maps it as 4x2 pixel tiles

// 160 bytes.
struct DcRayParams {
  float origin_local[3];  //   0  camera in its leaf's frame, [-0.5, 0.5]^3 (inside == 1)
  uint origin_cell;       //  12  that leaf (inside == 1)
  uint origin_coord[3];   //  16  its integer address (for the descent variant)
  uint origin_depth;      //  28  its depth
  float canvas_pos[3];    //  32  camera position / canvas edge (inside == 0)
  uint inside;            //  44  1: the camera is inside the canvas
  float forward[3];       //  48  unit view direction
  float tan_half_h;       //  60  tan(hfov / 2)
  float right[3];         //  64  unit, image x grows along it
  float tan_half_v;       //  76  tan(vfov / 2)
  float up[3];            //  80  unit, image y grows against it
  uint width;             //  92  image size in pixels
  float background[3];    //  96  linear RGB
  uint height;            // 108
  float termination;      // 112  stop when transmittance < this (0: never)
  uint max_steps;         // 116  per ray
  uint skip_empty;        // 120  1: an interior cell of colour 0 is an empty subtree (raycast.comp)
  uint reserved1;         // 124
  float cull_lo[3];       // 128  content box relative to the camera, metres (padded; see
  uint cull;              // 140  client_core::cull_box_relative_to); cull = 1: use it,
                          //      2: nothing painted, every ray is background
  float cull_hi[3];       // 144
  uint cull_count;        // 156  cull = 1: boxes given, 1..kRaycastCullBoxes (cull_lo/hi the
                          //      first, DcRayParamsBuffer::more_boxes the rest)
};

// Further content boxes (RenderOptions::content_boxes), each relative to the camera like
// cull_lo/cull_hi. 32 bytes.
struct DcCullBox {
  float lo[3];     //  0
  uint reserved0;  // 12
  float hi[3];     // 16
  uint reserved1;  // 28
};
DC_RC_CONST uint kRaycastCullBoxes = 8u;  // boxes per frame at most (client_core::kMaxContentBoxes)

// The ray casting pass's push constants after DcPoolInfo (raycast.comp "Scheduling"). 32 bytes.
struct DcRaycastDispatch {
  uint first_row;    //  0  image rows [first_row, first_row + row_count) of this dispatch
  uint row_count;    //  4
  uint work_base;    //  8  this dispatch's region of the work buffer, in words (kRaycastWork*)
  uint loop_budget;  // 12  items pass: a subgroup takes no new item past this estimate
  uint reserved0;    // 16
  uint reserved1;    // 20
  uint reserved2;    // 24
  uint reserved3;    // 28
};

// Items pass: pixels as work items of kRaycastTilesPerItem 8x8 tiles (row-major over the
// dispatch's rows), taken from a counter by whichever subgroup is free. Retry pass (an indirect
// dispatch right after it): one workgroup per tile of the items a subgroup gave up.
DC_RC_CONST uint kRaycastItems = 0u;
DC_RC_CONST uint kRaycastRetry = 1u;
DC_RC_CONST uint kRaycastTilesPerItem = 4u;
// At most this many items per dispatch, so a pass's workgroup counts (items / subgroups per
// workgroup; kRaycastTilesPerItem per item given up) stay within the 65535 every device allows.
DC_RC_CONST uint kRaycastMaxItemsPerDispatch = 16383u;

// At most this many subgroups per workgroup (64 invocations, subgroups of at least 1).
DC_RC_CONST uint kRaycastMaxSubgroupsPerWorkgroup = 64u;

// A dispatch's region of the work buffer (binding 5, a uint array), at DcRaycastDispatch::
// work_base, in words: the header, the items given up, one word per subgroup of the items pass.
DC_RC_CONST uint kRaycastWorkNextItem = 0u;     // the next item to hand out (0 before the pass)
DC_RC_CONST uint kRaycastWorkRetryGroups = 1u;  // 3 words: the retry pass's
                                                // VkDispatchIndirectCommand, x = 4 per item given
                                                // up (starts 0, 1, 1)
DC_RC_CONST uint kRaycastWorkRetryItems = 4u;   // then the items given up, one word each
// Then per subgroup (workgroup * subgroups per workgroup + subgroup): 1 + the item it is
// rendering, 0 when none (written by the subgroup; never read by the host).
DC_RC_CONST uint kRaycastWorkInProgress = kRaycastWorkRetryItems + kRaycastMaxItemsPerDispatch;
DC_RC_CONST uint kRaycastWorkWords =
    kRaycastWorkInProgress + kRaycastMaxItemsPerDispatch + kRaycastMaxSubgroupsPerWorkgroup;

#ifdef __cplusplus
static_assert(kRaycastLocalSizeX == 8 && kRaycastLocalSizeY == 8, "raycast.comp's tile mapping");
static_assert(sizeof(DcRaycastDispatch) == 32 && alignof(DcRaycastDispatch) == 4);
static_assert(offsetof(DcRaycastDispatch, work_base) == 8 &&
              offsetof(DcRaycastDispatch, loop_budget) == 12);
static_assert(kRaycastMaxItemsPerDispatch * kRaycastTilesPerItem <= 65535u,
              "the retry pass's workgroups fit the guaranteed maxComputeWorkGroupCount");
static_assert(sizeof(DcRayParams) == 160 && alignof(DcRayParams) == 4);
static_assert(offsetof(DcRayParams, origin_cell) == 12 &&
              offsetof(DcRayParams, origin_depth) == 28);
static_assert(offsetof(DcRayParams, inside) == 44 && offsetof(DcRayParams, tan_half_h) == 60);
static_assert(offsetof(DcRayParams, tan_half_v) == 76 && offsetof(DcRayParams, width) == 92);
static_assert(offsetof(DcRayParams, height) == 108 && offsetof(DcRayParams, max_steps) == 116);
static_assert(offsetof(DcRayParams, skip_empty) == 120 && offsetof(DcRayParams, cull_lo) == 128 && offsetof(DcRayParams, cull) == 140);
static_assert(offsetof(DcRayParams, cull_hi) == 144 && offsetof(DcRayParams, cull_count) == 156);
static_assert(sizeof(DcCullBox) == 32 && offsetof(DcCullBox, hi) == 16);
// The ray casting pass's parameter buffer (raycast.comp binding 3): the parameters, then boxes
// 1.. of the content cull. GLSL declares the same two members in its buffer block.
struct DcRayParamsBuffer {
  DcRayParams p;
  DcCullBox more_boxes[kRaycastCullBoxes - 1u];
};
static_assert(sizeof(DcRayParamsBuffer) == 160 + 7 * 32 &&
              offsetof(DcRayParamsBuffer, more_boxes) == 160);
}  // namespace deepcanvas::gpu_layout
#endif

#undef DC_RC_CONST

#endif  // DEEPCANVAS_RAYCAST_LAYOUT_H
