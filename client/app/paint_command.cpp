// deepcanvas-client paint: sends a painting's strokes to a server.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "cli_options.hpp"
#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/progress.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "generated_scene.hpp"

namespace deepcanvas::client_app {

namespace {

namespace cli = deepcanvas::base::cli;
using Clock = std::chrono::steady_clock;

constexpr const char* kDescription =
    "Sends a painting's strokes to a deepcanvas server as a painter and waits until the server\n"
    "has acknowledged the last one. Progress (strokes sent) goes to stderr.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client paint --connect ws://127.0.0.1:7878/main demo.apa\n"
    "  deepcanvas-client paint --connect ws://127.0.0.1:7878/main --generated\n"
    "  deepcanvas-client paint demo.apa --scale 2 --offset 0,1,0 --pace recorded\n"
    "      twice as large, 1 m higher, each stroke drawn at the artist's own pace\n"
    "\n"
    "FILE.apa is an A-Painter painting (format: shared/data/apainter/README.md).\n";

// A stroke's samples in chunks of about one controller frame group (~50 ms of recorded time).
void stream_recorded(client_core::Client& client, const protocol::Stroke& stroke,
                     std::uint64_t& handle_out, Result<void>& status) {
  const auto& samples = stroke.samples;
  const auto start = Clock::now();
  const std::uint32_t t0 = samples.front().t_ms;
  auto begin = client.begin_stroke(stroke.brush, {samples.front()});
  if (!begin) {
    status = begin.error();
    return;
  }
  handle_out = *begin;
  std::size_t i = 1;
  while (i < samples.size()) {
    const std::uint32_t chunk_end = samples[i].t_ms + 50;
    std::vector<protocol::StrokeSample> chunk;
    while (i < samples.size() && samples[i].t_ms <= chunk_end) chunk.push_back(samples[i++]);
    if (chunk.empty()) chunk.push_back(samples[i++]);  // timestamps going backwards
    const auto due = start + std::chrono::milliseconds(
                                 std::max<std::int64_t>(0, std::int64_t(chunk.back().t_ms) - t0));
    std::this_thread::sleep_until(due);
    if (auto r = client.add_samples(handle_out, std::move(chunk)); !r) {
      status = r;
      return;
    }
  }
  status = client.end_stroke(handle_out);
}

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

int run_paint(int argc, char** argv) {
  ConnectArgs connect;
  std::string painting, offset, pace = "fast";
  bool generated = false, quiet = false;
  paintings::ApaTransform transform;
  double timeout_s = 600;

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
  app.add_flag("--quiet", quiet, "no progress on stderr");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  if (generated == !painting.empty()) return usage_error(app, "give a FILE.apa or --generated");
  if (!offset.empty()) {
    const auto t = *parse_triple(offset);
    std::copy(t.begin(), t.end(), transform.offset);
  }

  auto loaded = load_strokes(generated ? std::string() : painting, transform);
  if (!loaded) return cli::fail(app, loaded.error().message);
  const std::vector<protocol::Stroke> strokes = std::move(*loaded);

  auto options = client_options(connect, protocol::Role::painter, "deepcanvas-client paint");
  // paint sends strokes and waits for their acks; it never looks at the canvas, so it asks for
  // no canvas stream (the server sends it no snapshot and no block frames).
  options.keep_replica = false;
  options.block_frames = false;
  auto client = client_core::Client::connect(options);
  if (!client)
    return cli::fail(app, "cannot join canvas '" + options.canvas + "' at " + connect.url + ": " +
                              client.error().message);
  auto& c = **client;
  const auto rate = std::max<std::uint32_t>(1, c.welcome().limits.max_strokes_per_second);
  // Stay a little under the server's rate limit.
  const auto interval = std::chrono::microseconds(1'000'000 / rate + 1'000'000 / rate / 10);
  base::Progress progress(
      "paint " + (generated ? std::string("generated scene")
                            : std::filesystem::path(painting).filename().string()),
      static_cast<double>(strokes.size()), "strokes", !quiet);
  const auto t_start = Clock::now();
  auto next_send = t_start;
  std::uint64_t last_handle = 0;
  std::uint32_t prev_end_ms = strokes.front().samples.front().t_ms;
  for (std::size_t k = 0; k < strokes.size(); ++k) {
    const auto& stroke = strokes[k];
    std::this_thread::sleep_until(next_send);
    next_send = std::max(next_send + interval, Clock::now());
    Result<void> status;
    if (pace == "fast") {
      auto h = c.send_stroke(stroke);
      if (h)
        last_handle = *h;
      else
        status = h.error();
    } else {
      const std::int64_t gap = std::int64_t(stroke.samples.front().t_ms) - prev_end_ms;
      std::this_thread::sleep_for(
          std::chrono::milliseconds(std::clamp<std::int64_t>(gap, 0, 2000)));
      stream_recorded(c, stroke, last_handle, status);
      prev_end_ms = stroke.samples.back().t_ms;
    }
    if (!status) {
      progress.finish();
      return cli::fail(app, "stroke " + std::to_string(k) + ": " + status.error().message);
    }
    if (auto err = c.wait_for_error(std::chrono::milliseconds(0))) {
      progress.finish();
      return cli::fail(app, "the server refused a stroke: " + err->message);
    }
    progress.update(static_cast<double>(k + 1));
  }
  progress.finish();
  auto ack = c.wait_for_ack(last_handle, std::chrono::milliseconds(std::int64_t(timeout_s * 1000)));
  if (!ack) {
    if (auto err = c.wait_for_error(std::chrono::milliseconds(0)))
      return cli::fail(app, "the server refused a stroke: " + err->message);
    return cli::fail(app, "no ack for the last stroke: " + ack.error().message);
  }
  const double secs = std::chrono::duration<double>(Clock::now() - t_start).count();
  std::printf(
      "painted %zu strokes into canvas '%s' in %.2f s; the last is stroke %llu in epoch %llu\n",
      strokes.size(), options.canvas.c_str(), secs, static_cast<unsigned long long>(ack->stroke_id),
      static_cast<unsigned long long>(ack->epoch));
  c.close();
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("paint", "send a painting's strokes (.apa or the generated scene)",
                          run_paint);

}  // namespace deepcanvas::client_app
