// `deepcanvas-server inspect`: what a data directory (or one canvas database) holds: strokes,
// authors, checkpoints, size on disk and SQLite's integrity check. Read-only: it can run beside
// the server that holds the directory.
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cli_options.hpp"
#include "commands.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/storage/canvas_store.hpp"
#include "deepcanvas/storage/durable_canvas.hpp"

namespace deepcanvas::server_app {
namespace {

namespace cli = deepcanvas::base::cli;
namespace fs = std::filesystem;

constexpr const char* kDescription =
    "Reports what a data directory (serve --data DIR) holds, canvas by canvas: events and\n"
    "strokes, their authors, the time span, the checkpoints, the size on disk and SQLite's\n"
    "integrity check. PATH is a data directory or one canvas file (DIR/NAME.canvas). It only\n"
    "reads, so it may run while a server holds the directory. --replay also repaints each\n"
    "canvas from its history (serve's default stroke options) and reports its cells, depth and\n"
    "canvas_hash, the hash a served canvas reports after the same strokes.\n"
    "Exit status: 0 when every canvas is sound, 3 when an integrity check failed, 1 when PATH\n"
    "cannot be read, 2 on bad options.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-server inspect deepcanvas-data\n"
    "  deepcanvas-server inspect deepcanvas-data --canvas main --json\n"
    "  sqlite3 deepcanvas-data/main.canvas 'SELECT seq, stroke, kind, artist FROM events "
    "ORDER BY seq DESC LIMIT 5'\n";

std::string iso_time(std::int64_t unix_ms) {
  if (unix_ms <= 0) return "-";
  const std::time_t t = static_cast<std::time_t>(unix_ms / 1000);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

nlohmann::json to_json(const storage::StoreSummary& s) {
  nlohmann::json authors = nlohmann::json::array();
  for (const auto& a : s.authors)
    authors.push_back({{"artist", a.artist},
                       {"role", a.role},
                       {"name", a.name},
                       {"strokes", a.strokes},
                       {"undos", a.undos},
                       {"imports", a.imports},
                       {"events", a.events}});
  nlohmann::json checkpoints = nlohmann::json::array();
  for (const auto& c : s.checkpoints)
    checkpoints.push_back({{"id", c.id},
                           {"event_seq", c.event_seq},
                           {"next_stroke", c.next_stroke},
                           {"block_count", c.block_count},
                           {"blocks_written", c.blocks_written},
                           {"bytes", c.bytes},
                           {"created", iso_time(c.created_ms)}});
  return {{"path", s.path},
          {"canvas", s.canvas},
          {"format_version", s.format_version},
          {"created", iso_time(s.created_ms)},
          {"edge_m", s.config.edge_m},
          {"roots_per_axis", s.config.roots_per_axis},
          {"max_depth", s.config.max_depth},
          {"block_cells", s.config.block_cells},
          {"max_cells", s.config.max_cells},
          {"events", s.events},
          {"last_seq", s.last_seq},
          {"strokes", s.strokes},
          {"first_event", iso_time(s.first_ms)},
          {"last_event", iso_time(s.last_ms)},
          {"authors", authors},
          {"checkpoints", checkpoints},
          {"db_bytes", s.db_bytes},
          {"wal_bytes", s.wal_bytes},
          {"integrity", s.integrity}};
}

void print_text(const storage::StoreSummary& s) {
  std::printf("canvas %s (%s)\n", s.canvas.c_str(), s.path.c_str());
  std::printf("  created %s, edge %g m, %u roots per axis, depth %d, capacity %llu cells\n",
              iso_time(s.created_ms).c_str(), s.config.edge_m, s.config.roots_per_axis,
              s.config.max_depth, static_cast<unsigned long long>(s.config.max_cells));
  std::printf("  %llu events, %llu strokes, %s .. %s\n",
              static_cast<unsigned long long>(s.events),
              static_cast<unsigned long long>(s.strokes), iso_time(s.first_ms).c_str(),
              iso_time(s.last_ms).c_str());
  for (const auto& a : s.authors) {
    std::printf("  author %llu: %s \"%s\", %llu strokes", static_cast<unsigned long long>(a.artist),
                a.role.c_str(), a.name.c_str(), static_cast<unsigned long long>(a.strokes));
    if (a.undos > 0)
      std::printf(", %llu undos and redos", static_cast<unsigned long long>(a.undos));
    if (a.imports > 0) std::printf(", %llu imports", static_cast<unsigned long long>(a.imports));
    std::printf("\n");
  }
  for (const auto& c : s.checkpoints)
    std::printf("  checkpoint %llu at event %llu: %llu blocks, %.1f MiB, %s\n",
                static_cast<unsigned long long>(c.id),
                static_cast<unsigned long long>(c.event_seq),
                static_cast<unsigned long long>(c.blocks_written),
                static_cast<double>(c.bytes) / (1 << 20), iso_time(c.created_ms).c_str());
  std::printf("  on disk %.1f MiB (+ %.1f MiB write-ahead log), integrity %s\n",
              static_cast<double>(s.db_bytes) / (1 << 20),
              static_cast<double>(s.wal_bytes) / (1 << 20), s.integrity.c_str());
}

int inspect_main(int argc, char** argv) {
  std::string path;
  std::vector<std::string> names;
  bool json = false;
  CLI::App app{kDescription, "deepcanvas-server inspect"};
  cli::standard(app, kExamples);
  app.add_option("PATH", path, "a data directory, or one canvas file DIR/NAME.canvas");
  app.add_option("--canvas", names, "only this canvas of the directory (repeatable)")
      ->type_name("NAME");
  app.add_flag("--json", json, "one JSON object on stdout: {\"canvases\": [...]}");
  bool replay = false;
  app.add_flag("--replay", replay,
               "repaint each canvas from its history to report cells and canvas_hash (takes as "
               "long as replaying it)");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  // Checked here rather than with required(), which would report a missing PATH before a
  // misspelt option.
  if (path.empty()) return usage_error(app, "give a data directory or a canvas file (PATH)");

  std::vector<std::string> files;
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    if (names.empty()) names = storage::list_canvases(path);
    for (const auto& n : names)
      files.push_back((fs::path(path) / (n + storage::kCanvasFileSuffix)).string());
    if (files.empty()) return cli::fail(app, path + ": no canvases (no *.canvas files)");
  } else {
    files.push_back(path);
  }
  nlohmann::json all = nlohmann::json::array();
  bool sound = true;
  for (const auto& f : files) {
    auto s = storage::summarize(f);
    if (!s) return cli::fail(app, s.error().message);
    sound = sound && s->integrity == "ok";
    nlohmann::json j = to_json(*s);
    if (replay) {
      auto r = storage::replay_history(f, server_core::CanvasServiceConfig{});
      if (!r) return cli::fail(app, r.error().message);
      const auto st = r->tree->stats();
      char hash[32];
      std::snprintf(hash, sizeof hash, "%016llx",
                    static_cast<unsigned long long>(r->tree->canvas_hash()));
      j["cells"] = st.live_cells;
      j["max_depth_painted"] = st.max_depth;
      j["canvas_hash"] = hash;
      j["strokes_unfinished"] = r->totals.open.size();
    }
    if (json) {
      all.push_back(j);
    } else {
      print_text(*s);
      if (replay)
        std::printf("  replayed: %llu cells, deepest level %d, canvas_hash %s\n",
                    static_cast<unsigned long long>(j["cells"].get<std::uint64_t>()),
                    j["max_depth_painted"].get<int>(), j["canvas_hash"].get<std::string>().c_str());
    }
  }
  if (json) std::printf("%s\n", nlohmann::json{{"canvases", all}}.dump(2).c_str());
  return sound ? 0 : 3;
}

}  // namespace

DEEPCANVAS_SERVER_COMMAND("inspect", "report what a data directory holds", inspect_main);

}  // namespace deepcanvas::server_app
