// deepcanvas-bench machine: how often this machine stops a running thread, and for how long.
//
// Latency tails on a shared VM come partly from the machine itself: a vCPU the host does not
// run for a few milliseconds stalls whatever thread is on it, however little work that thread
// has. This suite spins threads that only read the clock and counts the gaps between two
// consecutive reads (a gap is time the thread did not run), first with one thread (the other
// vCPUs idle), then with one thread per hardware thread (every vCPU busy, as when lavapipe
// renders beside the server). Nothing else of the project runs meanwhile.
//
// Figures (per phase, summed over its threads): gaps_over_{1,2,5,10}_ms, gaps per second over
// 5 ms, worst_gap_ms. The e2e and render tails (docs/performance.md) are read against these.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <thread>
#include <vector>

#include "bench.hpp"

namespace deepcanvas::bench {
namespace {

using Clock = std::chrono::steady_clock;

struct Gaps {
  std::uint64_t over_1 = 0, over_2 = 0, over_5 = 0, over_10 = 0;
  double worst_ms = 0;
  void add(const Gaps& o) {
    over_1 += o.over_1;
    over_2 += o.over_2;
    over_5 += o.over_5;
    over_10 += o.over_10;
    worst_ms = std::max(worst_ms, o.worst_ms);
  }
};

Gaps spin(double seconds) {
  Gaps g;
  const auto t0 = Clock::now();
  const auto end =
      t0 + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
  auto prev = t0;
  while (prev < end) {
    const auto t = Clock::now();
    const double ms = std::chrono::duration<double, std::milli>(t - prev).count();
    prev = t;
    if (ms > 1) ++g.over_1;
    if (ms > 2) ++g.over_2;
    if (ms > 5) ++g.over_5;
    if (ms > 10) ++g.over_10;
    g.worst_ms = std::max(g.worst_ms, ms);
  }
  return g;
}

Gaps run_phase(unsigned threads, double seconds) {
  std::vector<Gaps> per(threads);
  std::vector<std::thread> pool;
  for (unsigned i = 0; i < threads; ++i)
    pool.emplace_back([&per, i, seconds] { per[i] = spin(seconds); });
  for (auto& t : pool) t.join();
  Gaps all;
  for (const auto& g : per) all.add(g);
  return all;
}

nlohmann::json to_json(const Gaps& g, unsigned threads, double seconds) {
  return {{"threads", threads},
          {"seconds", seconds},
          {"gaps_over_1_ms", g.over_1},
          {"gaps_over_2_ms", g.over_2},
          {"gaps_over_5_ms", g.over_5},
          {"gaps_over_10_ms", g.over_10},
          {"gaps_over_5_ms_per_thread_second", static_cast<double>(g.over_5) / (threads * seconds)},
          {"worst_gap_ms", g.worst_ms}};
}

struct MachineOptions {
  double seconds = 0;  // 0: the default (20; --quick 3)
};

int run(const Options& opt, const MachineOptions& mo) {
  const double seconds = mo.seconds > 0 ? mo.seconds : opt.quick ? 3.0 : 20.0;
  const unsigned all = std::max(1u, std::thread::hardware_concurrency());
  // Progress only between the phases: an update while the threads spin would be a gap itself.
  auto progress = bench::progress(opt, "machine", 2 * seconds, "s");
  note(opt, "machine: 1 spinning thread for %.0f s...\n", seconds);
  const Gaps one = run_phase(1, seconds);
  progress.update(seconds);
  note(opt, "machine: %u spinning threads for %.0f s...\n", all, seconds);
  const Gaps every = run_phase(all, seconds);
  progress.update(2 * seconds);
  progress.finish();
  const nlohmann::json out = {{"suite", "machine"},
                              {"quick", opt.quick},
                              {"hardware_threads", all},
                              {"one_thread", to_json(one, 1, seconds)},
                              {"every_hardware_thread", to_json(every, all, seconds)}};
  if (opt.json) {
    std::printf("%s\n", out.dump().c_str());
  } else {
    std::printf("%-22s %8s %8s %8s %8s %10s\n", "phase", ">1 ms", ">2 ms", ">5 ms", ">10 ms",
                "worst ms");
    for (const auto& [name, g] : {std::pair{"1 thread", one}, std::pair{"every hw thread", every}})
      std::printf("%-22s %8llu %8llu %8llu %8llu %10.2f\n", name, (unsigned long long)g.over_1,
                  (unsigned long long)g.over_2, (unsigned long long)g.over_5,
                  (unsigned long long)g.over_10, g.worst_ms);
  }
  return 0;
}

SuiteRun setup(CLI::App& app) {
  auto mo = std::make_shared<MachineOptions>();
  app.add_option("--seconds", mo->seconds, "each phase's length (default 20; --quick 3)")
      ->transform(number(0.1, 600))
      ->type_name("S");
  return [mo](const Options& opt) { return run(opt, *mo); };
}

}  // namespace

DEEPCANVAS_BENCH_SUITE(Suite{
    "machine", "how often the machine stops a running thread (1 thread, then all busy)",
    "examples:\n"
    "  deepcanvas-bench machine --quick          # 3 s per phase\n"
    "  deepcanvas-bench machine --seconds 60 --json\n",
    setup});

}  // namespace deepcanvas::bench
