// deepcanvas-client paint: sends a painting's strokes to a server.
#include <unistd.h>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/protocol/apa.hpp"
#include "generated_scene.hpp"

namespace deepcanvas::client_app {

namespace {

using Clock = std::chrono::steady_clock;

void paint_usage(FILE* out) {
  std::fprintf(
      out,
      "usage: deepcanvas-client paint [--connect URL] (PAINTING.apa | --generated)\n"
      "                               [--scale S] [--offset X,Y,Z]\n"
      "                               [--pace recorded|fast] [--timeout SECONDS]\n\n"
      "Sends a painting's strokes to a deepcanvas server as a painter and waits until\n"
      "the server has acknowledged the last one.\n\n"
      "%s"
      "  PAINTING.apa       an A-Painter painting (format: shared/data/apainter/README.md)\n"
      "  --generated        the project's own generated scene instead of a file\n"
      "  --scale S          uniform scale applied to the painting (default 1)\n"
      "  --offset X,Y,Z     translation in canvas metres, after scaling (default 0,0,0)\n"
      "  --pace fast        whole strokes back to back, as fast as the server's\n"
      "                     strokes-per-second limit allows (default)\n"
      "  --pace recorded    streams each stroke's samples at the artist's recorded pace\n"
      "                     (stroke_begin / stroke_samples / stroke_end); pauses between\n"
      "                     strokes are capped at 2 s\n"
      "  --timeout SECONDS  how long to wait for the last ack (default 600)\n",
      kConnectHelp);
}

bool parse_offset(const std::string& s, double out[3]) {
  char* end = nullptr;
  const char* p = s.c_str();
  for (int i = 0; i < 3; ++i) {
    out[i] = std::strtod(p, &end);
    if (end == p) return false;
    p = end;
    if (i < 2) {
      if (*p != ',') return false;
      ++p;
    }
  }
  return *p == '\0';
}

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

int run_paint(int argc, char** argv) {
  ConnectArgs connect;
  std::string painting, pace = "fast";
  bool generated = false;
  protocol::ApaTransform transform;
  double timeout_s = 600;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto shared = parse_connect_option(argc, argv, i, connect);
    if (!shared) {
      std::fprintf(stderr, "paint: %s\n", shared.error().message.c_str());
      return 2;
    }
    if (*shared) continue;
    auto value = [&](const char* name) -> const char* {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "paint: %s needs a value\n", name);
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "-h" || a == "--help") {
      paint_usage(stdout);
      return 0;
    } else if (a == "--generated") {
      generated = true;
    } else if (a == "--scale") {
      char* end = nullptr;
      const char* v = value("--scale");
      transform.scale = std::strtod(v, &end);
      if (*end || !(transform.scale > 0) || !std::isfinite(transform.scale)) {
        std::fprintf(stderr, "paint: --scale must be a positive number, got '%s'\n", v);
        return 2;
      }
    } else if (a == "--offset") {
      const char* v = value("--offset");
      if (!parse_offset(v, transform.offset)) {
        std::fprintf(stderr, "paint: --offset must be X,Y,Z, got '%s'\n", v);
        return 2;
      }
    } else if (a == "--pace") {
      pace = value("--pace");
      if (pace != "fast" && pace != "recorded") {
        std::fprintf(stderr, "paint: --pace must be recorded or fast, got '%s'\n", pace.c_str());
        return 2;
      }
    } else if (a == "--timeout") {
      timeout_s = std::atof(value("--timeout"));
    } else if (!a.empty() && a[0] == '-') {
      std::fprintf(stderr, "paint: unknown option '%s'\n\n", a.c_str());
      paint_usage(stderr);
      return 2;
    } else if (painting.empty()) {
      painting = a;
    } else {
      std::fprintf(stderr, "paint: one painting at a time ('%s' and '%s')\n", painting.c_str(),
                   a.c_str());
      return 2;
    }
  }
  if (generated == !painting.empty()) {
    std::fprintf(stderr, "paint: give either a PAINTING.apa or --generated\n\n");
    paint_usage(stderr);
    return 2;
  }

  std::vector<protocol::Stroke> strokes;
  if (generated) {
    strokes = generated_scene();
    for (auto& s : strokes)
      for (auto& p : s.samples) {
        p.x = p.x * transform.scale + transform.offset[0];
        p.y = p.y * transform.scale + transform.offset[1];
        p.z = p.z * transform.scale + transform.offset[2];
        p.radius = static_cast<float>(p.radius * transform.scale);
      }
  } else {
    auto apa = protocol::read_apa_file(painting, transform);
    if (!apa) {
      std::fprintf(stderr, "paint: %s: %s\n", painting.c_str(), apa.error().message.c_str());
      return 1;
    }
    strokes = std::move(apa->strokes);
  }
  if (strokes.empty()) {
    std::fprintf(stderr, "paint: the painting has no strokes\n");
    return 1;
  }

  auto options = client_options(connect, protocol::Role::painter, "deepcanvas-client paint");
  if (!options) {
    std::fprintf(stderr, "paint: %s\n", options.error().message.c_str());
    return 2;
  }
  // paint sends strokes and waits for their acks; it never looks at the canvas, so it asks for
  // no canvas stream (the server sends it no snapshot and no block frames).
  options->keep_replica = false;
  options->block_frames = false;
  auto client = client_core::Client::connect(*options);
  if (!client) {
    std::fprintf(stderr, "paint: cannot join canvas '%s' at %s: %s\n", options->canvas.c_str(),
                 connect.url.c_str(), client.error().message.c_str());
    return 1;
  }
  auto& c = **client;
  const auto rate = std::max<std::uint32_t>(1, c.welcome().limits.max_strokes_per_second);
  // Stay a little under the server's rate limit.
  const auto interval = std::chrono::microseconds(1'000'000 / rate + 1'000'000 / rate / 10);
  const bool tty = isatty(2);
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
      std::fprintf(stderr, "\npaint: stroke %zu: %s\n", k, status.error().message.c_str());
      return 1;
    }
    while (auto err = c.wait_for_error(std::chrono::milliseconds(0))) {
      std::fprintf(stderr, "\npaint: the server refused a stroke: %s\n", err->message.c_str());
      return 1;
    }
    if (tty) std::fprintf(stderr, "\rpaint: stroke %zu/%zu", k + 1, strokes.size());
  }
  if (tty) std::fprintf(stderr, "\n");
  auto ack = c.wait_for_ack(last_handle, std::chrono::milliseconds(std::int64_t(timeout_s * 1000)));
  if (!ack) {
    if (auto err = c.wait_for_error(std::chrono::milliseconds(0)))
      std::fprintf(stderr, "paint: the server refused a stroke: %s\n", err->message.c_str());
    std::fprintf(stderr, "paint: no ack for the last stroke: %s\n", ack.error().message.c_str());
    return 1;
  }
  const double secs = std::chrono::duration<double>(Clock::now() - t_start).count();
  std::printf(
      "painted %zu strokes into canvas '%s' in %.2f s; the last is stroke %llu in epoch %llu\n",
      strokes.size(), options->canvas.c_str(), secs,
      static_cast<unsigned long long>(ack->stroke_id), static_cast<unsigned long long>(ack->epoch));
  c.close();
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("paint", "send a painting's strokes (.apa or the generated scene)",
                          run_paint);

}  // namespace deepcanvas::client_app
