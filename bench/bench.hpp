// deepcanvas-bench suites: each registers a name, a one-line summary, the examples its --help
// shows and a setup function that adds the suite's own options to its command line (CLI11,
// base/cli.hpp's convention) and returns what runs the suite once that line is parsed.
//
// Conventions for every suite:
// - `--quick` finishes in under 60 s on the 2-core CI machine (`deepcanvas-bench report` runs
//   every suite that way);
// - stdout is the result: a table, or with `--json` exactly one JSON object;
// - stderr is progress (base::Progress: a bar on a terminal, a line every few seconds
//   otherwise) and per-run detail lines (note()); `--quiet` silences both, errors stay;
// - usage errors exit 2 before anything is measured (the option named), runtime failures exit 1
//   with one line (fail());
// - timings are medians over several runs, comparisons are ratios measured in the same run.
#pragma once

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/percentile.hpp"
#include "deepcanvas/base/progress.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::bench {

// The options every suite takes (deepcanvas-bench main adds them to each suite's command line).
struct Options {
  bool quick = false;
  bool json = false;
  bool quiet = false;
  const CLI::App* app = nullptr;  // the suite's parsed command line ("deepcanvas-bench NAME")
};

using SuiteRun = std::function<int(const Options&)>;
// Adds the suite's own options to `app`, bound to state the returned SuiteRun owns.
using SuiteSetup = std::function<SuiteRun(CLI::App& app)>;

struct Suite {
  std::string name;
  std::string summary;
  std::string examples;  // the footer of `deepcanvas-bench NAME --help`
  SuiteSetup setup;
  bool takes_quick = true;  // false: the suite has no --quick (report: always quick)
};

std::vector<Suite>& suites();

struct Registrar {
  explicit Registrar(Suite s) { suites().push_back(std::move(s)); }
};

// A suite without options of its own.
inline SuiteSetup no_options(SuiteRun run) {
  return [run = std::move(run)](CLI::App&) { return run; };
}

// Strict number options: all of the value as a number in [lo, hi] (`integer`: no fraction),
// else the usage error "--NAME: must be an integer in [lo, hi], not 'TEXT'" (exit 2). Use with
// CLI::Option::transform (the value is rewritten in a form CLI11 converts exactly).
CLI::Validator number(double lo, double hi, bool integer = false);

// A runtime failure: "deepcanvas-bench NAME: MESSAGE" on stderr; returns exit code 1.
int fail(const Options& opt, const std::string& message);

// A progress display on stderr, silent with --quiet. `what` names the suite ("paint").
inline base::Progress progress(const Options& opt, std::string what, double total,
                               std::string unit) {
  return base::Progress(std::move(what), total, std::move(unit), !opt.quiet);
}

// A detail line on stderr (a run's figures as they come), silent with --quiet. On a terminal it
// clears a progress bar first; the bar is redrawn at its next update.
void note(const Options& opt, const char* format, ...) __attribute__((format(printf, 2, 3)));

// A line of the result on stdout (printf-like). Where stderr is a terminal it first clears a
// progress bar from the line, so that a table printed while a bar is up stays readable.
void print(const char* format, ...) __attribute__((format(printf, 1, 2)));

// The folder of real paintings: $DEEPCANVAS_PAINTINGS; not_found when it is unset or empty
// (the message says how to set it) or set but not a directory.
Result<std::filesystem::path> paintings_dir();

// The median of a sample: base::percentile's p50 (the one percentile definition in the tree;
// suites call base::percentile for the others). Copies: fine for the samples a benchmark takes.
inline double median(std::vector<double> v) {
  return base::percentile(std::move(v), 0.5);
}

// CPU time of the calling thread, in seconds: not inflated when other processes take the core
// (the machines these suites run on are shared and noisy), so it measures the code.
double thread_cpu_seconds();

}  // namespace deepcanvas::bench

#define DEEPCANVAS_BENCH_CONCAT2(a, b) a##b
#define DEEPCANVAS_BENCH_CONCAT(a, b) DEEPCANVAS_BENCH_CONCAT2(a, b)
// DEEPCANVAS_BENCH_SUITE(Suite{...}): registers a suite at static initialisation.
#define DEEPCANVAS_BENCH_SUITE(...)                                                    \
  static ::deepcanvas::bench::Registrar DEEPCANVAS_BENCH_CONCAT(deepcanvas_bench_reg_, \
                                                                __LINE__)(__VA_ARGS__)
