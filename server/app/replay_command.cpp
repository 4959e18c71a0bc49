// `deepcanvas-server replay`: applies .apa paintings and stroke logs headless (no network) and
// reports the canvas it made. Used to check the painter end to end and to measure it.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <cstdio>
#include <cstring>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <set>
#include <span>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "canvas_options.hpp"
#include "cli_options.hpp"
#include "commands.hpp"
#include "history_input.hpp"
#include "png_turntable.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/percentile.hpp"
#include "deepcanvas/base/progress.hpp"
#include "deepcanvas/export/mesh_export.hpp"
#include "deepcanvas/export/vdb_export.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/server_core/undo_history.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"
#include "deepcanvas/storage/canvas_store.hpp"

namespace deepcanvas::server_app {
namespace {

namespace cli = deepcanvas::base::cli;
using Clock = std::chrono::steady_clock;

constexpr const char* kDescription =
    "Applies the strokes of each INPUT in order to one fresh canvas, headless, and reports the\n"
    "result: a short summary, or with --json one JSON object on stdout. An INPUT is an\n"
    "A-Painter .apa painting, a deepcanvas stroke log, or a canvas of a data directory\n"
    "(DIR/NAME.canvas, or DIR/NAME; recognised by their magic bytes): a canvas's whole history,\n"
    "or with --until its history up to a stroke, on a canvas of the canvas's own shape.\n"
    "--scale and --offset apply to the INPUT that follows them only, then reset.\n"
    "\n"
    "A stroke log holds a canvas's stroke events (a stroke's begin, a batch of its samples, its\n"
    "end) in the order its painter took them, several artists' strokes interleaved (serve\n"
    "--stroke-log records one). They are replayed in that order, each painted to completion\n"
    "before the next, which reproduces the canvas (canvas_hash) when the canvas options match\n"
    "the server's. A painting is replayed stroke by stroke. Stroke ids are renumbered from 1\n"
    "across the INPUTs; --log-out writes the applied events (version-2 log; this also converts\n"
    "a version-1 log).\n"
    "\n"
    "An event the canvas refuses (outside the canvas, bad values, an id with no begin) is\n"
    "reported on stderr, counted in `rejected` and skipped; a stroke an error stops while it is\n"
    "painted (a limit) keeps its paint and is counted in `stopped`, as on a server; strokes\n"
    "with no end are counted in `unfinished` (their paint is kept). Unreadable inputs fail the\n"
    "command.\n"
    "Exit status: 0 when every event was applied, 3 when some were rejected or stopped, 1 on a\n"
    "failure, 2 on bad options.\n";

constexpr const char* kExamples =
    "JSON fields: events, strokes, rejected, stopped, unfinished, samples, cells, leaves,\n"
    "max_depth, pool_bytes, bytes_per_cell, canvas_hash, pool_hash, seconds, strokes_per_s,\n"
    "cells_changed, cells_changed_per_s, steps, step_ms_p50, step_ms_p99, step_ms_max.\n"
    "\n"
    "Examples:\n"
    "  deepcanvas-server replay demo.apa\n"
    "  deepcanvas-server replay --json demo.apa\n"
    "  deepcanvas-server replay demo.apa --scale 2 --offset 1,0,0 dancer.apa --log-out both.log\n"
    "      dancer.apa twice as large, 1 m along +x, after demo.apa; every event logged\n"
    "  deepcanvas-server replay both.log\n"
    "  deepcanvas-server replay --edge 8 --max-depth 12 canvas.log\n"
    "  deepcanvas-server replay --tile-to-cells 16000000 --seed 7 demo.apa dancer.apa --log-out big.dcs\n"
    "      a 16M-cell canvas of the two paintings at 0.01x..100x all over it, as a stroke log\n"
    "  deepcanvas-server replay deepcanvas-data/main --until 120\n"
    "      canvas main of a data directory as it was after its stroke 120 (its own shape)\n"
    "      a log that `serve --edge 8 --max-depth 12 --stroke-log canvas.log` recorded\n";

std::string hex(std::uint64_t v) {
  char b[32];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(v));
  return b;
}

void print_summary(const nlohmann::json& j) {
  auto u = [&](const char* k) { return j[k].get<std::uint64_t>(); };
  auto d = [&](const char* k) { return j[k].get<double>(); };
  std::printf(
      "replayed %llu strokes (%llu rejected, %llu samples) in %.2f s: %.1f strokes/s, "
      "%.2f M cells changed/s\n",
      static_cast<unsigned long long>(u("strokes")), static_cast<unsigned long long>(u("rejected")),
      static_cast<unsigned long long>(u("samples")), d("seconds"), d("strokes_per_s"),
      d("cells_changed_per_s") / 1e6);
  if (j.contains("undos") && u("undos") > 0)
    std::printf("undone or redone: %llu (undo and redo events)\n",
                static_cast<unsigned long long>(u("undos")));
  if (j.contains("imports") && u("imports") > 0)
    std::printf("imports: %llu (paste events)\n", static_cast<unsigned long long>(u("imports")));
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

struct ReplayOptions {
  std::vector<std::string> paths, scales, offsets;
  bool json = false, quiet = false;
  std::uint64_t until = 0;  // --until STROKE
  std::uint64_t tile_cells = 0, seed = 1;  // --tile-to-cells N, --seed S
  std::string log_out;
  // No extent limit: a replay paints strokes a server accepted, or a painting the operator
  // chose to place (--scale 1000 makes a painting ~1 km across); the limit guards a live canvas
  // against one client. The cell limit and the capacity still apply.
  server_core::PainterConfig painter = [] {
    server_core::PainterConfig c;
    c.limits.max_extent_m = 1e9;
    return c;
  }();
  // The canvas's shape: a stroke log replays to the served canvas on a canvas of the same shape.
  server_core::OctreeConfig octree;
  // The positional and transform options, to walk them in command-line order.
  CLI::Option* input_opt = nullptr;
  CLI::Option* scale_opt = nullptr;
  CLI::Option* offset_opt = nullptr;
};

void add_replay_options(CLI::App& app, ReplayOptions& o) {
  o.input_opt = app.add_option("INPUT", o.paths, "an .apa painting or a stroke log; at least one")
                    ->type_name("FILE");
  o.scale_opt = app.add_option("--scale", o.scales,
                               "multiply the next INPUT's positions and radii by S (default 1)")
                    ->type_name("S")
                    ->allow_extra_args(false)
                    ->transform(positive());
  o.offset_opt = app.add_option("--offset", o.offsets,
                                "then add this offset in canvas metres to the next INPUT "
                                "(default 0,0,0)")
                     ->type_name("X,Y,Z")
                     ->allow_extra_args(false)
                     ->check(triple());
  app.add_flag("--json", o.json, "print one JSON object with the figures on stdout");
  app.add_option("--log-out", o.log_out,
                 "write every applied event (transformed, renumbered) to a stroke log")
      ->type_name("FILE");
  app.add_option("--step-cap", o.painter.max_cells_per_step,
                 "painter cap on cells per adjustment step (default 65536)")
      ->type_name("N")
      ->transform(whole(8));
  app.add_flag("--quiet", o.quiet, "no progress on stderr");
  app.add_option("--until", o.until,
                 "for a canvas database: replay its history up to the end of this stroke")
      ->type_name("STROKE")
      ->transform(whole(1));
  app.add_option("--tile-to-cells", o.tile_cells,
                 "a large canvas: place the INPUTs again and again, each time one picked at "
                 "random, scaled by 10^U(-2,2) (0.01x to 100x) at a random place inside the "
                 "canvas, until the canvas holds N cells (deterministic for --seed; imports in "
                 "the INPUTs are left out)")
      ->type_name("N")
      ->transform(whole(1, 1ull << 28));
  app.add_option("--seed", o.seed, "--tile-to-cells: the placements' random seed (default 1)")
      ->type_name("S");
  add_octree_options(app, o.octree);
  add_stroke_limit_options(app, o.painter.limits, o.painter.capacity_reserve, "no limit");
}

// --scale and --offset bind to the INPUT after them: walks the options in command-line order.
// nullopt when a --scale or --offset follows the last INPUT.
std::optional<std::vector<Input>> inputs_with_transforms(const CLI::App& app,
                                                         const ReplayOptions& o) {
  std::vector<Input> inputs;
  Input next;
  bool pending = false;
  std::size_t n_scale = 0, n_offset = 0, n_input = 0;
  for (const CLI::Option* opt : app.parse_order()) {
    if (opt == o.scale_opt) {
      next.tf.scale = *parse_number(o.scales[n_scale++]);
      pending = true;
    } else if (opt == o.offset_opt) {
      const auto t = *parse_triple(o.offsets[n_offset++]);
      std::copy(t.begin(), t.end(), next.tf.offset);
      pending = true;
    } else if (opt == o.input_opt) {
      next.path = o.paths[n_input++];
      inputs.push_back(next);
      next = Input{};
      pending = false;
    }
  }
  if (pending) return std::nullopt;
  return inputs;
}

// What the replay loop counts; step_ms holds every painter call's duration.
struct ReplayTotals {
  std::uint64_t events = 0, strokes = 0, rejected = 0, stopped = 0, unfinished = 0, samples = 0,
                cells_changed = 0, undos = 0, pastes = 0, placements = 0;
  std::vector<double> step_ms;
  double seconds = 0;
};

// Replays events in order, each painted to completion before the next (what reproduces a
// canvas that painted several strokes interleaved: stroke_log.hpp). Stroke ids are renumbered
// from 1 in order of their begins across every input, so that inputs cannot collide.
class EventReplayer {
 public:
  EventReplayer(std::string command, server_core::Painter& p,
                std::optional<server_core::StrokeLogWriter>& writer, ReplayTotals& totals)
      : command_(std::move(command)), p_(p), writer_(writer), t_(totals) {}

  // A new input: its stroke ids are its own. `events` are its events (its undo and redo events
  // name the strokes whose changes must be kept).
  void next_input(std::span<const server_core::StrokeEvent> events) {
    ids_.clear();
    dead_.clear();
    ended_.clear();
    named_.clear();
    for (const auto& e : events)
      if (e.kind == server_core::StrokeEvent::Kind::undo ||
          e.kind == server_core::StrokeEvent::Kind::redo)
        named_.insert(e.stroke_id);
    if (!named_.empty()) p_.set_record_diffs(true);
  }

  // An event the painter refuses is reported and counted in `rejected` (a refused begin also
  // skips that stroke's later events); a stroke an error stops while it paints (a limit) is
  // normal and deterministic: reported and counted in `stopped`. Only a failing --log-out is an
  // error.
  Result<void> play(const server_core::StrokeEvent& e) {
    using Kind = server_core::StrokeEvent::Kind;
    ++t_.events;
    if (e.kind == Kind::undo || e.kind == Kind::redo) return play_undo(e);
    if (e.kind == Kind::paste) return play_paste(e);
    if (dead_.count(e.stroke_id) && e.kind != Kind::begin) return {};
    std::uint64_t id = 0;
    if (e.kind == Kind::begin) {
      // A begin for an id that is open (a log a restarted server continued: its ids start
      // again) is a new stroke; the earlier one stays unfinished, as it did on the server.
      id = ++next_id_;
      dead_.erase(e.stroke_id);
    } else if (auto it = ids_.find(e.stroke_id); it != ids_.end()) {
      id = it->second;
    } else {
      return reject(e.stroke_id, "no stroke with this id has begun");
    }
    auto s0 = Clock::now();
    Result<void> r = e.kind == Kind::begin     ? p_.begin_stroke(e.brush, id, e.samples)
                     : e.kind == Kind::samples ? p_.add_samples(id, e.samples)
                                               : p_.end_stroke(id);
    t_.step_ms.push_back(ms_since(s0));
    if (!r) {
      if (e.kind == Kind::begin) dead_.insert(e.stroke_id);
      return reject(e.stroke_id, r.error().message);
    }
    if (e.kind == Kind::begin) ids_[e.stroke_id] = id;
    t_.samples += e.kind == Kind::end ? 0 : e.samples.size();
    if (writer_) {
      server_core::StrokeEvent logged = e;
      logged.stroke_id = id;
      if (auto w = writer_->append(logged); !w)
        return Error{w.error().code, "--log-out: " + w.error().message};
    }
    for (;;) {
      s0 = Clock::now();
      auto more = p_.step();
      t_.step_ms.push_back(ms_since(s0));
      if (!more) {
        ++t_.stopped;
        t_.cells_changed += p_.stroke_stats().cells_changed();
        std::fprintf(stderr, "%s: stroke %llu stopped: %s\n", command_.c_str(),
                     static_cast<unsigned long long>(e.stroke_id), more.error().message.c_str());
        keep_change(e.stroke_id, id);
        ids_.erase(e.stroke_id);
        dead_.insert(e.stroke_id);
        return {};
      }
      if (!*more) break;
    }
    if (e.kind == Kind::end) {
      ++t_.strokes;
      t_.cells_changed += p_.stroke_stats().cells_changed();
      keep_change(e.stroke_id, id);
      ids_.erase(e.stroke_id);
    }
    return {};
  }

 private:
  static double ms_since(Clock::time_point t0) {
    return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  }
  // A finished stroke's change, kept when a later undo or redo of this input names it.
  void keep_change(std::uint64_t input_id, std::uint64_t id) {
    auto d = p_.take_stroke_diff(id);
    if (!d || !named_.count(input_id)) return;
    ended_[input_id] = id;
    if (d->too_large)
      history_.stroke_too_large(0, id);
    else
      history_.stroke_done(0, id, server_core::encode_cell_diff(*d));
  }
  Result<void> play_undo(const server_core::StrokeEvent& e) {
    const bool redo = e.kind == server_core::StrokeEvent::Kind::redo;
    const auto it = ended_.find(e.stroke_id);
    if (it == ended_.end()) return reject(e.stroke_id, "undo of a stroke that did not end here");
    const auto found = history_.find(it->second, redo);
    if (!found) return reject(e.stroke_id, redo ? "nothing to redo" : "nothing to undo");
    auto diff = server_core::decode_cell_diff(found->second->diff, p_.octree_config());
    if (!diff) return reject(e.stroke_id, diff.error().message);
    auto reverted = p_.revert(*diff);
    if (!reverted) return reject(e.stroke_id, reverted.error().message);
    history_.moved(found->first, it->second, redo, server_core::encode_cell_diff(*reverted));
    ++t_.undos;
    if (writer_) {
      server_core::StrokeEvent logged = e;
      logged.stroke_id = it->second;
      if (auto w = writer_->append(logged); !w)
        return Error{w.error().code, "--log-out: " + w.error().message};
    }
    return {};
  }
  // An import: one whole operation with its own id.
  Result<void> play_paste(const server_core::StrokeEvent& e) {
    auto cells = server_core::decode_cell_paste(e.paste, p_.octree_config());
    if (!cells) return reject(e.stroke_id, cells.error().message);
    const std::uint64_t id = ++next_id_;
    server_core::PasteStats st;
    auto change = p_.paste(*cells, &st);
    if (!change) return reject(e.stroke_id, change.error().message);
    ++t_.pastes;
    t_.cells_changed += st.cells_changed;
    if (named_.count(e.stroke_id)) {
      ended_[e.stroke_id] = id;
      if (change->too_large)
        history_.stroke_too_large(0, id);
      else
        history_.stroke_done(0, id, server_core::encode_cell_diff(*change));
    }
    if (writer_) {
      server_core::StrokeEvent logged = e;
      logged.stroke_id = id;
      if (auto w = writer_->append(logged); !w)
        return Error{w.error().code, "--log-out: " + w.error().message};
    }
    return {};
  }
  Result<void> reject(std::uint64_t stroke_id, const std::string& why) {
    ++t_.rejected;
    std::fprintf(stderr, "%s: event of stroke %llu rejected: %s\n", command_.c_str(),
                 static_cast<unsigned long long>(stroke_id), why.c_str());
    return {};
  }

  std::string command_;
  server_core::Painter& p_;
  std::optional<server_core::StrokeLogWriter>& writer_;
  ReplayTotals& t_;
  std::uint64_t next_id_ = 0;
  std::unordered_map<std::uint64_t, std::uint64_t> ids_;  // the input's id -> the replay's
  std::unordered_set<std::uint64_t> dead_;                // the input's refused/stopped strokes
  // Undo: the input's strokes its undos name, those of them that ended (-> the replay's id),
  // and their changes.
  std::set<std::uint64_t> named_;
  std::unordered_map<std::uint64_t, std::uint64_t> ended_;
  server_core::UndoHistory history_ = server_core::UndoHistory::without_artists({});
};

// Applies every loaded event in order, logging each applied one to writer if set.
Result<void> replay_all(const std::string& command, server_core::Painter& p,
                        const std::vector<std::vector<server_core::StrokeEvent>>& loaded,
                        std::optional<server_core::StrokeLogWriter>& writer,
                        base::Progress& progress, ReplayTotals& totals) {
  EventReplayer replayer(command, p, writer, totals);
  const auto t0 = Clock::now();
  std::uint64_t begun = 0;  // progress counts strokes (their begins)
  for (const auto& list : loaded) {
    replayer.next_input(list);
    for (const auto& e : list) {
      if (e.kind == server_core::StrokeEvent::Kind::begin)
        progress.update(static_cast<double>(begun++));
      if (auto r = replayer.play(e); !r) return r;
    }
  }
  progress.update(static_cast<double>(begun));
  totals.unfinished = p.open_strokes();
  totals.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return {};
}

// --tile-to-cells: the inputs placed again and again until the tree holds `target` cells. Each
// placement picks an input, a scale 10^U(-2, 2) and a position that keeps the scaled painting
// inside the canvas, from one seeded generator, so a seed makes the same canvas every time.
Result<void> replay_tiled(const std::string& command, server_core::Painter& p,
                          const server_core::Octree& tree,
                          const std::vector<std::vector<server_core::StrokeEvent>>& loaded,
                          std::optional<server_core::StrokeLogWriter>& writer,
                          base::Progress& progress, ReplayTotals& totals, std::uint64_t target,
                          std::uint64_t seed) {
  struct Source {
    const std::vector<server_core::StrokeEvent>* events;
    double lo[3], hi[3];
  };
  std::vector<Source> sources;
  for (const auto& list : loaded) {
    Source src{&list, {1e300, 1e300, 1e300}, {-1e300, -1e300, -1e300}};
    for (const auto& e : list)
      for (const auto& smp : e.samples) {
        const double c[3] = {smp.x, smp.y, smp.z};
        for (int k = 0; k < 3; ++k) {
          src.lo[k] = std::min(src.lo[k], c[k] - smp.radius);
          src.hi[k] = std::max(src.hi[k], c[k] + smp.radius);
        }
      }
    if (src.lo[0] <= src.hi[0]) sources.push_back(src);
  }
  if (sources.empty()) return make_error(Errc::invalid_argument, "--tile-to-cells: the INPUTs paint nothing");
  EventReplayer replayer(command, p, writer, totals);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const double edge = tree.config().edge_m;
  const auto t0 = Clock::now();
  std::uint64_t placements = 0;
  while (tree.live_cells() < target) {
    if (++placements > 1'000'000)
      return make_error(Errc::limit_exceeded, "--tile-to-cells: a million placements did not reach the cells asked for");
    const Source& src = sources[rng() % sources.size()];
    double scale = std::pow(10.0, -2.0 + 4.0 * unit(rng));
    double size = 0;
    for (int k = 0; k < 3; ++k) size = std::max(size, src.hi[k] - src.lo[k]);
    scale = std::min(scale, 0.9 * edge / std::max(size, 1e-9));  // it must fit in the canvas
    paintings::ApaTransform tf;
    tf.scale = scale;
    for (int k = 0; k < 3; ++k) {
      const double half = (src.hi[k] - src.lo[k]) * scale / 2;
      const double centre = -edge / 2 + half + (edge - 2 * half) * unit(rng);
      tf.offset[k] = centre - (src.lo[k] + src.hi[k]) / 2 * scale;
    }
    std::vector<server_core::StrokeEvent> placed;
    placed.reserve(src.events->size());
    for (const auto& e : *src.events) {
      if (e.kind == server_core::StrokeEvent::Kind::paste) continue;  // cells: not movable
      placed.push_back(e);
      transform_samples(placed.back().samples, tf);
    }
    replayer.next_input(placed);
    for (const auto& e : placed)
      if (auto r = replayer.play(e); !r) return r;
    progress.update(static_cast<double>(std::min(tree.live_cells(), target)));
  }
  totals.placements = placements;
  totals.unfinished = p.open_strokes();
  totals.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return {};
}

nlohmann::json report(const server_core::Octree& tree, const ReplayTotals& t) {
  const auto st = tree.stats();
  const auto& step_ms = t.step_ms;
  nlohmann::json j;
  j["events"] = t.events;
  j["strokes"] = t.strokes;
  j["rejected"] = t.rejected;
  j["stopped"] = t.stopped;
  j["undos"] = t.undos;
  j["imports"] = t.pastes;
  j["unfinished"] = t.unfinished;
  j["samples"] = t.samples;
  j["cells"] = st.live_cells;
  j["leaves"] = st.leaves;
  j["max_depth"] = st.max_depth;
  j["pool_bytes"] = st.pool_bytes;
  j["bytes_per_cell"] = st.live_cells ? static_cast<double>(st.pool_bytes) / st.live_cells : 0.0;
  j["canvas_hash"] = hex(tree.canvas_hash());
  j["pool_hash"] = hex(tree.pool_hash());
  j["seconds"] = t.seconds;
  j["strokes_per_s"] = t.seconds > 0 ? t.strokes / t.seconds : 0.0;
  j["cells_changed_per_s"] = t.seconds > 0 ? t.cells_changed / t.seconds : 0.0;
  j["cells_changed"] = t.cells_changed;
  if (t.placements) j["placements"] = t.placements;
  j["steps"] = step_ms.size();
  j["step_ms_p50"] = base::percentile(step_ms, 0.5);
  j["step_ms_p99"] = base::percentile(step_ms, 0.99);
  j["step_ms_max"] = step_ms.empty() ? 0 : *std::max_element(step_ms.begin(), step_ms.end());
  return j;
}

// The canvas the command line's INPUTs make (replay and export share it). nullopt with the exit
// code in `code` when it cannot be made; `code` is -1 otherwise.
struct Replayed {
  std::unique_ptr<server_core::Octree> tree;
  std::unique_ptr<server_core::Painter> painter;  // destroyed first: it holds field pools
  ReplayTotals totals;
};
std::optional<Replayed> replay_inputs(CLI::App& app, ReplayOptions& o, int& code) {
  code = -1;
  auto usage = [&](const std::string& m) {
    code = usage_error(app, m);
    return std::nullopt;
  };
  auto failed = [&](const std::string& m) {
    code = cli::fail(app, m);
    return std::nullopt;
  };
  // Checked here rather than with CLI11's required(), which would report a missing INPUT before
  // a misspelt option.
  if (o.paths.empty()) return usage("give at least one INPUT");
  const auto inputs = inputs_with_transforms(app, o);
  if (!inputs) return usage("--scale/--offset after the last INPUT apply to nothing");

  std::vector<std::vector<server_core::StrokeEvent>> loaded;
  std::size_t total_strokes = 0;
  for (const auto& in : *inputs) {
    const auto db = canvas_database(in.path);
    if (!db && o.until != 0) return usage("--until applies to a canvas database only");
    auto s = db ? load_history(*db, o.until, o.octree) : load_input(in, "deepcanvas-server replay");
    if (!s) return failed(s.error().message);
    for (const auto& e : *s) total_strokes += e.kind == server_core::StrokeEvent::Kind::begin;
    loaded.push_back(std::move(*s));
  }

  Replayed r;
  auto tree = server_core::Octree::create(o.octree);
  if (!tree) return failed(tree.error().message);
  r.tree = std::move(*tree);
  auto painter = server_core::Painter::create(*r.tree, o.painter);
  if (!painter) return failed(painter.error().message);
  r.painter = std::move(*painter);
  std::optional<server_core::StrokeLogWriter> writer;
  if (!o.log_out.empty()) {
    auto w =
        server_core::StrokeLogWriter::open(o.log_out, false, server_core::FsyncPolicy::on_flush);
    if (!w) return failed("--log-out: " + w.error().message);
    writer.emplace(std::move(*w));
  }

  base::Progress progress("replay", static_cast<double>(o.tile_cells ? o.tile_cells : total_strokes),
                          o.tile_cells ? "cells" : "strokes", !o.quiet);
  auto replayed =
      o.tile_cells ? replay_tiled(app.get_name(), *r.painter, *r.tree, loaded, writer, progress,
                                  r.totals, o.tile_cells, o.seed)
                   : replay_all(app.get_name(), *r.painter, loaded, writer, progress, r.totals);
  progress.finish();
  if (!replayed) return failed(replayed.error().message);
  if (writer) {
    if (auto c = writer->close(); !c) return failed("--log-out: " + c.error().message);
  }
  return r;
}

int replay_main(int argc, char** argv) {
  ReplayOptions o;
  CLI::App app{kDescription, "deepcanvas-server replay"};
  cli::standard(app, kExamples);
  add_replay_options(app, o);
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  int code = -1;
  auto r = replay_inputs(app, o, code);
  if (!r) return code;
  const nlohmann::json j = report(*r->tree, r->totals);
  if (o.json) {
    std::printf("%s\n", j.dump().c_str());
  } else {
    print_summary(j);
  }
  return r->totals.rejected == 0 && r->totals.stopped == 0 ? 0 : 3;
}

constexpr const char* kExportDescription =
    "Replays each INPUT like `replay` (an .apa painting, a stroke log, or a canvas of a data\n"
    "directory) and exports the canvas it makes, at one voxel level (--voxel-size) and within\n"
    "a region (--box).\n"
    "  vdb        an OpenVDB file with a float grid `density` (extinction in 1/metre from the\n"
    "             density model, a fog volume) and a Vec3f grid `Cd` (colour, 0..1), transform\n"
    "             in canvas metres; leaves coarser than the voxels are written as tiles, finer\n"
    "             cells are merged into them.\n"
    "  gltf, glb  the surface of the paint (OpenVDB's volume-to-mesh at opacity --iso) with\n"
    "  ply        vertex colours, adaptive to fit --max-triangles; glTF 2.0 (embedded or binary)\n"
    "             or binary PLY.\n"
    "  png        a turntable: --turntable N frames orbiting the content (FILE_0000.png, ...;\n"
    "             --size, --video with ffmpeg), rendered by deepcanvas-client (the server has no\n"
    "             renderer): the canvas is served on a free loopback port for the duration and\n"
    "             `deepcanvas-client render --turntable N` renders it ($DEEPCANVAS_CLIENT, else\n"
    "             beside this executable or on PATH).\n"
    "The format defaults to the --out file's extension. The size is estimated and printed\n"
    "before anything is written; past --max-bytes nothing is written.\n"
    "Exit status: 0 written, 1 a failure (or past a limit), 2 bad options.\n";

constexpr const char* kExportExamples =
    "Examples:\n"
    "  deepcanvas-server export demo.apa --out demo.vdb\n"
    "  deepcanvas-server export deepcanvas-data/main --out main.vdb --voxel-size 0.005\n"
    "      the canvas of a data directory at 5 mm voxels (the nearest octree level)\n"
    "  deepcanvas-server export demo.apa --out part.vdb --box -1,0,-1,1,2,1 --max-bytes 50000000\n"
    "  deepcanvas-server export demo.apa --out demo.glb --max-triangles 200000\n"
    "  deepcanvas-server export demo.apa --out demo.ply --iso 0.5 --voxel-size 0.01\n"
    "  deepcanvas-server export demo.apa --estimate\n"
    "  deepcanvas-server export deepcanvas-data/main --out spin/main.png --turntable 72 --video main.mp4\n";

int export_main(int argc, char** argv) {
  ReplayOptions o;
  std::string out, format, box;
  double voxel_size = 0, iso = 0.25, adaptivity = 0;
  std::uint64_t max_bytes = 0, max_triangles = 1'000'000;
  bool estimate_only = false;
  CLI::App app{kExportDescription, "deepcanvas-server export"};
  cli::standard(app, kExportExamples);
  add_replay_options(app, o);
  app.add_option("--out", out, "the file to write")->type_name("FILE");
  TurntableOptions turntable;
  app.add_option("--turntable", turntable.frames, "png: frames around the content (default 36)")
      ->type_name("N")
      ->check(CLI::Range(1u, 3600u));
  app.add_option("--size", turntable.size, "png: frame size (default 1280x720)")->type_name("WxH");
  app.add_option("--video", turntable.video, "png: also encode the frames with ffmpeg")->type_name("FILE.mp4");
  app.add_option("--format", format, "vdb, gltf, glb, ply or png (default: from --out's extension)")
      ->type_name("FORMAT")
      ->check(CLI::IsMember({"vdb", "gltf", "glb", "ply", "png"}));
  app.add_option("--voxel-size", voxel_size,
                 "voxel edge in metres, rounded to the nearest octree level (default: the "
                 "deepest painted cell's edge)")
      ->type_name("METRES")
      ->transform(positive());
  app.add_option("--box", box, "export only the cells meeting this box (canvas metres)")
      ->type_name("X0,Y0,Z0,X1,Y1,Z1")
      ->check(box_corners());
  app.add_option("--max-bytes", max_bytes, "refuse when the estimated size is larger (0: no limit)")
      ->type_name("N");
  app.add_flag("--estimate", estimate_only, "print the estimate only; write nothing");
  app.add_option("--iso", iso, "meshes: the surface's opacity, 0..1 exclusive (default 0.25)")
      ->type_name("ALPHA")
      ->check(CLI::Range(0.001, 0.999));
  app.add_option("--adaptivity", adaptivity,
                 "meshes: OpenVDB's adaptivity, 0 (every voxel) to 1 (fewest triangles)")
      ->type_name("A")
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--max-triangles", max_triangles,
                 "meshes: the triangle budget (default 1000000; 0: none); without --voxel-size the "
                 "finest voxel level that fits it, then adaptivity raised to fit")
      ->type_name("N");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  if (out.empty() && !estimate_only) return usage_error(app, "give --out FILE (or --estimate)");
  if (format.empty()) {
    const std::string ext = std::filesystem::path(out).extension().string();
    format = ext.empty() ? "vdb" : ext.substr(1);
    if (format != "png" && format != "vdb" && format != "gltf" && format != "glb" && format != "ply")
      return usage_error(app, "--out " + out + ": give --format (vdb, gltf, glb, ply) or one of "
                              "those extensions");
  }
  if (format == "png" && (estimate_only || !box.empty() || voxel_size > 0 || max_bytes > 0))
    return usage_error(app, "png: a turntable of the whole canvas (--turntable, --size, --video); "
                            "--box, --voxel-size, --max-bytes and --estimate are for files");
  exporting::VdbExportOptions xo;
  xo.max_bytes = max_bytes;
  if (!box.empty()) {
    const auto v = *parse_box(box);  // checked by the option's box_corners() validator
    xo.box = server_core::Aabb{{v[0], v[1], v[2]}, {v[3], v[4], v[5]}};
  }
  o.quiet = o.quiet || o.json;
  int code = -1;
  auto r = replay_inputs(app, o, code);
  if (!r) return code;
  if (format == "png") {
    r->painter.reset();  // it holds the tree's pools
    turntable.out = out;
    turntable.quiet = o.quiet;
    return export_png_turntable(std::move(r->tree), turntable);
  }
  if (voxel_size > 0) xo.voxel_depth = exporting::voxel_depth_for(r->tree->config(), voxel_size);
  if (format == "vdb") {
    auto est = exporting::estimate_vdb(*r->tree, xo);
    if (!est) return cli::fail(app, est.error().message);
    std::fprintf(stderr,
                 "export: voxel level %d (%.6g m), %llu voxels active (%llu written one by one, "
                 "%llu coarser leaves as tiles), about %.1f MB\n",
                 est->voxel_depth, est->voxel_size_m, static_cast<unsigned long long>(est->voxels),
                 static_cast<unsigned long long>(est->leaf_voxels),
                 static_cast<unsigned long long>(est->tiles), est->estimated_bytes / 1e6);
    if (estimate_only) return 0;
    auto done = exporting::export_vdb(*r->tree, xo, out);
    if (!done) return cli::fail(app, done.error().message);
    std::printf("wrote %s: grids density and Cd, %llu active voxels of %.6g m, %llu bytes\n",
                out.c_str(), static_cast<unsigned long long>(done->voxels), done->voxel_size_m,
                static_cast<unsigned long long>(done->file_bytes));
    return 0;
  }
  // A mesh's size is known once it is meshed: the estimate and the --max-bytes check come
  // between meshing and writing.
  exporting::MeshExportOptions mo;
  mo.volume = xo;
  mo.volume.max_bytes = 0;
  mo.iso_alpha = iso;
  mo.adaptivity = adaptivity;
  mo.max_triangles = max_triangles;
  const auto mf = format == "ply"   ? exporting::MeshFormat::ply
                  : format == "glb" ? exporting::MeshFormat::glb
                                    : exporting::MeshFormat::gltf;
  if (!o.quiet) std::fprintf(stderr, "export: meshing the surface at opacity %.3g...\n", iso);
  exporting::MeshExportSummary ms;
  auto mesh = exporting::mesh_canvas(*r->tree, mo, &ms);
  if (!mesh) return cli::fail(app, mesh.error().message);
  const std::uint64_t estimate = exporting::estimate_mesh_bytes(*mesh, mf);
  std::fprintf(stderr,
               "export: voxel level %d (%.6g m), %llu vertices, %llu triangles (adaptivity "
               "%.2f), about %.1f MB\n",
               ms.volume.voxel_depth, ms.volume.voxel_size_m,
               static_cast<unsigned long long>(ms.vertices),
               static_cast<unsigned long long>(ms.triangles), ms.adaptivity, estimate / 1e6);
  if (estimate_only) return 0;
  if (max_bytes != 0 && estimate > max_bytes)
    return cli::fail(app, "the mesh would take about " + std::to_string(estimate) +
                              " bytes, more than --max-bytes " + std::to_string(max_bytes) +
                              ": lower --max-triangles or choose a smaller --box; nothing written");
  auto bytes = exporting::write_mesh(*mesh, mf, out);
  if (!bytes) return cli::fail(app, bytes.error().message);
  std::printf("wrote %s: %llu vertices, %llu triangles (adaptivity %.2f, voxels of %.6g m), "
              "%llu bytes\n",
              out.c_str(), static_cast<unsigned long long>(ms.vertices),
              static_cast<unsigned long long>(ms.triangles), ms.adaptivity,
              ms.volume.voxel_size_m, static_cast<unsigned long long>(*bytes));
  return 0;
}

}  // namespace

DEEPCANVAS_SERVER_COMMAND("replay", "apply .apa paintings or stroke logs headless and report",
                          replay_main);
DEEPCANVAS_SERVER_COMMAND("export", "export a canvas (replayed like replay): OpenVDB, glTF, PLY",
                          export_main);

}  // namespace deepcanvas::server_app
