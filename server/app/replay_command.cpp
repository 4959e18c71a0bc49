// `deepcanvas-server replay`: applies .apa paintings and stroke logs headless (no network) and
// reports the canvas it made. Used to check the painter end to end and to measure it.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "commands.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/progress.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"
#include "cli_options.hpp"

namespace deepcanvas::server_app {
namespace {

namespace cli = deepcanvas::base::cli;
using Clock = std::chrono::steady_clock;

constexpr const char* kDescription =
    "Applies the strokes of each INPUT in order to one fresh canvas, headless, and reports the\n"
    "result: a short summary, or with --json one JSON object on stdout. An INPUT is an\n"
    "A-Painter .apa painting or a deepcanvas stroke log (recognised by its magic bytes).\n"
    "--scale and --offset apply to the INPUT that follows them only, then reset.\n"
    "\n"
    "A stroke the canvas rejects (outside the canvas, bad values) is reported on stderr,\n"
    "counted in `rejected` and skipped; unreadable inputs fail the command.\n"
    "Exit status: 0 when every stroke was applied, 3 when some were rejected, 1 on a failure,\n"
    "2 on bad options.\n";

constexpr const char* kExamples =
    "JSON fields: strokes, rejected, samples, cells, leaves, max_depth, pool_bytes,\n"
    "bytes_per_cell, canvas_hash, pool_hash, seconds, strokes_per_s, cells_changed,\n"
    "cells_changed_per_s, steps, step_ms_p50, step_ms_p99, step_ms_max.\n"
    "\n"
    "Examples:\n"
    "  deepcanvas-server replay demo.apa\n"
    "  deepcanvas-server replay --json demo.apa\n"
    "  deepcanvas-server replay demo.apa --scale 2 --offset 1,0,0 dancer.apa --log-out both.log\n"
    "      dancer.apa twice as large, 1 m along +x, after demo.apa; every stroke logged\n"
    "  deepcanvas-server replay both.log\n";

struct Input {
  std::string path;
  paintings::ApaTransform tf;
};

Result<std::vector<protocol::Stroke>> load(const Input& in) {
  auto bytes = paintings::read_file_bytes(in.path);
  if (!bytes) return std::move(bytes).error();
  if (!server_core::looks_like_stroke_log(*bytes)) {
    // read_apa_file reads the file again so that its messages (not a painting, where it is
    // malformed) name the file the one way every command prints them.
    auto apa = paintings::read_apa_file(in.path, in.tf);
    if (!apa) return std::move(apa).error();
    return std::move(apa->strokes);
  }
  auto log = server_core::read_stroke_log(*bytes);
  if (!log) return Error{log.error().code, in.path + ": " + log.error().message};
  if (log->tail)
    std::fprintf(stderr,
                 "deepcanvas-server replay: %s: stopped at offset %llu: %s (%zu strokes before it "
                 "kept)\n",
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

void print_summary(const nlohmann::json& j) {
  auto u = [&](const char* k) { return j[k].get<std::uint64_t>(); };
  auto d = [&](const char* k) { return j[k].get<double>(); };
  std::printf("replayed %llu strokes (%llu rejected, %llu samples) in %.2f s: %.1f strokes/s, "
              "%.2f M cells changed/s\n",
              static_cast<unsigned long long>(u("strokes")),
              static_cast<unsigned long long>(u("rejected")),
              static_cast<unsigned long long>(u("samples")), d("seconds"), d("strokes_per_s"),
              d("cells_changed_per_s") / 1e6);
  std::printf("canvas: %llu cells, %llu leaves, depth %llu, pools %.1f MiB (%.1f bytes/cell)\n",
              static_cast<unsigned long long>(u("cells")),
              static_cast<unsigned long long>(u("leaves")),
              static_cast<unsigned long long>(u("max_depth")),
              static_cast<double>(u("pool_bytes")) / (1 << 20), d("bytes_per_cell"));
  std::printf("hashes: canvas %s, pool %s\n", j["canvas_hash"].get<std::string>().c_str(),
              j["pool_hash"].get<std::string>().c_str());
  std::printf("painter steps: %llu, p50 %.3f ms, p99 %.3f ms, max %.3f ms\n",
              static_cast<unsigned long long>(u("steps")), d("step_ms_p50"), d("step_ms_p99"),
              d("step_ms_max"));
}

int replay_main(int argc, char** argv) {
  std::vector<std::string> paths, scales, offsets;
  bool json = false, quiet = false;
  std::string log_out;
  server_core::PainterConfig pc;

  CLI::App app{kDescription, "deepcanvas-server replay"};
  cli::standard(app, kExamples);
  auto* input_opt =
      app.add_option("INPUT", paths, "an .apa painting or a stroke log; at least one")
          ->type_name("FILE");
  auto* scale_opt =
      app.add_option("--scale", scales,
                     "multiply the next INPUT's positions and radii by S (default 1)")
          ->type_name("S")
          ->allow_extra_args(false)
          ->transform(positive());
  auto* offset_opt = app.add_option("--offset", offsets,
                                    "then add this offset in canvas metres to the next INPUT "
                                    "(default 0,0,0)")
                         ->type_name("X,Y,Z")
                         ->allow_extra_args(false)
                         ->check(triple());
  app.add_flag("--json", json, "print one JSON object with the figures on stdout");
  app.add_option("--log-out", log_out, "write every applied stroke (transformed) to a stroke log")
      ->type_name("FILE");
  app.add_option("--step-cap", pc.max_cells_per_step,
                 "painter cap on cells per adjustment step (default 65536)")
      ->type_name("N")
      ->transform(whole(8));
  app.add_flag("--quiet", quiet, "no progress on stderr");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  // Checked here rather than with CLI11's required(), which would report a missing INPUT before
  // a misspelt option.
  if (paths.empty()) return usage_error(app, "give at least one INPUT");

  // --scale and --offset bind to the INPUT after them: walk the options in command-line order.
  std::vector<Input> inputs;
  {
    Input next;
    bool pending = false;
    std::size_t n_scale = 0, n_offset = 0, n_input = 0;
    for (const CLI::Option* o : app.parse_order()) {
      if (o == scale_opt) {
        next.tf.scale = *parse_number(scales[n_scale++]);
        pending = true;
      } else if (o == offset_opt) {
        const auto t = *parse_triple(offsets[n_offset++]);
        std::copy(t.begin(), t.end(), next.tf.offset);
        pending = true;
      } else if (o == input_opt) {
        next.path = paths[n_input++];
        inputs.push_back(next);
        next = Input{};
        pending = false;
      }
    }
    if (pending) return usage_error(app, "--scale/--offset after the last INPUT apply to nothing");
  }

  std::vector<std::vector<protocol::Stroke>> loaded;
  std::size_t total_strokes = 0;
  for (const auto& in : inputs) {
    auto s = load(in);
    if (!s) return cli::fail(app, s.error().message);
    total_strokes += s->size();
    loaded.push_back(std::move(*s));
  }

  auto tree = server_core::Octree::create({});
  if (!tree) return cli::fail(app, tree.error().message);
  auto painter = server_core::Painter::create(**tree, pc);
  if (!painter) return cli::fail(app, painter.error().message);
  std::optional<server_core::StrokeLogWriter> writer;
  if (!log_out.empty()) {
    auto w = server_core::StrokeLogWriter::open(log_out, false, server_core::FsyncPolicy::on_flush);
    if (!w) return cli::fail(app, "--log-out: " + w.error().message);
    writer.emplace(std::move(*w));
  }

  base::Progress progress("replay", static_cast<double>(total_strokes), "strokes", !quiet);
  std::vector<double> step_ms;
  std::uint64_t strokes = 0, rejected = 0, samples = 0, cells_changed = 0, id = 0;
  const auto t0 = Clock::now();
  auto& p = **painter;
  for (const auto& list : loaded) {
    for (const auto& stroke : list) {
      ++id;
      progress.update(static_cast<double>(id - 1));
      auto s0 = Clock::now();
      auto r = p.begin_stroke(stroke.brush, id, stroke.samples);
      if (!r) {
        ++rejected;
        std::fprintf(stderr, "%s: stroke %llu rejected: %s\n", app.get_name().c_str(),
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
          progress.finish();
          return cli::fail(app, "stroke " + std::to_string(id) + " failed: " +
                                    more.error().message);
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
          progress.finish();
          return cli::fail(app, "--log-out: " + w.error().message);
        }
      }
    }
  }
  progress.update(static_cast<double>(id));
  progress.finish();
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  if (writer) {
    if (auto c = writer->close(); !c) return cli::fail(app, "--log-out: " + c.error().message);
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
    print_summary(j);
  }
  return rejected == 0 ? 0 : 3;
}

}  // namespace

DEEPCANVAS_SERVER_COMMAND("replay", "apply .apa paintings or stroke logs headless and report",
                          replay_main);

}  // namespace deepcanvas::server_app
