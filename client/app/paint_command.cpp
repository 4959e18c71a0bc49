// deepcanvas-client paint: sends a painting's strokes to a server.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "cli_options.hpp"
#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "generated_scene.hpp"
#include "resumable_paint.hpp"

namespace deepcanvas::client_app {

namespace {

namespace cli = deepcanvas::base::cli;

constexpr const char* kDescription =
    "Sends a painting's strokes to a deepcanvas server as a painter and waits until the server\n"
    "has acknowledged every one. Progress (strokes sent) goes to stderr. A lost connection is\n"
    "reconnected with backoff and the strokes not yet acknowledged are sent again; the server\n"
    "paints each once (hello client_id, PROTOCOL.md 3.3.1).\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client paint --connect ws://127.0.0.1:7878/main demo.apa\n"
    "  deepcanvas-client paint --connect ws://127.0.0.1:7878/main --generated\n"
    "  deepcanvas-client paint demo.apa --scale 2 --offset 0,1,0 --pace recorded\n"
    "      twice as large, 1 m higher, each stroke drawn at the artist's own pace\n"
    "  deepcanvas-client paint demo.apa --client-id alice --undo-last 3\n"
    "      paint, then take back the last 3 strokes (a later run: --client-id alice\n"
    "      --undo-last 1 without a painting takes back one more)\n"
    "\n"
    "FILE.apa is an A-Painter painting (format: shared/data/apainter/README.md).\n";

// The strokes to send: the .apa file at `painting`, or the generated scene where it is empty,
// both placed by `transform`. An error for an unreadable file (the reader's messages start with
// the file's name) or a painting without strokes.
Result<std::vector<protocol::Stroke>> load_strokes(const std::string& painting,
                                                   const paintings::ApaTransform& transform) {
  std::vector<protocol::Stroke> strokes;
  if (painting.empty()) {
    strokes = generated_scene();
    for (auto& s : strokes)
      for (auto& p : s.samples) {
        p.x = p.x * transform.scale + transform.offset[0];
        p.y = p.y * transform.scale + transform.offset[1];
        p.z = p.z * transform.scale + transform.offset[2];
        p.radius = static_cast<float>(p.radius * transform.scale);
      }
  } else {
    auto apa = paintings::read_apa_file(painting, transform);
    if (!apa) return std::move(apa).error();
    strokes = std::move(apa->strokes);
  }
  if (strokes.empty()) return make_error(Errc::invalid_argument, "the painting has no strokes");
  return strokes;
}

// Undoes this artist's last `n` strokes, one at a time; each answer names the stroke.
int undo_strokes(CLI::App& app, client_core::Client& client, unsigned n, double timeout_s,
                 bool quiet) {
  const auto timeout = std::chrono::milliseconds(static_cast<std::int64_t>(timeout_s * 1000));
  for (unsigned i = 0; i < n; ++i) {
    auto id = client.request_undo();
    if (!id) return cli::fail(app, "undo: " + id.error().message);
    auto r = client.wait_for_undo(*id, timeout);
    if (!r)
      return cli::fail(app, "undo " + std::to_string(i + 1) + " of " + std::to_string(n) + ": " +
                                r.error().message);
    if (!quiet)
      std::fprintf(stderr, "paint: undid stroke %llu (epoch %llu)\n",
                   static_cast<unsigned long long>(r->stroke_id),
                   static_cast<unsigned long long>(r->epoch));
  }
  std::printf("undid %u strokes\n", n);
  return 0;
}

int run_paint(int argc, char** argv) {
  ConnectArgs connect;
  std::string painting, offset, pace = "fast";
  bool generated = false, quiet = false;
  paintings::ApaTransform transform;
  double timeout_s = 600, reconnect_s = 60;
  unsigned undo_last = 0;
  std::string client_id;

  CLI::App app{kDescription, "deepcanvas-client paint"};
  cli::standard(app, kExamples);
  add_connect_options(app, connect);
  app.add_option("PAINTING", painting, "the painting to send (or --generated)")
      ->type_name("FILE.apa");
  app.add_flag("--generated", generated, "the project's own generated scene instead of a file");
  app.add_option("--scale", transform.scale, "uniform scale applied to the painting (default 1)")
      ->type_name("S")
      ->transform(positive());
  app.add_option("--offset", offset, "translation in canvas metres, after scaling (default 0,0,0)")
      ->type_name("X,Y,Z")
      ->check(triple());
  app.add_option("--pace", pace,
                 "fast: whole strokes back to back, as fast as the server's strokes-per-second "
                 "limit allows (default); recorded: each stroke's samples streamed at the "
                 "artist's recorded pace (stroke_begin / stroke_samples / stroke_end), pauses "
                 "between strokes capped at 2 s")
      ->type_name("fast|recorded")
      ->check(CLI::Validator(
          [](std::string& s) -> std::string {
            return s == "fast" || s == "recorded" ? std::string()
                                                  : "expected fast or recorded, got '" + s + "'";
          },
          ""));
  app.add_option("--timeout", timeout_s, "how long to wait for the last ack (default 600)")
      ->type_name("SECONDS")
      ->transform(positive());
  app.add_option("--reconnect-for", reconnect_s,
                 "after a lost connection, keep reconnecting (0.2 s apart, doubling to 5 s) for "
                 "this long before giving up; 0: do not reconnect (default 60)")
      ->type_name("SECONDS")
      ->check(CLI::Range(0.0, 86400.0));
  app.add_option("--undo-last", undo_last,
                 "then undo the last N strokes this client id painted (one by one, each "
                 "answered before the next; PROTOCOL.md 3.10)")
      ->type_name("N")
      ->check(CLI::Range(0u, 100000u));
  app.add_option("--client-id", client_id,
                 "the painter's id (1 to 64 of A-Z a-z 0-9 _ -): the server keys undo by it, so "
                 "a later run with the same id and no painting can --undo-last what this one "
                 "painted (default: a random id per run)")
      ->type_name("ID")
      ->check(CLI::Validator(
          [](std::string& v) -> std::string {
            return protocol::is_valid_client_id(v) ? std::string()
                                                   : "1 to 64 characters of A-Z a-z 0-9 _ -";
          },
          ""));
  app.add_flag("--quiet", quiet, "no progress on stderr");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  const bool paints = generated || !painting.empty();
  if (generated && !painting.empty()) return usage_error(app, "give a FILE.apa or --generated");
  if (!paints && undo_last == 0)
    return usage_error(app, "give a FILE.apa or --generated (or --client-id and --undo-last)");
  if (!paints && client_id.empty())
    return usage_error(app, "--undo-last without a painting needs the --client-id that painted");
  if (!offset.empty()) {
    const auto t = *parse_triple(offset);
    std::copy(t.begin(), t.end(), transform.offset);
  }

  std::vector<protocol::Stroke> strokes;
  if (paints) {
    auto loaded = load_strokes(generated ? std::string() : painting, transform);
    if (!loaded) return cli::fail(app, loaded.error().message);
    strokes = std::move(*loaded);
  }

  auto options = client_options(connect, protocol::Role::painter, "deepcanvas-client paint");
  // paint sends strokes and waits for their acks; it never looks at the canvas, so it asks for
  // no canvas stream (the server sends it no snapshot and no block frames).
  options.keep_replica = false;
  options.block_frames = false;
  options.client_id = client_id.empty() ? random_client_id() : client_id;
  auto client = client_core::Client::connect(options);
  if (!client)
    return cli::fail(app, "cannot join canvas '" + options.canvas + "' at " + connect.url + ": " +
                              client.error().message);
  if (!paints) return undo_strokes(app, **client, undo_last, timeout_s, quiet);
  ResumableOptions run;
  run.recorded_pace = pace == "recorded";
  run.ack_timeout_s = timeout_s;
  run.reconnect_s = reconnect_s;
  run.quiet = quiet;
  run.progress_label = "paint " + (generated ? std::string("generated scene")
                                             : std::filesystem::path(painting).filename().string());
  const auto t_start = std::chrono::steady_clock::now();
  auto done = paint_resumable(std::move(*client), options, strokes, run);
  if (!done) return cli::fail(app, done.error().message);
  const double secs =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  std::printf(
      "painted %zu strokes into canvas '%s' in %.2f s; the last is stroke %llu in epoch %llu\n",
      strokes.size(), options.canvas.c_str(), secs,
      static_cast<unsigned long long>(done->last_ack.stroke_id),
      static_cast<unsigned long long>(done->last_ack.epoch));
  if (done->reconnects > 0 && !quiet)
    std::fprintf(stderr, "paint: %d reconnects, %zu strokes sent again\n", done->reconnects,
                 done->resent);
  if (undo_last == 0) return 0;
  // The painting's connection is over: a new one with the same client id is the same artist.
  auto again = client_core::Client::connect(options);
  if (!again)
    return cli::fail(app, "cannot join canvas '" + options.canvas + "' again to undo: " +
                              again.error().message);
  return undo_strokes(app, **again, undo_last, timeout_s, quiet);
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("paint", "send a painting's strokes (.apa or the generated scene)",
                          run_paint);

}  // namespace deepcanvas::client_app
