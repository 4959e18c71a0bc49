// deepcanvas-bench network: a large canvas joined, and strokes painted and watched, by clients
// across real shaped links (scripts/shaped-link.py: network namespaces joined by a link with a
// rate, a round trip and random loss), against loopback.
//
// Per link (loopback; 50 Mbit/s, 40 ms round trip, 0.5% loss; 10 Mbit/s, 80 ms):
//   first_picture_s          a viewer's connect -> the first part of its snapshot resident on
//                            its GPU replica (progressive join, PROTOCOL.md 4.5: shallowest
//                            blocks first, missing subtrees shown as their filtered parents);
//                            join_parts: the parts shown before the whole
//   join_s                   a viewer's connect -> the whole canvas resident on its GPU replica.
//                            The canvas: replay --tile-to-cells
//                            of demo.apa and dancer.apa (--quick 1M cells asked, else 16M),
//                            painted by a `serve --playback` server on the link's server side
//   join_bytes               the block frame bytes of that join
//   reply_during_join_s      the joiner asks for stats as soon as it is welcomed: request ->
//                            reply, while its snapshot streams in (replies go out ahead of a
//                            queued batch, so this is about a round trip, not the join)
//   stroke_to_resident_ms    p50/p99: a painter sends a stroke of demo.apa whole -> a viewer's
//                            GPU replica holds the epoch of its ack; one stroke at a time, both
//                            clients across the link (--quick 40 strokes, else 150)
//   bytes_per_stroke         block frame bytes the viewer received per stroke in that run
//   link                     what the link carried and lost (its own count)
// The slow client (a viewer behind 1 Mbit/s, 80 ms, joined while the same strokes are painted):
//   fast_viewer_ms_p99        stroke -> resident on a viewer beside the server, p99, alone and
//                            with the slow viewer joined (the ratio: does it slow the others?)
//   server_rss_peak_bytes    the server's peak resident memory in each of the two runs
//   slow_catch_up_s          the last stroke's ack -> the slow viewer holding that epoch (its
//                            backlog coalesced: it gets the newest version of each block)
// The server runs as a child process in the link's server namespace; the clients run in this
// process, moved to its client namespace. Needs root and /dev/net/tun; without them the shaped
// links are skipped with the reason and loopback alone is measured.
#include <fcntl.h>
#include <sched.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <fstream>
#include <memory>
#include <optional>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "bench.hpp"
#include "join_report.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "durability_run.hpp"
#include "tiled_canvas.hpp"

namespace {

namespace bench = deepcanvas::bench;
namespace cc = deepcanvas::client_core;
namespace cg = deepcanvas::client_gpu;
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using deepcanvas::Errc;
using deepcanvas::make_error;
using deepcanvas::Result;

struct LinkProfile {
  std::string name;  // as reported
  double rate_mbit = 0, rtt_ms = 0, loss = 0;
  bool shaped = false;  // false: plain loopback
};

struct LinkRow {
  LinkProfile link;
  double join_s = 0, join_bytes = 0, reply_during_join_s = 0;
  double first_picture_s = 0;   // connect -> the first part of the snapshot resident
  std::uint64_t join_parts = 0;  // parts of the snapshot shown before it was whole
  std::vector<double> stroke_ms;
  double bytes_per_stroke = 0;
  nlohmann::json carried;  // the link's own count
};

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Moves the calling thread between network namespaces; back to where it was on destruction.
// Sockets keep the namespace they were made in, and threads and child processes start in their
// creator's: clients connected after enter("x-c") stay there.
class NetnsMove {
 public:
  NetnsMove() : home_(::open("/proc/self/ns/net", O_RDONLY | O_CLOEXEC)) {}
  ~NetnsMove() {
    if (home_ >= 0) {
      (void)::setns(home_, CLONE_NEWNET);
      ::close(home_);
    }
  }
  NetnsMove(const NetnsMove&) = delete;
  NetnsMove& operator=(const NetnsMove&) = delete;
  Result<void> enter(const std::string& name) {
    const std::string path = "/var/run/netns/" + name;
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return make_error(Errc::io_error, "cannot open " + path);
    const int r = ::setns(fd, CLONE_NEWNET);
    ::close(fd);
    if (r != 0) return make_error(Errc::io_error, "setns " + name + " failed");
    return {};
  }

 private:
  int home_;
};

// scripts/shaped-link.py as a child process: up until stop().
class ShapedLink {
 public:
  static std::string script() {
    const char* env = std::getenv("DEEPCANVAS_SHAPED_LINK");
    return env && *env ? env : DEEPCANVAS_SHAPED_LINK_SCRIPT;
  }
  static Result<std::unique_ptr<ShapedLink>> start(const LinkProfile& p, const std::string& name) {
    if (::geteuid() != 0) return make_error(Errc::unsupported, "needs root (network namespaces)");
    if (!fs::exists("/dev/net/tun")) return make_error(Errc::unsupported, "no /dev/net/tun");
    if (!fs::exists(script())) return make_error(Errc::not_found, "no " + script());
    std::vector<std::string> args = {"python3",      script(),
                                     "--name",       name,
                                     "--rate-mbit",  std::to_string(p.rate_mbit),
                                     "--rtt-ms",     std::to_string(p.rtt_ms),
                                     "--loss",       std::to_string(p.loss)};
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    int out[2];
    if (::pipe2(out, O_CLOEXEC) != 0) return make_error(Errc::io_error, "pipe failed");
    auto link = std::unique_ptr<ShapedLink>(new ShapedLink());
    link->name_ = name;
    link->pid_ = ::fork();
    if (link->pid_ < 0) return make_error(Errc::io_error, "fork failed");
    if (link->pid_ == 0) {
      ::dup2(out[1], 1);
      ::execvp(argv[0], argv.data());
      ::_exit(127);
    }
    ::close(out[1]);
    link->out_ = ::fdopen(out[0], "r");
    char line[512] = {};
    if (!std::fgets(line, sizeof line, link->out_) || std::string(line).rfind("ready", 0) != 0) {
      link->stop();
      return make_error(Errc::io_error, "shaped-link.py did not make the link (see its stderr)");
    }
    return link;
  }
  ~ShapedLink() { stop(); }
  const std::string& name() const { return name_; }
  // Ends the link (its namespaces go); returns its count of what it carried.
  nlohmann::json stop() {
    if (pid_ <= 0) return counts_;
    ::kill(pid_, SIGTERM);
    std::string rest;
    char buf[4096];
    while (std::size_t k = std::fread(buf, 1, sizeof buf, out_)) rest.append(buf, k);
    std::fclose(out_);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
    const auto nl = rest.find_last_of('\n', rest.size() >= 2 ? rest.size() - 2 : 0);
    counts_ = nlohmann::json::parse(nl == std::string::npos ? rest : rest.substr(nl + 1), nullptr,
                                    false);
    return counts_;
  }

 private:
  ShapedLink() = default;
  std::string name_;
  pid_t pid_ = -1;
  FILE* out_ = nullptr;
  nlohmann::json counts_;
};

struct Setup {
  std::string server_binary, tokens_file, log;  // log: the tiled canvas's stroke log
  fs::path paintings;
  const cg::Context* ctx = nullptr;
  std::size_t strokes = 40;
  deepcanvas::paintings::ApaPainting demo;  // demo.apa, whose strokes are painted
};

cc::ClientOptions client_options(const std::string& url, const std::string& canvas,
                                 deepcanvas::protocol::Role role) {
  cc::ClientOptions o;
  o.url = url;
  o.canvas = canvas;
  o.role = role;
  o.token = role == deepcanvas::protocol::Role::painter ? "p-bench" : "v-bench";
  return o;
}

// A painter that only paints (no block frames, no replica), as `deepcanvas-client paint` does.
cc::ClientOptions painter_options(const std::string& url) {
  auto o = client_options(url, "main", deepcanvas::protocol::Role::painter);
  o.block_frames = false;
  o.keep_replica = false;
  return o;
}

struct LastAck {
  std::uint64_t epoch = 0;
  Clock::time_point at;
};

// demo.apa's first s.strokes strokes, each sent whole once the previous one was seen:
// `seen(i, epoch)` returns once the watching viewer holds the epoch of stroke i's ack. Send ->
// seen per stroke in `ms`; returns the last ack.
Result<LastAck> paint_one_at_a_time(const Setup& s, cc::Client& painter,
                                    const std::function<Result<void>(std::size_t, std::uint64_t)>& seen,
                                    std::vector<double>& ms) {
  LastAck last;
  const std::size_t n = std::min(s.strokes, s.demo.strokes.size());
  for (std::size_t i = 0; i < n; ++i) {
    const auto t0 = Clock::now();
    auto h = painter.send_stroke(s.demo.strokes[i]);
    if (!h) return std::move(h).error();
    auto ack = painter.wait_for_ack(*h, std::chrono::seconds(60));
    if (!ack) return std::move(ack).error();
    last = {ack->epoch, Clock::now()};
    if (auto r = seen(i, ack->epoch); !r) return std::move(r).error();
    ms.push_back(seconds_since(t0) * 1000);
  }
  return last;
}

// Starts a server in the link's server namespace (loopback: here) and returns it and the URL
// its clients use.
Result<std::pair<std::unique_ptr<bench::durability::ChildServer>, std::string>> serve(
    const Setup& s, ShapedLink* link, std::vector<std::string> args) {
  NetnsMove move;
  if (link)
    if (auto r = move.enter(link->name() + "-s"); !r) return std::move(r).error();
  args.insert(args.end(), {"--tokens", s.tokens_file});
  auto child = bench::durability::ChildServer::start(s.server_binary, args, std::chrono::seconds(120),
                                                     link ? "10.77.0.1:0" : "127.0.0.1:0");
  if (!child) return std::move(child).error();
  const std::string host = link ? "10.77.0.1" : "127.0.0.1";
  const std::string url = "ws://" + host + ":" + std::to_string((*child)->port()) + "/";
  return std::make_pair(std::move(*child), url);
}

// The tiled canvas served by a playback server and painted there; a viewer joins it.
Result<void> measure_join(const bench::Options& opt, const Setup& s, ShapedLink* link, LinkRow& row) {
  auto served = serve(s, link, {"--playback", s.log});
  if (!served) return std::move(served).error();
  auto& [child, url] = *served;
  NetnsMove move;
  if (link)
    if (auto r = move.enter(link->name() + "-c"); !r) return std::move(r).error();
  auto so = client_options(url, "default", deepcanvas::protocol::Role::viewer);
  so.block_frames = false;
  auto stepper = cc::Client::connect(so);
  if (!stepper) return std::move(stepper).error();
  deepcanvas::protocol::PlaybackStep all;
  all.strokes = deepcanvas::protocol::kMaxJsonInteger;
  auto id = (*stepper)->request_playback_step(all);
  if (!id) return std::move(id).error();
  if (auto pos = (*stepper)->wait_for_playback(*id, std::chrono::minutes(20)); !pos)
    return std::move(pos).error();
  bench::note(opt, "network: %s: the canvas is painted; a viewer joins\n", row.link.name.c_str());
  const auto j0 = Clock::now();
  auto vo = client_options(url, "default", deepcanvas::protocol::Role::viewer);
  auto viewer = cc::Client::connect(vo);
  if (!viewer) return std::move(viewer).error();
  auto replica = cg::StreamingReplica::create(*s.ctx, cg::replica_config_for((*viewer)->welcome()));
  if (!replica) return std::move(replica).error();
  cg::stream_client_into(**viewer, **replica);
  const auto r0 = Clock::now();
  if (auto r = (*viewer)->request_stats(); !r) return std::move(r).error();
  if (auto st = (*viewer)->wait_for_stats(std::chrono::minutes(20)); !st)
    return std::move(st).error();
  row.reply_during_join_s = seconds_since(r0);
  const bool resident = (*replica)->wait_resident((*viewer)->welcome().epoch, std::chrono::minutes(20));
  row.join_s = seconds_since(j0);
  row.join_bytes = static_cast<double>((*viewer)->stats().frame_bytes);
  row.join_parts = (*viewer)->stats().partial_commits;
  const auto batches = (*replica)->take_resident_log();
  row.first_picture_s = batches.empty()
                            ? row.join_s
                            : std::chrono::duration<double>(batches.front().resident_at - j0).count();
  (*viewer)->set_epoch_listener({});
  bench::note(opt, "network: %s: %s\n", row.link.name.c_str(), bench::first_picture_text(batches, j0).c_str());
  if (!resident) return make_error(Errc::io_error, "the canvas did not become resident");
  (*viewer)->close();
  (*stepper)->close();
  child->terminate(std::chrono::seconds(30));
  return {};
}

// demo.apa's first strokes, each sent whole once the previous one is resident on the viewer.
Result<void> measure_strokes(const bench::Options& opt, const Setup& s, ShapedLink* link,
                             LinkRow& row) {
  auto served = serve(s, link, {"--in-memory", "--canvas", "main"});
  if (!served) return std::move(served).error();
  auto& [child, url] = *served;
  NetnsMove move;
  if (link)
    if (auto r = move.enter(link->name() + "-c"); !r) return std::move(r).error();
  auto painter = cc::Client::connect(painter_options(url));
  if (!painter) return std::move(painter).error();
  auto viewer = cc::Client::connect(client_options(url, "main", deepcanvas::protocol::Role::viewer));
  if (!viewer) return std::move(viewer).error();
  auto replica = cg::StreamingReplica::create(*s.ctx, cg::replica_config_for((*viewer)->welcome()));
  if (!replica) return std::move(replica).error();
  cg::stream_client_into(**viewer, **replica);
  const std::uint64_t bytes0 = (*viewer)->stats().frame_bytes;
  const std::size_t n = std::min(s.strokes, s.demo.strokes.size());
  auto painted = paint_one_at_a_time(
      s, **painter,
      [&](std::size_t i, std::uint64_t epoch) -> Result<void> {
        if ((*replica)->wait_resident(epoch, std::chrono::seconds(60))) return {};
        return make_error(Errc::io_error, "stroke " + std::to_string(i) + " never became resident");
      },
      row.stroke_ms);
  row.bytes_per_stroke =
      static_cast<double>((*viewer)->stats().frame_bytes - bytes0) / static_cast<double>(std::max<std::size_t>(1, n));
  (*viewer)->set_epoch_listener({});
  if (!painted) return std::move(painted).error();
  bench::note(opt, "network: %s: %zu strokes\n", row.link.name.c_str(), n);
  (*viewer)->close();
  (*painter)->close();
  child->terminate(std::chrono::seconds(30));
  return {};
}

struct SlowClientRow {
  std::vector<double> alone_ms, with_slow_ms;
  std::uint64_t rss_alone = 0, rss_with_slow = 0;
  double slow_catch_up_s = 0, slow_bytes = 0;
  nlohmann::json carried;
};

// One run of demo.apa's strokes, whole and one at a time, by a painter beside the server, timed
// to a viewer beside it; with `slow_link`, a third client watches from its far side meanwhile.
Result<void> run_beside(const Setup& s, ShapedLink& link, bool with_slow,
                        std::vector<double>& ms, std::uint64_t& rss_peak, double* catch_up_s,
                        double* slow_bytes) {
  auto served = serve(s, &link, {"--in-memory", "--canvas", "main"});
  if (!served) return std::move(served).error();
  auto& [child, url] = *served;
  std::unique_ptr<cc::Client> slow;
  if (with_slow) {
    NetnsMove far;
    if (auto r = far.enter(link.name() + "-c"); !r) return std::move(r).error();
    auto c = cc::Client::connect(client_options(url, "main", deepcanvas::protocol::Role::viewer));
    if (!c) return std::move(c).error();
    slow = std::move(*c);
  }
  NetnsMove beside;
  if (auto r = beside.enter(link.name() + "-s"); !r) return std::move(r).error();
  auto painter = cc::Client::connect(painter_options(url));
  if (!painter) return std::move(painter).error();
  auto viewer = cc::Client::connect(client_options(url, "main", deepcanvas::protocol::Role::viewer));
  if (!viewer) return std::move(viewer).error();
  auto last = paint_one_at_a_time(
      s, **painter,
      [&, server_pid = child->pid()](std::size_t, std::uint64_t epoch) -> Result<void> {
        if (auto e = (*viewer)->wait_for_epoch(epoch, std::chrono::seconds(60)); !e)
          return std::move(e).error();
        rss_peak = std::max(rss_peak, bench::rss_bytes(server_pid));
        return {};
      },
      ms);
  if (!last) return std::move(last).error();
  if (slow) {
    if (auto e = slow->wait_for_epoch(last->epoch, std::chrono::minutes(5)); !e)
      return make_error(Errc::io_error, "the slow viewer never caught up: " + e.error().message);
    *catch_up_s = seconds_since(last->at);
    *slow_bytes = static_cast<double>(slow->stats().frame_bytes);
    rss_peak = std::max(rss_peak, bench::rss_bytes(child->pid()));
    slow->close();
  }
  (*viewer)->close();
  (*painter)->close();
  child->terminate(std::chrono::seconds(30));
  return {};
}

Result<SlowClientRow> measure_slow_client(const bench::Options& opt, const Setup& s) {
  SlowClientRow row;
  auto link = ShapedLink::start({"1 Mbit/s, 80 ms", 1, 80, 0, true},
                                "dcs" + std::to_string(::getpid() % 100000));
  if (!link) return std::move(link).error();
  bench::note(opt, "network: the slow client: alone\n");
  if (auto r = run_beside(s, **link, false, row.alone_ms, row.rss_alone, nullptr, nullptr); !r)
    return std::move(r).error();
  bench::note(opt, "network: the slow client: with a viewer behind 1 Mbit/s\n");
  if (auto r = run_beside(s, **link, true, row.with_slow_ms, row.rss_with_slow,
                          &row.slow_catch_up_s, &row.slow_bytes);
      !r)
    return std::move(r).error();
  row.carried = (*link)->stop();
  return row;
}

struct Args {
  std::string device;
  std::uint64_t cells = 0;  // 0: the default for --quick or not
  bool joins_only = false;
  std::vector<std::string> links;  // empty: all of kLinks
};

// The links measured, by the name --links takes.
struct NamedLink {
  const char* key;
  LinkProfile profile;
};
const NamedLink kLinks[] = {
    {"loopback", {"loopback", 0, 0, 0, false}},
    {"50mbit", {"50 Mbit/s, 40 ms, 0.5% loss", 50, 40, 0.005, true}},
    {"10mbit", {"10 Mbit/s, 80 ms", 10, 80, 0, true}},
};

int run(const bench::Options& opt, const Args& args) {
  const std::string& device = args.device;
  auto dir = bench::paintings_dir();
  if (!dir) return bench::fail(opt, dir.error().message);
  auto server = bench::durability::ChildServer::find_binary();
  if (!server) return bench::fail(opt, server.error().message);
  auto ctx = cg::ContextBuilder().app_name("deepcanvas-bench network").device(device).build();
  if (!ctx) return bench::fail(opt, ctx.error().message);
  const std::string stem = (fs::temp_directory_path() / ("deepcanvas_network_" + std::to_string(::getpid()))).string();
  Setup s;
  s.server_binary = *server;
  s.paintings = *dir;
  s.ctx = ctx->get();
  s.strokes = opt.quick ? 40 : 150;
  auto demo = deepcanvas::paintings::read_apa_file((s.paintings / "demo.apa").string(), {});
  if (!demo) return bench::fail(opt, demo.error().message);
  s.demo = std::move(*demo);
  s.tokens_file = stem + ".tokens";
  s.log = stem + ".dcs";
  {
    std::ofstream t(s.tokens_file);
    t << "default painter p-bench\ndefault viewer v-bench\nmain painter p-bench\nmain viewer v-bench\n";
  }
  const std::uint64_t cells_asked = args.cells > 0 ? args.cells : opt.quick ? 1'000'000 : 16'000'000;
  auto gen = bench::generate_tiled_log(s.server_binary, s.paintings, cells_asked, s.log);
  if (!gen) return bench::fail(opt, gen.error().message);
  const std::uint64_t cells = (*gen)["cells"].get<std::uint64_t>();
  std::vector<LinkProfile> profiles;
  for (const auto& l : kLinks)
    if (args.links.empty() ||
        std::find(args.links.begin(), args.links.end(), l.key) != args.links.end())
      profiles.push_back(l.profile);
  auto progress = bench::progress(opt, "network", static_cast<double>(profiles.size()), "links");
  std::vector<LinkRow> rows;
  std::string skipped;
  for (const auto& p : profiles) {
    LinkRow row;
    row.link = p;
    std::unique_ptr<ShapedLink> link;
    if (p.shaped) {
      auto l = ShapedLink::start(p, "dcb" + std::to_string(::getpid() % 100000));
      if (!l) {
        skipped = l.error().message;
        bench::note(opt, "network: %s skipped: %s\n", p.name.c_str(), skipped.c_str());
        progress.add(1);
        continue;
      }
      link = std::move(*l);
    }
    auto r = measure_join(opt, s, link.get(), row);
    if (r && !args.joins_only) r = measure_strokes(opt, s, link.get(), row);
    if (link) row.carried = link->stop();
    if (!r) {
      fs::remove(s.log);
      fs::remove(s.tokens_file);
      return bench::fail(opt, p.name + ": " + r.error().message);
    }
    rows.push_back(std::move(row));
    progress.add(1);
  }
  std::optional<SlowClientRow> slow;
  if (skipped.empty() && !args.joins_only) {
    auto r = measure_slow_client(opt, s);
    if (!r) {
      fs::remove(s.log);
      fs::remove(s.tokens_file);
      return bench::fail(opt, "the slow client: " + r.error().message);
    }
    slow = std::move(*r);
  }
  progress.finish();
  fs::remove(s.log);
  fs::remove(s.tokens_file);
  using deepcanvas::base::percentile;
  if (opt.json) {
    nlohmann::json j;
    j["suite"] = "network";
    j["device"] = (*ctx)->info().name;
    j["cells"] = cells;
    if (!skipped.empty()) j["shaped_links_skipped"] = skipped;
    for (const auto& r : rows)
      j["links"].push_back({{"link", r.link.name},
                            {"join_s", r.join_s},
                            {"join_bytes", r.join_bytes},
                            {"first_picture_s", r.first_picture_s},
                            {"join_parts", r.join_parts},
                            {"reply_during_join_s", r.reply_during_join_s},
                            {"stroke_to_resident_ms_p50", deepcanvas::base::percentile(r.stroke_ms, 0.5)},
                            {"stroke_to_resident_ms_p99", deepcanvas::base::percentile(r.stroke_ms, 0.99)},
                            {"strokes", r.stroke_ms.size()},
                            {"bytes_per_stroke", r.bytes_per_stroke},
                            {"carried", r.carried}});
    if (slow) {
      const double alone = percentile(slow->alone_ms, 0.99);
      const double with = percentile(slow->with_slow_ms, 0.99);
      j["slow_client"] = {{"fast_viewer_ms_p99_alone", alone},
                          {"fast_viewer_ms_p99_with_slow", with},
                          {"fast_viewer_p99_ratio", alone > 0 ? with / alone : 0},
                          {"server_rss_peak_bytes_alone", slow->rss_alone},
                          {"server_rss_peak_bytes_with_slow", slow->rss_with_slow},
                          {"slow_catch_up_s", slow->slow_catch_up_s},
                          {"slow_frame_bytes", slow->slow_bytes},
                          {"carried", slow->carried}};
    }
    j["targets"] = {{"join_first_picture_s_max", 1.0}};
    std::printf("%s\n", j.dump().c_str());
    return 0;
  }
  for (const auto& r : rows)
    bench::print("network: %s: a viewer joins %.1fM cells: first picture %.2f s (%llu parts before "
                 "the whole), whole in %.2f s (%.1f MB; a reply during it "
                 "%.3f s); stroke -> resident p50 %.1f ms, p99 %.1f ms over %zu strokes, %.0f KB "
                 "a stroke\n",
                 r.link.name.c_str(), static_cast<double>(cells) / 1e6, r.first_picture_s,
                 static_cast<unsigned long long>(r.join_parts), r.join_s, r.join_bytes / 1e6,
                 r.reply_during_join_s,
                 deepcanvas::base::percentile(r.stroke_ms, 0.5), deepcanvas::base::percentile(r.stroke_ms, 0.99),
                 r.stroke_ms.size(), r.bytes_per_stroke / 1e3);
  if (slow)
    bench::print("network: a viewer beside the server, stroke -> epoch p99: %.1f ms alone, %.1f ms "
                 "with a viewer behind 1 Mbit/s joined; server peak memory %.0f / %.0f MB; the slow "
                 "viewer caught up %.2f s after the last ack (%.1f MB)\n",
                 percentile(slow->alone_ms, 0.99), percentile(slow->with_slow_ms, 0.99),
                 static_cast<double>(slow->rss_alone) / 1e6, static_cast<double>(slow->rss_with_slow) / 1e6,
                 slow->slow_catch_up_s, slow->slow_bytes / 1e6);
  if (!skipped.empty()) bench::print("network: shaped links skipped: %s\n", skipped.c_str());
  return 0;
}

bench::SuiteRun setup(CLI::App& app) {
  auto a = std::make_shared<Args>();
  app.add_option("--device", a->device, "Vulkan device (else DEEPCANVAS_VK_DEVICE / automatic)")->type_name("SPEC");
  app.add_option("--cells", a->cells, "the canvas to join, cells asked of replay --tile-to-cells (default 16M; --quick 1M)")
      ->transform(bench::number(100000, 256e6, true))
      ->type_name("N");
  app.add_flag("--joins-only", a->joins_only, "measure the joins only (no strokes, no slow client)");
  app.add_option("--links", a->links, "the links to measure (default all): loopback, 50mbit, 10mbit")
      ->delimiter(',')
      ->check(CLI::IsMember({"loopback", "50mbit", "10mbit"}))
      ->type_name("NAME,...");
  return [a](const bench::Options& opt) { return run(opt, *a); };
}

}  // namespace

DEEPCANVAS_BENCH_SUITE(deepcanvas::bench::Suite{
    "network", "a large canvas joined and strokes watched across shaped links (rate, delay, loss)",
    "examples:\n"
    "  deepcanvas-bench network --quick\n"
    "  deepcanvas-bench network --json\n"
    "  deepcanvas-bench network --cells 128000000 --joins-only   (about 20 GB of memory)\n"
    "  deepcanvas-bench network --cells 128000000 --joins-only --links 50mbit\n"
    "needs root and /dev/net/tun for the shaped links (else loopback only)\n"
    "environment: DEEPCANVAS_PAINTINGS, DEEPCANVAS_SERVER (the server binary), DEEPCANVAS_SHAPED_LINK\n"
    "(scripts/shaped-link.py), DEEPCANVAS_VK_DEVICE\n",
    setup});
