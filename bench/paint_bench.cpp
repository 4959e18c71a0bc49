// deepcanvas-bench paint: the real paintings painted into our octree and into OpenVDB (issue 4).
//
// For each A-Painter painting (the folder DEEPCANVAS_PAINTINGS names),
// placed at its natural metre scale (ApaTransform scale 1, offset 0), in the same run:
// - ours: a fresh Octree (default config: 4^3 roots, 20 km, depth 24) and Painter; every stroke
//   through Painter::apply_stroke (the real multi-step path: paint at the tree's resolution,
//   refine one level per bounded step, merge back). Memory: Octree::allocated_bytes() (committed
//   pools up to the high-water mark + block bookkeeping) and stats().pool_bytes. The painter's
//   temporary field pools (stroke marks, pre-stroke values, strengths) are not counted.
// - OpenVDB (openvdb_peer.hpp): the same strokes through the same stamp rasterizer, a grid whose
//   voxel is the finest cell our tree used for the painting (the deepest stamp target depth),
//   each rasterized cell a fill of the same cube, the same stroke-level blending (max strength
//   per stroke in a stroke layer, blended once from the pre-stroke value), tools::prune at the
//   end. Memory: Grid::memUsage() after prune. The primary peer stores the octree's own RGBA8
//   cell format in an openvdb::UInt32Grid (same result, same precision: the fair peer); a
//   Vec4f grid (float RGBA, what OpenVDB users reach for first) is measured beside it.
// Both run on this one thread: TBB is capped at one thread (tbb::global_control) and the peer
// calls no threaded tool (prune with threaded = false).
// Time: thread CPU time of painting all strokes (stamps, rasterization, tree/grid updates;
// loading the file is excluded), median over runs (3; --quick: 1 run on a subset). Wall time is
// reported too. Ratios are ours / OpenVDB: openvdb_memory_ratio (target <= 0.5) and
// openvdb_time_ratio (target <= 1.0), per painting and overall (sums over the paintings).
// Agreement check (not timed): at up to 2000 stroke sample positions per painting our pick()
// and the peer's voxel are compared (RGB within 3/255, alpha at our leaf's edge within 3/255);
// the fraction that agrees is reported (near stroke edges the two evaluate coverage at
// different cell centres, so it is not 1 by design).
//
// The Vec4f peer is timed in one run only (the last) to keep the suite's run time down; its
// memory is deterministic.
// Options: --quick, --json, --paintings a,b,c (file names without .apa), --runs N,
// --no-vec4f (only the RGBA8 peer).

#include <openvdb/openvdb.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "bench.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/protocol/density_model.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/server_core/stamp.hpp"
#include "openvdb_peer.hpp"

namespace deepcanvas::bench {
namespace {

namespace fs = std::filesystem;
using server_core::Octree;
using server_core::OctreeConfig;
using server_core::Painter;
using Clock = std::chrono::steady_clock;

double wall_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// All 17 paintings of the shared set, alphabetical.
const char* const kAllPaintings[] = {
    "ET_logos",   "allhands",          "dancer",           "demo",     "demon",
    "it_follows", "logo_fire",         "mozdino",          "mozfest",  "mozilla",
    "palmtree",   "rose_bush",         "the_gentle_robot", "the_leap", "volcano",
    "winner",     "you_shall_not_pass"};
// --quick: one run of these four (thread CPU seconds of ours + RGBA8 + Vec4f peers in
// `deepcanvas-bench paint --json` on the 2-core CI VM: demo 0.7 + 1.0 + 1.0, mozfest 0.7 + 0.9 +
// 0.9, mozilla 0.1 + 0.1 + 0.1, palmtree 1.3 + 3.5 + 3.5; ~14 s of CPU in all, well under 60 s):
// the finest brushes (demo, 0.3 mm voxels), medium and broad ones (palmtree), a one-size
// painting.
const char* const kQuickPaintings[] = {"demo", "mozfest", "mozilla", "palmtree"};

struct Input {
  std::string name;
  paintings::ApaPainting painting;
  std::uint64_t stamps = 0;
  int finest_depth = 0;  // deepest stamp target depth: the voxel depth of the peer
};

struct Ours {
  double cpu = 0, wall = 0;
  std::uint64_t allocated_bytes = 0, pool_bytes = 0, live_cells = 0, leaves = 0;
  std::uint64_t cells_created = 0, cells_freed = 0, steps = 0;
  int max_depth = 0;
  std::uint64_t canvas_hash = 0;
};

struct Vdb {
  double cpu = 0, wall = 0;
  VdbMemory mem;
  VdbPeerStats stats;
};

struct Row {
  std::string name;
  std::size_t strokes = 0, samples = 0;
  std::uint64_t stamps = 0;
  int finest_depth = 0;
  double voxel_edge_m = 0;
  Ours ours;  // memory/counters of the last run, times are medians
  Vdb rgba8, vec4f;
  bool have_vec4f = false;
  double agree = 0;
  std::size_t agree_checked = 0;
};

Result<Input> load(const fs::path& dir, const std::string& name,
                   const server_core::CanvasGeometry& geo, const server_core::StampParams& sp) {
  auto p = paintings::read_apa_file((dir / (name + ".apa")).string(), paintings::ApaTransform{});
  if (!p) return std::move(p).error();
  Input in;
  in.name = name;
  in.painting = std::move(*p);
  for (const auto& s : in.painting.strokes) {
    auto st = server_core::stroke_stamps(geo, sp, s);
    if (!st) return std::move(st).error();
    in.stamps += st->size();
    for (const auto& x : *st) in.finest_depth = std::max(in.finest_depth, x.depth);
  }
  return in;
}

Result<Ours> run_ours(const Input& in, std::unique_ptr<Octree>* keep,
                      std::unique_ptr<Painter>* keep_painter) {
  auto tree = Octree::create(OctreeConfig{});
  if (!tree) return std::move(tree).error();
  auto painter = Painter::create(**tree);
  if (!painter) return std::move(painter).error();
  Ours o;
  const auto w0 = Clock::now();
  const double c0 = thread_cpu_seconds();
  for (const auto& s : in.painting.strokes) {
    auto r = (*painter)->apply_stroke(s);
    if (!r) return std::move(r).error();
    o.cells_created += r->cells_created;
    o.cells_freed += r->cells_freed;
    o.steps += r->steps;
  }
  o.cpu = thread_cpu_seconds() - c0;
  o.wall = wall_since(w0);
  const auto st = (*tree)->stats();
  o.allocated_bytes = (*tree)->allocated_bytes();
  o.pool_bytes = st.pool_bytes;
  o.live_cells = st.live_cells;
  o.leaves = st.leaves;
  o.max_depth = st.max_depth;
  o.canvas_hash = (*tree)->canvas_hash();
  if (keep) {
    *keep_painter = std::move(*painter);  // the painter goes first (it holds field pools)
    *keep = std::move(*tree);
  }
  return o;
}

Result<Vdb> run_vdb(const Input& in, VdbValueKind kind, std::unique_ptr<OpenVdbPeer>* keep) {
  VdbPeerConfig cfg;
  cfg.kind = kind;
  cfg.voxel_depth = in.finest_depth;
  auto peer = OpenVdbPeer::create(OctreeConfig{}, cfg);
  if (!peer) return std::move(peer).error();
  Vdb v;
  const auto w0 = Clock::now();
  const double c0 = thread_cpu_seconds();
  for (const auto& s : in.painting.strokes) {
    auto r = (*peer)->apply_stroke(s);
    if (!r) return std::move(r).error();
  }
  (*peer)->prune();
  v.cpu = thread_cpu_seconds() - c0;
  v.wall = wall_since(w0);
  v.mem = (*peer)->memory();
  v.stats = (*peer)->stats();
  if (keep) *keep = std::move(*peer);
  return v;
}

// Fraction of stroke sample positions (at most 2000, evenly spread) where both canvases agree.
std::pair<double, std::size_t> agreement(const Input& in, const Painter& ours,
                                         const OpenVdbPeer& peer) {
  std::vector<server_core::Vec3d> pts;
  for (const auto& s : in.painting.strokes)
    for (const auto& x : s.samples) pts.push_back({x.x, x.y, x.z});
  const std::size_t step = std::max<std::size_t>(1, pts.size() / 2000);
  std::size_t n = 0, ok = 0;
  for (std::size_t i = 0; i < pts.size(); i += step) {
    auto a = ours.pick(pts[i]);
    auto b = peer.sample(pts[i]);
    if (!a || !b) continue;
    ++n;
    // The peer's density at our leaf's edge: alpha' = 1 - exp(-sigma h).
    const double pa =
        std::isinf(b->sigma_per_m) ? 1.0 : -std::expm1(-b->sigma_per_m * a->cell_edge_m);
    bool same = std::abs(pa - a->alpha) <= 3.0 / 255.0 + 1e-9;
    if (a->alpha > 0.05f)
      for (int k = 0; k < 3; ++k)
        same = same && std::abs(a->rgb[k] - b->rgb[k]) <= 3.0f / 255.0f + 1e-6f;
    ok += same;
  }
  return {n ? double(ok) / double(n) : 0.0, n};
}

double ratio(double a, double b) {
  return b > 0 ? a / b : 0.0;
}

struct PaintOptions {
  std::vector<std::string> paintings;  // file names without .apa; empty: the default set
  int runs = 0;                        // 0: the default (3; --quick 1)
  bool no_vec4f = false;
};

// The paintings asked for (a trailing .apa dropped), else the default set for the mode.
std::vector<std::string> painting_names(const PaintOptions& po, bool quick) {
  std::vector<std::string> names;
  for (const auto& n : po.paintings)
    if (!n.empty())
      names.push_back(n.size() > 4 && n.ends_with(".apa") ? n.substr(0, n.size() - 4) : n);
  if (names.empty()) {
    if (quick)
      names.assign(std::begin(kQuickPaintings), std::end(kQuickPaintings));
    else
      names.assign(std::begin(kAllPaintings), std::end(kAllPaintings));
  }
  return names;
}

// One painting, `runs` times ours then the RGBA8 peer; in the last run also their agreement and
// (with_vec4f) the Vec4f peer. Times are medians over the runs, the rest from the last run.
// `progress` advances by one per run.
Result<Row> measure_painting(const Options& opt, const Input& in, double voxel_edge_m, int runs,
                             bool with_vec4f, base::Progress& progress) {
  const std::string& name = in.name;
  Row row;
  row.name = name;
  row.strokes = in.painting.strokes.size();
  row.samples = in.painting.sample_count;
  row.stamps = in.stamps;
  row.finest_depth = in.finest_depth;
  row.voxel_edge_m = voxel_edge_m;
  std::vector<double> oc, ow, rc, rw, vc, vw;
  for (int run = 0; run < runs; ++run) {
    const bool last = run == runs - 1;
    std::unique_ptr<Octree> tree;
    std::unique_ptr<Painter> painter;
    std::unique_ptr<OpenVdbPeer> peer;
    auto o = run_ours(in, last ? &tree : nullptr, last ? &painter : nullptr);
    if (!o) return make_error(o.error().code, name + ": ours: " + o.error().message);
    oc.push_back(o->cpu);
    ow.push_back(o->wall);
    row.ours = *o;
    auto r = run_vdb(in, VdbValueKind::rgba8, last ? &peer : nullptr);
    if (!r) return make_error(r.error().code, name + ": openvdb: " + r.error().message);
    rc.push_back(r->cpu);
    rw.push_back(r->wall);
    row.rgba8 = *r;
    if (last) {
      const auto [f, n] = agreement(in, *painter, *peer);
      row.agree = f;
      row.agree_checked = n;
    }
    peer.reset();
    if (with_vec4f && last) {  // the secondary peer: one run (the last) per painting
      auto v = run_vdb(in, VdbValueKind::vec4f, nullptr);
      if (!v) return make_error(v.error().code, name + ": openvdb vec4f: " + v.error().message);
      vc.push_back(v->cpu);
      vw.push_back(v->wall);
      row.vec4f = *v;
      row.have_vec4f = true;
    }
    note(opt, "paint: %-20s run %d/%d: ours %.2f s, openvdb %.2f s%s\n", name.c_str(), run + 1,
         runs, o->cpu, r->cpu,
         with_vec4f && last ? (", vec4f " + std::to_string(vc.back()) + " s").c_str() : "");
    progress.add(1);
  }
  row.ours.cpu = median(oc);
  row.ours.wall = median(ow);
  row.rgba8.cpu = median(rc);
  row.rgba8.wall = median(rw);
  if (with_vec4f) {
    row.vec4f.cpu = median(vc);
    row.vec4f.wall = median(vw);
  }
  return row;
}

// Overall: sums over the paintings (c: CPU s, w: wall s, m: bytes; o: ours, r: RGBA8 peer,
// v: Vec4f peer, op: our pool bytes).
struct Sums {
  double oc = 0, ow = 0, rc = 0, rw = 0, vc = 0, vw = 0;
  double om = 0, op = 0, rm = 0, vm = 0;
  double mem_ratio() const { return ratio(om, rm); }
  double time_ratio() const { return ratio(oc, rc); }
};

Sums sums_of(const std::vector<Row>& rows) {
  Sums s;
  for (const auto& r : rows) {
    s.oc += r.ours.cpu;
    s.ow += r.ours.wall;
    s.rc += r.rgba8.cpu;
    s.rw += r.rgba8.wall;
    s.vc += r.vec4f.cpu;
    s.vw += r.vec4f.wall;
    s.om += double(r.ours.allocated_bytes);
    s.op += double(r.ours.pool_bytes);
    s.rm += double(r.rgba8.mem.mem_usage);
    s.vm += double(r.vec4f.mem.mem_usage);
  }
  return s;
}

void print_table(const Options& opt, const std::vector<Row>& rows, const Sums& s, int runs,
                 bool with_vec4f, double total) {
  const double mem_ratio = s.mem_ratio(), time_ratio = s.time_ratio();
  std::printf(
      "\npaint: ours (Painter::apply_stroke) vs OpenVDB (UInt32 RGBA8 grid%s), one "
      "thread each (TBB capped at 1), thread CPU time, median of %d run%s%s\n",
      with_vec4f ? "; Vec4f grid beside it, timed in one run" : "", runs, runs == 1 ? "" : "s",
      opt.quick ? " (quick subset)" : "");
  std::printf("%-19s %6s %7s %2s %8s | %8s %9s %9s | %8s %9s | %6s %6s | %8s %9s %6s %6s | %5s\n",
              "painting", "strokes", "stamps", "d", "voxel_mm", "ours_s", "ours_MB", "cells",
              "vdb_s", "vdb_MB", "mem_r", "time_r", "v4f_s", "v4f_MB", "mem_r", "time_r", "agree");
  for (const auto& r : rows) {
    std::printf(
        "%-19s %6zu %7llu %2d %8.3f | %8.3f %9.2f %9llu | %8.3f %9.2f | %6.3f %6.3f | "
        "%8.3f %9.2f %6.3f %6.3f | %5.3f\n",
        r.name.c_str(), r.strokes, (unsigned long long)r.stamps, r.finest_depth,
        r.voxel_edge_m * 1e3, r.ours.cpu, r.ours.allocated_bytes / 1e6,
        (unsigned long long)r.ours.live_cells, r.rgba8.cpu, r.rgba8.mem.mem_usage / 1e6,
        ratio(double(r.ours.allocated_bytes), double(r.rgba8.mem.mem_usage)),
        ratio(r.ours.cpu, r.rgba8.cpu), r.vec4f.cpu, r.vec4f.mem.mem_usage / 1e6,
        ratio(double(r.ours.allocated_bytes), double(r.vec4f.mem.mem_usage)),
        ratio(r.ours.cpu, r.vec4f.cpu), r.agree);
  }
  std::printf(
      "%-19s %6s %7s %2s %8s | %8.3f %9.2f %9s | %8.3f %9.2f | %6.3f %6.3f | %8.3f "
      "%9.2f %6.3f %6.3f |\n",
      "overall (sums)", "", "", "", "", s.oc, s.om / 1e6, "", s.rc, s.rm / 1e6, mem_ratio,
      time_ratio, s.vc, s.vm / 1e6, ratio(s.om, s.vm), ratio(s.oc, s.vc));
  std::printf(
      "targets: openvdb_memory_ratio <= 0.5: %s (%.3f); openvdb_time_ratio <= 1.0: %s "
      "(%.3f). %.1f s in all.\n",
      mem_ratio <= 0.5 ? "met" : "NOT met", mem_ratio, time_ratio <= 1.0 ? "met" : "NOT met",
      time_ratio, total);
}

void print_row_json(const Row& r, bool first) {
  std::printf(
      "%s{\"name\":\"%s\",\"strokes\":%zu,\"samples\":%zu,\"stamps\":%llu,\"finest_depth\":%d,"
      "\"voxel_edge_m\":%.6g,\"ours_seconds\":%.6f,\"ours_wall_seconds\":%.6f,"
      "\"ours_allocated_bytes\":%llu,\"ours_pool_bytes\":%llu,\"ours_cells\":%llu,"
      "\"ours_leaves\":%llu,\"ours_max_depth\":%d,\"ours_cells_created\":%llu,"
      "\"ours_cells_freed\":%llu,\"ours_steps\":%llu,\"ours_canvas_hash\":\"%016llx\","
      "\"openvdb_seconds\":%.6f,\"openvdb_wall_seconds\":%.6f,\"openvdb_bytes\":%llu,"
      "\"openvdb_active_voxels\":%llu,\"openvdb_leaf_nodes\":%llu,\"openvdb_active_tiles\":%llu,"
      "\"openvdb_cells_filled\":%llu,\"openvdb_memory_ratio\":%.6f,\"openvdb_time_ratio\":%.6f,"
      "\"ours_pool_bytes_ratio\":%.6f",
      first ? "" : ",", r.name.c_str(), r.strokes, r.samples, (unsigned long long)r.stamps,
      r.finest_depth, r.voxel_edge_m, r.ours.cpu, r.ours.wall,
      (unsigned long long)r.ours.allocated_bytes, (unsigned long long)r.ours.pool_bytes,
      (unsigned long long)r.ours.live_cells, (unsigned long long)r.ours.leaves, r.ours.max_depth,
      (unsigned long long)r.ours.cells_created, (unsigned long long)r.ours.cells_freed,
      (unsigned long long)r.ours.steps, (unsigned long long)r.ours.canvas_hash, r.rgba8.cpu,
      r.rgba8.wall, (unsigned long long)r.rgba8.mem.mem_usage,
      (unsigned long long)r.rgba8.mem.active_voxels, (unsigned long long)r.rgba8.mem.leaf_nodes,
      (unsigned long long)r.rgba8.mem.active_tiles, (unsigned long long)r.rgba8.stats.cells,
      ratio(double(r.ours.allocated_bytes), double(r.rgba8.mem.mem_usage)),
      ratio(r.ours.cpu, r.rgba8.cpu),
      ratio(double(r.ours.pool_bytes), double(r.rgba8.mem.mem_usage)));
  if (r.have_vec4f)
    std::printf(
        ",\"openvdb_vec4f_seconds\":%.6f,\"openvdb_vec4f_bytes\":%llu,"
        "\"openvdb_vec4f_memory_ratio\":%.6f,\"openvdb_vec4f_time_ratio\":%.6f",
        r.vec4f.cpu, (unsigned long long)r.vec4f.mem.mem_usage,
        ratio(double(r.ours.allocated_bytes), double(r.vec4f.mem.mem_usage)),
        ratio(r.ours.cpu, r.vec4f.cpu));
  std::printf(",\"agreement\":%.4f,\"agreement_points\":%zu}", r.agree, r.agree_checked);
}

void print_json(const Options& opt, const std::vector<Row>& rows, const Sums& s, int runs,
                bool with_vec4f, double total) {
  const double mem_ratio = s.mem_ratio(), time_ratio = s.time_ratio();
  std::printf(
      "{\"suite\":\"paint\",\"quick\":%s,\"runs\":%d,\"threads\":1,\"tbb_max_parallelism\":1,"
      "\"clock\":\"thread_cpu_time\",\"placement\":{\"scale\":1,\"offset\":[0,0,0]},"
      "\"peer\":\"openvdb UInt32Grid holding RGBA8 cells (tree 5-4-3), voxel = finest cell, "
      "fill per rasterized cell, stroke layer FloatGrid (max), prune at end\","
      "\"peer_vec4f\":%s,\"peer_vec4f_runs\":%d,\"memory_ours\":\"Octree::allocated_bytes\","
      "\"memory_openvdb\":\"Grid::memUsage after prune\",\"paintings\":[",
      opt.quick ? "true" : "false", runs, with_vec4f ? "true" : "false", with_vec4f ? 1 : 0);
  for (std::size_t i = 0; i < rows.size(); ++i) print_row_json(rows[i], i == 0);
  std::printf(
      "],\"ours_seconds\":%.6f,\"ours_allocated_bytes\":%.0f,\"ours_pool_bytes\":%.0f,"
      "\"openvdb_seconds\":%.6f,\"openvdb_bytes\":%.0f,\"openvdb_memory_ratio\":%.6f,"
      "\"openvdb_time_ratio\":%.6f,\"memory_target\":0.5,\"time_target\":1.0,"
      "\"memory_target_met\":%s,\"time_target_met\":%s",
      s.oc, s.om, s.op, s.rc, s.rm, mem_ratio, time_ratio, mem_ratio <= 0.5 ? "true" : "false",
      time_ratio <= 1.0 ? "true" : "false");
  if (with_vec4f)
    std::printf(
        ",\"openvdb_vec4f_seconds\":%.6f,\"openvdb_vec4f_bytes\":%.0f,"
        "\"openvdb_vec4f_memory_ratio\":%.6f,\"openvdb_vec4f_time_ratio\":%.6f",
        s.vc, s.vm, ratio(s.om, s.vm), ratio(s.oc, s.vc));
  std::printf(",\"ours_wall_seconds\":%.6f,\"openvdb_wall_seconds\":%.6f,\"seconds\":%.2f}\n", s.ow,
              s.rw, total);
}

int paint_main(const Options& opt, const PaintOptions& po) {
  const int runs = po.runs > 0 ? po.runs : opt.quick ? 1 : 3;
  const bool with_vec4f = !po.no_vec4f;
  const std::vector<std::string> names = painting_names(po, opt.quick);
  auto dir = paintings_dir();
  if (!dir) return fail(opt, dir.error().message);
  // One thread for everything OpenVDB (and TBB) might parallelise.
  tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
  openvdb::initialize();
  auto progress = bench::progress(opt, "paint", double(names.size() * runs), "runs");
  const auto geo = server_core::CanvasGeometry::of(OctreeConfig{});
  const server_core::StampParams sp{};
  const auto start = Clock::now();
  std::vector<Row> rows;
  for (const auto& name : names) {
    auto in = load(*dir, name, geo, sp);
    if (!in) return fail(opt, in.error().message);
    auto row =
        measure_painting(opt, *in, geo.cell_edge(in->finest_depth), runs, with_vec4f, progress);
    if (!row) return fail(opt, row.error().message);
    rows.push_back(std::move(*row));
  }
  const double total = wall_since(start);
  progress.finish();
  const Sums sums = sums_of(rows);
  if (opt.json)
    print_json(opt, rows, sums, runs, with_vec4f, total);
  else
    print_table(opt, rows, sums, runs, with_vec4f, total);
  return 0;
}

SuiteRun setup(CLI::App& app) {
  auto po = std::make_shared<PaintOptions>();
  app.add_option("--paintings", po->paintings,
                 "file names without .apa (default: all in DEEPCANVAS_PAINTINGS; --quick: demo, "
                 "mozfest, mozilla, palmtree)")
      ->delimiter(',')
      ->type_name("a,b,c");
  app.add_option("--runs", po->runs, "timed runs per painting (default 3; --quick 1)")
      ->transform(number(1, 1000, true))
      ->type_name("N");
  app.add_flag("--no-vec4f", po->no_vec4f, "skip the Vec4f OpenVDB peer");
  return [po](const Options& opt) { return paint_main(opt, *po); };
}

}  // namespace

DEEPCANVAS_BENCH_SUITE(Suite{
    "paint", "real paintings into our octree vs an OpenVDB grid: time, memory, ratios",
    "examples:\n"
    "  deepcanvas-bench paint --quick\n"
    "  deepcanvas-bench paint --paintings demo,palmtree --runs 5 --json\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder)\n",
    setup});

}  // namespace deepcanvas::bench
