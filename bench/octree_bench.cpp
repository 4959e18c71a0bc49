// deepcanvas-bench octree: memory and speed of the dynamic deep octree (issue 3).
//
// Workloads (all single-threaded, one core):
// - "stroke bursts": 16 spheres (stamps) along a short path; every leaf a stamp touches is
//   refined level by level until its cell edge is about radius/5 (about ten cells across the
//   stamp, as painting does; 10^4..10^5 cells a stroke as in the paper), 2:1 balance cascades
//   included; erasing coarsens the same region bottom-up.
//   Only the refine()/coarsen() calls are timed; finding the leaves to change is not.
// - a uniform build (breadth-first refinement of every leaf) to reach 1M / 16M / 64M cells.
// Timing: the machine is shared (other builds run beside the benchmark), so refine/coarsen are
// timed in thread CPU time over large batches: each workload is first run on one tree while
// recording the exact refine()/coarsen() calls it makes (finding the leaves is untimed), then
// replayed on an identically built twin tree (allocation is deterministic, so indices match;
// the replay checks every result and the final pool_hash). Every figure is a median over runs.
#include <sys/resource.h>

#include <stdlib.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "bench.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::bench {
namespace {

using server_core::Aabb;
using server_core::BlockId;
using server_core::CellCoord;
using server_core::CellIndex;
using server_core::kNoCell;
using server_core::Octree;
using server_core::OctreeConfig;
using server_core::Vec3d;
using Clock = std::chrono::steady_clock;

double secs(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

std::unique_ptr<Octree> make_tree(std::uint32_t block_cells = 4096) {
  OctreeConfig cfg;
  cfg.block_cells = block_cells;
  auto r = Octree::create(cfg);
  if (!r.ok()) {
    std::fprintf(stderr, "octree: %s\n", r.error().message.c_str());
    std::abort();
  }
  return std::move(r).value();
}

struct Sphere {
  Vec3d c;
  double r;
};

bool touches(const Aabb& b, const Sphere& s) {
  auto d = [](double v, double lo, double hi) { return v < lo ? lo - v : v > hi ? v - hi : 0.0; };
  const double dx = d(s.c.x, b.min.x, b.max.x), dy = d(s.c.y, b.min.y, b.max.y),
               dz = d(s.c.z, b.min.z, b.max.z);
  return dx * dx + dy * dy + dz * dz <= s.r * s.r;
}


int depth_for(const Octree& t, double radius) {
  int d = 0;
  while (d < t.config().max_depth && t.cell_edge_m(d) > radius / 5) ++d;
  return d;
}

// Cells touching the sphere: leaves shallower than dmax (want_leaves), or internal cells whose
// children are all leaves (coarsening candidates).
void collect(const Octree& t, const Sphere& s, int dmax, bool want_leaves,
             std::vector<CellIndex>& out, std::vector<std::pair<CellIndex, CellCoord>>& stack) {
  out.clear();
  stack.clear();
  const std::uint32_t n = t.config().roots_per_axis;
  for (CellIndex r = 0; r < t.root_count(); ++r) {
    const CellCoord k{0, r % n, (r / n) % n, r / (n * n)};
    if (touches(t.bounds_m(k), s)) stack.push_back({r, k});
  }
  while (!stack.empty()) {
    auto [c, k] = stack.back();
    stack.pop_back();
    const CellIndex fc = t.first_child(c);
    if (fc == kNoCell) {
      if (want_leaves && k.depth < dmax) out.push_back(c);
      continue;
    }
    if (!want_leaves) {
      bool all_leaves = true;
      for (int i = 0; i < 8 && all_leaves; ++i) all_leaves = t.is_leaf(fc + i);
      if (all_leaves) {
        out.push_back(c);
        continue;
      }
    }
    for (std::uint32_t i = 0; i < 8; ++i) {
      const CellCoord ck = child_coord(k, i);
      if (touches(t.bounds_m(ck), s)) stack.push_back({fc + i, ck});
    }
  }
}

struct Timed {
  double seconds = 0;
  std::uint64_t cells = 0;
  std::uint64_t calls = 0;
};

struct Scratch {
  std::vector<CellIndex> cells;
  std::vector<std::pair<CellIndex, CellCoord>> stack;
  std::vector<CellIndex>* record = nullptr;  // when set, every refine/coarsen call is appended
};

// Refines every leaf the sphere touches down to dmax; times only the refine() calls.
void refine_sphere(Octree& t, const Sphere& s, int dmax, Timed& acc, Scratch& sc) {
  for (;;) {
    collect(t, s, dmax, true, sc.cells, sc.stack);
    if (sc.cells.empty()) return;
    std::uint64_t made_total = 0, calls = 0;
    const auto t0 = Clock::now();
    for (CellIndex c : sc.cells) {
      if (!t.is_leaf(c)) continue;  // refined by a balance cascade already
      std::uint64_t made = 0;
      if (!t.refine(c, &made).ok()) return;
      if (sc.record) sc.record->push_back(c);
      made_total += made;
      ++calls;
    }
    acc.seconds += secs(t0, Clock::now());
    acc.cells += made_total;
    acc.calls += calls;
  }
}

// Coarsens bottom-up everything the sphere touches (as far as 2:1 balance allows).
void erase_sphere(Octree& t, const Sphere& s, Timed& acc, Scratch& sc) {
  for (;;) {
    collect(t, s, 0, false, sc.cells, sc.stack);
    std::uint64_t removed = 0;
    const auto t0 = Clock::now();
    for (CellIndex c : sc.cells) {
      if (t.coarsen(c).ok()) removed += 8;
      if (sc.record) sc.record->push_back(c);
    }
    acc.seconds += secs(t0, Clock::now());
    acc.cells += removed;
    acc.calls += sc.cells.size();
    if (removed == 0) return;
  }
}

// A stroke: `stamps` spheres along a straight path, spaced by the radius.
std::vector<Sphere> stroke(std::mt19937_64& rng, Vec3d start, double r, int stamps) {
  std::normal_distribution<double> g(0, 1);
  Vec3d dir{g(rng), g(rng), g(rng)};
  const double len = std::sqrt(dir.x * dir.x + dir.y * dir.y + dir.z * dir.z);
  std::vector<Sphere> out;
  for (int i = 0; i < stamps; ++i) {
    Vec3d c{start.x + dir.x / len * r * i, start.y + dir.y / len * r * i,
            start.z + dir.z / len * r * i};
    c.x = std::clamp(c.x, -9999.0, 9999.0);
    c.y = std::clamp(c.y, -9999.0, 9999.0);
    c.z = std::clamp(c.z, -9999.0, 9999.0);
    out.push_back({c, r});
  }
  return out;
}

Vec3d random_point(std::mt19937_64& rng, double half) {
  std::uniform_real_distribution<double> u(-half, half);
  return {u(rng), u(rng), u(rng)};
}

double log_uniform(std::mt19937_64& rng, double lo, double hi) {
  std::uniform_real_distribution<double> u(std::log(lo), std::log(hi));
  return std::exp(u(rng));
}

// Breadth-first refinement of every leaf until `target` live cells (no balance cascades).
Timed build_uniform(Octree& t, std::uint64_t target) {
  Timed acc;
  std::vector<CellIndex> level, next;
  for (CellIndex r = 0; r < t.root_count(); ++r) level.push_back(r);
  while (t.live_cells() < target && !level.empty()) {
    next.clear();
    const double t0 = thread_cpu_seconds();
    for (CellIndex c : level) {
      if (t.live_cells() >= target) break;
      std::uint64_t made = 0;
      if (!t.refine(c, &made).ok()) break;
      acc.cells += made;
      ++acc.calls;
    }
    acc.seconds += thread_cpu_seconds() - t0;
    for (CellIndex c : level) {
      const CellIndex fc = t.first_child(c);
      if (fc != kNoCell)
        for (int i = 0; i < 8; ++i) next.push_back(fc + i);
    }
    level.swap(next);
  }
  return acc;
}

// A painting-like history: strokes of random sizes at random places, some erased again.
void random_history(Octree& t, std::mt19937_64& rng, std::uint64_t target_cells, Scratch& sc) {
  Timed ignore;
  std::vector<std::vector<Sphere>> done;
  while (t.live_cells() < target_cells) {
    const double r = log_uniform(rng, 0.05, 500.0);
    auto s = stroke(rng, random_point(rng, 9000), r, 6);
    const int d = depth_for(t, r);
    for (const auto& sp : s) refine_sphere(t, sp, d, ignore, sc);
    done.push_back(std::move(s));
    if (std::uniform_real_distribution<double>(0, 1)(rng) < 0.3 && !done.empty()) {
      const std::size_t i = std::uniform_int_distribution<std::size_t>(0, done.size() - 1)(rng);
      for (const auto& sp : done[i]) erase_sphere(t, sp, ignore, sc);
      done.erase(done.begin() + static_cast<std::ptrdiff_t>(i));
    }
  }
}

std::uint64_t rss_bytes() {
  FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0;
  unsigned long long size = 0, rss = 0;
  if (std::fscanf(f, "%llu %llu", &size, &rss) != 2) rss = 0;
  std::fclose(f);
  return rss * 4096ull;
}

// ---------------------------------------------------------------------------------------------

// Replays recorded calls on a twin tree; returns CPU seconds, adds created/removed cells.
double replay(Octree& t, const std::vector<CellIndex>& ops, bool refine, std::uint64_t& cells,
              double* wall = nullptr) {
  const auto w0 = Clock::now();
  const double t0 = thread_cpu_seconds();
  if (refine) {
    for (CellIndex c : ops) {
      std::uint64_t made = 0;
      if (!t.refine(c, &made).ok()) {
        std::fprintf(stderr, "octree bench: replay diverged (refine)\n");
        std::abort();
      }
      cells += made;
    }
  } else {
    for (CellIndex c : ops)
      if (t.coarsen(c).ok()) cells += 8;
  }
  const double cpu = thread_cpu_seconds() - t0;
  if (wall) *wall += secs(w0, Clock::now());
  return cpu;
}

void expect_twins(const Octree& a, const Octree& b) {
  if (a.pool_hash() != b.pool_hash()) {
    std::fprintf(stderr, "octree bench: twin trees diverged\n");
    std::abort();
  }
}

struct BurstRates {
  double refine_cells_per_s;
  double coarsen_cells_per_s;
  double refine_cells_per_stroke;
  double refine_cells_per_wall_s;  // the same, wall clock (inflated when the core is shared)
};

// Stroke bursts (refine, then erase) on a canvas that already holds a painting-like history.
BurstRates stroke_rates(std::uint64_t seed, std::uint64_t history_cells, int strokes) {
  auto rec = make_tree();
  auto twin = make_tree();
  Scratch sc;
  {
    std::mt19937_64 rng(seed);
    random_history(*rec, rng, history_cells, sc);
  }
  {
    std::mt19937_64 rng(seed);
    random_history(*twin, rng, history_cells, sc);
  }
  std::mt19937_64 rng(seed + 1);
  Timed ignore;
  double ref_s = 0, coa_s = 0, ref_wall = 0;
  std::uint64_t ref_cells = 0, coa_cells = 0;
  std::vector<CellIndex> ops;
  sc.record = &ops;
  for (int i = 0; i < strokes; ++i) {
    const double r = log_uniform(rng, 0.01, 50.0);
    auto s = stroke(rng, random_point(rng, 9000), r, 16);
    const int d = depth_for(*rec, r);
    ops.clear();
    for (const auto& sp : s) refine_sphere(*rec, sp, d, ignore, sc);
    ref_s += replay(*twin, ops, true, ref_cells, &ref_wall);
    ops.clear();
    for (const auto& sp : s) erase_sphere(*rec, sp, ignore, sc);
    coa_s += replay(*twin, ops, false, coa_cells);
  }
  sc.record = nullptr;
  expect_twins(*rec, *twin);
  return {double(ref_cells) / ref_s, double(coa_cells) / coa_s, double(ref_cells) / strokes,
          double(ref_cells) / ref_wall};
}

// Per-created-cell refine time of `strokes` stroke bursts. Scattered: every stroke starts at a
// random place in the canvas (its region is cold in a big tree: the worst case). Clustered: each
// stroke starts near where the previous one ended, as when an artist works on one area (the
// region a session paints stays warm).
double burst_ns_per_cell(Octree& rec, Octree& twin, std::uint64_t seed, int strokes,
                         bool scattered) {
  std::mt19937_64 rng(seed);
  Scratch sc;
  Timed ignore;
  std::vector<CellIndex> ops;
  sc.record = &ops;
  Vec3d at = random_point(rng, 9000);
  for (int i = 0; i < strokes; ++i) {
    const double r = log_uniform(rng, 0.05, 20.0);
    if (scattered) {
      at = random_point(rng, 9000);
    } else {
      const Vec3d jump = random_point(rng, 4 * r);
      at = {std::clamp(at.x + jump.x, -9000.0, 9000.0), std::clamp(at.y + jump.y, -9000.0, 9000.0),
            std::clamp(at.z + jump.z, -9000.0, 9000.0)};
    }
    auto s = stroke(rng, at, r, 16);
    at = s.back().c;
    const int d = depth_for(rec, r);
    for (const auto& sp : s) refine_sphere(rec, sp, d, ignore, sc);
  }
  // Replayed stroke by stroke would need per-stroke timers; the whole round is one batch.
  std::uint64_t cells = 0;
  const double sec = replay(twin, ops, true, cells);
  return sec * 1e9 / double(cells);
}

struct NavTimes {
  double locate_ns, neighbour_ns, g3_ns, mean_depth;
};

NavTimes navigation(std::uint64_t seed, int runs, std::size_t queries) {
  auto t = make_tree();
  std::mt19937_64 rng(seed);
  Scratch sc;
  Timed ignore;
  std::vector<Sphere> regions;
  for (int i = 0; i < 16; ++i) {
    const double r = t->cell_edge_m(24) * 8;
    Sphere s{random_point(rng, 9999.9), r};
    if (i == 0) s.c = {9999.99, -9999.99, 9999.99};  // next to a canvas corner
    refine_sphere(*t, s, 24, ignore, sc);
    regions.push_back(s);
  }
  std::vector<Vec3d> pts;
  std::uniform_real_distribution<double> u(-1, 1);
  while (pts.size() < queries) {
    const Sphere& s = regions[pts.size() % regions.size()];
    pts.push_back(
        {s.c.x + u(rng) * s.r * 0.5, s.c.y + u(rng) * s.r * 0.5, s.c.z + u(rng) * s.r * 0.5});
  }
  std::shuffle(pts.begin(), pts.end(), rng);
  std::vector<CellIndex> cells;
  double depth_sum = 0;
  for (const auto& p : pts) {
    auto r = t->locate(p, 24);
    cells.push_back(r->cell);
    depth_sum += r->coord.depth;
  }
  std::vector<int> faces(queries);
  for (auto& f : faces) f = static_cast<int>(rng() % 6);
  std::vector<double> loc, nb, g3;
  std::uint64_t sink = 0;
  for (int run = 0; run < runs; ++run) {
    const double t0 = thread_cpu_seconds();
    for (const auto& p : pts) sink += t->locate(p, 24)->cell;
    const double t1 = thread_cpu_seconds();
    for (std::size_t i = 0; i < cells.size(); ++i) sink += t->face_neighbour(cells[i], faces[i]);
    const double t2 = thread_cpu_seconds();
    for (std::size_t i = 0; i < cells.size(); ++i) sink += t->g3(cells[i], faces[i] >> 1);
    const double t3 = thread_cpu_seconds();
    loc.push_back((t1 - t0) * 1e9 / double(queries));
    nb.push_back((t2 - t1) * 1e9 / double(queries));
    g3.push_back((t3 - t2) * 1e9 / double(queries));
  }
  if (sink == 42) std::fprintf(stderr, " ");
  return {median(loc), median(nb), median(g3), depth_sum / double(queries)};
}

struct BlockChoice {
  std::uint32_t block_cells;
  double dirty_blocks_per_stroke;
  double staging_bytes_per_stroke;
  double cells_changed_per_stroke;
  double dirty_blocks_per_stamp;
  double staging_bytes_per_stamp;
  double cells_changed_per_stamp;
};

// Same history and strokes for each block size: distinct dirty blocks per stroke (refine burst
// and, separately, erase burst) and the bytes a stager copies for them (the four replicated
// pools, 8.625 B a cell, plus one mask bit per group).
std::vector<BlockChoice> block_choice(std::uint64_t history_cells, int strokes) {
  std::vector<BlockChoice> out;
  for (std::uint32_t bc : {1024u, 4096u, 16384u}) {
    auto t = make_tree(bc);
    std::mt19937_64 rng(77);
    Scratch sc;
    random_history(*t, rng, history_cells, sc);
    std::vector<double> blocks, bytes, cells, sblocks, sbytes, scells;
    Timed acc;
    const double block_bytes = bc * 8.625 + bc / 64.0;
    for (int i = 0; i < strokes; ++i) {
      const double r = log_uniform(rng, 0.01, 20.0);
      auto s = stroke(rng, random_point(rng, 9000), r, 16);
      const int d = depth_for(*t, r);
      for (int phase = 0; phase < 2; ++phase) {
        t->take_dirty_blocks();
        const std::uint64_t before = acc.cells;
        std::vector<BlockId> all;
        for (const auto& sp : s) {
          const std::uint64_t sb = acc.cells;
          if (phase == 0)
            refine_sphere(*t, sp, d, acc, sc);
          else
            erase_sphere(*t, sp, acc, sc);
          // Per stamp: what a stager publishing after every stamp would copy.
          const auto dirty = t->take_dirty_blocks();
          all.insert(all.end(), dirty.begin(), dirty.end());
          if (acc.cells == sb) continue;
          sblocks.push_back(double(dirty.size()));
          sbytes.push_back(double(dirty.size()) * block_bytes);
          scells.push_back(double(acc.cells - sb));
        }
        std::sort(all.begin(), all.end());
        const double distinct = double(std::unique(all.begin(), all.end()) - all.begin());
        blocks.push_back(distinct);
        bytes.push_back(distinct * block_bytes);
        cells.push_back(double(acc.cells - before));
      }
    }
    out.push_back({bc, median(blocks), median(bytes), median(cells), median(sblocks),
                   median(sbytes), median(scells)});
  }
  return out;
}

// Persistent pool bytes per cell: first_child + colour per cell, parent + depth_flags + six
// links per group of eight.
constexpr double kBytesPerCell = 4 + 4 + (4 + 1 + 24) / 8.0;
constexpr double kBytesPerCellReplicated = 4 + 4 + (4 + 1) / 8.0;

// Refine and coarsen rates, one entry per run.
struct RefineRates {
  std::vector<double> build, refine, coarsen, per_stroke, refine_wall;
};

// Raw refine throughput: uniform breadth-first build (no cascades); then stroke bursts with
// balance and erasure. `progress` advances by one per run.
RefineRates measure_refine(const Options& opt, int runs, base::Progress& progress,
                           const std::function<void(const char*)>& phase) {
  const bool q = opt.quick;
  RefineRates out;
  phase("uniform build");
  for (int i = 0; i < runs; ++i) {
    auto t = make_tree();
    const Timed b = build_uniform(*t, q ? 4u << 20 : 16u << 20);
    out.build.push_back(b.cells / b.seconds);
    progress.add(1);
  }
  phase("stroke bursts (refine / coarsen)");
  for (int i = 0; i < runs; ++i) {
    const BurstRates r = stroke_rates(100 + i, q ? 500000 : 2000000, q ? 20 : 40);
    out.refine.push_back(r.refine_cells_per_s);
    out.coarsen.push_back(r.coarsen_cells_per_s);
    out.per_stroke.push_back(r.refine_cells_per_stroke);
    out.refine_wall.push_back(r.refine_cells_per_wall_s);
    progress.add(1);
  }
  return out;
}

struct MemoryFigures {
  double alloc_per_live = 0, rss_per_live = 0, hw_over_live = 0;
  std::uint64_t live = 0;
};

// Memory after a painting-like random workload of a few million cells.
MemoryFigures measure_memory(bool quick) {
  MemoryFigures m;
  const std::uint64_t rss0 = rss_bytes();
  auto t = make_tree();
  std::mt19937_64 rng(5);
  Scratch sc;
  random_history(*t, rng, quick ? 2000000 : 4000000, sc);
  m.live = t->live_cells();
  m.alloc_per_live = double(t->allocated_bytes()) / double(m.live);
  m.hw_over_live = double(t->high_water_cells()) / double(m.live);
  const std::uint64_t rss1 = rss_bytes();
  m.rss_per_live = double(rss1 > rss0 ? rss1 - rss0 : 0) / double(m.live);
  return m;
}

struct GrowthFigures {
  std::uint64_t small = 0, large = 0;  // cells of the two trees
  std::vector<double> clustered, scattered, small_ns, large_ns;
};

// Refine time per cell on a large tree vs a small one. Both trees live side by side; rounds
// alternate between them with the same strokes (same seeds), so load from other processes hits
// both alike; the ratio is taken per round. `progress` advances by one per round.
GrowthFigures measure_size_growth(bool quick, int rounds, base::Progress& progress) {
  GrowthFigures g;
  g.small = 1u << 20;
  g.large = quick ? 16u << 20 : 64u << 20;
  auto ts = make_tree(), ts2 = make_tree();
  build_uniform(*ts, g.small);
  build_uniform(*ts2, g.small);
  auto tl = make_tree(), tl2 = make_tree();
  build_uniform(*tl, g.large);
  build_uniform(*tl2, g.large);
  for (int i = 0; i < rounds; ++i) {
    const std::uint64_t seed = 300 + i;
    const int k = quick ? 12 : 24;
    const double sc1 = burst_ns_per_cell(*ts, *ts2, seed, k, false);
    const double lc1 = burst_ns_per_cell(*tl, *tl2, seed, k, false);
    const double ls1 = burst_ns_per_cell(*tl, *tl2, seed + 1000, k, true);
    const double ss1 = burst_ns_per_cell(*ts, *ts2, seed + 1000, k, true);
    g.clustered.push_back(lc1 / sc1);
    g.scattered.push_back(ls1 / ss1);
    g.small_ns.push_back(sc1);
    g.large_ns.push_back(lc1);
    progress.add(1);
  }
  expect_twins(*ts, *ts2);
  expect_twins(*tl, *tl2);
  return g;
}

struct OctreeFigures {
  RefineRates rates;
  MemoryFigures memory;
  NavTimes nav;
  GrowthFigures growth;
  std::vector<BlockChoice> blocks;
  int runs = 0;
  double seconds = 0;
};

void print_text(const Options& opt, const OctreeFigures& f) {
  const RefineRates& r = f.rates;
  const MemoryFigures& m = f.memory;
  std::printf("octree (one core%s)\n", opt.quick ? ", quick" : "");
  std::printf(
      "  bytes_per_cell                 %.3f (target <= 16; %.3f replicated without links)\n",
      kBytesPerCell, kBytesPerCellReplicated);
  std::printf(
      "  allocated_bytes_per_live_cell  %.2f (target <= 20; RSS-based %.2f; %llu live, "
      "high water / live %.3f)\n",
      m.alloc_per_live, m.rss_per_live, (unsigned long long)m.live, m.hw_over_live);
  std::printf(
      "  refine_cells_per_s             %.3g (stroke bursts; uniform build %.3g; target >= "
      "2e7)\n",
      median(r.refine), median(r.build));
  std::printf("  coarsen_cells_per_s            %.3g\n", median(r.coarsen));
  std::printf("  locate_ns / neighbour_ns / g3  %.1f / %.1f / %.1f (mean depth %.2f)\n",
              f.nav.locate_ns, f.nav.neighbour_ns, f.nav.g3_ns, f.nav.mean_depth);
  std::printf(
      "  size_growth_ratio              %.3f clustered strokes, %.3f scattered (%llu vs %llu "
      "cells; target <= 1.2)\n",
      median(f.growth.clustered), median(f.growth.scattered), (unsigned long long)f.growth.large,
      (unsigned long long)f.growth.small);
  for (const auto& b : f.blocks)
    std::printf(
        "  block %5u: stroke %.1f dirty blocks %.0f staging B (%.0f cells); "
        "stamp %.1f blocks %.0f B (%.0f cells)\n",
        b.block_cells, b.dirty_blocks_per_stroke, b.staging_bytes_per_stroke,
        b.cells_changed_per_stroke, b.dirty_blocks_per_stamp, b.staging_bytes_per_stamp,
        b.cells_changed_per_stamp);
  std::printf("  %.1f s\n", f.seconds);
}

void print_json(const Options& opt, const OctreeFigures& f) {
  const RefineRates& r = f.rates;
  const MemoryFigures& m = f.memory;
  std::printf("{\"suite\":\"octree\",\"quick\":%s,\"threads\":1,\"clock\":\"thread_cpu_time\",",
              opt.quick ? "true" : "false");
  std::printf("\"bytes_per_cell\":%.4f,\"bytes_per_cell_replicated\":%.4f,", kBytesPerCell,
              kBytesPerCellReplicated);
  std::printf(
      "\"allocated_bytes_per_live_cell\":%.3f,\"rss_bytes_per_live_cell\":%.3f,"
      "\"high_water_over_live\":%.4f,\"memory_workload_live_cells\":%llu,",
      m.alloc_per_live, m.rss_per_live, m.hw_over_live, (unsigned long long)m.live);
  std::printf(
      "\"refine_cells_per_s\":%.0f,\"refine_uniform_build_cells_per_s\":%.0f,"
      "\"coarsen_cells_per_s\":%.0f,\"refine_cells_per_stroke\":%.0f,"
      "\"refine_cells_per_s_wall_clock\":%.0f,",
      median(r.refine), median(r.build), median(r.coarsen), median(r.per_stroke),
      median(r.refine_wall));
  std::printf("\"locate_ns\":%.2f,\"neighbour_ns\":%.2f,\"g3_ns\":%.2f,\"locate_mean_depth\":%.3f,",
              f.nav.locate_ns, f.nav.neighbour_ns, f.nav.g3_ns, f.nav.mean_depth);
  std::printf(
      "\"size_growth_ratio\":%.4f,\"size_growth_ratio_scattered\":%.4f,"
      "\"size_growth_cells\":[%llu,%llu],"
      "\"refine_ns_per_cell_small\":%.3f,\"refine_ns_per_cell_large\":%.3f,",
      median(f.growth.clustered), median(f.growth.scattered), (unsigned long long)f.growth.small,
      (unsigned long long)f.growth.large, median(f.growth.small_ns), median(f.growth.large_ns));
  std::printf("\"block_size_choice\":[");
  for (std::size_t i = 0; i < f.blocks.size(); ++i)
    std::printf(
        "%s{\"block_cells\":%u,\"dirty_blocks_per_burst\":%.2f,"
        "\"staging_bytes_per_burst\":%.0f,\"cells_changed_per_burst\":%.0f,"
        "\"dirty_blocks_per_stamp\":%.2f,\"staging_bytes_per_stamp\":%.0f,"
        "\"cells_changed_per_stamp\":%.0f}",
        i ? "," : "", f.blocks[i].block_cells, f.blocks[i].dirty_blocks_per_stroke,
        f.blocks[i].staging_bytes_per_stroke, f.blocks[i].cells_changed_per_stroke,
        f.blocks[i].dirty_blocks_per_stamp, f.blocks[i].staging_bytes_per_stamp,
        f.blocks[i].cells_changed_per_stamp);
  double load[3] = {0, 0, 0};
  if (getloadavg(load, 3) < 1) load[0] = -1;
  std::printf(
      "],\"targets\":{\"bytes_per_cell_max\":16,\"allocated_bytes_per_live_cell_max\":20,"
      "\"refine_cells_per_s_min\":2e7,\"size_growth_ratio_max\":1.2},"
      "\"runs\":%d,\"load_average_1m\":%.2f,\"seconds\":%.2f}\n",
      f.runs, load[0], f.seconds);
}

int run(const Options& opt) {
  const bool q = opt.quick;
  const int runs = q ? 3 : 5;
  const int rounds = q ? 5 : 9;  // size growth rounds
  const auto start = Clock::now();
  // Units: one per timed run or round, one per memory / navigation / block size phase.
  auto progress = bench::progress(opt, "octree", double(2 * runs + 2 + rounds + 1), "steps");
  auto phase = [&](const char* what) {
    note(opt, "octree: %5.1f s: %s\n", secs(start, Clock::now()), what);
  };
  OctreeFigures f;
  f.runs = runs;
  f.rates = measure_refine(opt, runs, progress, phase);
  phase("memory after a random workload");
  f.memory = measure_memory(q);
  progress.add(1);
  phase("locate / neighbour at depth 24");
  f.nav = navigation(9, runs, q ? 200000 : 1000000);
  progress.add(1);
  phase("size growth");
  f.growth = measure_size_growth(q, rounds, progress);
  phase("block size choice");
  f.blocks = block_choice(q ? 500000 : 2000000, q ? 12 : 30);
  progress.add(1);
  progress.finish();
  f.seconds = secs(start, Clock::now());
  if (opt.json)
    print_json(opt, f);
  else
    print_text(opt, f);
  return 0;
}

DEEPCANVAS_BENCH_SUITE(Suite{"octree",
                             "dynamic deep octree: memory, refine/coarsen, locate, growth",
                             "examples:\n"
                             "  deepcanvas-bench octree --quick\n"
                             "  deepcanvas-bench octree --json > octree.json\n",
                             no_options(run)});

}  // namespace
}  // namespace deepcanvas::bench
