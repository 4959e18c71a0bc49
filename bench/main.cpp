// deepcanvas-bench: one binary, one subcommand per suite. `deepcanvas-bench SUITE ...` is parsed
// by that suite's own command line ("deepcanvas-bench SUITE"), so its --help, --version and
// usage errors name the suite; anything else goes to the top-level line, which lists the suites.
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "bench.hpp"

namespace deepcanvas::bench {

std::vector<Suite>& suites() {
  static std::vector<Suite> all;
  return all;
}

CLI::Validator number(double lo, double hi, bool integer) {
  return CLI::Validator(
      [=](std::string& text) -> std::string {
        const char* begin = text.c_str();
        char* end = nullptr;
        const double v = std::strtod(begin, &end);
        char buf[160];
        if (end != begin && *end == '\0' && std::isfinite(v) && v >= lo && v <= hi &&
            (!integer || v == std::floor(v))) {
          std::snprintf(buf, sizeof buf, integer ? "%.0f" : "%.17g", v);
          text = buf;
          return {};
        }
        std::snprintf(buf, sizeof buf, "must be %s in [%.10g, %.10g], not '",
                      integer ? "an integer" : "a number", lo, hi);
        return buf + text + "'";
      },
      "", "number");
}

int fail(const Options& opt, const std::string& message) {
  if (opt.app) return base::cli::fail(*opt.app, message);
  std::fprintf(stderr, "deepcanvas-bench: %s\n", message.c_str());
  return base::cli::kExitRuntime;
}

void note(const Options& opt, const char* format, ...) {
  if (opt.quiet) return;
  static const bool terminal = isatty(fileno(stderr)) == 1;
  if (terminal) std::fputs("\r\033[K", stderr);
  va_list args;
  va_start(args, format);
  std::vfprintf(stderr, format, args);
  va_end(args);
  std::fflush(stderr);
}

void print(const char* format, ...) {
  static const bool terminal = isatty(fileno(stderr)) == 1;
  if (terminal) {
    std::fputs("\r\033[K", stderr);
    std::fflush(stderr);
  }
  va_list args;
  va_start(args, format);
  std::vprintf(format, args);
  va_end(args);
  std::fflush(stdout);
}

Result<std::filesystem::path> paintings_dir() {
  namespace fs = std::filesystem;
  if (const char* e = std::getenv("DEEPCANVAS_PAINTINGS"); e && *e) {
    if (!fs::is_directory(e))
      return make_error(Errc::not_found,
                        std::string("DEEPCANVAS_PAINTINGS=") + e + " is not a directory");
    return fs::path(e);
  }
  // No default folder: where the paintings live is the machine's business, not the tree's.
  return make_error(Errc::not_found,
                    "no paintings: set DEEPCANVAS_PAINTINGS to the folder of A-Painter .apa "
                    "paintings");
}

double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

}  // namespace deepcanvas::bench

namespace {

namespace cli = deepcanvas::base::cli;
using deepcanvas::bench::Suite;

int run_suite(const Suite& s, int argc, const char* const* argv) {
  CLI::App app{s.summary, "deepcanvas-bench " + s.name};
  cli::standard(app, s.examples);
  deepcanvas::bench::Options opt;
  opt.app = &app;
  if (s.takes_quick) app.add_flag("--quick", opt.quick, "a short run (under a minute on 2 cores)");
  app.add_flag("--json", opt.json, "the result as one line of JSON on stdout");
  app.add_flag("--quiet", opt.quiet, "no progress or per-run lines on stderr (errors stay)");
  const deepcanvas::bench::SuiteRun run = s.setup(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  return run(opt);
}

}  // namespace

int main(int argc, char** argv) {
  auto all = deepcanvas::bench::suites();
  std::sort(all.begin(), all.end(), [](const Suite& a, const Suite& b) { return a.name < b.name; });
  if (argc >= 2 && argv[1][0] != '-') {
    for (const Suite& s : all)
      if (s.name == argv[1]) return run_suite(s, argc - 1, argv + 1);
    std::string names;
    for (const Suite& s : all) names += (names.empty() ? "" : ", ") + s.name;
    std::fprintf(stderr,
                 "deepcanvas-bench: unknown suite '%s' (one of: %s)\n"
                 "Run 'deepcanvas-bench --help' for the options.\n",
                 argv[1], names.c_str());
    return cli::kExitUsage;
  }

  CLI::App app{"Measures deepcanvas, one suite per subcommand.", "deepcanvas-bench"};
  cli::standard(app,
                "Every suite takes --quick (under a minute on 2 cores), --json (the result as one\n"
                "line of JSON on stdout), --quiet (no progress on stderr) and --help.\n\n"
                "examples:\n"
                "  deepcanvas-bench octree --quick\n"
                "  DEEPCANVAS_PAINTINGS=../shared/data/apainter deepcanvas-bench server --json\n"
                "  deepcanvas-bench report                 # every suite's --quick, written to "
                "docs/performance.md\n"
                "  deepcanvas-bench paint --help\n");
  for (const Suite& s : all) app.add_subcommand(s.name, s.summary);
  app.require_subcommand(1);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  return cli::kExitUsage;  // not reached: a suite's name is handled above
}
