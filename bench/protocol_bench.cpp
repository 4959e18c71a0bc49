// deepcanvas-bench protocol: block frame compression ratio and speed by zstd level, with and
// without the delta + byte-plane transform, on blocks of a synthetic painted octree.
//
// The octree is grown the way the server grows one: 64 roots, groups of eight allocated from a
// LIFO free list or the end of the pools, strokes that refine the leaves they touch down to a
// depth set by the brush radius (children inherit the colour), paint the leaves inside the brush,
// and erase strokes that coarsen (free groups, later reused). The pools are cut into blocks of
// 4096 cells, the server's block size, and every block is encoded as a late joiner receives it.
// Ratio = raw payload bytes / frame bytes (header included); speeds are raw bytes per second,
// medians over several runs of one thread's CPU time.
//
// With a real painting (--painting FILE.apa, or demo.apa in $DEEPCANVAS_PAINTINGS) the suite also
// paints it stroke by stroke with server_core's Octree + Painter and measures (a) the live
// stream: after every stroke, the dirty blocks encoded as the server sends them, and (b) the
// final snapshot a late joiner receives.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <zlib.h>

#include "bench.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace dp = deepcanvas::protocol;

namespace {

constexpr std::uint32_t kNone = dp::kNoCellWire;
constexpr std::uint32_t kBlockCells = 4096;

struct SyntheticTree {
  std::vector<std::uint32_t> first_child, colour, group_parent;
  std::vector<std::uint8_t> depth_flags;
  std::vector<std::uint64_t> mask;  // one bit per group, set for groups created/freed lately
  std::vector<double> cx, cy, cz;   // cell centres (bench only; not a wire field)
  std::vector<std::uint32_t> free_groups;
  double edge = 20000.0;
  std::uint32_t roots_per_axis = 4;

  SyntheticTree() {
    const std::uint32_t n = roots_per_axis;
    const double e = edge / n;
    for (std::uint32_t z = 0; z < n; ++z)
      for (std::uint32_t y = 0; y < n; ++y)
        for (std::uint32_t x = 0; x < n; ++x) {
          first_child.push_back(kNone);
          colour.push_back(0);
          cx.push_back(-edge / 2 + (x + 0.5) * e);
          cy.push_back(-edge / 2 + (y + 0.5) * e);
          cz.push_back(-edge / 2 + (z + 0.5) * e);
        }
    for (std::uint32_t g = 0; g < n * n * n / 8; ++g) {
      group_parent.push_back(kNone);
      depth_flags.push_back(0);
    }
  }
  int depth(std::uint32_t c) const { return depth_flags[c / 8] & 0x1F; }
  double cell_edge(int d) const { return edge / roots_per_axis / std::ldexp(1.0, d); }
  void mark(std::uint32_t g) {
    if (mask.size() <= g / 64) mask.resize(g / 64 + 1, 0);
    mask[g / 64] |= std::uint64_t{1} << (g % 64);
  }

  void refine(std::uint32_t c) {
    std::uint32_t g;
    if (!free_groups.empty()) {
      g = free_groups.back();
      free_groups.pop_back();
    } else {
      g = static_cast<std::uint32_t>(group_parent.size());
      group_parent.push_back(0);
      depth_flags.push_back(0);
      first_child.resize(first_child.size() + 8);
      colour.resize(colour.size() + 8);
      cx.resize(cx.size() + 8);
      cy.resize(cy.size() + 8);
      cz.resize(cz.size() + 8);
    }
    const int d = depth(c) + 1;
    const double h = cell_edge(d) / 2;
    group_parent[g] = c;
    depth_flags[g] = static_cast<std::uint8_t>(d);
    for (std::uint32_t k = 0; k < 8; ++k) {
      const std::uint32_t i = 8 * g + k;
      first_child[i] = kNone;
      colour[i] = colour[c];
      cx[i] = cx[c] + ((k & 1) ? h : -h);
      cy[i] = cy[c] + ((k & 2) ? h : -h);
      cz[i] = cz[c] + ((k & 4) ? h : -h);
    }
    first_child[c] = 8 * g;
    mark(g);
  }

  void coarsen(std::uint32_t c) {
    const std::uint32_t g = first_child[c] / 8;
    first_child[c] = kNone;
    // The freed group links to the next free one, as server_core's free list does.
    group_parent[g] = free_groups.empty() ? kNone : free_groups.back();
    depth_flags[g] = 0x80;
    for (std::uint32_t k = 0; k < 8; ++k) {
      first_child[8 * g + k] = kNone;
      colour[8 * g + k] = 0;
    }
    free_groups.push_back(g);
    mark(g);
  }

  // Refines down to `target` depth where the cell meets the sphere, paints leaves inside it.
  void stamp(std::uint32_t c, double px, double py, double pz, double r, int target,
             std::uint32_t rgb, bool erase) {
    const double h = cell_edge(depth(c)) / 2;
    const double dx = std::max(0.0, std::abs(px - cx[c]) - h);
    const double dy = std::max(0.0, std::abs(py - cy[c]) - h);
    const double dz = std::max(0.0, std::abs(pz - cz[c]) - h);
    if (dx * dx + dy * dy + dz * dz > r * r) return;
    if (first_child[c] == kNone) {
      if (erase) {
        colour[c] = 0;
        return;
      }
      if (depth(c) < target) refine(c);
    }
    if (first_child[c] == kNone) {
      const double dist = std::sqrt((px - cx[c]) * (px - cx[c]) + (py - cy[c]) * (py - cy[c]) +
                                    (pz - cz[c]) * (pz - cz[c]));
      // Brush with hardness 0.5: full density in the inner half, a linear falloff outside.
      const double a = (rgb >> 24) / 255.0 * std::clamp(2.0 * (1.0 - dist / r), 0.0, 1.0);
      const std::uint32_t old_a = colour[c] >> 24;
      const std::uint32_t new_a = std::max(old_a, static_cast<std::uint32_t>(a * 255.0 + 0.5));
      colour[c] = (rgb & 0xFFFFFFu) | (new_a << 24);
      return;
    }
    const std::uint32_t fc = first_child[c];
    for (std::uint32_t k = 0; k < 8; ++k) stamp(fc + k, px, py, pz, r, target, rgb, erase);
    if (erase) {
      bool all_clear = true;
      for (std::uint32_t k = 0; k < 8; ++k)
        all_clear = all_clear && first_child[fc + k] == kNone && colour[fc + k] == 0;
      if (all_clear) coarsen(c);
    }
  }

  std::uint32_t root_at(double x, double y, double z) const {
    const auto idx = [&](double v) {
      return std::min(roots_per_axis - 1,
                      static_cast<std::uint32_t>((v + edge / 2) / (edge / roots_per_axis)));
    };
    return idx(x) + roots_per_axis * (idx(y) + roots_per_axis * idx(z));
  }
};

SyntheticTree paint(std::size_t target_cells, std::uint64_t seed) {
  SyntheticTree t;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const double centre[3] = {12.3, -4.5, 7.8};  // a sculpture a few metres across
  while (t.first_child.size() < target_cells) {
    const bool erase = rng() % 8 == 0;
    const double r = 0.02 + 0.15 * (u(rng) + 1);
    const int target = static_cast<int>(std::ceil(std::log2(t.cell_edge(0) / (r / 3))));
    // Colour per stroke; the high byte is the brush density (0.5..1).
    const std::uint32_t rgb =
        (static_cast<std::uint32_t>(rng()) & 0xFFFFFFu) | std::uint32_t(128 + rng() % 128) << 24;
    double p[3] = {centre[0] + 2 * u(rng), centre[1] + 2 * u(rng), centre[2] + 2 * u(rng)};
    double v[3] = {u(rng), u(rng), u(rng)};
    for (int s = 0; s < 40; ++s) {
      for (int a = 0; a < 3; ++a) {
        v[a] = 0.8 * v[a] + 0.2 * u(rng);
        p[a] += v[a] * r * 0.5;
      }
      t.stamp(t.root_at(p[0], p[1], p[2]), p[0], p[1], p[2], r, std::min(target, 24), rgb, erase);
    }
    if (rng() % 4 == 0) t.mask.clear();  // masks are cleared when blocks are staged
  }
  return t;
}

std::vector<dp::BlockView> blocks_of(const SyntheticTree& t) {
  std::vector<dp::BlockView> out;
  const auto cells = static_cast<std::uint32_t>(t.first_child.size());
  static std::vector<std::uint64_t> mask_storage;
  mask_storage.assign((cells / 8 + 63) / 64 + kBlockCells / 512, 0);
  std::copy(t.mask.begin(), t.mask.end(), mask_storage.begin());
  for (std::uint32_t first = 0; first < cells; first += kBlockCells) {
    dp::BlockView v;
    v.block_id = first / kBlockCells;
    v.version = 1;
    v.epoch = 1;
    v.first_cell = first;
    v.cell_count = std::min(kBlockCells, cells - first);
    const std::uint32_t groups = v.cell_count / 8;
    v.first_child = std::span(t.first_child).subspan(first, v.cell_count);
    v.colour = std::span(t.colour).subspan(first, v.cell_count);
    v.group_parent = std::span(t.group_parent).subspan(first / 8, groups);
    v.depth_flags = std::span(t.depth_flags).subspan(first / 8, groups);
    v.neighbour_mask = std::span(mask_storage).subspan(first / 512, (groups + 63) / 64);
    out.push_back(v);
  }
  return out;
}

// One encoder setting's totals over a set of frames.
struct Tally {
  std::size_t raw = 0, stored = 0;
  double ratio() const { return stored ? double(raw) / double(stored) : 0.0; }
};

dp::BlockView view_of(const deepcanvas::server_core::Octree& t, std::uint32_t b) {
  const std::uint32_t bc = t.config().block_cells;
  const auto hw = static_cast<std::uint32_t>(t.high_water_cells());
  dp::BlockView v;
  v.block_id = b;
  v.version = t.block_state(b).version;
  v.first_cell = b * bc;
  v.cell_count = std::min(bc, hw - v.first_cell);
  v.first_child = t.first_child_pool().subspan(v.first_cell, v.cell_count);
  v.colour = t.colour_pool().subspan(v.first_cell, v.cell_count);
  v.group_parent = t.group_parent_pool().subspan(v.first_cell / 8, v.cell_count / 8);
  v.depth_flags = t.group_depth_flags_pool().subspan(v.first_cell / 8, v.cell_count / 8);
  v.neighbour_mask = t.neighbour_mask(b).first((v.cell_count / 8 + 63) / 64);
  return v;
}

// Paints `path` and tallies the live stream and the final snapshot for each setting.
int real_painting(const deepcanvas::bench::Options& opt, const std::string& path,
                  std::string& json_out) {
  const bool quick = opt.quick;
  namespace sc = deepcanvas::server_core;
  auto painting = deepcanvas::paintings::read_apa_file(path, {});
  if (!painting) return deepcanvas::bench::fail(opt, painting.error().message);
  auto tree = sc::Octree::create({});
  if (!tree) return deepcanvas::bench::fail(opt, tree.error().message);
  auto painter = sc::Painter::create(**tree);
  if (!painter) return deepcanvas::bench::fail(opt, painter.error().message);
  const std::vector<dp::BlockEncodeOptions> settings = {
      {1, false, true}, {3, false, true}, {1, true, true}, {3, true, true}, {5, true, true}};
  std::vector<dp::BlockEncoder> encoders;
  for (const auto& o : settings) encoders.emplace_back(o);
  std::vector<Tally> live(settings.size()), snapshot(settings.size());
  std::vector<std::uint8_t> frame;
  std::size_t strokes = 0, frames = 0;
  const std::size_t max_strokes = quick ? 150 : painting->strokes.size();
  for (const auto& stroke : painting->strokes) {
    if (strokes == max_strokes) break;
    if (!(*painter)->apply_stroke(stroke)) continue;  // e.g. a stroke outside limits
    ++strokes;
    for (const auto b : (*tree)->take_dirty_blocks()) {
      const dp::BlockView v = view_of(**tree, b);
      for (std::size_t i = 0; i < settings.size(); ++i) {
        if (auto e = encoders[i].encode(v, frame); !e)
          return deepcanvas::bench::fail(opt, e.error().message);
        live[i].raw += dp::block_payload_size(v.cell_count, dp::kFieldAll);
        live[i].stored += frame.size();
      }
      (*tree)->clear_neighbour_mask(b);
      ++frames;
    }
  }
  for (std::uint32_t b = 0; b < (*tree)->block_count(); ++b) {
    const dp::BlockView v = view_of(**tree, b);
    for (std::size_t i = 0; i < settings.size(); ++i) {
      if (auto e = encoders[i].encode(v, frame); !e)
        return deepcanvas::bench::fail(opt, e.error().message);
      snapshot[i].raw += dp::block_payload_size(v.cell_count, dp::kFieldAll);
      snapshot[i].stored += frame.size();
    }
  }
  if (!opt.json)
    deepcanvas::bench::print("protocol: %s: %zu strokes, %zu live block frames, %llu cells\n",
                             path.c_str(), strokes, frames,
                             static_cast<unsigned long long>((*tree)->high_water_cells()));
  json_out = ",\"painting\":{\"file\":\"" + path.substr(path.find_last_of('/') + 1) +
             "\",\"strokes\":" + std::to_string(strokes) +
             ",\"live_frames\":" + std::to_string(frames) +
             ",\"cells\":" + std::to_string((*tree)->high_water_cells()) + ",\"settings\":[";
  for (std::size_t i = 0; i < settings.size(); ++i) {
    if (!opt.json)
      deepcanvas::bench::print(
          "  level %d %-6s live ratio %6.2f (%zu -> %zu B)  snapshot ratio %6.2f\n",
          settings[i].level, settings[i].transform ? "delta" : "plain", live[i].ratio(),
          live[i].raw, live[i].stored, snapshot[i].ratio());
    char buf[200];
    std::snprintf(buf, sizeof buf,
                  "%s{\"level\":%d,\"delta\":%s,\"live_ratio\":%.3f,\"snapshot_ratio\":%.3f}",
                  i ? "," : "", settings[i].level, settings[i].transform ? "true" : "false",
                  live[i].ratio(), snapshot[i].ratio());
    json_out += buf;
  }
  json_out += "]}";
  return 0;
}

// CRC-32 of every block frame (ISA-L, protocol/src/crc32.cpp) against zlib's crc32 on the same
// bytes, one thread: GB/s of each, median of `runs`.
struct CrcSpeed {
  double ours_gb_s = 0, zlib_gb_s = 0;
};

CrcSpeed measure_crc(std::size_t bytes, int runs) {
  std::vector<std::uint8_t> data(bytes);
  std::uint64_t x = 0x9E3779B97F4A7C15ull;
  for (auto& b : data) {
    x ^= x << 13, x ^= x >> 7, x ^= x << 17;
    b = static_cast<std::uint8_t>(x);
  }
  std::vector<double> ours, theirs;
  volatile std::uint32_t sink = 0;
  for (int r = 0; r < runs; ++r) {
    double t0 = deepcanvas::bench::thread_cpu_seconds();
    sink = sink + dp::crc32(data);
    ours.push_back(deepcanvas::bench::thread_cpu_seconds() - t0);
    t0 = deepcanvas::bench::thread_cpu_seconds();
    sink = sink + static_cast<std::uint32_t>(
                      ::crc32(0, data.data(), static_cast<uInt>(data.size())));
    theirs.push_back(deepcanvas::bench::thread_cpu_seconds() - t0);
  }
  return {bytes / deepcanvas::bench::median(ours) / 1e9,
          bytes / deepcanvas::bench::median(theirs) / 1e9};
}

struct ProtocolOptions {
  std::string painting;  // empty: demo.apa in the paintings' folder, when there is one
};

int run(const deepcanvas::bench::Options& opt, const ProtocolOptions& po) {
  namespace bench = deepcanvas::bench;
  // The real painting: the one given, else demo.apa where the paintings are (none: synthetic
  // blocks only); a DEEPCANVAS_PAINTINGS that is set but wrong is an error.
  std::string painting_path = po.painting;
  if (painting_path.empty()) {
    if (auto dir = bench::paintings_dir())
      painting_path = (*dir / "demo.apa").string();
    else if (std::getenv("DEEPCANVAS_PAINTINGS"))
      return bench::fail(opt, dir.error().message);
  }
  const std::size_t cells = opt.quick ? 400000 : 2000000;
  const int runs = opt.quick ? 5 : 9;
  auto progress = bench::progress(opt, "protocol", painting_path.empty() ? 8 : 9, "steps");
  bench::note(opt, "protocol: painting a synthetic octree of %zu cells...\n", cells);
  const SyntheticTree tree = paint(cells, 7);
  const auto blocks = blocks_of(tree);
  std::size_t raw_total = 0;
  for (const auto& b : blocks) raw_total += dp::block_payload_size(b.cell_count, dp::kFieldAll);
  if (!opt.json)
    deepcanvas::bench::print("protocol: synthetic octree, %zu cells, %zu blocks, %.1f MB raw\n",
                             tree.first_child.size(), blocks.size(), raw_total / 1e6);

  struct Row {
    int level;
    bool transform;
    double ratio, compress_mb_s, decompress_mb_s;
  };
  std::vector<Row> rows;
  std::vector<std::uint8_t> frame;
  std::vector<std::vector<std::uint8_t>> frames(blocks.size());
  dp::BlockDecoder decoder;
  dp::BlockFrame decoded;
  for (const bool transform : {false, true}) {
    for (const int level : {1, 3, 5, 9}) {
      dp::BlockEncoder enc({level, transform, true});
      std::vector<double> enc_s, dec_s;
      std::size_t stored_total = 0;
      for (int r = 0; r < runs; ++r) {
        stored_total = 0;
        double t0 = deepcanvas::bench::thread_cpu_seconds();
        for (std::size_t i = 0; i < blocks.size(); ++i) {
          if (auto e = enc.encode(blocks[i], frames[i]); !e)
            return bench::fail(opt, e.error().message);
          stored_total += frames[i].size();
        }
        enc_s.push_back(deepcanvas::bench::thread_cpu_seconds() - t0);
        t0 = deepcanvas::bench::thread_cpu_seconds();
        for (const auto& f : frames)
          if (auto d = decoder.decode(f, decoded); !d) return bench::fail(opt, d.error().message);
        dec_s.push_back(deepcanvas::bench::thread_cpu_seconds() - t0);
      }
      rows.push_back({level, transform, double(raw_total) / double(stored_total),
                      raw_total / deepcanvas::bench::median(enc_s) / 1e6,
                      raw_total / deepcanvas::bench::median(dec_s) / 1e6});
      const Row& w = rows.back();
      if (!opt.json)
        deepcanvas::bench::print(
            "  level %d %-9s ratio %6.2f  compress %7.1f MB/s  decompress %7.1f MB/s\n", level,
            transform ? "delta" : "plain", w.ratio, w.compress_mb_s, w.decompress_mb_s);
      progress.add(1);
    }
  }
  const CrcSpeed crc = measure_crc(std::size_t{64} << 20, runs);
  if (!opt.json)
    deepcanvas::bench::print("  crc32 (ISA-L) %.2f GB/s, zlib %.2f GB/s: %.1fx\n", crc.ours_gb_s,
                             crc.zlib_gb_s, crc.ours_gb_s / crc.zlib_gb_s);
  std::string painting_json;
  if (!painting_path.empty()) {
    if (const int rc = real_painting(opt, painting_path, painting_json)) return rc;
    progress.add(1);
  }
  progress.finish();

  // The encoder's default, reported under its own keys for the server's figures.
  const auto chosen = std::find_if(rows.begin(), rows.end(), [](const Row& r) {
    return r.transform && r.level == dp::kDefaultZstdLevel;
  });
  if (opt.json) {
    std::printf(
        "{\"suite\":\"protocol\",\"quick\":%s,\"cells\":%zu,\"blocks\":%zu,\"block_cells\":%u,"
        "\"raw_bytes\":%zu,\"chosen_level\":%d,\"compression_ratio\":%.3f,"
        "\"compress_mb_per_s\":%.1f,\"decompress_mb_per_s\":%.1f,\"crc32_gb_per_s\":%.2f,"
        "\"crc32_zlib_gb_per_s\":%.2f,\"crc32_vs_zlib\":%.2f,\"levels\":[",
        opt.quick ? "true" : "false", tree.first_child.size(), blocks.size(), kBlockCells,
        raw_total, dp::kDefaultZstdLevel, chosen->ratio, chosen->compress_mb_s,
        chosen->decompress_mb_s, crc.ours_gb_s, crc.zlib_gb_s, crc.ours_gb_s / crc.zlib_gb_s);
    for (std::size_t i = 0; i < rows.size(); ++i)
      std::printf(
          "%s{\"level\":%d,\"delta\":%s,\"ratio\":%.3f,\"compress_mb_per_s\":%.1f,"
          "\"decompress_mb_per_s\":%.1f}",
          i ? "," : "", rows[i].level, rows[i].transform ? "true" : "false", rows[i].ratio,
          rows[i].compress_mb_s, rows[i].decompress_mb_s);
    std::printf("]%s}\n", painting_json.c_str());
  }
  return 0;
}

deepcanvas::bench::SuiteRun setup(CLI::App& app) {
  auto po = std::make_shared<ProtocolOptions>();
  app.add_option("--painting", po->painting,
                 "also measure a real painting's stream and snapshot (default demo.apa in "
                 "DEEPCANVAS_PAINTINGS)")
      ->type_name("FILE.apa");
  return [po](const deepcanvas::bench::Options& opt) { return run(opt, *po); };
}

}  // namespace

DEEPCANVAS_BENCH_SUITE(deepcanvas::bench::Suite{
    "protocol", "block frame compression: ratio and MB/s by zstd level, delta on/off",
    "examples:\n"
    "  deepcanvas-bench protocol --quick\n"
    "  deepcanvas-bench protocol --painting ../shared/data/apainter/palmtree.apa --json\n",
    setup});
