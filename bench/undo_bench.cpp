// deepcanvas-bench undo: undo on real paintings (issue: undo and redo for each artist).
//
// Per painting, through a live CanvasService (in memory, default canvas):
//   - every stroke is painted as one artist, whole, waiting for its ack: paint_ms is submit ->
//     ack (the ack fires once the stroke's blocks are published);
//   - then the last K strokes are undone one by one: undo_ms is undo() -> its answer (fired once
//     the undo's blocks are published); undo_vs_paint compares each undo with that stroke's paint;
//   - exact: after the undos the canvas_hash equals a painter that painted only the strokes
//     before them.
// Through the painter alone (the history's side): history_bytes_per_stroke (each stroke's
// encoded change, what the undo history holds), and the heaviest stroke (the largest change)
// undone and redone in place under every later stroke: its paint, undo and redo times.
// Targets: undo of any stroke no slower than painting it was; history under 2 MB for the
// heaviest stroke.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <future>

#include "bench.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/canvas_service.hpp"
#include "deepcanvas/server_core/cell_diff.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas::bench {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using server_core::CanvasService;

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

struct UndoOptions {
  std::vector<std::string> paintings;
  int undos = 0;  // 0: the default (quick 30, else 100)
};

struct Row {
  std::string name;
  std::size_t strokes = 0, undone = 0;
  std::vector<double> paint_ms, undo_ms, ratio;  // ratio: undo / paint of the same stroke
  std::vector<double> bytes;                     // each stroke's encoded change
  bool exact = false;
  // The heaviest stroke, undone and redone under every later stroke (painter only).
  std::size_t heavy_index = 0;
  double heavy_bytes = 0, heavy_cells = 0, heavy_paint_ms = 0, heavy_undo_ms = 0,
         heavy_redo_ms = 0;
  bool heavy_exact = false;
  // Painting every stroke with its change recorded / without (painter only, same run).
  double record_overhead = 0;
};

Result<std::uint64_t> paint_only(const std::vector<protocol::Stroke>& strokes, std::size_t n) {
  auto tree = server_core::Octree::create(server_core::OctreeConfig{});
  if (!tree) return std::move(tree).error();
  auto painter = server_core::Painter::create(**tree);
  if (!painter) return std::move(painter).error();
  for (std::size_t i = 0; i < n; ++i)
    if (auto r = (*painter)->apply_stroke(strokes[i]); !r) return std::move(r).error();
  return (*tree)->canvas_hash();
}

// The service side: paint all, undo the last `k`.
Result<void> through_service(const std::vector<protocol::Stroke>& strokes, std::size_t k,
                             Row& row) {
  server_core::CanvasServiceConfig cfg;
  cfg.name = "undo-bench";
  auto svc = CanvasService::create(cfg);
  if (!svc) return std::move(svc).error();
  std::vector<double> paint_ms;
  for (const auto& s : strokes) {
    auto v = protocol::ValidatedStroke::make(s, (*svc)->stroke_rules());
    if (!v) return std::move(v).error();
    std::promise<Result<server_core::StrokeDone>> p;
    auto f = p.get_future();
    const auto t0 = Clock::now();
    auto r = (*svc)->submit_stroke(
        std::move(*v), t0, [&p](Result<server_core::StrokeDone> d) { p.set_value(std::move(d)); },
        1);
    if (!r) return std::move(r).error();
    auto d = f.get();
    paint_ms.push_back(ms_since(t0));
    if (!d) return std::move(d).error();
  }
  for (std::size_t i = 0; i < k; ++i) {
    std::promise<Result<server_core::UndoDone>> p;
    auto f = p.get_future();
    const auto t0 = Clock::now();
    auto r = (*svc)->undo(1, false, t0,
                          [&p](Result<server_core::UndoDone> d) { p.set_value(std::move(d)); });
    if (!r) return std::move(r).error();
    auto d = f.get();
    const double ms = ms_since(t0);
    if (!d) return std::move(d).error();
    const double painted = paint_ms[strokes.size() - 1 - i];
    row.undo_ms.push_back(ms);
    row.paint_ms.push_back(painted);
    row.ratio.push_back(painted > 0 ? ms / painted : 0);
  }
  auto q = (*svc)->quiesce();
  if (!q) return std::move(q).error();
  auto want = paint_only(strokes, strokes.size() - k);
  if (!want) return std::move(want).error();
  row.exact = q->canvas_hash == *want;
  row.undone = k;
  return {};
}

// The painter side: every stroke's change, and the heaviest undone and redone in place.
Result<void> through_painter(const std::vector<protocol::Stroke>& strokes, Row& row) {
  double plain_ms = 0;
  // The cost of recording: the same strokes on a painter that records nothing.
  {
    auto plain_tree = server_core::Octree::create(server_core::OctreeConfig{});
    if (!plain_tree) return std::move(plain_tree).error();
    auto plain = server_core::Painter::create(**plain_tree);
    if (!plain) return std::move(plain).error();
    const auto t0 = Clock::now();
    for (const auto& s : strokes)
      if (auto r = (*plain)->apply_stroke(s); !r) return std::move(r).error();
    plain_ms = ms_since(t0);
  }
  auto tree = server_core::Octree::create(server_core::OctreeConfig{});
  if (!tree) return std::move(tree).error();
  server_core::PainterConfig pc;
  pc.record_diffs = true;
  auto painter = server_core::Painter::create(**tree, pc);
  if (!painter) return std::move(painter).error();
  std::vector<server_core::CellDiff> diffs;
  std::vector<double> paint_ms;
  for (std::size_t i = 0; i < strokes.size(); ++i) {
    protocol::Stroke s = strokes[i];
    s.id = i + 1;
    const auto t0 = Clock::now();
    if (auto r = (*painter)->apply_stroke(s); !r) return std::move(r).error();
    paint_ms.push_back(ms_since(t0));
    auto d = (*painter)->take_stroke_diff(s.id);
    if (!d) return make_error(Errc::internal, "no diff recorded");
    row.bytes.push_back(static_cast<double>(server_core::encode_cell_diff(*d).size()));
    diffs.push_back(std::move(*d));
  }
  {
    double on = 0;
    for (double x : paint_ms) on += x;
    row.record_overhead = plain_ms > 0 ? on / plain_ms : 0;
  }
  const auto heavy = static_cast<std::size_t>(
      std::max_element(row.bytes.begin(), row.bytes.end()) - row.bytes.begin());
  row.heavy_index = heavy;
  row.heavy_bytes = row.bytes[heavy];
  row.heavy_cells = static_cast<double>(diffs[heavy].size());
  row.heavy_paint_ms = paint_ms[heavy];
  const std::uint64_t full = (*tree)->canvas_hash();
  auto t0 = Clock::now();
  server_core::RevertStats st;
  auto undone = (*painter)->revert(diffs[heavy], &st);
  row.heavy_undo_ms = ms_since(t0);
  if (!undone) return std::move(undone).error();
  t0 = Clock::now();
  auto redone = (*painter)->revert(*undone);
  row.heavy_redo_ms = ms_since(t0);
  if (!redone) return std::move(redone).error();
  row.heavy_exact = (*tree)->canvas_hash() == full;
  return {};
}

double pct(const std::vector<double>& v, double q) {
  return v.empty() ? 0.0 : base::percentile(v, q);
}

int undo_main(const Options& opt, const UndoOptions& uo) {
  base::set_log_level(base::LogLevel::warn);
  auto dir = paintings_dir();
  if (!dir) return fail(opt, dir.error().message);
  std::vector<std::string> names = uo.paintings;
  if (names.empty())
    names = opt.quick ? std::vector<std::string>{"demo", "mozfest"}
                      : std::vector<std::string>{"demo", "mozfest", "palmtree", "logo_fire"};
  const std::size_t k_default = opt.quick ? 30 : 100;
  auto progress = bench::progress(opt, "undo", double(names.size()), "paintings");
  const auto start = Clock::now();
  std::vector<Row> rows;
  for (const auto& name : names) {
    auto p = paintings::read_apa_file((*dir / (name + ".apa")).string(), {});
    if (!p) return fail(opt, p.error().message);
    Row row;
    row.name = name;
    row.strokes = p->strokes.size();
    const std::size_t k =
        std::min(p->strokes.size(), uo.undos > 0 ? static_cast<std::size_t>(uo.undos) : k_default);
    if (auto r = through_service(p->strokes, k, row); !r) return fail(opt, name + ": " + r.error().message);
    if (auto r = through_painter(p->strokes, row); !r) return fail(opt, name + ": " + r.error().message);
    note(opt, "%s: undo p50 %.2f ms vs paint %.2f ms, heaviest stroke %zu: %.0f bytes\n", name.c_str(),
         pct(row.undo_ms, 0.5), pct(row.paint_ms, 0.5), row.heavy_index + 1, row.heavy_bytes);
    rows.push_back(std::move(row));
    progress.update(double(rows.size()));
  }
  progress.finish();
  const double total = std::chrono::duration<double>(Clock::now() - start).count();
  double worst_ratio_p50 = 0, heaviest = 0;
  bool exact = true;
  for (const auto& r : rows) {
    worst_ratio_p50 = std::max(worst_ratio_p50, pct(r.ratio, 0.5));
    heaviest = std::max(heaviest, r.heavy_bytes);
    exact = exact && r.exact && r.heavy_exact;
  }
  if (opt.json) {
    std::printf("{\"suite\":\"undo\",\"quick\":%s,\"paintings\":[", opt.quick ? "true" : "false");
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const Row& r = rows[i];
      std::printf(
          "%s{\"name\":\"%s\",\"strokes\":%zu,\"undone\":%zu,\"undo_ms_p50\":%.4f,"
          "\"undo_ms_p99\":%.4f,\"paint_ms_p50\":%.4f,\"paint_ms_p99\":%.4f,"
          "\"undo_vs_paint_p50\":%.4f,\"undo_vs_paint_p99\":%.4f,\"undo_slower_than_paint\":%zu,"
          "\"history_bytes_per_stroke_p50\":%.0f,\"history_bytes_per_stroke_max\":%.0f,"
          "\"exact\":%s,\"record_overhead\":%.4f,\"heaviest\":{\"stroke\":%zu,\"bytes\":%.0f,\"cells\":%.0f,"
          "\"paint_ms\":%.4f,\"undo_ms\":%.4f,\"redo_ms\":%.4f,\"exact\":%s}}",
          i ? "," : "", r.name.c_str(), r.strokes, r.undone, pct(r.undo_ms, 0.5),
          pct(r.undo_ms, 0.99), pct(r.paint_ms, 0.5), pct(r.paint_ms, 0.99), pct(r.ratio, 0.5),
          pct(r.ratio, 0.99),
          static_cast<std::size_t>(std::count_if(r.ratio.begin(), r.ratio.end(),
                                                 [](double x) { return x > 1.0; })),
          pct(r.bytes, 0.5), pct(r.bytes, 1.0), r.exact ? "true" : "false", r.record_overhead,
          r.heavy_index + 1,
          r.heavy_bytes, r.heavy_cells, r.heavy_paint_ms, r.heavy_undo_ms, r.heavy_redo_ms,
          r.heavy_exact ? "true" : "false");
    }
    std::printf(
        "],\"undo_vs_paint_p50_worst\":%.4f,\"heaviest_history_bytes\":%.0f,"
        "\"undo_vs_paint_target\":1,\"history_target_bytes\":2000000,\"history_target_met\":%s,\"exact\":%s,"
        "\"seconds\":%.2f}\n",
        worst_ratio_p50, heaviest, heaviest < 2e6 ? "true" : "false", exact ? "true" : "false",
        total);
    return 0;
  }
  print("undo: the last K strokes of each painting undone through a live canvas (in memory)\n");
  print("%-10s %7s %4s %9s %9s %9s %9s %8s %8s %9s %9s %6s\n", "painting", "strokes", "K",
        "undo p50", "undo p99", "paint p50", "paint p99", "ratio50", "ratio99", "hist p50",
        "hist max", "exact");
  for (const auto& r : rows)
    print("%-10s %7zu %4zu %7.2fms %7.2fms %7.2fms %7.2fms %8.2f %8.2f %8.0fB %8.0fB %6s\n",
          r.name.c_str(), r.strokes, r.undone, pct(r.undo_ms, 0.5), pct(r.undo_ms, 0.99),
          pct(r.paint_ms, 0.5), pct(r.paint_ms, 0.99), pct(r.ratio, 0.5), pct(r.ratio, 0.99),
          pct(r.bytes, 0.5), pct(r.bytes, 1.0), r.exact ? "yes" : "NO");
  print("\nheaviest stroke (largest change), undone and redone in place under every later one:\n");
  for (const auto& r : rows)
    print("%-10s stroke %4zu: %8.0f bytes, %8.0f cells; paint %7.2f ms, undo %7.2f ms, redo %7.2f "
          "ms, exact %s\n",
          r.name.c_str(), r.heavy_index + 1, r.heavy_bytes, r.heavy_cells, r.heavy_paint_ms,
          r.heavy_undo_ms, r.heavy_redo_ms, r.heavy_exact ? "yes" : "NO");
  for (const auto& r : rows)
    print("%-10s painting with changes recorded / without: %.2fx (painter alone)\n", r.name.c_str(),
          r.record_overhead);
  print("\ntargets: undo no slower than painting (worst painting's median ratio %.2f); history "
        "under 2 MB for the heaviest stroke (%.0f bytes): %s\n",
        worst_ratio_p50, heaviest, heaviest < 2e6 ? "met" : "NOT met");
  return 0;
}

SuiteRun setup(CLI::App& app) {
  auto uo = std::make_shared<UndoOptions>();
  app.add_option("--paintings", uo->paintings,
                 "file names without .apa (default: demo, mozfest, palmtree, logo_fire; --quick: "
                 "demo, mozfest)")
      ->delimiter(',')
      ->type_name("a,b,c");
  app.add_option("--undos", uo->undos,
                 "strokes undone at the end of each painting (default 100; --quick 30)")
      ->transform(number(1, 100000, true))
      ->type_name("K");
  return [uo](const Options& opt) { return undo_main(opt, *uo); };
}

}  // namespace

DEEPCANVAS_BENCH_SUITE(Suite{
    "undo", "undo and redo on real paintings: time against painting, history bytes per stroke",
    "examples:\n"
    "  deepcanvas-bench undo --quick\n"
    "  deepcanvas-bench undo --paintings demo,mozfest --undos 50 --json\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder)\n",
    setup});

}  // namespace deepcanvas::bench
