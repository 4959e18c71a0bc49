// Cell-local ray casting through the octree pools (pool_layout.h): one ray per pixel, pixels
// handed out to subgroups as work items (see "Scheduling").
// The same algorithm as the CPU reference (client_core/reference_renderer.hpp, Precision::
// float32 mirrors this arithmetic): every step in the current cell's own frame (origin at its
// centre, edge 1); exit face by the slab test; neighbour by sibling arithmetic, root-array
// arithmetic or the group link (+ one first_child step); down through first_child into finer
// cells; front-to-back compositing with the density model (a segment of t cell edges through a
// cell of alpha a transmits (1-a)^t); early termination below params.termination.
//
// first_child and colour are read as storage images (imageLoad): on lavapipe that costs less
// CPU per frame than texelFetch on a usampler2D, markedly so for the descent variant
// (deepcanvas-bench render, frame_cpu_ms_p50). (1 - a)^t is exp2(t log2(1 - a)).
//
// Empty subtrees (DcRayParams::skip_empty: client_core::RenderOptions::skip_empty_subtrees on
// pools whose interior values are current, PoolView::filtered_interiors): an interior cell of
// colour 0 has nothing below it (protocol::density::filter_rgba), so the ray stops going down
// there and crosses it as one cell, and a link of colour 0 is taken as the coarser cell (the
// ray climbs into it). Empty space between paintings is then crossed in cells of its own size,
// not in the small 2:1-balanced cells kept around paint (deepcanvas-bench large: a 640x360
// frame of an 8.3M-cell canvas took ~40% less time on lavapipe). The descent variant stops its
// descent at the same cells, so both still visit the same cells.
//
// Content cull (DcRayParams::cull, client_core::RenderOptions::content_bounds or content_boxes):
// a ray that misses every content box is background; one that hits some stops once the distance
// travelled (metres, summed per step) passes 1 + 1/64 of the farthest exit distance among them.
// Only empty cells are skipped. cull = 2 (RenderOptions::content_empty, or no box in view):
// every ray is background.
//
// Cost on lavapipe (x86 code read from the JIT, perf): every iteration runs the whole loop body
// under lane masks (no branch is skipped), so rare paths (the root step) cost on every step;
// the four gathers (first_child, colour, link, the link's first_child) carry most cache misses.
//
// Scheduling (raycast_layout.h): pixels are handed out as work items (kRaycastTilesPerItem 8x8
// tiles, row-major over the dispatch's rows) from a counter that every subgroup takes its next
// item from, so all workers stay busy until the dispatch is done. lavapipe gives each of its
// worker threads an equal, contiguous share of a dispatch's workgroups: with one workgroup per
// tile, the thread with the costlier rows finishes last while the others idle (a render loop's
// bands then use well under all the CPUs), and a thread that loses its CPU holds the band up by
// as long.
// Every subgroup takes at least one item, and the items pass has at least one subgroup per item
// (GpuRaycaster::render_rows), so every item is taken.
//
// Loop limiter: lavapipe (gallivm) ends every loop of a shader invocation, silently, once all
// loops of that invocation together have run 65535 iterations (LP_MAX_TGSI_LOOP_ITERATIONS, one
// counter per subgroup on a CPU device, shared by every loop and never reset: each loop's end
// decrements it and leaves the loop when it reaches 0). A subgroup that loops over items must
// stop before that: past it, its rays stop short and its item loop ends with an item half drawn
// (whole runs of pixels left unrendered). So:
//  * each loop iteration a lane runs counts in lane_loops; the sum over the subgroup's lanes
//    bounds the iterations the subgroup ran (every iteration has an active lane, counted), plus
//    a margin per run for loops run with no lane active or left at their condition; after each
//    item the subgroup adds that up and takes no new item once its total plus twice its
//    costliest item passes loop_budget;
//  * the estimate is not trusted: while a subgroup renders an item, the item is marked in the
//    work buffer (kRaycastWorkInProgress), and the mark is cleared at the top of the item loop's
//    next iteration, which only runs if the limiter did not end the loop. After the loop, a
//    mark left behind is an item the limiter interrupted: it goes on the retry list, and the
//    retry pass (kPass kRaycastRetry, an indirect dispatch after this one) renders its tiles
//    again, one workgroup per tile, one run per subgroup, as fresh invocations. The mark lives
//    in memory, read volatile, because the compiler may assume that a loop is only ever left by
//    a break: a flag set before every break would read "left on purpose" whatever happened.
// A GPU has no such limiter (loop_budget is then ~0u and no mark is ever left behind).
//
// Specialization constant 0 (kDescent) = 1 switches neighbour finding to "descend from the root
// at every step" (the g3_vs_descent benchmark); the images are identical.
#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#include "pool_layout.h"
#include "raycast_layout.h"

layout(local_size_x = kRaycastLocalSizeX, local_size_y = kRaycastLocalSizeY) in;
layout(constant_id = 0) const uint kDescent = 0u;
// Specialization constant 1: the pass, kRaycastItems or kRaycastRetry (see "Scheduling"). Not a
// push constant: both passes in one pipeline means two copies of the ray loop in one shader,
// which costs lavapipe's frames measurably more CPU (deepcanvas-bench render --frames-only).
layout(constant_id = 1) const uint kPass = kRaycastItems;

// range: the image rows [first, first + count) this dispatch covers (frames may be cut into
// several short submissions).
layout(push_constant) uniform Push {
  DcPoolInfo pool;
  DcRaycastDispatch dispatch;
} pc;

layout(binding = 0, r32ui) uniform readonly uimage2D first_child_tex;
layout(binding = 1, r32ui) uniform readonly uimage2D colour_tex;
layout(binding = 2, r32ui) uniform readonly uimage2DArray links_img;
layout(std430, binding = 3) readonly buffer Params {
  DcRayParams p;
  DcCullBox more_boxes[kRaycastCullBoxes - 1u];  // DcRayParamsBuffer
} prm;
layout(std430, binding = 4) writeonly buffer Out { uint px[]; } outp;
// Work item counters and the items given up (raycast_layout.h; see "Scheduling").
layout(std430, binding = 5) volatile buffer Work { uint w[]; } work;

// The pool geometry, read from the push constants once per invocation: lavapipe turned each
// push-constant read inside the loops into eight per-lane scalar loads (seen in its x86 code).
uint g_width_log2;
uint g_cell_count;
uint g_root_count;
uint g_roots_per_axis;
float g_inv_roots;  // 1 / roots_per_axis (its rounding is far below the +0.5 margins it meets)
bool g_skip_empty;  // DcRayParams::skip_empty (see "Empty subtrees")

uint fetch_first_child(uint cell) {
  uint w = g_width_log2;
  return imageLoad(first_child_tex, ivec2(dc_cell_texel_x(cell, w), dc_cell_texel_y(cell, w))).r;
}
uint fetch_colour(uint cell) {
  uint w = g_width_log2;
  return imageLoad(colour_tex, ivec2(dc_cell_texel_x(cell, w), dc_cell_texel_y(cell, w))).r;
}
uint fetch_link(uint group, uint face) {
  uint w = g_width_log2;
  return imageLoad(links_img, ivec3(dc_group_texel_x(group, w), dc_group_texel_y(group, w), face)).r;
}
bool in_range(uint cell) { return cell < g_cell_count; }
float offs(bool b) { return b ? 0.5 : -0.5; }

// Ray state.
uint cell;
uint depth;
float cell_edge_m;  // the cell's edge in metres: root edge * 2^-depth, kept exactly by *2, *0.5
uvec3 coord;
vec3 p;
vec3 d;
// vec3(1) with -1 on the step's axis: mirrors p across that axis without indexing a vector by
// a run-time component (which lavapipe lowers to per-lane scratch accesses).
vec3 axis_flip;
// Loop iterations this lane ran (see "Loop limiter"): +1 at the top of every loop body.
uint lane_loops;
// With g_skip_empty: the colour of the cell descend_to_leaf() stopped at (read on the way down,
// so the step does not read it again).
uint g_rgba;

const uint kOk = 0u;
const uint kLeft = 1u;
const uint kBad = 2u;

// Down to the leaf holding p, or (g_skip_empty) to the first empty subtree on the way.
bool descend_to_leaf() {
  for (;;) {
    lane_loops += 1u;
    if (g_skip_empty) {
      g_rgba = fetch_colour(cell);
      if (g_rgba == 0u) return true;
    }
    uint fc = fetch_first_child(cell);
    if (fc == kNoCell) return true;
    if ((fc & 7u) != 0u || !in_range(fc) || depth >= kMaxDepth) return false;
    bvec3 b = bvec3(p.x > 0.0 || (p.x == 0.0 && d.x >= 0.0), p.y > 0.0 || (p.y == 0.0 && d.y >= 0.0),
                    p.z > 0.0 || (p.z == 0.0 && d.z >= 0.0));
    uvec3 bi = uvec3(b);
    p = 2.0 * p - vec3(offs(b.x), offs(b.y), offs(b.z));
    if (kDescent != 0u) coord = 2u * coord + bi;
    cell = fc + (bi.x | (bi.y << 1u) | (bi.z << 2u));
    depth += 1u;
    cell_edge_m *= 0.5;
  }
}

uint step_g3(uint axis, bool positive) {
  uint n = g_roots_per_axis;
  uint face = dc_face(axis, positive);
  if (cell < g_root_count) {
    // Root (x, y, z) = x + n (y + n z): the coordinate on `axis` by multiplying with 1/n in
    // float (exact after the +0.5 for these small integers; integer division has no SIMD
    // instruction on a CPU device, lavapipe runs it lane by lane).
    uint stride = axis == 0u ? 1u : (axis == 1u ? n : n * n);
    float inv_stride = axis == 0u ? 1.0 : (axis == 1u ? g_inv_roots : g_inv_roots * g_inv_roots);
    uint q = uint((float(cell) + 0.5) * inv_stride);
    uint c = q - n * uint((float(q) + 0.5) * g_inv_roots);
    if (positive ? c + 1u >= n : c == 0u) return kLeft;
    cell = positive ? cell + stride : cell - stride;
    p *= axis_flip;
    return kOk;
  }
  uint slot = cell & 7u;
  if (dc_face_is_inner(cell, face)) {
    cell = dc_sibling_across(cell, face);
    p *= axis_flip;
    return kOk;
  }
  uint link = fetch_link(dc_group_of(cell), face);
  if (link == kNoCell) return kLeft;
  if (!in_range(link)) return kBad;
  uint fc = g_skip_empty && fetch_colour(link) == 0u ? kNoCell : fetch_first_child(link);
  if (fc == kNoCell) {
    // The coarser leaf (or empty subtree): p in the parent's frame, then across the parent's
    // face.
    p = (p + vec3(offs((slot & 1u) != 0u), offs((slot & 2u) != 0u), offs((slot & 4u) != 0u))) * 0.5;
    p *= axis_flip;
    cell = link;
    depth -= 1u;
    cell_edge_m *= 2.0;
    return kOk;
  }
  if ((fc & 7u) != 0u || !in_range(fc)) return kBad;
  cell = dc_mirror_child(cell, face, fc);
  p *= axis_flip;
  return kOk;
}

uint step_descent(uint axis, bool positive) {
  uint n = g_roots_per_axis;
  uint extent = n << depth;
  // coord[axis] +- 1 without indexing a vector by a run-time component (see axis_flip).
  uvec3 on_axis = uvec3(equal(uvec3(axis), uvec3(0u, 1u, 2u)));
  uint c_axis = axis == 0u ? coord.x : (axis == 1u ? coord.y : coord.z);
  if (positive ? c_axis + 1u >= extent : c_axis == 0u) return kLeft;
  // The step leaves the parent (step_g3 takes the link then): an empty parent-level neighbour
  // is where the descent stops, as in step_g3.
  bool leaves_parent = ((c_axis & 1u) != 0u) == positive;
  coord = positive ? coord + on_axis : coord - on_axis;
  p *= axis_flip;
  uint k = depth;
  uint c = dc_root_index(coord.x >> k, coord.y >> k, coord.z >> k, n);
  uint level = 0u;
  // Both loops below run at most k + 2 iterations together, exits included (see "Loop
  // limiter"): counted once here, not per iteration (a count per iteration slows the descent
  // variant measurably).
  lane_loops += k + 2u;
  while (level < k) {
    if (g_skip_empty && leaves_parent && level + 1u == k && fetch_colour(c) == 0u) break;
    uint fc = fetch_first_child(c);
    if (fc == kNoCell) break;
    if ((fc & 7u) != 0u || !in_range(fc)) return kBad;
    level += 1u;
    uint sh = k - level;
    c = fc + dc_slot(coord.x >> sh, coord.y >> sh, coord.z >> sh);
  }
  for (uint lv = k; lv > level; --lv) {
    p = (p + vec3(offs((coord.x & 1u) != 0u), offs((coord.y & 1u) != 0u), offs((coord.z & 1u) != 0u))) * 0.5;
    coord >>= 1u;
  }
  cell = c;
  cell_edge_m = ldexp(cell_edge_m, int(k) - int(level));
  depth = level;
  return kOk;
}

// A camera outside: slab test against the canvas (edge 1, centred on the origin), then into
// the root holding the entry point.
// travelled: the distance to the entry point in metres.
bool enter_canvas(vec3 q, out float travelled) {
  float t_near = 0.0;
  float t_far = 1.0 / 0.0;
  int near_axis = -1;
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0.0) {
      if (q[a] < -0.5 || q[a] > 0.5) return false;
      continue;
    }
    float t0 = (-0.5 - q[a]) / d[a];
    float t1 = (0.5 - q[a]) / d[a];
    if (t0 > t1) { float tmp = t0; t0 = t1; t1 = tmp; }
    if (t0 > t_near) { t_near = t0; near_axis = a; }
    t_far = min(t_far, t1);
  }
  if (t_near > t_far) return false;
  travelled = t_near * pc.pool.canvas_edge_m;
  float n = float(pc.pool.roots_per_axis);
  uvec3 r;
  for (int a = 0; a < 3; ++a) {
    float e = clamp(q[a] + t_near * d[a], -0.5, 0.5);
    if (a == near_axis) e = d[a] > 0.0 ? -0.5 : 0.5;
    float sa = (e + 0.5) * n;
    float i = floor(sa);
    if (sa == i && d[a] < 0.0) i -= 1.0;
    i = clamp(i, 0.0, n - 1.0);
    r[a] = uint(i);
    p[a] = clamp(sa - i - 0.5, -0.5, 0.5);
  }
  coord = r;
  cell = r.x + pc.pool.roots_per_axis * (r.y + pc.pool.roots_per_axis * r.z);
  depth = 0u;
  return true;
}

// The ray through pixel (x, row) of the frame: front-to-back compositing into the output buffer.
void render_pixel(uint x, uint row) {
  uint width = prm.p.width;
  vec3 fw = vec3(prm.p.forward[0], prm.p.forward[1], prm.p.forward[2]);
  vec3 rt = vec3(prm.p.right[0], prm.p.right[1], prm.p.right[2]);
  vec3 up = vec3(prm.p.up[0], prm.p.up[1], prm.p.up[2]);
  float sx = (2.0 * (float(x) + 0.5) / float(width) - 1.0) * prm.p.tan_half_h;
  float sy = (1.0 - 2.0 * (float(row) + 0.5) / float(prm.p.height)) * prm.p.tan_half_v;
  d = normalize(fw + sx * rt + sy * up);

  // 1/d (inf where d == 0: that face is never hit).
  vec3 inv_d = vec3(d.x != 0.0 ? 1.0 / d.x : 1.0 / 0.0, d.y != 0.0 ? 1.0 / d.y : 1.0 / 0.0,
                    d.z != 0.0 ? 1.0 / d.z : 1.0 / 0.0);
  vec3 rgb = vec3(0.0);
  float trans = 1.0;
  bool started = true;
  // Content cull (client_core::RenderOptions::content_bounds or content_boxes): a ray missing
  // every box is background; one hitting some stops past 1 + 1/64 of the farthest exit among
  // them (cull_count is the same for every lane: no divergence; each iteration counts toward
  // the loop limiter).
  float stop_at = 1.0 / 0.0;
  if (prm.p.cull == 2u) {
    started = false;  // nothing painted (RenderOptions::content_empty): background
  } else if (prm.p.cull != 0u) {
    bool hit = false;
    float farthest = 0.0;
    uint boxes = min(prm.p.cull_count, kRaycastCullBoxes);
    for (uint b = 0u; b < boxes; ++b) {
      lane_loops += 1u;
      vec3 lo, hi;
      if (b == 0u) {
        lo = vec3(prm.p.cull_lo[0], prm.p.cull_lo[1], prm.p.cull_lo[2]);
        hi = vec3(prm.p.cull_hi[0], prm.p.cull_hi[1], prm.p.cull_hi[2]);
      } else {
        DcCullBox mb = prm.more_boxes[b - 1u];
        lo = vec3(mb.lo[0], mb.lo[1], mb.lo[2]);
        hi = vec3(mb.hi[0], mb.hi[1], mb.hi[2]);
      }
      bool inside_slabs = true;
      float t_near = 0.0;
      float t_far = 1.0 / 0.0;
      for (int a = 0; a < 3; ++a) {
        if (d[a] == 0.0) {
          if (lo[a] > 0.0 || hi[a] < 0.0) inside_slabs = false;
          continue;
        }
        float t0 = lo[a] * inv_d[a];
        float t1 = hi[a] * inv_d[a];
        t_near = max(t_near, min(t0, t1));
        t_far = min(t_far, max(t0, t1));
      }
      if (inside_slabs && t_near <= t_far) {
        hit = true;
        farthest = max(farthest, t_far);
      }
    }
    if (!hit) started = false;
    stop_at = farthest * (1.0 + 1.0 / 64.0);
  }
  float travelled = 0.0;
  if (!started) {
  } else if (prm.p.inside != 0u) {
    cell = prm.p.origin_cell;
    depth = prm.p.origin_depth;
    coord = uvec3(prm.p.origin_coord[0], prm.p.origin_coord[1], prm.p.origin_coord[2]);
    p = vec3(prm.p.origin_local[0], prm.p.origin_local[1], prm.p.origin_local[2]);
    started = in_range(cell);
  } else {
    started = enter_canvas(vec3(prm.p.canvas_pos[0], prm.p.canvas_pos[1], prm.p.canvas_pos[2]),
                           travelled);
  }
  if (started) {
    // Faces the ray heads for (+-1/2 per axis).
    vec3 bound = mix(vec3(-0.5), vec3(0.5), greaterThan(d, vec3(0.0)));
    cell_edge_m = ldexp(pc.pool.canvas_edge_m / float(g_roots_per_axis), -int(depth));
    uint steps = 0u;
    uint max_steps = prm.p.max_steps;
    float termination = prm.p.termination;
    for (;;) {
      lane_loops += 1u;
      if (!descend_to_leaf()) break;
      if (steps >= max_steps) break;
      steps += 1u;
      // Slab test, vectorised: distances to the three faces ahead (inf where d == 0).
      vec3 tv = mix((bound - p) * inv_d, vec3(1.0 / 0.0), equal(d, vec3(0.0)));
      float t = min(tv.x, min(tv.y, tv.z));
      uint axis = t == tv.x ? 0u : (t == tv.y ? 1u : 2u);
      t = max(t, 0.0);
      uint rgba = g_skip_empty ? g_rgba : fetch_colour(cell);
      uint a8 = rgba >> 24u;
      if (a8 != 0u && t > 0.0) {
        // (1 - a)^t as exp2(t log2(1 - a)); a8 == 255: log2(0) = -inf, exp2 -> 0.
        float seg = exp2(t * log2(1.0 - float(a8) * (1.0 / 255.0)));
        float w = trans * (1.0 - seg) * (1.0 / 255.0);
        rgb += w * vec3(uvec3(rgba, rgba >> 8u, rgba >> 16u) & 0xFFu);
        trans *= seg;
        if (trans < termination) break;
      }
      travelled += t * cell_edge_m;
      if (travelled > stop_at) break;  // past the content box: only empty cells follow
      vec3 mask = vec3(equal(uvec3(axis), uvec3(0u, 1u, 2u)));
      bool positive = dot(d, mask) > 0.0;
      axis_flip = vec3(1.0) - 2.0 * mask;
      p = mix(clamp(p + t * d, -0.5, 0.5), bound, mask);
      uint next = kDescent != 0u ? step_descent(axis, positive) : step_g3(axis, positive);
      if (next != kOk) break;
    }
  }
  vec3 bg = vec3(prm.p.background[0], prm.p.background[1], prm.p.background[2]);
  vec3 c = clamp(rgb + trans * bg, 0.0, 1.0);
  float a = clamp(1.0 - trans, 0.0, 1.0);
  uvec4 q = uvec4(c * 255.0 + 0.5, a * 255.0 + 0.5);
  outp.px[row * width + x] = dc_pack_rgba8(q.x, q.y, q.z, q.w);
}

// The pixel of a tile (8x8, row-major over the dispatch's rows) that invocation `li` (0..63) of
// a tile renders: eight 4x2 blocks, one per run of eight (what a CPU device such as lavapipe
// packs into one 256-bit SIMD batch): compact blocks keep a batch's rays coherent (a few percent
// fewer lane-steps than 8x1 rows on the real paintings).
void render_tile_pixel(uint tile, uint li, uint tiles_x, float inv_tiles_x) {
  // tile / tiles_x by a float reciprocal and one correction (integer division runs lane by
  // lane on a CPU device).
  uint ty = uint((float(tile) + 0.5) * inv_tiles_x);
  ty = ty * tiles_x > tile ? ty - 1u : ((ty + 1u) * tiles_x <= tile ? ty + 1u : ty);
  uvec2 pix = uvec2(tile - ty * tiles_x, ty) * 8u +
              uvec2(((li >> 3u) & 1u) * 4u + (li & 3u), (li >> 4u) * 2u + ((li >> 2u) & 1u));
  uint row = pc.dispatch.first_row + pix.y;
  if (pix.x < prm.p.width && pix.y < pc.dispatch.row_count && row < prm.p.height) {
    render_pixel(pix.x, row);
  }
}

// One lane: `item` goes on the retry list, its tiles on the retry pass's workgroup count.
void give_up(uint item) {
  uint base = pc.dispatch.work_base;
  uint slot = atomicAdd(work.w[base + kRaycastWorkRetryGroups], kRaycastTilesPerItem) /
              kRaycastTilesPerItem;
  work.w[base + kRaycastWorkRetryItems + slot] = item;
}

// The items pass (see "Scheduling" and "Loop limiter" above). A subgroup renders an item's
// tiles in runs of gl_SubgroupSize pixels. One loop over runs, taking a new item when the last
// one's runs are done, not a loop over tiles around a loop over runs: nested loops are slower on
// lavapipe, and the in-progress mark must be cleared at the top of the one loop's next iteration
// (with a nested runs' loop the compiler may move the clearing right after it, as it assumes
// loops end only at a break; GpuRender.EveryPixelOfEveryBandIsRendered with no budget catches
// that). item, run and the budget are the same in every lane, so their branches are uniform.
// One counter update per item of kRaycastTilesPerItem tiles: an update per run or per tile costs
// more CPU. Whole frames take somewhat more CPU than with one workgroup per tile and no loop, the
// price of the scheduling (deepcanvas-bench render --frames-only).
void render_items(uint base, uint tiles, uint tiles_x, float inv_tiles_x) {
  uint lanes = gl_SubgroupSize;
  uint runs = 64u / lanes;  // per tile
  uint item_runs = kRaycastTilesPerItem * runs;
  // Loops an item may run with no lane counting them, per run: this loop, and the ray's loops
  // entered with no active lane or left at their condition (see "Loop limiter").
  uint item_margin = item_runs * 24u + 8u;
  uint mark = base + kRaycastWorkInProgress + gl_WorkGroupID.x * gl_NumSubgroups + gl_SubgroupID;
  if (subgroupElect()) work.w[mark] = 0u;  // the buffer holds the last band's marks
  uint run = item_runs;  // take an item first
  uint item = 0u;
  bool have = false;  // an item is in progress
  uint used = 0u, costliest = 0u;
  lane_loops = 0u;
  for (;;) {
    uint tile = item * kRaycastTilesPerItem + run / runs;
    if (run == item_runs || tile >= tiles) {
      if (have) {
        // The item is done, with the limiter intact (see "Loop limiter"): clear its mark and
        // count its cost.
        if (subgroupElect()) work.w[mark] = 0u;
        have = false;
        uint cost = min(subgroupAdd(lane_loops) + item_margin, 0x10000000u);
        lane_loops = 0u;
        used = min(used + cost, 0x40000000u);
        costliest = max(costliest, cost);
        if (used + 2u * costliest > pc.dispatch.loop_budget) break;
      }
      uint taken = 0u;
      if (subgroupElect()) taken = atomicAdd(work.w[base + kRaycastWorkNextItem], 1u);
      item = subgroupBroadcastFirst(taken);
      run = 0u;
      tile = item * kRaycastTilesPerItem;
      if (tile >= tiles) break;
      have = true;
      if (subgroupElect()) work.w[mark] = item + 1u;
    }
    render_tile_pixel(tile, (run % runs) * lanes + gl_SubgroupInvocationID, tiles_x, inv_tiles_x);
    run += 1u;
  }
  // A mark left behind: the limiter ended the loop during that item; render it again.
  if (subgroupElect()) {
    uint left_behind = work.w[mark];
    if (left_behind != 0u) give_up(left_behind - 1u);
  }
}

void main() {
  g_width_log2 = pc.pool.width_log2;
  g_cell_count = pc.pool.cell_count;
  g_root_count = pc.pool.root_count;
  g_roots_per_axis = pc.pool.roots_per_axis;
  g_inv_roots = 1.0 / float(g_roots_per_axis);
  g_skip_empty = prm.p.skip_empty != 0u;
  uint base = pc.dispatch.work_base;
  uint tiles_x = (prm.p.width + 7u) / 8u;
  uint tiles = tiles_x * ((pc.dispatch.row_count + 7u) / 8u);
  float inv_tiles_x = 1.0 / float(tiles_x);
  if (kPass == kRaycastRetry) {
    // One workgroup per tile of an item given up, one pixel per invocation.
    uint g = gl_WorkGroupID.x;
    uint item = work.w[base + kRaycastWorkRetryItems + g / kRaycastTilesPerItem];
    uint tile = item * kRaycastTilesPerItem + g % kRaycastTilesPerItem;
    if (tile < tiles) render_tile_pixel(tile, gl_LocalInvocationIndex, tiles_x, inv_tiles_x);
  } else {
    render_items(base, tiles, tiles_x, inv_tiles_x);
  }
}
