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
// 5 ms, worst_gap_ms. The e2e and render tails (README "Status") are read against these.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
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

int run(const Options& opt) {
  double seconds = opt.quick ? 3.0 : 20.0;
  for (std::size_t i = 0; i < opt.args.size(); i += 2) {
    if (opt.args[i] != "--seconds") {
      std::fprintf(stderr, "machine: unknown option '%s' (see --help)\n", opt.args[i].c_str());
      return 2;
    }
    if (i + 1 >= opt.args.size()) {
      std::fprintf(stderr, "machine: --seconds needs a value\n");
      return 2;
    }
    const auto n = option_number("machine", "--seconds", opt.args[i + 1], 0.1, 600);
    if (!n) return 2;
    seconds = *n;
  }
  const unsigned all = std::max(1u, std::thread::hardware_concurrency());
  std::fprintf(stderr, "machine: 1 spinning thread for %.0f s...\n", seconds);
  const Gaps one = run_phase(1, seconds);
  std::fprintf(stderr, "machine: %u spinning threads for %.0f s...\n", all, seconds);
  const Gaps every = run_phase(all, seconds);
  const nlohmann::json out = {{"suite", "machine"},
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

}  // namespace

DEEPCANVAS_BENCH_SUITE("machine",
                       "how often the machine stops a running thread (1 thread, then all busy)",
                       run, "  --seconds S              per phase (default 20; --quick 3)\n");

}  // namespace deepcanvas::bench
