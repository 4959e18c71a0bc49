#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "bench.hpp"

namespace deepcanvas::bench {

std::vector<Suite>& suites() {
  static std::vector<Suite> all;
  return all;
}

Result<std::filesystem::path> paintings_dir() {
  namespace fs = std::filesystem;
  if (const char* e = std::getenv("DEEPCANVAS_PAINTINGS"); e && *e) {
    if (!fs::is_directory(e))
      return make_error(Errc::not_found,
                        std::string("DEEPCANVAS_PAINTINGS=") + e + " is not a directory");
    return fs::path(e);
  }
  // <repo>/../shared/data/apainter, the repo found from this source file's path.
  const fs::path repo = fs::path(__FILE__).parent_path().parent_path();
  const fs::path candidates[] = {repo / ".." / "shared" / "data" / "apainter",
                                 fs::path("/work/shared/data/apainter")};
  for (const auto& c : candidates)
    if (fs::is_directory(c)) return fs::weakly_canonical(c);
  return make_error(Errc::not_found, "paintings not found: set DEEPCANVAS_PAINTINGS (tried " +
                                         candidates[0].string() + " and " + candidates[1].string() +
                                         ")");
}

double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

std::optional<double> option_number(std::string_view suite, std::string_view option,
                                    const std::string& text, double lo, double hi, bool integer) {
  const char* begin = text.c_str();
  char* end = nullptr;
  const double v = std::strtod(begin, &end);
  if (end != begin && *end == '\0' && std::isfinite(v) && v >= lo && v <= hi &&
      (!integer || v == std::floor(v))) {
    return v;
  }
  std::fprintf(stderr, "%.*s: %.*s must be %s in [%.10g, %.10g], not '%s'\n",
               static_cast<int>(suite.size()), suite.data(), static_cast<int>(option.size()),
               option.data(), integer ? "an integer" : "a number", lo, hi, text.c_str());
  return std::nullopt;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const double h = std::clamp(q, 0.0, 1.0) * static_cast<double>(v.size() - 1);
  const auto lo = static_cast<std::size_t>(std::floor(h));
  const std::size_t hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (h - static_cast<double>(lo)) * (v[hi] - v[lo]);
}

}  // namespace deepcanvas::bench

namespace {

void usage(FILE* out) {
  std::fprintf(out,
               "usage: deepcanvas-bench SUITE [--quick] [--json] [suite options]\n\n"
               "Measures deepcanvas. --quick runs each suite in under a minute on 2 cores;\n"
               "--json prints one JSON object on stdout (progress goes to stderr).\n\nsuites:\n");
  auto all = deepcanvas::bench::suites();
  std::sort(all.begin(), all.end(), [](const auto& a, const auto& b) { return a.name < b.name; });
  for (const auto& s : all) std::fprintf(out, "  %-10s %s\n", s.name.c_str(), s.summary.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || !std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h")) {
    usage(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  const std::string name = argv[1];
  for (const auto& s : deepcanvas::bench::suites()) {
    if (s.name != name) continue;
    deepcanvas::bench::Options opt;
    for (int i = 2; i < argc; ++i) {
      const std::string a = argv[i];
      if (a == "--help" || a == "-h") {
        std::printf("usage: deepcanvas-bench %s [--quick] [--json] [options]\n\n%s.\n",
                    s.name.c_str(), s.summary.c_str());
        std::printf(
            "  --quick  a short run (under a minute on 2 cores)\n"
            "  --json   one JSON object on stdout (progress goes to stderr)\n%s",
            s.options.c_str());
        return 0;
      }
      if (a == "--quick")
        opt.quick = true;
      else if (a == "--json")
        opt.json = true;
      else
        opt.args.push_back(a);
    }
    // Suites without options of their own take none: a mistyped option is refused, not
    // silently measured without.
    if (s.options.empty() && !opt.args.empty()) {
      std::fprintf(stderr, "%s: unknown option '%s' (this suite takes only --quick and --json)\n",
                   s.name.c_str(), opt.args.front().c_str());
      return 2;
    }
    return s.main(opt);
  }
  std::fprintf(stderr, "deepcanvas-bench: unknown suite '%s'\n\n", name.c_str());
  usage(stderr);
  return 2;
}
