// deepcanvas-bench suites: each registers a name, a one-line summary and an entry point.
// Conventions for every suite: `--quick` finishes in under 60 s on the 2-core CI machine,
// `--json` prints exactly one JSON object on stdout (progress and tables go to stderr),
// timings are medians over several runs, comparisons are ratios measured in the same run.
#pragma once

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "deepcanvas/protocol/result.hpp"

namespace deepcanvas::bench {

struct Options {
  bool quick = false;
  bool json = false;
  std::vector<std::string> args;  // the suite's remaining arguments
};

using SuiteMain = std::function<int(const Options&)>;

struct Suite {
  std::string name;
  std::string summary;
  SuiteMain main;
  std::string options;  // the suite's own options, one per line (`deepcanvas-bench NAME --help`)
};

std::vector<Suite>& suites();

struct Registrar {
  Registrar(std::string name, std::string summary, SuiteMain main, std::string options = {}) {
    suites().push_back({std::move(name), std::move(summary), std::move(main), std::move(options)});
  }
};

// The folder of real paintings: $DEEPCANVAS_PAINTINGS (an error if set but not a directory),
// else <repo>/../shared/data/apainter, else /work/shared/data/apainter; not_found naming them.
Result<std::filesystem::path> paintings_dir();

// A suite option's value read strictly: all of `text` as a number in [lo, hi] (`integer`: no
// fraction). Otherwise prints "SUITE: OPTION must be ... in [lo, hi], not 'TEXT'" to stderr and
// returns nullopt; suites then exit 2 before measuring anything.
std::optional<double> option_number(std::string_view suite, std::string_view option,
                                    const std::string& text, double lo, double hi,
                                    bool integer = false);

// The q-quantile (0 <= q <= 1) of a sample, interpolated linearly between the two closest ranks
// (numpy's default); 0 for an empty sample. Copies: fine for the samples a benchmark takes.
double percentile(std::vector<double> v, double q);
inline double median(std::vector<double> v) {
  return percentile(std::move(v), 0.5);
}

// CPU time of the calling thread, in seconds: not inflated when other processes take the core
// (the machines these suites run on are shared and noisy), so it measures the code.
double thread_cpu_seconds();

}  // namespace deepcanvas::bench

#define DEEPCANVAS_BENCH_CONCAT2(a, b) a##b
#define DEEPCANVAS_BENCH_CONCAT(a, b) DEEPCANVAS_BENCH_CONCAT2(a, b)
// DEEPCANVAS_BENCH_SUITE(name, summary, fn[, options]): registers a suite at static init.
#define DEEPCANVAS_BENCH_SUITE(name, summary, ...)                                                \
  static ::deepcanvas::bench::Registrar DEEPCANVAS_BENCH_CONCAT(deepcanvas_bench_reg_, __LINE__)( \
      name, summary, __VA_ARGS__)
