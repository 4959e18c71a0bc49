// `deepcanvas-server replay`: applies .apa paintings and stroke logs headless (no network) and
// reports the canvas it made. Used to check the painter end to end and to measure it.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "commands.hpp"
#include "deepcanvas/protocol/apa.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"

namespace {

using namespace deepcanvas;
using Clock = std::chrono::steady_clock;

void usage(FILE* out) {
  std::fprintf(
      out,
      "usage: deepcanvas-server replay [options] INPUT [[--scale S] [--offset X,Y,Z] INPUT]...\n\n"
      "Applies the strokes of each INPUT in order to one fresh canvas, headless, and\n"
      "reports the result. An INPUT is an A-Painter .apa painting or a deepcanvas stroke\n"
      "log (recognised by its magic bytes).\n\n"
      "Per-input transform (applies to the next INPUT only, then resets):\n"
      "  --scale S          multiply positions and radii by S (default 1)\n"
      "  --offset X,Y,Z     then add this offset in canvas metres (default 0,0,0)\n\n"
      "Options:\n"
      "  --json             print one JSON object with the figures on stdout\n"
      "  --log-out FILE     write every applied stroke (transformed) to a stroke log\n"
      "  --step-cap N       painter cap on cells per adjustment step (default 65536)\n"
      "  --quiet            no progress bar (it is shown only when stderr is a terminal)\n"
      "  --help             this text\n\n"
      "JSON fields: strokes, rejected, samples, cells, leaves, max_depth, pool_bytes,\n"
      "bytes_per_cell, canvas_hash, pool_hash, seconds, strokes_per_s,\n"
      "cells_changed_per_s, step_ms_p50, step_ms_p99, step_ms_max, steps.\n"
      "A stroke the canvas rejects (outside the canvas, bad values) is reported on\n"
      "stderr, counted in `rejected` and skipped; unreadable inputs fail the command.\n");
}

struct Input {
  std::string path;
  protocol::ApaTransform tf;
};

bool parse_double(const char* s, double& out) {
  char* end = nullptr;
  out = std::strtod(s, &end);
  return end != s && *end == '\0' && std::isfinite(out);
}

bool parse_offset(const char* s, double out[3]) {
  std::string str(s);
  for (int i = 0; i < 3; ++i) {
    const auto comma = str.find(',');
    const std::string part = i < 2 ? str.substr(0, comma) : str;
    if ((i < 2 && comma == std::string::npos) || !parse_double(part.c_str(), out[i])) return false;
    if (i < 2) str = str.substr(comma + 1);
  }
  return true;
}

Result<std::vector<protocol::Stroke>> load(const Input& in) {
  auto bytes = protocol::read_file_bytes(in.path);
  if (!bytes) return std::move(bytes).error();
  if (server_core::looks_like_stroke_log(*bytes)) {
    auto log = server_core::read_stroke_log(*bytes);
    if (!log) return Error{log.error().code, in.path + ": " + log.error().message};
    if (log->tail)
      std::fprintf(stderr, "replay: %s: stopped at offset %llu: %s (%zu strokes before it kept)\n",
                   in.path.c_str(), static_cast<unsigned long long>(log->tail->offset),
                   log->tail->reason.c_str(), log->strokes.size());
    for (auto& s : log->strokes)
      for (auto& p : s.samples) {
        p.x = p.x * in.tf.scale + in.tf.offset[0];
        p.y = p.y * in.tf.scale + in.tf.offset[1];
        p.z = p.z * in.tf.scale + in.tf.offset[2];
        p.radius = static_cast<float>(p.radius * in.tf.scale);
      }
    return std::move(log->strokes);
  }
  auto apa = protocol::parse_apa(*bytes, in.tf);
  if (!apa) return Error{apa.error().code, in.path + ": " + apa.error().message};
  return std::move(apa->strokes);
}

double percentile(std::vector<double>& v, double p) {
  if (v.empty()) return 0;
  const auto k =
      static_cast<std::size_t>(std::min<double>(v.size() - 1, std::ceil(p * v.size()) - 1));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

std::string hex(std::uint64_t v) {
  char b[32];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(v));
  return b;
}

int replay_main(int argc, char** argv) {
  std::vector<Input> inputs;
  Input next;
  bool json = false, quiet = false;
  std::optional<std::string> log_out;
  server_core::PainterConfig pc;
  for (int i = 1; i < argc; ++i) {
    const std::string_view a = argv[i];
    auto need = [&](const char* what) -> const char* {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "replay: %s needs a value\n", what);
        return nullptr;
      }
      return argv[++i];
    };
    if (a == "--help" || a == "-h") {
      usage(stdout);
      return 0;
    } else if (a == "--json") {
      json = true;
    } else if (a == "--quiet") {
      quiet = true;
    } else if (a == "--scale") {
      const char* v = need("--scale");
      if (!v || !parse_double(v, next.tf.scale) || next.tf.scale <= 0) {
        std::fprintf(stderr, "replay: --scale needs a number > 0\n");
        return 2;
      }
    } else if (a == "--offset") {
      const char* v = need("--offset");
      if (!v || !parse_offset(v, next.tf.offset)) {
        std::fprintf(stderr, "replay: --offset needs X,Y,Z (three numbers)\n");
        return 2;
      }
    } else if (a == "--log-out") {
      const char* v = need("--log-out");
      if (!v) return 2;
      log_out = v;
    } else if (a == "--step-cap") {
      const char* v = need("--step-cap");
      double cap = 0;
      if (!v || !parse_double(v, cap) || cap < 8) {
        std::fprintf(stderr, "replay: --step-cap needs a number >= 8\n");
        return 2;
      }
      pc.max_cells_per_step = static_cast<std::uint64_t>(cap);
    } else if (a.size() > 1 && a[0] == '-') {
      std::fprintf(stderr, "replay: unknown option '%s' (see --help)\n", argv[i]);
      return 2;
    } else {
      next.path = std::string(a);
      inputs.push_back(next);
      next = Input{};
    }
  }
  if (inputs.empty()) {
    usage(stderr);
    return 2;
  }

  std::vector<std::vector<protocol::Stroke>> loaded;
  std::size_t total_strokes = 0;
  for (const auto& in : inputs) {
    auto s = load(in);
    if (!s) {
      std::fprintf(stderr, "replay: %s\n", s.error().message.c_str());
      return 1;
    }
    total_strokes += s->size();
    loaded.push_back(std::move(*s));
  }

  auto tree = server_core::Octree::create({});
  if (!tree) {
    std::fprintf(stderr, "replay: %s\n", tree.error().message.c_str());
    return 1;
  }
  auto painter = server_core::Painter::create(**tree, pc);
  if (!painter) {
    std::fprintf(stderr, "replay: %s\n", painter.error().message.c_str());
    return 1;
  }
  std::optional<server_core::StrokeLogWriter> writer;
  if (log_out) {
    auto w =
        server_core::StrokeLogWriter::open(*log_out, false, server_core::FsyncPolicy::on_flush);
    if (!w) {
      std::fprintf(stderr, "replay: %s\n", w.error().message.c_str());
      return 1;
    }
    writer.emplace(std::move(*w));
  }

  const bool bar = !quiet && isatty(STDERR_FILENO);
  std::vector<double> step_ms;
  std::uint64_t strokes = 0, rejected = 0, samples = 0, cells_changed = 0, id = 0;
  auto last_bar = Clock::now();
  const auto t0 = Clock::now();
  auto& p = **painter;
  for (const auto& list : loaded) {
    for (const auto& stroke : list) {
      ++id;
      auto s0 = Clock::now();
      auto r = p.begin_stroke(stroke.brush, id, stroke.samples);
      if (!r) {
        ++rejected;
        std::fprintf(stderr, "replay: stroke %llu rejected: %s\n",
                     static_cast<unsigned long long>(id), r.error().message.c_str());
        continue;
      }
      (void)p.end_stroke();
      step_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - s0).count());
      for (;;) {
        s0 = Clock::now();
        auto more = p.step();
        step_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - s0).count());
        if (!more) {
          std::fprintf(stderr, "replay: stroke %llu failed: %s\n",
                       static_cast<unsigned long long>(id), more.error().message.c_str());
          return 1;
        }
        if (!*more) break;
      }
      ++strokes;
      samples += stroke.samples.size();
      cells_changed += p.stroke_stats().cells_changed();
      if (writer) {
        protocol::Stroke logged = stroke;
        logged.id = id;
        if (auto w = writer->append(logged); !w) {
          std::fprintf(stderr, "replay: %s\n", w.error().message.c_str());
          return 1;
        }
      }
      if (bar && Clock::now() - last_bar > std::chrono::milliseconds(100)) {
        last_bar = Clock::now();
        const double f = static_cast<double>(id) / static_cast<double>(total_strokes);
        const int w = static_cast<int>(f * 40);
        std::fprintf(stderr, "\r[%-40.*s] %llu/%zu strokes", w,
                     "========================================",
                     static_cast<unsigned long long>(id), total_strokes);
        std::fflush(stderr);
      }
    }
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  if (bar) std::fprintf(stderr, "\r%70s\r", "");
  if (writer) {
    if (auto c = writer->close(); !c) {
      std::fprintf(stderr, "replay: %s\n", c.error().message.c_str());
      return 1;
    }
  }
  const auto st = (*tree)->stats();
  const double ms_max = step_ms.empty() ? 0 : *std::max_element(step_ms.begin(), step_ms.end());
  const double p50 = percentile(step_ms, 0.5), p99 = percentile(step_ms, 0.99);
  nlohmann::json j;
  j["strokes"] = strokes;
  j["rejected"] = rejected;
  j["samples"] = samples;
  j["cells"] = st.live_cells;
  j["leaves"] = st.leaves;
  j["max_depth"] = st.max_depth;
  j["pool_bytes"] = st.pool_bytes;
  j["bytes_per_cell"] = st.live_cells ? static_cast<double>(st.pool_bytes) / st.live_cells : 0.0;
  j["canvas_hash"] = hex((*tree)->canvas_hash());
  j["pool_hash"] = hex((*tree)->pool_hash());
  j["seconds"] = seconds;
  j["strokes_per_s"] = seconds > 0 ? strokes / seconds : 0.0;
  j["cells_changed_per_s"] = seconds > 0 ? cells_changed / seconds : 0.0;
  j["cells_changed"] = cells_changed;
  j["steps"] = step_ms.size();
  j["step_ms_p50"] = p50;
  j["step_ms_p99"] = p99;
  j["step_ms_max"] = ms_max;
  if (json) {
    std::printf("%s\n", j.dump().c_str());
  } else {
    std::printf("%s\n", j.dump(2).c_str());
  }
  return rejected == 0 ? 0 : 3;
}

}  // namespace

DEEPCANVAS_SERVER_COMMAND("replay", replay_main);
