#include "deepcanvas/server_core/metrics.hpp"

#include <cmath>
#include <cstdio>

namespace deepcanvas::server_core {

double Histogram::bound(int i) noexcept {
  return kFirstBound * std::exp2(static_cast<double>(i) / kBucketsPerOctave);
}

void Histogram::observe_seconds(double s) noexcept {
  if (!(s >= 0)) s = 0;  // NaN or negative clock skew: count it in the first bucket
  // The bucket from the logarithm, then corrected by comparing with the bounds themselves, so
  // that a value equal to a bound lands in that bound's bucket whatever the rounding.
  int i = 0;
  if (s > kFirstBound) {
    const double x = std::ceil(std::log2(s / kFirstBound) * kBucketsPerOctave);
    i = x >= kBuckets ? kBuckets : static_cast<int>(x);
    while (i > 0 && s <= bound(i - 1)) --i;
    while (i < kBuckets && s > bound(i)) ++i;
  }
  buckets_[static_cast<std::size_t>(i)].fetch_add(1, std::memory_order_relaxed);
  count_.fetch_add(1, std::memory_order_relaxed);
  sum_ns_.fetch_add(static_cast<std::uint64_t>(s * 1e9), std::memory_order_relaxed);
}

void Histogram::merge_from(const Histogram& other) noexcept {
  for (int i = 0; i <= kBuckets; ++i)
    buckets_[static_cast<std::size_t>(i)].fetch_add(other.bucket(i), std::memory_order_relaxed);
  count_.fetch_add(other.count(), std::memory_order_relaxed);
  sum_ns_.fetch_add(other.sum_ns_.load(std::memory_order_relaxed), std::memory_order_relaxed);
}

double Histogram::quantile_seconds(double q) const noexcept {
  const std::uint64_t n = count();
  if (n == 0) return 0;
  const auto target = static_cast<std::uint64_t>(std::ceil(q * static_cast<double>(n)));
  std::uint64_t acc = 0;
  for (int i = 0; i <= kBuckets; ++i) {
    const std::uint64_t in = bucket(i);
    if (acc + in >= target && in > 0) {
      if (i == kBuckets) return INFINITY;
      const double lo = i == 0 ? 0.0 : bound(i - 1), hi = bound(i);
      const double frac = static_cast<double>(target - acc) / static_cast<double>(in);
      return lo + (hi - lo) * frac;
    }
    acc += in;
  }
  return INFINITY;
}

std::string PrometheusWriter::label(std::string_view key, std::string_view value) {
  std::string s(key);
  s += "=\"";
  for (char c : value) {
    if (c == '\\')
      s += "\\\\";
    else if (c == '"')
      s += "\\\"";
    else if (c == '\n')
      s += "\\n";
    else
      s += c;
  }
  s += '"';
  return s;
}

std::string* PrometheusWriter::family(std::string_view name, std::string_view help,
                                     std::string_view type) {
  const auto [it, inserted] = index_.try_emplace(std::string(name), families_.size());
  if (inserted) {
    families_.push_back(Family{std::string(name), std::string(help), std::string(type), {}});
    return &families_.back().samples;
  }
  Family& f = families_[it->second];
  if (f.type != type) {
    ++conflicts_;
    return nullptr;
  }
  return &f.samples;
}

namespace {
// HELP text escaping (backslash and newline; quotes stay as they are).
void append_help(std::string& out, std::string_view help) {
  for (char c : help) {
    if (c == '\\')
      out += "\\\\";
    else if (c == '\n')
      out += "\\n";
    else
      out += c;
  }
}
std::string braces(std::string_view labels) {
  if (labels.empty()) return {};
  return "{" + std::string(labels) + "}";
}
std::string number(double v) {
  if (std::isnan(v)) return "NaN";
  if (std::isinf(v)) return v > 0 ? "+Inf" : "-Inf";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}
}  // namespace

std::string PrometheusWriter::text() const {
  std::string out;
  for (const Family& f : families_) {
    out += "# HELP ";
    out += f.name;
    out += ' ';
    append_help(out, f.help);
    out += "\n# TYPE ";
    out += f.name;
    out += ' ';
    out += f.type;
    out += '\n';
    out += f.samples;
  }
  return out;
}

void PrometheusWriter::counter(std::string_view name, std::string_view help,
                               std::string_view labels, std::uint64_t value) {
  std::string* out = family(name, help, "counter");
  if (out == nullptr) return;
  *out += name;
  *out += braces(labels);
  *out += ' ';
  *out += std::to_string(value);
  *out += '\n';
}

void PrometheusWriter::gauge(std::string_view name, std::string_view help, std::string_view labels,
                             double value) {
  std::string* out = family(name, help, "gauge");
  if (out == nullptr) return;
  *out += name;
  *out += braces(labels);
  *out += ' ';
  *out += number(value);
  *out += '\n';
}

void PrometheusWriter::histogram(std::string_view name, std::string_view help,
                                 std::string_view labels, const Histogram& h) {
  std::string* out = family(name, help, "histogram");
  if (out == nullptr) return;
  const std::string sep = labels.empty() ? "" : ",";
  std::uint64_t acc = 0;
  for (int i = 0; i <= Histogram::kBuckets; ++i) {
    acc += h.bucket(i);
    *out += name;
    *out += "_bucket{";
    *out += labels;
    *out += sep;
    *out += "le=\"";
    *out += i < Histogram::kBuckets ? number(Histogram::bound(i)) : "+Inf";
    *out += "\"} ";
    *out += std::to_string(acc);
    *out += '\n';
  }
  *out += name;
  *out += "_sum" + braces(labels) + " " + number(h.sum_seconds()) + "\n";
  *out += name;
  // _count from the buckets just read, so it always equals the +Inf bucket.
  *out += "_count" + braces(labels) + " " + std::to_string(acc) + "\n";
}

}  // namespace deepcanvas::server_core
