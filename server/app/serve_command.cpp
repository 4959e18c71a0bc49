// deepcanvas-server serve: serve canvases over WebSocket until SIGINT/SIGTERM.
#include <pthread.h>
#include <signal.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "canvas_options.hpp"
#include "cli_options.hpp"
#include "commands.hpp"
#include "history_input.hpp"
#include "import_worker.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_core/playback.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"
#include "deepcanvas/server_net/server.hpp"
#include "deepcanvas/storage/canvas_store.hpp"
#include "deepcanvas/storage/durable_canvas.hpp"

namespace deepcanvas::server_app {
namespace {

namespace cli = deepcanvas::base::cli;
using server_net::Server;
using server_net::ServerConfig;

constexpr const char* kDescription =
    "Serves canvases over WebSocket: clients send a hello (protocol version, role, token,\n"
    "canvas), then strokes; every client receives the canvas's blocks (a snapshot, then live\n"
    "updates grouped by epoch). HTTP on the same port answers GET /metrics (Prometheus text)\n"
    "and GET /healthz. Log lines (key=value, or JSON with --log-format json) go to stderr.\n"
    "SIGINT/SIGTERM drain it (the strokes read are answered) and stop it; SIGHUP reloads the\n"
    "--tokens file.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-server serve\n"
    "      one canvas 'default' on ws://127.0.0.1:7878/default\n"
    "  deepcanvas-server serve --listen 127.0.0.1:0 --canvas main --canvas scratch\n"
    "      two canvases on a free port (the 'listening' log line names it)\n"
    "  deepcanvas-server serve --listen 0.0.0.0:7878 --tokens tokens.txt --log-format json\n"
    "      every interface; tokens.txt holds lines '<canvas> <role> <token>'; JSON log lines\n"
    "  deepcanvas-server serve --listen 0.0.0.0:7878 --tokens tokens.txt --tls-cert cert.pem "
    "--tls-key key.pem\n"
    "      the same over wss:// (clients: wss://HOST:7878/, --ca cert.pem for a private CA)\n"
    "  deepcanvas-server serve --data /var/lib/deepcanvas --canvas main\n"
    "      keep the canvases in /var/lib/deepcanvas (every canvas there is served; main is\n"
    "      created if missing); an ack means the stroke is on disk\n"
    "  deepcanvas-server serve --in-memory --canvas scratch\n"
    "      nothing on disk: the canvas is gone when the server stops\n"
    "  deepcanvas-server serve --canvas main --stroke-log main.dcs\n"
    "      record main's stroke order; `deepcanvas-server replay main.dcs` repaints it\n"
    "  deepcanvas-server serve --playback deepcanvas-data/main --listen 127.0.0.1:7900\n"
    "      play canvas main's history back for a time-lapse: the canvas 'main' starts empty\n"
    "      and paints forward as clients step it (deepcanvas-client timelapse --playback)\n";

// "HOST:PORT" or "[V6]:PORT", port 0..65535.
bool parse_listen(std::string_view v, std::string& host, std::uint16_t& port) {
  const auto colon = v.rfind(':');
  if (colon == std::string_view::npos) return false;
  const auto p = parse_whole(v.substr(colon + 1));
  if (!p || *p > 65535) return false;
  host = std::string(v.substr(0, colon));
  if (host.size() > 2 && host.front() == '[' && host.back() == ']')
    host = host.substr(1, host.size() - 2);
  if (host.empty()) return false;
  port = static_cast<std::uint16_t>(*p);
  return true;
}

// What the command line sets, before it becomes a ServerConfig.
struct ServeOptions {
  ServerConfig server;
  server_core::CanvasServiceConfig canvas;  // the template every named canvas starts from
  std::vector<std::string> names;
  std::string listen = "127.0.0.1:7878";
  std::string tokens_path;
  std::string log_level = "info";
  std::string log_format = "text";
  double hello_timeout_s = 5;
  double message_timeout_s = 30;
  double drain_timeout_s = 10;
  std::string stroke_log;  // --stroke-log FILE; empty: none
  std::string data_dir = "deepcanvas-data";  // --data DIR
  bool in_memory = false;                     // --in-memory
  bool salvage = false;                       // --salvage
  double checkpoint_every_s = 30;             // --checkpoint-every
  std::string playback;                       // --playback SOURCE
};

std::chrono::milliseconds to_ms(double seconds) {
  return std::chrono::milliseconds(static_cast<std::int64_t>(seconds * 1000.0 + 0.5));
}

void add_address_options(CLI::App& app, ServeOptions& o) {
  app.add_option("--listen", o.listen,
                 "address to listen on (default 127.0.0.1:7878; port 0 picks a free port, "
                 "printed in the 'listening' log line)")
      ->type_name("HOST:PORT")
      ->check(CLI::Validator(
          [](std::string& v) -> std::string {
            std::string host;
            std::uint16_t port = 0;
            return parse_listen(v, host, port) ? std::string()
                                               : "expected HOST:PORT, got '" + v + "'";
          },
          ""));
  app.add_option("--canvas", o.names,
                 "serve a canvas with this name; repeat for several canvases, each with its own "
                 "tree and threads (default: the canvases named in --tokens, or one canvas "
                 "'default')")
      ->type_name("NAME")
      ->allow_extra_args(false);
  app.add_option("--tokens", o.tokens_path,
                 "access tokens: lines '<canvas> <role> <token>', role painter or viewer ('#' "
                 "comments). Without it every client gets the role it asks for, and only a "
                 "loopback address may be used")
      ->type_name("FILE");
  app.add_option("--tls-cert", o.server.tls_cert_file,
                 "serve wss:// (TLS 1.2+): PEM certificate chain, the server's certificate "
                 "first; needs --tls-key. A file that does not load stops the start")
      ->type_name("FILE");
  app.add_option("--tls-key", o.server.tls_key_file,
                 "the PEM private key of --tls-cert (keep it readable by the server only)")
      ->type_name("FILE");
  app.add_option("--threads", o.server.network_threads, "network threads (default 2)")
      ->type_name("N")
      ->transform(whole(1, 64));
}

void add_canvas_shape_options(CLI::App& app, server_core::CanvasServiceConfig& canvas) {
  add_octree_options(app, canvas.octree);
  app.add_option("--max-cells-per-step", canvas.max_cells_per_step,
                 "painter step bound in work units (default 8192)")
      ->type_name("N")
      ->transform(whole(1));
  app.add_option("--zstd-level", canvas.zstd_level, "block compression level (default 3)")
      ->type_name("L")
      ->transform(whole(1, 19));
  add_stroke_limit_options(app, canvas.stroke_limits, canvas.capacity_reserve, "100");
  app.add_option("--max-cells-per-second", canvas.max_cells_per_second_per_artist,
                 "cells one artist's strokes may create per second on average; 0: no limit "
                 "(default 2000000)")
      ->type_name("N")
      ->transform(number(0, 1e12));
  app.add_option("--undo-depth", canvas.undo.depth,
                 "strokes each artist may undo; 0: no undo, and no change kept while painting "
                 "(default 100)")
      ->type_name("N")
      ->transform(whole(0, 100000));
  app.add_option("--undo-max-stroke-bytes", canvas.undo.max_stroke_bytes,
                 "the largest encoded change of one stroke the undo history keeps; a larger "
                 "stroke cannot be undone (default 2097152)")
      ->type_name("BYTES")
      ->transform(whole(1024, 1ull << 32));
  app.add_option("--undo-max-bytes", canvas.undo.max_bytes,
                 "the undo history's memory for all artists of a canvas together; past it the "
                 "oldest strokes of anyone are dropped first (default 134217728)")
      ->type_name("BYTES")
      ->transform(whole(1u << 20, 1ull << 40));
  app.add_option("--undo-max-recording-bytes", canvas.undo.max_recording_bytes,
                 "the memory a canvas's open strokes may hold together recording their changes "
                 "(about 36 bytes a changed cell); past it the largest recording is dropped and "
                 "that stroke cannot be undone (default 67108864)")
      ->type_name("BYTES")
      ->transform(whole(1u << 20, 1ull << 40));
  app.add_option("--samples-per-turn", canvas.samples_per_turn,
                 "samples of one stroke painted per turn before another artist's stroke gets "
                 "the painter (default 64)")
      ->type_name("N")
      ->transform(whole(1, 1u << 20));
  app.add_option("--turn-seconds", canvas.turn_seconds,
                 "while other strokes are open, a stroke's turn holds only the samples that its "
                 "samples so far took this long to paint, at least one; 0: always "
                 "--samples-per-turn (default 0.016)")
      ->type_name("SECONDS")
      ->check(CLI::Range(0.0, 10.0));
}

void add_client_limit_options(CLI::App& app, ServerConfig& cfg) {
  app.add_option("--max-frame-bytes", cfg.limits.max_frame_bytes,
                 "largest message a client may send (default 16777216)")
      ->type_name("N")
      ->transform(whole(0));
  app.add_option("--max-samples", cfg.limits.max_samples_per_stroke,
                 "samples per stroke (default 100000)")
      ->type_name("N")
      ->transform(whole(1, 0xFFFFFFFFu));
  app.add_option("--max-strokes-per-second", cfg.limits.max_strokes_per_second,
                 "strokes per second per session (default 100)")
      ->type_name("N")
      ->transform(whole(0, 0xFFFFFFFFu));
  app.add_option("--max-open-strokes", cfg.limits.max_open_strokes,
                 "streamed strokes open at once per session (default 16)")
      ->type_name("N")
      ->transform(whole(1, 0xFFFFFFFFu));
  app.add_option("--stroke-receipts", cfg.limits.stroke_receipts,
                 "strokes remembered per client id, so that one resent after a lost connection "
                 "is answered with its ack instead of painted twice (default 256; 0: none)")
      ->type_name("N")
      ->transform(whole(0, 1u << 20));
  app.add_option("--max-sessions", cfg.max_sessions, "open WebSocket sessions (default 1024)")
      ->type_name("N")
      ->transform(whole(1));
  app.add_option("--send-buffer-bytes", cfg.socket_send_buffer_bytes,
                 "SO_SNDBUF per client socket (default: the OS's autotuning); smaller makes slow "
                 "clients coalesce sooner")
      ->type_name("N")
      ->transform(whole(0, 1u << 30));
}

// The pre-authentication budget: what a connection may cost before its hello is accepted.
void add_pre_auth_options(CLI::App& app, ServeOptions& o) {
  ServerConfig& cfg = o.server;
  app.add_option("--max-unauthenticated", cfg.max_unauthenticated,
                 "connections without an accepted hello, all addresses together (default 256); "
                 "more are answered HTTP 503 and closed")
      ->type_name("N")
      ->transform(whole(1, 1000000));
  app.add_option("--max-unauthenticated-per-address", cfg.max_unauthenticated_per_address,
                 "connections without an accepted hello from one client address (IPv6: one /64) "
                 "(default 16)")
      ->type_name("N")
      ->transform(whole(1, 1000000));
  app.add_option("--pre-auth-frame-bytes", cfg.pre_auth_frame_bytes,
                 "largest message before the hello is accepted (default 16384; at most "
                 "--max-frame-bytes)")
      ->type_name("N")
      ->transform(whole(1024, 1u << 30));
  app.add_option("--hello-timeout", o.hello_timeout_s,
                 "seconds from the upgrade to the hello before the connection is closed "
                 "(default 5)")
      ->type_name("SECONDS")
      ->transform(number(0.01, 3600));
  app.add_option("--message-timeout", o.message_timeout_s,
                 "seconds a started message may take to arrive whole before the connection is "
                 "closed (default 30)")
      ->type_name("SECONDS")
      ->transform(number(0.01, 3600));
  app.add_option("--drain-timeout", o.drain_timeout_s,
                 "on SIGTERM/SIGINT, seconds to answer the strokes in flight before closing "
                 "(default 10)")
      ->type_name("SECONDS")
      ->transform(number(0, 3600));
}

void add_stroke_log_option(CLI::App& app, ServeOptions& o) {
  app.add_option("--stroke-log", o.stroke_log,
                 "append every canvas's stroke events (strokes' begins, sample batches and ends "
                 "in the order the canvas painted them) to FILE, for `deepcanvas-server replay "
                 "FILE` to reproduce the canvas; with several canvases each has its own file, "
                 "FILE.<canvas>. An existing log is continued. Fsynced at shutdown only: a record "
                 "of stroke order for replays, not durable storage of the canvas")
      ->type_name("FILE");
}

void add_storage_options(CLI::App& app, ServeOptions& o) {
  auto* data = app.add_option("--data", o.data_dir,
                              "keep the canvases in DIR, one SQLite database per canvas "
                              "(DIR/NAME.canvas): every canvas found there is served, and a "
                              "stroke is acked once it is on disk (default deepcanvas-data in "
                              "the working directory)")
                   ->type_name("DIR");
  app.add_flag("--in-memory", o.in_memory,
               "keep the canvases in memory only: nothing is read or written, and the canvases "
               "are gone when the server stops (tests, benchmarks)")
      ->excludes(data);
  app.add_flag("--salvage", o.salvage,
               "start even when a canvas's history holds a corrupt record: keep the strokes "
               "before it and delete it and everything after it (logged)");
  app.add_option("--checkpoint-every", o.checkpoint_every_s,
                 "seconds between checkpoints of a canvas that changed (default 30); a restart "
                 "replays the strokes after the newest checkpoint")
      ->type_name("SECONDS")
      ->transform(number(0.1, 86400));
}

void add_playback_option(CLI::App& app, ServeOptions& o) {
  app.add_option("--playback", o.playback,
                 "serve one canvas that plays SOURCE's history back (PROTOCOL.md 3.13): it "
                 "starts empty and paints the history forward, step by step, as its clients ask "
                 "(deepcanvas-client timelapse --playback); it takes no strokes. SOURCE is a "
                 "canvas of a data directory (DIR/NAME: the canvas is called NAME and has its "
                 "shape), a stroke log or an .apa painting. Kept in memory only")
      ->type_name("SOURCE");
}

// --playback: the history loaded into the one canvas's config (its shape too, for a data
// directory's canvas). Returns the exit code when the history cannot be read.
std::optional<int> load_playback(CLI::App& app, ServeOptions& o) {
  if (o.playback.empty()) return std::nullopt;
  if (o.names.size() > 1) return usage_error(app, "--playback serves one canvas: give one --canvas");
  if (!o.stroke_log.empty()) return usage_error(app, "--playback records nothing: no --stroke-log");
  o.in_memory = true;
  Result<std::vector<server_core::StrokeEvent>> events = std::vector<server_core::StrokeEvent>{};
  if (const auto db = canvas_database(o.playback)) {
    events = load_history(*db, 0, o.canvas.octree);
    if (o.names.empty()) o.names.push_back(std::filesystem::path(*db).stem().string());
  } else {
    events = load_input(Input{o.playback, {}}, "deepcanvas-server serve");
  }
  if (!events) return cli::fail(app, "--playback: " + events.error().message);
  auto history = std::make_shared<server_core::PlaybackHistory>(
      server_core::make_playback_history(std::move(*events), o.canvas.octree));
  base::log_event(base::LogLevel::info, "playback_loaded",
                  {{"source", o.playback},
                   {"events", history->events.size()},
                   {"strokes", history->operations},
                   {"painting_seconds", history->seconds_total()},
                   {"timed", history->timed()}});
  o.canvas.playback = std::move(history);
  return std::nullopt;
}

void add_log_options(CLI::App& app, ServeOptions& o) {
  app.add_option("--log-level", o.log_level, "debug | info | warn | error | off (default info)")
      ->type_name("LEVEL")
      ->check(CLI::Validator(
          [](std::string& v) -> std::string {
            base::LogLevel level;
            return base::parse_log_level(v, level)
                       ? std::string()
                       : "expected debug, info, warn, error or off, got '" + v + "'";
          },
          ""));
  app.add_option("--log-format", o.log_format,
                 "text (key=value lines) | json (one JSON object a line) (default text)")
      ->type_name("FORMAT")
      ->check(CLI::Validator(
          [](std::string& v) -> std::string {
            base::LogFormat format;
            return base::parse_log_format(v, format) ? std::string()
                                                     : "expected text or json, got '" + v + "'";
          },
          ""));
}

void apply_log_options(const ServeOptions& o) {
  base::LogLevel level = base::LogLevel::info;
  base::parse_log_level(o.log_level, level);  // validated by the option's check
  base::set_log_level(level);
  base::LogFormat format = base::LogFormat::text;
  base::parse_log_format(o.log_format, format);
  base::set_log_format(format);
}

// The canvases come from --canvas, else from the tokens file, else one 'default'.
// Returns the exit code when the tokens file cannot be loaded.
std::optional<int> build_server_config(CLI::App& app, ServeOptions& o) {
  parse_listen(o.listen, o.server.listen_address, o.server.port);
  o.server.hello_timeout = to_ms(o.hello_timeout_s);
  o.server.message_timeout = to_ms(o.message_timeout_s);
  if (!o.tokens_path.empty()) {
    auto t = server_net::TokenTable::load(o.tokens_path);
    if (!t) return cli::fail(app, "--tokens: " + t.error().message);
    if (o.names.empty()) o.names = t->canvases();
    o.server.tokens = std::move(*t);
  }
  if (!o.in_memory) {
    // Every canvas kept in the data directory is served, with those named.
    for (auto& n : storage::list_canvases(o.data_dir))
      if (std::find(o.names.begin(), o.names.end(), n) == o.names.end()) o.names.push_back(n);
  }
  if (o.names.empty()) o.names.push_back("default");
  for (const auto& n : o.names) {
    auto c = o.canvas;
    c.name = n;
    o.server.canvases.push_back(std::move(c));
  }
  return std::nullopt;
}

// --stroke-log: one recorder per canvas, wired to its on_stroke_event. They outlive the server
// (closed by close_stroke_logs after it has stopped, so the last events are in). Names that are
// not valid canvas names get no file: the server refuses them at its start.
Result<std::vector<std::shared_ptr<server_core::StrokeLogRecorder>>> open_stroke_logs(
    const std::string& path, std::vector<server_core::CanvasServiceConfig>& canvases) {
  std::vector<std::shared_ptr<server_core::StrokeLogRecorder>> out;
  if (path.empty()) return out;
  for (auto& c : canvases) {
    if (!protocol::is_valid_canvas_name(c.name)) continue;
    const std::string file = canvases.size() == 1 ? path : path + "." + c.name;
    auto r = server_core::StrokeLogRecorder::open(file, c.name);
    if (!r) return Error{r.error().code, "--stroke-log: " + r.error().message};
    if (const auto& tail = (*r)->recovered_tail())
      base::log_event(
          base::LogLevel::warn, "stroke_log_tail_cut",
          {{"canvas", c.name}, {"file", file}, {"offset", tail->offset}, {"reason", tail->reason}});
    base::log_event(base::LogLevel::info, "stroke_log_open", {{"canvas", c.name}, {"file", file}});
    c.on_stroke_event = server_core::StrokeLogRecorder::callback(*r);
    out.push_back(std::move(*r));
  }
  return out;
}

// After the server has stopped: fsyncs and closes each log, and says what it holds.
void close_stroke_logs(const std::vector<std::shared_ptr<server_core::StrokeLogRecorder>>& logs) {
  for (const auto& r : logs) {
    auto c = r->close();
    base::log_event(c ? base::LogLevel::info : base::LogLevel::error, "stroke_log_closed",
                    {{"canvas", r->canvas()},
                     {"events_written", r->events_written()},
                     {"events_dropped", r->dropped()},
                     {"error", c ? std::string() : c.error().message}});
  }
}

// --data: the canvases restored from (or created in) the data directory, which this server holds
// (DataDirLock) from its first canvas on, for as long as the server lives. The lock is taken when
// the server makes its first canvas, after it has checked its configuration, so that a refused
// configuration leaves no directory behind. Each canvas's restore is logged with what it took.
void use_data_directory(const ServeOptions& o, ServerConfig& cfg) {
  storage::StoreOptions store;
  store.checkpoint_every = to_ms(o.checkpoint_every_s);
  auto lock = std::make_shared<std::optional<storage::DataDirLock>>();
  // Each canvas's stroke names, from its restore until the server seeds its receipts with them.
  auto names = std::make_shared<std::map<std::string, server_net::RestoredStrokeNames>>();
  cfg.restored_stroke_names = [names](const std::string& canvas) {
    server_net::RestoredStrokeNames out;
    if (auto it = names->find(canvas); it != names->end()) {
      out = std::move(it->second);
      names->erase(it);
    }
    return out;
  };
  cfg.make_canvas = [dir = o.data_dir, store, salvage = o.salvage, lock, names,
                     canvases = cfg.canvases.size()](const server_core::CanvasServiceConfig& c)
      -> Result<std::unique_ptr<server_core::CanvasService>> {
    if (!*lock) {
      auto l = storage::DataDirLock::acquire(dir);
      if (!l) return Error{l.error().code, "--data: " + l.error().message};
      *lock = std::move(*l);
      base::log_event(base::LogLevel::info, "data_directory",
                      {{"dir", std::filesystem::absolute(dir).string()}, {"canvases", canvases}});
    }
    storage::RestoreReport rep;
    auto svc = storage::open_durable_canvas(dir, c, store, salvage, &rep);
    if (!svc) return svc;
    for (const auto& note : rep.notes)
      base::log_event(base::LogLevel::warn, "canvas_restore_note",
                      {{"canvas", c.name}, {"note", note}});
    base::log_event(base::LogLevel::info, rep.created ? "canvas_created" : "canvas_restored",
                    {{"canvas", c.name},
                     {"file", rep.path},
                     {"checkpoint", rep.checkpoint_id},
                     {"events_replayed", rep.events_replayed},
                     {"strokes_ended", rep.strokes_ended},
                     {"strokes_cut_named", rep.cut_stroke_names.size()},
                     {"stroke_names", rep.stroke_names.size()},
                     {"last_event", rep.last_seq},
                     {"seconds", rep.seconds},
                     {"memory_bound_bytes", server_core::canvas_memory_bound_bytes(c)}});
    (*names)[c.name] = {std::move(rep.stroke_names), std::move(rep.cut_stroke_names)};
    return svc;
  };
}

// SIGHUP: reads the tokens file again. A file that does not load keeps the tokens in use.
void reload_tokens(Server& server, const std::string& path) {
  if (path.empty()) {
    base::log_event(base::LogLevel::warn, "tokens_reload_skipped",
                    {{"reason", "the server was started without --tokens"}});
    return;
  }
  auto t = server_net::TokenTable::load(path);
  if (!t) {
    base::log_event(base::LogLevel::error, "tokens_reload_failed",
                    {{"file", path}, {"error", t.error().message}, {"kept", "previous tokens"}});
    return;
  }
  if (auto r = server.reload_tokens(*t); !r) {
    base::log_event(base::LogLevel::error, "tokens_reload_failed",
                    {{"file", path}, {"error", r.error().message}});
    return;
  }
  base::log_event(base::LogLevel::info, "tokens_reloaded",
                  {{"file", path}, {"entries", t->entries().size()}});
}

// Starts the server and serves until SIGINT or SIGTERM (drained), reloading tokens on SIGHUP.
int serve_until_signal(CLI::App& app, ServerConfig cfg, const ServeOptions& o) {
  // Block the signals in every thread (threads inherit the mask); this thread waits for them
  // with sigwait, so no async-signal-safety concerns arise.
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
  // A client that vanishes mid-write must not kill the server.
  signal(SIGPIPE, SIG_IGN);

  // invalid_argument: the server refuses the configuration the options made (a bad canvas
  // name, an odd --roots, a public address without --tokens), a usage error; anything else
  // (the port is taken) is a runtime failure.
  auto refused = [&](const Error& e) {
    return e.code == Errc::invalid_argument ? usage_error(app, e.message)
                                            : cli::fail(app, e.message);
  };
  auto server = Server::create(std::move(cfg));
  if (!server) return refused(server.error());
  if (auto r = (*server)->start(); !r) return refused(r.error());
  for (;;) {
    int sig = 0;
    sigwait(&set, &sig);
    const char* name = sig == SIGINT ? "SIGINT" : sig == SIGTERM ? "SIGTERM" : "SIGHUP";
    base::log_event(base::LogLevel::info, "signal", {{"signal", name}});
    if (sig == SIGHUP) {
      reload_tokens(**server, o.tokens_path);
      continue;
    }
    (*server)->drain(to_ms(o.drain_timeout_s));
    return 0;
  }
}

int serve_main(int argc, char** argv) {
  ServeOptions o;
  CLI::App app{kDescription, "deepcanvas-server serve"};
  cli::standard(app, kExamples);
  add_address_options(app, o);
  add_canvas_shape_options(app, o.canvas);
  add_client_limit_options(app, o.server);
  add_pre_auth_options(app, o);
  add_stroke_log_option(app, o);
  add_storage_options(app, o);
  add_playback_option(app, o);
  add_log_options(app, o);
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;

  apply_log_options(o);
  if (auto code = load_playback(app, o)) return *code;
  if (auto code = build_server_config(app, o)) return *code;
  auto logs = open_stroke_logs(o.stroke_log, o.server.canvases);
  if (!logs) return cli::fail(app, logs.error().message);
  ServerConfig cfg = std::move(o.server);
  if (!o.in_memory) use_data_directory(o, cfg);
  // Imports (PROTOCOL.md 3.11): files converted by the export target's importer, in a child
  // process (import_worker.cpp: a damaged file may crash a reader, never the server).
  cfg.import_cells = [](const protocol::Import& m, const server_core::OctreeConfig& canvas) {
    return import_in_worker(m, canvas);
  };
  // Exports for clients (PROTOCOL.md 3.12): the canvas's copy written in this process (the tree
  // is the server's own, not untrusted bytes).
  cfg.export_canvas = export_for_client;
  const int rc = serve_until_signal(app, std::move(cfg), o);
  close_stroke_logs(*logs);
  return rc;
}

}  // namespace

DEEPCANVAS_SERVER_COMMAND("serve", "serve canvases over WebSocket", serve_main);

}  // namespace deepcanvas::server_app
