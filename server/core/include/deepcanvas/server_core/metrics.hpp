// Metrics for the streaming server: lock-free counters, gauges and fixed-bucket histograms, and a
// writer for the Prometheus text exposition format (version 0.0.4).
//
// Why hand-rolled: the server needs a dozen series, written from hot threads (stroke thread,
// compress thread, network strands) with relaxed atomics and no allocation; a scrape reads them
// without stopping anyone. Values read during a scrape are individually exact but not a
// consistent snapshot across series (Prometheus does not require one).
//
// Threading: every member function is safe to call from any thread at any time.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

namespace deepcanvas::server_core {

class Counter {
 public:
  void add(std::uint64_t n = 1) noexcept { v_.fetch_add(n, std::memory_order_relaxed); }
  std::uint64_t value() const noexcept { return v_.load(std::memory_order_relaxed); }

 private:
  std::atomic<std::uint64_t> v_{0};
};

class Gauge {
 public:
  void set(std::int64_t v) noexcept { v_.store(v, std::memory_order_relaxed); }
  void add(std::int64_t n) noexcept { v_.fetch_add(n, std::memory_order_relaxed); }
  std::int64_t value() const noexcept { return v_.load(std::memory_order_relaxed); }

 private:
  std::atomic<std::int64_t> v_{0};
};

// A latency histogram in seconds with fixed exponential buckets from 50 us to ~52 s, four per
// octave (factor 2^(1/4), so a bound is within 19% of any value in its bucket): fine enough to
// read a p99 against a 5 ms target (3.4 / 4.0 / 4.8 / 5.7 ms are bounds) and to see
// multi-second stalls.
class Histogram {
 public:
  static constexpr int kBucketsPerOctave = 4;
  static constexpr int kBuckets = 20 * kBucketsPerOctave;
  static constexpr double kFirstBound = 50e-6;

  void observe_seconds(double s) noexcept;
  // Adds another histogram's observations (e.g. to summarise several runs of a benchmark).
  void merge_from(const Histogram& other) noexcept;
  // Bucket upper bound i (seconds); the last bucket is +Inf and not listed.
  static double bound(int i) noexcept;
  std::uint64_t count() const noexcept { return count_.load(std::memory_order_relaxed); }
  double sum_seconds() const noexcept {
    return static_cast<double>(sum_ns_.load(std::memory_order_relaxed)) * 1e-9;
  }
  std::uint64_t bucket(int i) const noexcept {
    return buckets_[static_cast<std::size_t>(i)].load(std::memory_order_relaxed);
  }
  // Estimated quantile q in 0..1 from the buckets: linear interpolation inside the bucket that
  // holds it (so within that bucket's 19% width); +Inf if it lies in the overflow bucket.
  double quantile_seconds(double q) const noexcept;

 private:
  std::array<std::atomic<std::uint64_t>, kBuckets + 1> buckets_{};  // last = overflow
  std::atomic<std::uint64_t> count_{0};
  std::atomic<std::uint64_t> sum_ns_{0};
};

// Builds Prometheus text (exposition format 0.0.4).
//
// Samples are grouped by family: every sample of a family is written under that family's one
// HELP and TYPE line, in the order the family was first written, whatever order the calls come
// in. Why: /metrics is assembled from independent writers (the server's own series, then each
// canvas's CanvasService::write_metrics, each writing every per-canvas family with its
// `canvas="NAME"` label), so the calls for one family arrive interleaved with other families;
// the format requires a family's samples to be contiguous, and a parser reads a sample that
// follows another family's block as a new family of unknown type.
//
// A family's HELP and TYPE are those of its first call. A later call with the same name and a
// different type is a programming error; its sample is dropped so that the text stays valid
// (conflicts() counts them; tests/ops parses the server's real /metrics with a Prometheus
// parser).
// `labels` is either empty or a comma-separated list of label() results; label values are
// escaped here, HELP text is escaped in text(). Names are the caller's constants and are not
// checked.
//
// Threading: one writer per scrape, used by one thread; the metrics it reads may be written
// concurrently (see above).
class PrometheusWriter {
 public:
  void counter(std::string_view name, std::string_view help, std::string_view labels,
               std::uint64_t value);
  void gauge(std::string_view name, std::string_view help, std::string_view labels, double value);
  void histogram(std::string_view name, std::string_view help, std::string_view labels,
                 const Histogram& h);
  // `key="value"` with the value escaped as the format requires (backslash, quote, newline).
  static std::string label(std::string_view key, std::string_view value);
  // The exposition text: each family's HELP, TYPE and samples, families in first-seen order.
  std::string text() const;
  // Calls dropped because their name was already a family of another type.
  std::size_t conflicts() const noexcept { return conflicts_; }

 private:
  struct Family {
    std::string name, help, type, samples;
  };
  // The family's sample text to append to, or nullptr on a type conflict.
  std::string* family(std::string_view name, std::string_view help, std::string_view type);
  std::vector<Family> families_;
  std::unordered_map<std::string, std::size_t> index_;  // name -> position in families_
  std::size_t conflicts_ = 0;
};

}  // namespace deepcanvas::server_core
