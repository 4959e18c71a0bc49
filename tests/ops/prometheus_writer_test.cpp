// PrometheusWriter: families grouped whatever the call order, HELP/TYPE once per family, label
// values and HELP text escaped, histograms cumulative. The grouping is checked against a
// brute-force reference (for each family in first-seen order, every call of that family in call
// order) over random call sequences, and the output is read back by a small line parser that
// applies the exposition format's rules for where a sample may appear.
#include <gtest/gtest.h>

#include <limits>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "deepcanvas/server_core/metrics.hpp"

namespace deepcanvas::server_core {
namespace {

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) out.push_back(line);
  return out;
}

// The metric name of a sample line (up to '{' or ' ').
std::string sample_name(const std::string& line) {
  return line.substr(0, line.find_first_of("{ "));
}

bool belongs_to(const std::string& sample, const std::string& family, const std::string& type) {
  if (sample == family) return type != "histogram";
  if (type != "histogram") return false;
  for (const char* suffix : {"_bucket", "_sum", "_count"})
    if (sample == family + suffix) return true;
  return false;
}

// Parses `text` as the exposition format's grouping rules demand: every family declared once
// by HELP then TYPE, every sample inside the block of the family it belongs to. Returns the
// family names in order, and fails the test on any violation.
std::vector<std::string> parse_families(const std::string& text) {
  std::vector<std::string> order;
  std::set<std::string> seen;
  std::string current, type;
  const auto lines = lines_of(text);
  for (std::size_t i = 0; i < lines.size(); ++i) {
    const std::string& line = lines[i];
    if (line.rfind("# HELP ", 0) == 0) {
      std::istringstream in(line.substr(7));
      in >> current;
      EXPECT_TRUE(seen.insert(current).second) << "family declared twice: " << current;
      order.push_back(current);
      EXPECT_LT(i + 1, lines.size());
      if (i + 1 >= lines.size()) break;
      const std::string& next = lines[++i];
      std::istringstream tin(next.substr(next.rfind("# TYPE ", 0) == 0 ? 7 : 0));
      std::string tname;
      tin >> tname >> type;
      EXPECT_EQ(tname, current) << "TYPE must follow HELP: " << next;
      continue;
    }
    EXPECT_FALSE(current.empty()) << "sample before any family: " << line;
    EXPECT_TRUE(belongs_to(sample_name(line), current, type))
        << "sample " << line << " inside family " << current;
  }
  return order;
}

TEST(PrometheusWriter, InterleavedCanvasesAreGroupedByFamily) {
  PrometheusWriter w;
  w.counter("x_server_total", "Server-wide.", "", 7);
  Histogram h;
  h.observe_seconds(0.001);
  for (const char* canvas : {"a", "b"}) {
    const std::string l = PrometheusWriter::label("canvas", canvas);
    w.counter("x_strokes_total", "Strokes.", l, 1);
    w.gauge("x_cells", "Cells.", l, 2.5);
    w.histogram("x_step_seconds", "Steps.", l, h);
  }
  const std::string text = w.text();
  EXPECT_EQ(parse_families(text),
            (std::vector<std::string>{"x_server_total", "x_strokes_total", "x_cells",
                                      "x_step_seconds"}));
  // Both canvases' samples of a family are adjacent, in call order.
  EXPECT_NE(text.find("x_strokes_total{canvas=\"a\"} 1\nx_strokes_total{canvas=\"b\"} 1\n"),
            std::string::npos)
      << text;
  EXPECT_NE(text.find("x_cells{canvas=\"a\"} 2.5\nx_cells{canvas=\"b\"} 2.5\n"), std::string::npos);
  EXPECT_EQ(w.conflicts(), 0u);
}

TEST(PrometheusWriter, LabelValuesAndHelpAreEscaped) {
  EXPECT_EQ(PrometheusWriter::label("canvas", "a\"b\\c\nd"), "canvas=\"a\\\"b\\\\c\\nd\"");
  EXPECT_EQ(PrometheusWriter::label("k", ""), "k=\"\"");
  PrometheusWriter w;
  w.gauge("g", "line one\nback\\slash \"quoted\"", "", 1);
  EXPECT_EQ(w.text(), "# HELP g line one\\nback\\\\slash \"quoted\"\n# TYPE g gauge\ng 1\n");
}

TEST(PrometheusWriter, TypeConflictIsDroppedAndCounted) {
  PrometheusWriter w;
  w.counter("m", "A counter.", "", 3);
  w.gauge("m", "Now a gauge.", "", 4);
  Histogram h;
  w.histogram("m", "Now a histogram.", "", h);
  EXPECT_EQ(w.text(), "# HELP m A counter.\n# TYPE m counter\nm 3\n");
  EXPECT_EQ(w.conflicts(), 2u);
}

TEST(PrometheusWriter, SpecialValues) {
  PrometheusWriter w;
  w.gauge("g", "h", "", std::numeric_limits<double>::quiet_NaN());
  w.gauge("g", "h", "k=\"1\"", std::numeric_limits<double>::infinity());
  w.gauge("g", "h", "k=\"2\"", -std::numeric_limits<double>::infinity());
  EXPECT_EQ(w.text(), "# HELP g h\n# TYPE g gauge\ng NaN\ng{k=\"1\"} +Inf\ng{k=\"2\"} -Inf\n");
}

TEST(PrometheusWriter, HistogramIsCumulativeWithCountEqualToInf) {
  Histogram h;
  for (double s : {1e-5, 1e-4, 1e-3, 1e-3, 0.5, 1e6}) h.observe_seconds(s);
  PrometheusWriter w;
  w.histogram("lat_seconds", "Latency.", PrometheusWriter::label("canvas", "x"), h);
  std::uint64_t last = 0, inf = 0, count = 0;
  int buckets = 0;
  for (const std::string& line : lines_of(w.text())) {
    if (line.rfind("lat_seconds_bucket{", 0) == 0) {
      EXPECT_NE(line.find("canvas=\"x\",le=\""), std::string::npos) << line;
      const std::uint64_t v = std::stoull(line.substr(line.rfind(' ') + 1));
      EXPECT_GE(v, last) << line;
      last = v;
      ++buckets;
      if (line.find("le=\"+Inf\"") != std::string::npos) inf = v;
    } else if (line.rfind("lat_seconds_count", 0) == 0) {
      count = std::stoull(line.substr(line.rfind(' ') + 1));
    }
  }
  EXPECT_EQ(buckets, Histogram::kBuckets + 1);
  EXPECT_EQ(inf, 6u);
  EXPECT_EQ(count, 6u);
}

// One call of a random sequence, and the sample text the reference expects for it.
struct Call {
  std::string name, type, labels;
  std::uint64_t value;
};

std::string reference_text(const std::vector<Call>& calls) {
  std::string out;
  std::set<std::string> done;
  for (const Call& first : calls) {
    if (!done.insert(first.name).second) continue;
    out += "# HELP " + first.name + " Help of " + first.name + ".\n";
    out += "# TYPE " + first.name + " " + first.type + "\n";
    for (const Call& c : calls) {
      if (c.name != first.name) continue;
      out += c.name + (c.labels.empty() ? "" : "{" + c.labels + "}") + " " +
             std::to_string(c.value) + "\n";
    }
  }
  return out;
}

TEST(PrometheusWriter, RandomCallOrdersMatchTheReference) {
  std::mt19937_64 rng(26);
  const std::vector<std::string> canvases = {"a", "b", "we\"ird", "back\\slash", "new\nline"};
  for (int round = 0; round < 200; ++round) {
    const int families = 1 + static_cast<int>(rng() % 12);
    std::vector<Call> calls;
    const int n = static_cast<int>(rng() % 60);
    for (int i = 0; i < n; ++i) {
      const int f = static_cast<int>(rng() % static_cast<std::uint64_t>(families));
      Call c;
      c.name = "fam_" + std::to_string(f);
      c.type = f % 2 == 0 ? "counter" : "gauge";  // one type per name: no conflicts here
      const std::size_t k = rng() % (canvases.size() + 1);
      c.labels = k == canvases.size() ? "" : PrometheusWriter::label("canvas", canvases[k]);
      c.value = rng() % 1000;
      calls.push_back(c);
    }
    PrometheusWriter w;
    for (const Call& c : calls) {
      const std::string help = "Help of " + c.name + ".";
      if (c.type == "counter")
        w.counter(c.name, help, c.labels, c.value);
      else
        w.gauge(c.name, help, c.labels, static_cast<double>(c.value));
    }
    const std::string text = w.text();
    ASSERT_EQ(text, reference_text(calls)) << "round " << round;
    parse_families(text);
    EXPECT_EQ(w.conflicts(), 0u);
  }
}

}  // namespace
}  // namespace deepcanvas::server_core
