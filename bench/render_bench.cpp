// deepcanvas-bench render: the GPU ray caster and the GPU G3 pass.
//
//   mrays_per_s_640x360, mrays_per_s_1280x720  rays per second (width * height / frame time),
//                                              frame time = record + submit + wait, host clock,
//                                              median over the frames; with the content cull
//                                              (RenderOptions::content_bounds = the painted box,
//                                              what a client passes); *_nocull: without it
//   frame_cpu_ms_p50        process CPU time per frame (lavapipe's threads do the work): the
//                           load-independent cost on a shared machine
//   frame_gpu_ms_p50, frame_gpu_ms_1280x720_p50  the device's timestamps around a frame's passes
//                           (-1 where it has none): frame time less the submit and the wait
//   g3_vs_descent_speedup   the same frames (640x360) with the neighbour found by descending from
//                           the root at every step, divided by the G3-stepping time (same shader
//                           source, a specialization constant; the images are identical, tested),
//                           the two interleaved frame by frame; *_cpu_*: the same in CPU time
//   mask_vs_full_speedup    G3 update after a typical stroke on a canvas of >= 4M cells: all
//                           groups / the masked groups only (GPU timestamps when the device has
//                           them, else host time around the submission), medians
//   frame_ms_p50            640x360 frame time, median
//   cpu_reference_mrays_per_s  the double-precision CPU reference, one thread, for scale
//
// Scene: a real painting (--painting FILE.apa, else demo.apa in $DEEPCANVAS_PAINTINGS) painted
// through the server's Painter at scale 1, framed by its bounding box; without one a synthetic
// scene (random refinement clusters, random colours), reported as "scene":"synthetic".
// Options: --painting FILE, --device SPEC (else DEEPCANVAS_VK_DEVICE / automatic),
// --frames-only (stop after the static frames: for profiling the ray caster), --stream-nocull
// (the streaming frames without the render loop's content cull, for comparison),
// --stream-whole-strokes (one epoch per whole stroke instead of one per painter step as the
// server streams; see bench/render_stream.hpp).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <time.h>

#include "bench.hpp"
#include "deepcanvas/bridge/pool_view_of_octree.hpp"
#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/client_gpu/replica_gpu.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "render_stream.hpp"

namespace {

namespace cc = deepcanvas::client_core;
namespace cg = deepcanvas::client_gpu;
namespace sc = deepcanvas::server_core;
namespace dp = deepcanvas::protocol;
using deepcanvas::base::percentile;
using deepcanvas::bench::median;

// CPU time of the whole process (all threads): lavapipe's workers do the frame's work, the
// main thread only waits. On a shared machine this is the load-independent measure of a
// frame's cost (wall time there depends on what else runs).
double process_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) * 1e3 + static_cast<double>(ts.tv_nsec) * 1e-6;
}

// Random refinement around a few centres until `cells` live cells, random colours on leaves.
void synthetic_fill(sc::Octree& tree, std::uint64_t cells, std::uint64_t seed, int max_depth) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  const double e = tree.config().edge_m;
  std::vector<sc::Vec3d> centres;
  for (int i = 0; i < 4; ++i)
    centres.push_back({u(rng) * e * 0.5, u(rng) * e * 0.5, u(rng) * e * 0.5});
  while (tree.live_cells() < cells) {
    const auto& c = centres[rng() % centres.size()];
    const double spread = std::ldexp(e * 0.2, -static_cast<int>(rng() % 10));
    const sc::Vec3d p{std::clamp(c.x + u(rng) * spread, -e / 2, e / 2),
                      std::clamp(c.y + u(rng) * spread, -e / 2, e / 2),
                      std::clamp(c.z + u(rng) * spread, -e / 2, e / 2)};
    auto loc = tree.locate(p, max_depth);
    if (!loc || loc->coord.depth >= max_depth) continue;
    if (!tree.refine(loc->cell)) break;
  }
  for (std::uint32_t c = 0; c < tree.high_water_cells(); ++c) {
    if (!tree.is_live(c) || !tree.is_leaf(c)) continue;
    const std::uint64_t v = rng();
    const std::uint32_t a = (v % 4 == 0) ? 0u : 20u + static_cast<std::uint32_t>((v >> 8) % 200);
    tree.set_colour(c, a ? ((static_cast<std::uint32_t>(v >> 20) & 0xFFFFFFu) | (a << 24)) : 0u);
  }
}

struct FrameSeries {
  // per frame: record + submit + wait; process CPU time; the GPU's timestamps (-1: none)
  std::vector<double> wall_ms, cpu_ms, gpu_ms;
};

// Renders the painting framed by `box` at w x h once per entry of `configs` per round, `frames`
// rounds after one warm-up round: the configurations interleaved frame by frame, so that the
// machine's load (shared, noisy) falls on all of them alike. Empty on failure.
std::vector<FrameSeries> time_interleaved(cg::GpuRaycaster& rc, const cc::PoolView& pools,
                                          const cc::DAabb& box, std::uint32_t w, std::uint32_t h,
                                          const std::vector<cc::RenderOptions>& configs,
                                          int frames) {
  auto cam = cc::Camera::frame_box(box, w, h);
  if (!cam) return {};
  auto origin = cc::make_ray_origin(pools, cam->position());
  if (!origin) return {};
  std::vector<FrameSeries> out(configs.size());
  for (int i = 0; i < frames + 1; ++i) {
    for (std::size_t k = 0; k < configs.size(); ++k) {
      if (!rc.set_frame(*cam, *origin, configs[k])) return {};
      cg::FrameTiming t;
      const double c0 = process_cpu_ms();
      if (!rc.render(1, &t)) return {};
      if (i > 0) {  // the first round warms caches
        out[k].wall_ms.push_back(t.wall_ms);
        out[k].cpu_ms.push_back(process_cpu_ms() - c0);
        out[k].gpu_ms.push_back(t.gpu_ms);
      }
    }
  }
  return out;
}

struct RenderOptions {
  std::string painting;  // empty: demo.apa in the paintings' folder, else a synthetic scene
  std::string device;
  bool frames_only = false, stream_nocull = false, stream_whole_strokes = false;
};

// The scene: --painting, else demo.apa where the paintings are, else "" (a synthetic scene);
// a DEEPCANVAS_PAINTINGS that is set but wrong is an error.
deepcanvas::Result<std::string> scene_painting(const RenderOptions& ro) {
  if (!ro.painting.empty()) return ro.painting;
  auto dir = deepcanvas::bench::paintings_dir();
  if (dir) return (*dir / "demo.apa").string();
  if (std::getenv("DEEPCANVAS_PAINTINGS")) return std::move(dir).error();
  return std::string();
}

// The server tree the frames render: the painting's strokes (--quick: the first 300) through
// the Painter, or the synthetic scene.
struct Scene {
  std::unique_ptr<sc::Octree> tree;
  std::string name = "synthetic";
  std::size_t strokes = 0;
};

deepcanvas::Result<Scene> build_scene(const std::string& painting, bool quick) {
  Scene scene;
  auto tree = sc::Octree::create({});
  if (!tree) return std::move(tree).error();
  scene.tree = std::move(*tree);
  if (!painting.empty()) {
    auto p = deepcanvas::paintings::read_apa_file(painting, {});
    if (!p) return std::move(p).error();
    auto painter = sc::Painter::create(*scene.tree);
    if (!painter) return std::move(painter).error();
    const std::size_t max_strokes = quick ? 300 : p->strokes.size();
    for (const auto& s : p->strokes) {
      if (scene.strokes == max_strokes) break;
      if ((*painter)->apply_stroke(s)) ++scene.strokes;
    }
    scene.name = painting.substr(painting.find_last_of('/') + 1);
  } else {
    synthetic_fill(*scene.tree, 300000, 1, 14);
  }
  (void)scene.tree->take_dirty_blocks();
  scene.tree->clear_all_neighbour_masks();
  return scene;
}

// The scene on the GPU (uploaded whole, links computed) and a ray caster over it.
struct GpuScene {
  std::unique_ptr<cg::GpuReplica> replica;
  std::unique_ptr<cg::GpuRaycaster> raycaster;
};

deepcanvas::Result<GpuScene> upload_scene(const cg::Context& ctx, const cc::PoolView& pools) {
  GpuScene g;
  cg::GpuReplicaConfig rcfg;
  rcfg.width_log2 = 12;
  rcfg.block_log2 = 12;
  auto replica = cg::GpuReplica::create(ctx, rcfg);
  if (!replica) return std::move(replica).error();
  g.replica = std::move(*replica);
  if (auto u = g.replica->upload_all(pools); !u) return std::move(u).error();
  if (auto l = g.replica->compute_all_links(pools); !l) return std::move(l).error();
  auto rc = cg::GpuRaycaster::create(*g.replica);
  if (!rc) return std::move(rc).error();
  g.raycaster = std::move(*rc);
  return g;
}

// Static frames of the framed painting (medians over the frames).
struct StaticFrames {
  std::vector<double> frames_640;  // wall ms, G3, content cull
  double ms_640 = 0, ms_640_descent = 0, cpu_640 = 0, cpu_640_descent = 0, ms_1280 = 0;
  double gpu_640 = -1, gpu_1280 = -1;  // the GPU's timestamps around the passes, -1: none
  double ms_nocull = 0, ms_nocull_descent = 0, cpu_nocull = 0;
  double mrays_640 = 0, mrays_1280 = 0, mrays_nocull = 0;
};

// G3 and descent (and the uncull pair) are interleaved frame by frame, so the machine's load
// falls on both alike and their ratio is fair. `progress` advances by one per series.
deepcanvas::Result<StaticFrames> measure_static_frames(cg::GpuRaycaster& rc,
                                                       const cc::PoolView& pools,
                                                       const cc::DAabb& box, bool quick,
                                                       deepcanvas::base::Progress& progress) {
  const int frames = quick ? 7 : 15;
  cc::RenderOptions g3_opt;
  g3_opt.background = {0.1, 0.1, 0.12};
  g3_opt.content_bounds = box;
  cc::RenderOptions descent_opt = g3_opt;
  descent_opt.stepping = cc::Stepping::descent;
  cc::RenderOptions g3_nocull = g3_opt, descent_nocull = descent_opt;
  g3_nocull.content_bounds.reset();
  descent_nocull.content_bounds.reset();
  const auto s640 = time_interleaved(rc, pools, box, 640, 360, {g3_opt, descent_opt}, frames);
  progress.add(1);
  const auto s1280 = time_interleaved(rc, pools, box, 1280, 720, {g3_opt}, frames);
  progress.add(1);
  const auto snocull =
      time_interleaved(rc, pools, box, 640, 360, {g3_nocull, descent_nocull}, quick ? 2 : 5);
  progress.add(1);
  if (s640.empty() || s1280.empty() || snocull.empty())
    return deepcanvas::make_error(deepcanvas::Errc::io_error, "a frame failed");
  StaticFrames f;
  f.frames_640 = s640[0].wall_ms;
  f.ms_640 = median(f.frames_640);
  f.ms_640_descent = median(s640[1].wall_ms);
  f.cpu_640 = median(s640[0].cpu_ms);
  f.cpu_640_descent = median(s640[1].cpu_ms);
  f.ms_1280 = median(s1280[0].wall_ms);
  f.gpu_640 = median(s640[0].gpu_ms);
  f.gpu_1280 = median(s1280[0].gpu_ms);
  f.ms_nocull = median(snocull[0].wall_ms);
  f.ms_nocull_descent = median(snocull[1].wall_ms);
  f.cpu_nocull = median(snocull[0].cpu_ms);
  f.mrays_640 = 640.0 * 360.0 / (f.ms_640 * 1e3);
  f.mrays_1280 = 1280.0 * 720.0 / (f.ms_1280 * 1e3);
  f.mrays_nocull = 640.0 * 360.0 / (f.ms_nocull * 1e3);
  return f;
}

void print_static_frames(const StaticFrames& f) {
  deepcanvas::bench::print(
      "render: 640x360 %.2f ms (%.2f Mrays/s), 1280x720 %.2f ms (%.2f Mrays/s), "
      "descent %.2f ms -> G3 speedup %.2fx\n",
      f.ms_640, f.mrays_640, f.ms_1280, f.mrays_1280, f.ms_640_descent,
      f.ms_640_descent / f.ms_640);
  deepcanvas::bench::print(
      "render: 640x360 CPU time per frame %.2f ms (G3), %.2f ms (descent) -> %.2fx; device time "
      "%.2f ms, 1280x720 %.2f ms\n",
      f.cpu_640, f.cpu_640_descent, f.cpu_640_descent / f.cpu_640, f.gpu_640, f.gpu_1280);
  deepcanvas::bench::print(
      "render: 640x360 without the content cull: %.2f ms (%.2f Mrays/s, CPU %.2f ms), "
      "descent %.2f ms -> G3 speedup %.2fx\n",
      f.ms_nocull, f.mrays_nocull, f.cpu_nocull, f.ms_nocull_descent,
      f.ms_nocull_descent / f.ms_nocull);
}

// Frames while the painting streams in (bench/render_stream.cpp), one run per loop.
struct StreamLoops {
  std::vector<deepcanvas::bench::StreamingFrames> runs;  // runs.front(): the clients' loop
  std::string json;                                      // "name":{...},...
};

// Three loops over the same painting and stream: as clients run it (RenderLoopOptions defaults:
// at most 60 fps, a quarter of each interval kept free, uploads only in those gaps), with
// uploads between bands instead (upload_share 0), and frames back to back. `progress` advances
// by one per loop.
deepcanvas::Result<StreamLoops> measure_stream_loops(const cg::Context& ctx,
                                                     const std::string& painting,
                                                     const Scene& scene, const cc::DAabb& box,
                                                     const deepcanvas::bench::Options& opt,
                                                     const RenderOptions& ro,
                                                     deepcanvas::base::Progress& progress) {
  struct Variant {
    const char* name;
    double max_fps, upload_share;
  };
  const cg::RenderLoopOptions loop_defaults;
  const Variant variants[] = {{"default", loop_defaults.max_fps, loop_defaults.upload_share},
                              {"share0", loop_defaults.max_fps, 0.0},
                              {"unpaced", 0.0, 0.0}};
  StreamLoops out;
  for (const Variant& v : variants) {
    auto r = deepcanvas::bench::measure_streaming_frames(
        ctx, painting, scene.strokes, box, 640, 360, opt.quick ? 100.0 : 300.0, opt.quick ? 20 : 60,
        !ro.stream_nocull, !ro.stream_whole_strokes, v.max_fps, v.upload_share);
    if (!r)
      return deepcanvas::make_error(
          r.error().code, std::string("streaming (") + v.name + "): " + r.error().message);
    if (!opt.json) deepcanvas::bench::print_streaming(std::string(v.name) + " loop", *r);
    progress.add(1);
    out.json += std::string(out.json.empty() ? "" : ",") + "\"" + v.name +
                "\":" + deepcanvas::bench::streaming_json(*r);
    out.runs.push_back(std::move(*r));
  }
  return out;
}

// The CPU reference, one thread, for scale (with the content cull, as the GPU frames), and the
// leaves per ray with and without the cull.
struct CpuReference {
  double mrays = 0, steps_per_ray = 0, steps_per_ray_nocull = 0;
  std::uint64_t max_steps = 0;
};

deepcanvas::Result<CpuReference> measure_cpu_reference(const cc::PoolView& pools,
                                                       const cc::DAabb& box, bool quick) {
  CpuReference out;
  auto cam = cc::Camera::frame_box(box, 320, 180);
  cc::RenderOptions ref;
  cc::RenderStats nocull;
  if (auto r = cc::render_reference(pools, *cam, ref, &nocull); !r) return std::move(r).error();
  out.steps_per_ray_nocull = static_cast<double>(nocull.steps) / static_cast<double>(nocull.rays);
  ref.content_bounds = box;
  std::vector<double> s;
  for (int i = 0; i < (quick ? 1 : 3); ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    cc::RenderStats rs;
    auto img = cc::render_reference(pools, *cam, ref, &rs);
    if (!img) return std::move(img).error();
    out.steps_per_ray = static_cast<double>(rs.steps) / static_cast<double>(rs.rays);
    out.max_steps = rs.max_steps;
    s.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  out.mrays = 320.0 * 180.0 / median(s) / 1e6;
  return out;
}

// Masked vs full G3 update after a typical stroke on a >= 4M-cell canvas.
struct MaskedG3 {
  std::uint64_t canvas_cells = 0, groups = 0, stroke_cells_created = 0;
  std::uint32_t masked_groups = 0;
  double mask_ms = 0, all_ms = 0;
  bool links_equal = false;  // the masked result is the server's
};

// A typical stroke: a painted stroke of 24 samples, radius 2 m, across a refined region.
dp::Stroke typical_stroke() {
  dp::Stroke stroke;
  stroke.brush.colour[0] = 0.9f;
  stroke.brush.colour[3] = 0.8f;
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  const double x0 = u(rng) * 4000, y0 = u(rng) * 4000, z0 = u(rng) * 4000;
  for (int i = 0; i < 24; ++i) {
    dp::StrokeSample s;
    s.x = x0 + i * 1.0;
    s.y = y0 + 0.3 * i;
    s.z = z0;
    s.radius = 2.0f;
    stroke.samples.push_back(s);
  }
  return stroke;
}

// The masked groups of every block (the neighbour masks the stroke left).
std::vector<std::uint64_t> neighbour_masks(const sc::Octree& tree) {
  std::vector<std::uint64_t> mask;
  for (sc::BlockId b = 0; b < tree.block_count(); ++b) {
    const auto m = tree.neighbour_mask(b);
    mask.insert(mask.end(), m.begin(), m.end());
  }
  return mask;
}

deepcanvas::Result<MaskedG3> measure_masked_g3(const cg::Context& ctx, bool quick) {
  auto big_r = sc::Octree::create({});
  if (!big_r) return std::move(big_r).error();
  sc::Octree& big = **big_r;
  const std::uint64_t big_cells = 4u << 20;
  synthetic_fill(big, big_cells, 2, 16);
  (void)big.take_dirty_blocks();
  big.clear_all_neighbour_masks();
  cg::GpuReplicaConfig bcfg;
  bcfg.width_log2 = 12;
  bcfg.block_log2 = 12;
  bcfg.initial_capacity_cells = big.high_water_cells() + (1u << 20);
  auto breplica_r = cg::GpuReplica::create(ctx, bcfg);
  if (!breplica_r) return std::move(breplica_r).error();
  cg::GpuReplica& brep = **breplica_r;
  if (auto u = brep.upload_all(deepcanvas::bridge::pool_view_of(big)); !u)
    return std::move(u).error();
  if (auto l = brep.compute_all_links(deepcanvas::bridge::pool_view_of(big)); !l)
    return std::move(l).error();
  auto bpainter = sc::Painter::create(big);
  if (!bpainter) return std::move(bpainter).error();
  auto st = (*bpainter)->apply_stroke(typical_stroke());
  if (!st) return deepcanvas::make_error(st.error().code, "stroke failed: " + st.error().message);
  const cc::PoolView bpools = deepcanvas::bridge::pool_view_of(big);
  const auto dirty = big.take_dirty_blocks();
  if (auto u = brep.upload_blocks(bpools, dirty); !u) return std::move(u).error();
  const std::vector<std::uint64_t> mask = neighbour_masks(big);
  std::vector<double> masked_ms, full_ms;
  MaskedG3 out;
  const int link_runs = quick ? 5 : 11;
  for (int i = 0; i < link_runs; ++i) {
    cg::LinksTiming tm, tf;
    auto t0 = std::chrono::steady_clock::now();
    if (auto l = brep.compute_links_masked(bpools, mask, &tm); !l) return std::move(l).error();
    const double wm =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    t0 = std::chrono::steady_clock::now();
    if (auto l = brep.compute_all_links(bpools, &tf); !l) return std::move(l).error();
    const double wf =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    masked_ms.push_back(tm.gpu_ms >= 0 ? tm.gpu_ms : wm);
    full_ms.push_back(tf.gpu_ms >= 0 ? tf.gpu_ms : wf);
    out.masked_groups = tm.groups;
  }
  // The masked result is the server's (checked here too, not only in the tests).
  auto links = brep.read_links();
  if (!links) return std::move(links).error();
  const auto want = big.group_link_pool();
  out.links_equal = std::equal(links->begin(), links->end(), want.begin());
  out.mask_ms = median(masked_ms);
  out.all_ms = median(full_ms);
  out.canvas_cells = big.live_cells();
  out.groups = big.high_water_cells() / 8;
  out.stroke_cells_created = st->cells_created;
  return out;
}

void print_masked_g3(const MaskedG3& m) {
  deepcanvas::bench::print(
      "render: G3 update, %llu cells (%llu groups), stroke created %llu cells: masked %u "
      "groups %.3f ms, all groups %.3f ms -> %.1fx (links equal server: %s)\n",
      static_cast<unsigned long long>(m.canvas_cells), static_cast<unsigned long long>(m.groups),
      static_cast<unsigned long long>(m.stroke_cells_created), m.masked_groups, m.mask_ms, m.all_ms,
      m.all_ms / m.mask_ms, m.links_equal ? "yes" : "NO");
}

void print_json(const deepcanvas::bench::Options& opt, const RenderOptions& ro,
                const std::string& device, const Scene& scene, const StaticFrames& f,
                const StreamLoops& loops, const CpuReference& cpu, const MaskedG3& m) {
  const auto& streamed = loops.runs.front();
  const double stream_p99 = streamed.frame_ms_p99_while_streaming;
  deepcanvas::bench::print(
      "{\"suite\":\"render\",\"quick\":%s,\"device\":\"%s\",\"scene\":\"%s\",\"strokes\":%zu,"
      "\"scene_cells\":%llu,\"mrays_per_s_640x360\":%.3f,\"mrays_per_s_1280x720\":%.3f,"
      "\"frame_ms_p50\":%.3f,\"frame_ms_p99\":%.3f,\"frame_ms_1280x720_p50\":%.3f,"
      "\"descent_frame_ms_p50\":%.3f,\"g3_vs_descent_speedup\":%.3f,"
      "\"frame_cpu_ms_p50\":%.3f,\"descent_frame_cpu_ms_p50\":%.3f,"
      "\"frame_gpu_ms_p50\":%.3f,\"frame_gpu_ms_1280x720_p50\":%.3f,"
      "\"frame_ms_p99_while_streaming\":%.3f,\"streaming_frames\":%zu,"
      "\"stream_epochs\":\"%s\",\"stream_content_cull\":%s,"
      "\"stream_frame_ms_p50\":%.3f,\"stream_p99_over_p50\":%.3f,"
      "\"stream_loops\":{%s},"
      "\"cpu_reference_mrays_per_s\":%.3f,\"leaves_per_ray\":%.2f,"
      "\"leaves_per_ray_nocull\":%.2f,\"mrays_per_s_640x360_nocull\":%.3f,"
      "\"g3_vs_descent_speedup_nocull\":%.3f,\"g3_vs_descent_cpu_speedup\":%.3f,"
      "\"mask_canvas_cells\":%llu,"
      "\"mask_stroke_cells_created\":%llu,\"masked_groups\":%u,\"masked_links_ms\":%.4f,"
      "\"full_links_ms\":%.4f,\"mask_vs_full_speedup\":%.2f,\"links_equal_server\":%s,"
      "\"targets\":{\"g3_vs_descent_speedup_min\":3.0,\"stream_p99_over_p50_max\":1.15}}\n",
      opt.quick ? "true" : "false", device.c_str(), scene.name.c_str(), scene.strokes,
      static_cast<unsigned long long>(scene.tree->live_cells()), f.mrays_640, f.mrays_1280,
      f.ms_640, percentile(f.frames_640, 0.99), f.ms_1280, f.ms_640_descent,
      f.ms_640_descent / f.ms_640, f.cpu_640, f.cpu_640_descent, f.gpu_640, f.gpu_1280, stream_p99,
      streamed.streaming_ms.size(), ro.stream_whole_strokes ? "whole_strokes" : "painter_steps",
      ro.stream_nocull ? "false" : "true", streamed.frame_ms_p50,
      stream_p99 / streamed.frame_ms_p50, loops.json.c_str(), cpu.mrays, cpu.steps_per_ray,
      cpu.steps_per_ray_nocull, f.mrays_nocull, f.ms_nocull_descent / f.ms_nocull,
      f.cpu_640_descent / f.cpu_640, static_cast<unsigned long long>(m.canvas_cells),
      static_cast<unsigned long long>(m.stroke_cells_created), m.masked_groups, m.mask_ms, m.all_ms,
      m.all_ms / m.mask_ms, m.links_equal ? "true" : "false");
}

int run(const deepcanvas::bench::Options& opt, const RenderOptions& ro) {
  namespace bench = deepcanvas::bench;
  auto painting = scene_painting(ro);
  if (!painting) return bench::fail(opt, painting.error().message);
  // Steps: the three static series, then (without --frames-only) the three streaming loops,
  // the CPU reference and the masked G3 update.
  auto progress = bench::progress(opt, "render", ro.frames_only ? 3 : 8, "steps");
  auto ctx_r = cg::ContextBuilder().app_name("deepcanvas-bench").device(ro.device).build();
  if (!ctx_r) return bench::fail(opt, ctx_r.error().message);
  cg::Context& ctx = **ctx_r;
  bench::note(opt, "render: device %s\n", ctx.info().name.c_str());
  auto scene = build_scene(*painting, opt.quick);
  if (!scene) return bench::fail(opt, scene.error().message);
  const cc::PoolView pools = deepcanvas::bridge::pool_view_of(*scene->tree);
  bench::note(opt, "render: scene %s, %zu strokes, %llu live cells, max depth %d\n",
              scene->name.c_str(), scene->strokes,
              static_cast<unsigned long long>(scene->tree->live_cells()),
              scene->tree->stats().max_depth);
  auto box = cc::painted_bounds(pools);
  if (!box || !box->has_value()) return bench::fail(opt, "nothing painted");
  auto gpu = upload_scene(ctx, pools);
  if (!gpu) return bench::fail(opt, gpu.error().message);
  auto frames = measure_static_frames(*gpu->raycaster, pools, **box, opt.quick, progress);
  if (!frames) return bench::fail(opt, frames.error().message);
  if (!opt.json) print_static_frames(*frames);
  if (ro.frames_only) {
    progress.finish();
    return 0;
  }
  auto loops = measure_stream_loops(ctx, *painting, *scene, **box, opt, ro, progress);
  if (!loops) return bench::fail(opt, loops.error().message);
  auto cpu = measure_cpu_reference(pools, **box, opt.quick);
  if (!cpu) return bench::fail(opt, cpu.error().message);
  progress.add(1);
  if (!opt.json)
    bench::print(
        "render: CPU reference %.3f Mrays/s, %.2f leaves per ray (max %llu), %.2f "
        "without the content cull\n",
        cpu->mrays, cpu->steps_per_ray, static_cast<unsigned long long>(cpu->max_steps),
        cpu->steps_per_ray_nocull);
  auto masked = measure_masked_g3(ctx, opt.quick);
  if (!masked) return bench::fail(opt, masked.error().message);
  progress.add(1);
  progress.finish();
  if (!opt.json) print_masked_g3(*masked);
  if (opt.json) print_json(opt, ro, ctx.info().name, *scene, *frames, *loops, *cpu, *masked);
  if (!masked->links_equal) return bench::fail(opt, "the masked G3 links differ from the server's");
  return 0;
}

deepcanvas::bench::SuiteRun setup(CLI::App& app) {
  auto ro = std::make_shared<RenderOptions>();
  app.add_option("--painting", ro->painting,
                 "the scene (default demo.apa in DEEPCANVAS_PAINTINGS, else a synthetic scene)")
      ->type_name("FILE.apa");
  app.add_option("--device", ro->device, "Vulkan device (else DEEPCANVAS_VK_DEVICE / automatic)")
      ->type_name("SPEC");
  app.add_flag("--frames-only", ro->frames_only,
               "stop after the static frames (profiling the ray caster)");
  app.add_flag("--stream-nocull", ro->stream_nocull, "streaming frames without the content cull");
  app.add_flag("--stream-whole-strokes", ro->stream_whole_strokes,
               "one epoch per whole stroke while streaming (instead of one per painter step)");
  return [ro](const deepcanvas::bench::Options& opt) { return run(opt, *ro); };
}

}  // namespace

DEEPCANVAS_BENCH_SUITE(deepcanvas::bench::Suite{
    "render", "GPU ray casting (Mrays/s, G3 vs descent) and masked G3 updates",
    "examples:\n"
    "  deepcanvas-bench render --quick\n"
    "  deepcanvas-bench render --painting \"$DEEPCANVAS_PAINTINGS/winner.apa\" --json\n"
    "  DEEPCANVAS_BENCH_TRACE=1 deepcanvas-bench render --quick   # a line per frame and batch\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder), DEEPCANVAS_VK_DEVICE\n",
    setup});
