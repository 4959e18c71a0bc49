// deepcanvas-bench studio: the artist's window under load, measured as an artist meets it.
//
// Setup: a real X server (Xvfb, started here unless --display names one), a server on loopback
// (in this process), `deepcanvas-client studio` at 1280x720 with --latency-log, and two artists:
//   scripted  real X pointer input (xdotool: press, moves, release) drawing the 2D shapes of a
//             real painting's strokes across the window, one move every --step-ms;
//   second    a painter in this process streaming another real painting's strokes at the
//             recorded pace, and sending its presence (its current sample) every 50 ms.
// Figures:
//   input_to_photon_ms_p50 / _p99  a pointer move issued (just before xdotool runs) -> the
//       first presented frame that shows the stamp it made (the studio draws the stroke's path
//       locally, so this is the local preview's latency: X delivery, the frame loop, present)
//   fps_1280x720          frames presented per second while both artists paint
//   frame_ms_p99_over_p50 frame interval p99 / p50 over the same frames
//   presence_latency_ms_p99  the second artist's presence sent -> the first frame that draws
//       its cursor at that position (relay through the server included; matched by position)
// Targets (lavapipe): input_to_photon p99 < 100 ms; fps_1280x720 >= 20. Printed as met / not
// met, never asserted. The studio's clock and this process's are the same monotonic clock.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench.hpp"
#include "deepcanvas/base/percentile.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_net/server.hpp"

namespace deepcanvas::bench {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

constexpr std::uint32_t kWidth = 1280, kHeight = 720;

struct StudioOptions {
  std::string display;  // empty: start Xvfb
  std::string scripted = "mozdino.apa", second = "dancer.apa";
  double seconds = 20;
  double step_ms = 16;
  std::string render_scale = "auto";
};

long long now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch())
      .count();
}

bool on_path(const std::string& tool) {
  return std::system(("command -v " + tool + " >/dev/null 2>&1").c_str()) == 0;
}

// A child process; killed (TERM, then KILL) when destroyed.
class Proc {
 public:
  Proc(std::vector<std::string> args, const std::string& log) {
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    pid_ = fork();
    if (pid_ == 0) {
      if (FILE* f = std::fopen(log.c_str(), "w")) {
        dup2(fileno(f), 1);
        dup2(fileno(f), 2);
      }
      execvp(argv[0], argv.data());
      _exit(127);
    }
  }
  ~Proc() {
    if (pid_ <= 0) return;
    kill(pid_, SIGTERM);
    for (int i = 0; i < 50; ++i) {
      if (waitpid(pid_, nullptr, WNOHANG) == pid_) return;
      std::this_thread::sleep_for(100ms);
    }
    kill(pid_, SIGKILL);
    waitpid(pid_, nullptr, 0);
  }
  bool alive() const { return pid_ > 0 && kill(pid_, 0) == 0; }

 private:
  pid_t pid_ = -1;
};

int sh(const std::string& display, const std::string& cmd) {
  return std::system(("DISPLAY=" + display + " " + cmd + " >/dev/null 2>&1").c_str());
}

std::string client_binary() {
  if (const char* e = std::getenv("DEEPCANVAS_CLIENT"); e && *e) return e;
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  const fs::path sibling = self.parent_path().parent_path() / "client" / "deepcanvas-client";
  if (!ec && fs::exists(sibling)) return sibling.string();
  return "deepcanvas-client";
}

// The scripted artist's pointer path: each stroke's samples in 2D (x, y of the painting, y up),
// fitted into the window's middle with a margin, consecutive points at least 3 px apart.
std::vector<std::vector<std::pair<int, int>>> pointer_strokes(const paintings::ApaPainting& p,
                                                              std::size_t max_strokes) {
  double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
  for (const auto& s : p.strokes)
    for (const auto& q : s.samples) {
      x0 = std::min(x0, q.x), x1 = std::max(x1, q.x), y0 = std::min(y0, q.y), y1 = std::max(y1, q.y);
    }
  const double scale = std::min((kWidth * 0.5) / std::max(x1 - x0, 1e-9),
                                (kHeight * 0.6) / std::max(y1 - y0, 1e-9));
  std::vector<std::vector<std::pair<int, int>>> out;
  for (const auto& s : p.strokes) {
    if (out.size() == max_strokes) break;
    std::vector<std::pair<int, int>> path;
    for (const auto& q : s.samples) {
      const int x = static_cast<int>(kWidth * 0.35 + (q.x - x0) * scale);
      const int y = static_cast<int>(kHeight * 0.8 - (q.y - y0) * scale);
      if (!path.empty() && std::hypot(x - path.back().first, y - path.back().second) < 3) continue;
      path.emplace_back(x, y);
    }
    if (path.size() >= 4) out.push_back(std::move(path));
  }
  return out;
}

// The second artist: streams `painting`'s strokes at the recorded pace (pauses over 1 s cut to
// 1 s) until `stop`, sends its presence every 50 ms; records when each presence position was
// sent.
void second_artist(client_core::Client& client, const paintings::ApaPainting& painting,
                   const std::atomic<bool>& stop, std::map<std::array<double, 3>, long long>& sent) {
  auto last_presence = Clock::now() - 1s;
  for (const auto& stroke : painting.strokes) {
    if (stop) return;
    auto h = client.begin_stroke(stroke.brush, {});
    if (!h) return;
    std::uint32_t prev_t = stroke.samples.empty() ? 0 : stroke.samples.front().t_ms;
    for (const auto& q : stroke.samples) {
      if (stop) break;
      const std::uint32_t dt = std::min<std::uint32_t>(q.t_ms - std::min(q.t_ms, prev_t), 1000);
      prev_t = q.t_ms;
      std::this_thread::sleep_for(std::chrono::milliseconds(dt));
      (void)client.add_samples(*h, {q});
      if (Clock::now() - last_presence >= 50ms) {
        protocol::Presence p;
        p.cursor = {q.x, q.y, q.z};
        p.cursor_on_canvas = true;
        p.eye = {q.x, q.y, q.z + 2};
        p.target = {q.x, q.y, q.z};
        p.colour = {stroke.brush.colour[0], stroke.brush.colour[1], stroke.brush.colour[2], 1};
        p.size_m = q.radius;
        p.painting = true;
        const long long t = now_ns();
        if (client.send_presence(p)) {
          sent.emplace(p.cursor, t);
          last_presence = Clock::now();
        }
      }
    }
    (void)client.end_stroke(*h);
  }
}

int studio_main(const Options& opt, const StudioOptions& so) {
  for (const char* tool : {"xdotool", so.display.empty() ? "Xvfb" : "true"})
    if (!on_path(tool)) return fail(opt, std::string(tool) + " is not installed (scripts/setup.sh)");
  auto dir = paintings_dir();
  if (!dir) return fail(opt, dir.error().message);
  auto scripted = paintings::read_apa_file((*dir / so.scripted).string(), {});
  auto second = paintings::read_apa_file((*dir / so.second).string(), {});
  if (!scripted || !second)
    return fail(opt, "cannot read " + so.scripted + " or " + so.second + " in " + dir->string());
  const double seconds = opt.quick ? 6 : so.seconds;
  const fs::path work = fs::temp_directory_path() / ("deepcanvas_studio_bench_" +
                                                     std::to_string(getpid()));
  fs::create_directories(work);

  std::string display = so.display;
  std::unique_ptr<Proc> xvfb;
  if (display.empty()) {  // Xvfb picks a free display and writes its number (-displayfd)
    const fs::path xlog = work / "xvfb.log";
    xvfb = std::make_unique<Proc>(std::vector<std::string>{"Xvfb", "-displayfd", "1", "-screen",
                                                           "0", "1400x800x24", "-nolisten", "tcp"},
                                  xlog.string());
    for (int i = 0; i < 200 && display.empty(); ++i) {
      std::ifstream f(xlog);
      for (std::string line; std::getline(f, line);)
        if (!line.empty() && line.find_first_not_of("0123456789") == std::string::npos)
          display = ":" + line;
      if (display.empty()) std::this_thread::sleep_for(50ms);
    }
    if (display.empty()) return fail(opt, "Xvfb did not start (see " + xlog.string() + ")");
    for (int i = 0; i < 100 && sh(display, "xdotool getmouselocation") != 0; ++i)
      std::this_thread::sleep_for(50ms);
  }
  setenv("DISPLAY", display.c_str(), 1);  // for the studio
  server_net::ServerConfig scfg;
  scfg.port = 0;
  scfg.limits.max_strokes_per_second = 100000;
  server_core::CanvasServiceConfig c;
  c.name = "studio";
  scfg.canvases.push_back(c);
  auto server = server_net::Server::create(scfg);
  if (!server) return fail(opt, server.error().message);
  if (auto r = (*server)->start(); !r) return fail(opt, r.error().message);
  const std::string url = "ws://127.0.0.1:" + std::to_string((*server)->port()) + "/studio";
  const fs::path log = work / "latency.log";
  auto studio = std::make_unique<Proc>(
      std::vector<std::string>{client_binary(), "studio", "--connect", url, "--name", "bench",
                               "--size", "1280x720", "--fps", "60", "--no-vsync",
                               "--render-scale", so.render_scale, "--latency-log", log.string()},
      (work / "studio.log").string());
  note(opt, "studio: waiting for the window on %s", display.c_str());
  std::string wid;
  for (int i = 0; i < 100 && wid.empty(); ++i) {
    std::this_thread::sleep_for(100ms);
    FILE* p = popen(("DISPLAY=" + display + " xdotool search --name 'deepcanvas studio' 2>/dev/null").c_str(), "r");
    char buf[64] = {};
    if (p && std::fgets(buf, sizeof buf, p)) wid = std::string(buf).substr(0, std::string(buf).find('\n'));
    if (p) pclose(p);
  }
  if (wid.empty()) return fail(opt, "the studio window did not open (see " + (work / "studio.log").string() + ")");
  std::this_thread::sleep_for(2s);

  client_core::ClientOptions o;
  o.url = "ws://127.0.0.1:" + std::to_string((*server)->port()) + "/";
  o.canvas = "studio";
  o.client_name = "second artist";
  o.block_frames = false;
  auto other = client_core::Client::connect(o);
  if (!other) return fail(opt, other.error().message);
  std::atomic<bool> stop{false};
  std::map<std::array<double, 3>, long long> presence_sent;
  const long long paint_start = now_ns();
  std::thread second_thread([&] { second_artist(**other, *second, stop, presence_sent); });

  // The scripted artist: real pointer events, each move's issue time kept by position.
  std::map<std::pair<int, int>, long long> moved;
  const auto strokes = pointer_strokes(*scripted, 400);
  const auto deadline = Clock::now() + std::chrono::duration<double>(seconds);
  std::size_t strokes_drawn = 0;
  for (const auto& path : strokes) {
    if (Clock::now() >= deadline) break;
    const auto xy = [&](std::pair<int, int> q) {
      return std::to_string(q.first) + " " + std::to_string(q.second);
    };
    sh(display, "xdotool mousemove --window " + wid + " " + xy(path[0]) + " mousedown 1");
    for (std::size_t i = 1; i < path.size() && Clock::now() < deadline; ++i) {
      const auto t = Clock::now();
      moved.emplace(path[i], now_ns());
      sh(display, "xdotool mousemove --window " + wid + " " + xy(path[i]));
      std::this_thread::sleep_until(t + std::chrono::duration<double, std::milli>(so.step_ms));
    }
    sh(display, "xdotool mouseup 1");
    ++strokes_drawn;
  }
  const long long paint_end = now_ns();
  stop = true;
  second_thread.join();
  std::this_thread::sleep_for(1s);
  const bool studio_alive = studio->alive();
  studio.reset();  // ends the studio: its log is complete
  (*other)->close();

  // Read the studio's log.
  std::ifstream in(log);
  std::string line;
  std::vector<double> intervals, input_ms, presence_ms;
  long long prev_frame = 0, frames = 0;
  std::map<std::pair<int, int>, bool> seen;
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    std::string kind;
    ls >> kind;
    if (kind == "frame") {
      long long start = 0, present = 0;
      ls >> start >> present;
      if (present >= paint_start && present <= paint_end) {
        ++frames;
        if (prev_frame) intervals.push_back((present - prev_frame) / 1e6);
        prev_frame = present;
      }
    } else if (kind == "sample") {
      int x = 0, y = 0;
      long long present = 0;
      ls >> x >> y >> present;
      auto it = moved.find({x, y});
      if (it != moved.end() && !seen[{x, y}]) {
        seen[{x, y}] = true;
        input_ms.push_back((present - it->second) / 1e6);
      }
    } else if (kind == "presence") {
      unsigned long long artist = 0;
      std::array<double, 3> p{};
      long long present = 0;
      ls >> artist >> p[0] >> p[1] >> p[2] >> present;
      auto it = presence_sent.find(p);
      if (it != presence_sent.end()) {
        presence_ms.push_back((present - it->second) / 1e6);
        presence_sent.erase(it);
      }
    }
  }
  std::error_code ec;
  fs::remove_all(work, ec);
  const double span_s = (paint_end - paint_start) / 1e9;
  nlohmann::json out;
  out["studio_ran_to_the_end"] = studio_alive;
  out["render_scale"] = so.render_scale;
  out["seconds"] = span_s;
  out["scripted_strokes"] = strokes_drawn;
  out["pointer_moves"] = moved.size();
  out["samples_matched"] = input_ms.size();
  out["input_to_photon_ms_p50"] = base::percentile(input_ms, 0.5);
  out["input_to_photon_ms_p99"] = base::percentile(input_ms, 0.99);
  out["fps_1280x720"] = span_s > 0 ? frames / span_s : 0;
  out["frame_ms_p50"] = base::percentile(intervals, 0.5);
  out["frame_ms_p99_over_p50"] =
      base::percentile(intervals, 0.5) > 0
          ? base::percentile(intervals, 0.99) / base::percentile(intervals, 0.5)
          : 0;
  out["presence_matched"] = presence_ms.size();
  out["presence_latency_ms_p50"] = base::percentile(presence_ms, 0.5);
  out["presence_latency_ms_p99"] = base::percentile(presence_ms, 0.99);
  out["targets"] = {{"input_to_photon_ms_p99_max", 100}, {"fps_1280x720_min", 20}};
  if (opt.json) {
    print("%s\n", out.dump().c_str());
  } else {
    const double p99 = out["input_to_photon_ms_p99"], fps = out["fps_1280x720"];
    print("studio (render scale %s): %zu scripted strokes (%zu pointer moves, %zu matched) with "
          "a second artist, %.1f s\n",
          so.render_scale.c_str(), strokes_drawn, moved.size(), input_ms.size(), span_s);
    print("  input_to_photon_ms p50 %.1f p99 %.1f (target < 100: %s)\n",
          static_cast<double>(out["input_to_photon_ms_p50"]), p99, p99 < 100 ? "met" : "not met");
    print("  fps_1280x720 %.1f (target >= 20: %s), frame_ms p50 %.1f, p99/p50 %.2f\n", fps,
          fps >= 20 ? "met" : "not met", static_cast<double>(out["frame_ms_p50"]),
          static_cast<double>(out["frame_ms_p99_over_p50"]));
    print("  presence_latency_ms p50 %.1f p99 %.1f (%zu matched)\n",
          static_cast<double>(out["presence_latency_ms_p50"]),
          static_cast<double>(out["presence_latency_ms_p99"]), presence_ms.size());
  }
  return studio_alive ? 0 : fail(opt, "the studio exited during the run");
}

SuiteRun setup(CLI::App& app) {
  auto so = std::make_shared<StudioOptions>();
  app.add_option("--display", so->display, "an X display to use (default: start Xvfb)")
      ->type_name(":N");
  app.add_option("--seconds", so->seconds, "how long both artists paint (default 20; 6 with --quick)")
      ->type_name("S")
      ->transform(number(1, 3600));
  app.add_option("--step-ms", so->step_ms, "the scripted pointer's interval between moves (default 16)")
      ->type_name("MS")
      ->transform(number(1, 1000));
  app.add_option("--render-scale", so->render_scale,
                 "the studio's --render-scale (default auto; 1: every window pixel ray cast)")
      ->type_name("F|auto");
  return [so](const Options& opt) { return studio_main(opt, *so); };
}

DEEPCANVAS_BENCH_SUITE(Suite{
    "studio",
    "the studio window under Xvfb: input -> photon, fps at 1280x720, presence latency, two artists",
    "examples:\n"
    "  deepcanvas-bench studio --quick\n"
    "  deepcanvas-bench studio --seconds 30 --json > studio.json\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder); DEEPCANVAS_CLIENT (the\n"
    "deepcanvas-client binary; default: the build's, beside this one)\n",
    setup});

}  // namespace
}  // namespace deepcanvas::bench
