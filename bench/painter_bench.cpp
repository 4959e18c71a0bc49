// deepcanvas-bench painter: the server's painter alone, fed the way the server feeds it.
//
// For each real painting (at its natural metre scale) every stroke goes through the streamed
// path: begin_stroke with the first sample, then each further sample through add_samples, with
// step() called until idle after each (what the server's canvas does between messages), then
// end_stroke and step() until the stroke is done (refinement and merging included). Time is the
// thread's CPU time (this thread only; nothing else runs in it), per painting and per stroke.
// Runs alternate PainterConfig::exact_shortcuts on and off (fresh trees each), so the shortcut
// speedup is a ratio measured in the same run; both must end with byte-identical pools (checked:
// exit 1 otherwise). Medians over the runs (5; --quick 2 runs of demo.apa only).
//
// Figures, per painting and summed: cpu_ms (shortcuts on, the server's default), cpu_ms_without
// (off), shortcut_speedup = without / with; heaviest_stroke_ms (the stroke with the most CPU,
// the one that decides the e2e tail) with its index.
// Options: --painting NAME.apa (repeatable; default demo, mozfest, winner), --runs N.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "bench.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas::bench {
namespace {

namespace sc = server_core;

double thread_cpu_ms() {
  return thread_cpu_seconds() * 1e3;
}

struct Replay {
  double cpu_ms = 0;
  std::vector<double> stroke_ms;
  std::uint64_t pool_hash = 0;
  std::uint64_t live_cells = 0;
};

Result<Replay> replay(const paintings::ApaPainting& p, bool shortcuts) {
  auto tree = sc::Octree::create(sc::OctreeConfig{});
  if (!tree) return std::move(tree).error();
  sc::PainterConfig pc;
  pc.exact_shortcuts = shortcuts;
  auto painter = sc::Painter::create(**tree, pc);
  if (!painter) return std::move(painter).error();
  sc::Painter& P = **painter;
  auto drain = [&]() -> Result<void> {
    for (;;) {
      auto more = P.step();
      if (!more) return std::move(more).error();
      if (!*more) return {};
    }
  };
  // Validated before the clock starts, as the server's decoder does before its stroke thread
  // sees a stroke: the painter's own time is what this suite measures.
  std::vector<protocol::ValidatedStroke> strokes;
  strokes.reserve(p.strokes.size());
  for (const protocol::Stroke& s : p.strokes) {
    auto v = protocol::ValidatedStroke::make(s, P.stroke_rules());
    if (!v) return std::move(v).error();
    strokes.push_back(std::move(*v));
  }
  Replay r;
  r.stroke_ms.reserve(strokes.size());
  const double t0 = thread_cpu_ms();
  for (std::size_t i = 0; i < strokes.size(); ++i) {
    const protocol::ValidatedStroke& s = strokes[i];
    const double a = thread_cpu_ms();
    const std::size_t n = s.samples().span().size();
    if (auto v = P.begin_stroke(s.brush(), i + 1, s.samples().slice(0, 1)); !v)
      return std::move(v).error();
    if (auto v = drain(); !v) return v.error();
    for (std::size_t k = 1; k < n; ++k) {
      if (auto v = P.add_samples(s.samples().slice(k, 1)); !v) return std::move(v).error();
      if (auto v = drain(); !v) return v.error();
    }
    if (auto v = P.end_stroke(); !v) return std::move(v).error();
    if (auto v = drain(); !v) return v.error();
    r.stroke_ms.push_back(thread_cpu_ms() - a);
  }
  r.cpu_ms = thread_cpu_ms() - t0;
  r.pool_hash = (*tree)->pool_hash();
  r.live_cells = (*tree)->live_cells();
  return r;
}

struct PainterOptions {
  std::vector<std::string> paintings;  // empty: the default set
  int runs = 0;                        // 0: the default (5; --quick 2)
};

int run(const Options& opt, const PainterOptions& po) {
  auto dir = paintings_dir();
  if (!dir) return fail(opt, dir.error().message);
  std::vector<std::string> names = po.paintings;
  if (names.empty()) {
    names = {"demo.apa"};
    if (!opt.quick) names.insert(names.end(), {"mozfest.apa", "winner.apa"});
  }
  const int runs = po.runs > 0 ? po.runs : opt.quick ? 2 : 5;
  auto progress = bench::progress(opt, "painter", double(names.size() * runs), "runs");

  nlohmann::json per = nlohmann::json::array();
  double sum_with = 0, sum_without = 0;
  for (const std::string& name : names) {
    auto painting = paintings::read_apa_file((*dir / name).string(), {});
    if (!painting) return fail(opt, name + ": " + painting.error().message);
    std::vector<double> with_ms, without_ms, heaviest_ms;
    std::size_t heaviest = 0;
    std::uint64_t live = 0;
    for (int k = 0; k < runs; ++k) {
      auto with = replay(*painting, true);
      auto without = with ? replay(*painting, false) : with;
      if (!with || !without)
        return fail(opt, name + ": " + (!with ? with : without).error().message);
      if (with->pool_hash != without->pool_hash)
        return fail(opt, name + ": pools differ with and without exact_shortcuts");
      with_ms.push_back(with->cpu_ms);
      without_ms.push_back(without->cpu_ms);
      const auto it = std::max_element(with->stroke_ms.begin(), with->stroke_ms.end());
      heaviest_ms.push_back(it == with->stroke_ms.end() ? 0.0 : *it);
      heaviest = static_cast<std::size_t>(it - with->stroke_ms.begin());
      live = with->live_cells;
      note(opt, "painter: %s run %d/%d: %.1f ms with shortcuts, %.1f without\n", name.c_str(),
           k + 1, runs, with_ms.back(), without_ms.back());
      progress.add(1);
    }
    const double w = median(with_ms), wo = median(without_ms);
    sum_with += w;
    sum_without += wo;
    per.push_back({{"painting", name},
                   {"strokes", painting->strokes.size()},
                   {"live_cells", live},
                   {"cpu_ms", w},
                   {"cpu_ms_without", wo},
                   {"shortcut_speedup", wo / w},
                   {"heaviest_stroke", heaviest},
                   {"heaviest_stroke_ms", median(heaviest_ms)}});
    if (!opt.json)
      print(
          "painter %-12s %4zu strokes: %8.1f ms CPU (without shortcuts %8.1f, %.2fx); "
          "heaviest stroke #%zu %.1f ms\n",
          name.c_str(), painting->strokes.size(), w, wo, wo / w, heaviest, median(heaviest_ms));
  }
  progress.finish();
  if (!opt.json) {
    print("painter total: %.1f ms CPU (without shortcuts %.1f, %.2fx), %d runs\n", sum_with,
          sum_without, sum_without / sum_with, runs);
    return 0;
  }
  const nlohmann::json out = {{"suite", "painter"},
                              {"quick", opt.quick},
                              {"runs", runs},
                              {"clock", "thread_cpu_time"},
                              {"cpu_ms", sum_with},
                              {"cpu_ms_without", sum_without},
                              {"shortcut_speedup", sum_without / sum_with},
                              {"paintings", per}};
  std::printf("%s\n", out.dump().c_str());
  return 0;
}

SuiteRun setup(CLI::App& app) {
  auto po = std::make_shared<PainterOptions>();
  app.add_option("--painting", po->paintings,
                 "a painting in DEEPCANVAS_PAINTINGS (repeatable; default demo, mozfest, winner; "
                 "--quick: demo)")
      ->type_name("NAME.apa");
  app.add_option("--runs", po->runs, "runs per configuration (default 5, --quick 2)")
      ->transform(number(1, 1000, true))
      ->type_name("N");
  return [po](const Options& opt) { return run(opt, *po); };
}

DEEPCANVAS_BENCH_SUITE(Suite{
    "painter",
    "the server's painter alone on the real paintings, streamed sample by sample: CPU per "
    "painting and heaviest stroke, exact shortcuts on vs off",
    "examples:\n"
    "  deepcanvas-bench painter --quick\n"
    "  deepcanvas-bench painter --painting mozfest.apa --runs 9 --json\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder)\n",
    setup});

}  // namespace
}  // namespace deepcanvas::bench
