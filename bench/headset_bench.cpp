// deepcanvas-bench headset: the headset's frame loop (client_gpu::HeadsetLoop) with a generated
// pose trace (client_core::generate_pose_trace: head turns, leaning in to paint, a 8x world
// scale) while a real painting streams in, then the finished painting.
//
//   frame_ms_p50 / _p99        both eyes' render time per frame (pose latched -> complete)
//   frame_gpu_ms_p50           of it, the device's timestamps around the passes (-1: none)
//   missed_frames, missed_pct  frames complete after their slot on the --hz grid
//   missed_gpu_ms_p50          the device time of the missed frames (next to frame_gpu_ms_p50:
//                              whether a miss was the device's work or the host's record,
//                              submit and wait)
//   missed_after_upload        missed frames that were the first on a newly resident epoch
//   missed_while_streaming     missed frames before the last stroke was pushed
//   render_scale_p50 / _min    the dynamic resolution's scale of each eye side
//   pixel_share_last           its estimate, at the last frame, of the share of a frame's time
//                              that scales with the pixels (ResolutionController)
//   motion_to_photon_ms_p50 / _p99  pose latched -> both eyes rendered (no display scan-out)
//   stereo_over_mono           the finished painting at render scale 1: a stereo frame's render
//                              time over a mono frame's (the left eye alone), medians of the same
//                              number of frames each, interleaved in blocks of 10
//   two_submissions_over_mono  the same with a submission and a wait per eye (the eyes one
//                              after the other) instead of both eyes side by side in one
//
// Stream: the painting's strokes painted through the server's Painter in this process and
// captured one epoch per stroke first (the server's CPU work is not what is measured), then
// pushed into the StreamingReplica at the painting's recorded pace (its samples' t_ms), squeezed
// into the first 60% of the run when longer, while the loop renders. Paintings: demo.apa and the
// largest in $DEEPCANVAS_PAINTINGS (--painting FILE for one). Eye size and rate: --eye-size
// (default 640x576), --hz (default 30): what lavapipe on two cores can hold; on a GPU,
// --eye-size 1680x1512 --hz 90 (the paper's Vive). DEEPCANVAS_BENCH_TRACE=1 prints the upload
// batches that held the GPU lock over 5 ms (what a frame waiting on the lock waited for).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "bench.hpp"
#include "deepcanvas/client_core/pose_trace.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/headset_loop.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "tree_stream.hpp"

namespace {

namespace bench = deepcanvas::bench;
namespace cc = deepcanvas::client_core;
namespace cg = deepcanvas::client_gpu;
namespace sc = deepcanvas::server_core;
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using deepcanvas::Result;

struct HeadsetArgs {
  std::string painting, device, eye_size = "640x576", frames_csv;
  double hz = 30, seconds = 0;
};

struct Figures {
  std::string name;
  std::size_t frames = 0, missed = 0, missed_after_upload = 0, missed_while_streaming = 0;
  double missed_gpu_p50 = -1;
  double frame_p50 = 0, frame_p99 = 0, gpu_p50 = -1, share_last = -1, scale_p50 = 0, scale_min = 0, mtp_p50 = 0, mtp_p99 = 0;
  double stereo_ms = 0, mono_ms = 0, two_submissions_ms = 0;
  std::uint64_t epochs = 0;
};

Result<Figures> measure(const cg::Context& ctx, const fs::path& painting, const HeadsetArgs& a,
                        std::uint32_t eye_w, std::uint32_t eye_h, double seconds, int cost_frames) {
  auto apa = deepcanvas::paintings::read_apa_file(painting.string(), {});
  if (!apa) return std::move(apa).error();
  auto tree = sc::Octree::create({});
  if (!tree) return std::move(tree).error();
  auto painter = sc::Painter::create(**tree);
  if (!painter) return std::move(painter).error();
  cg::GpuReplicaConfig cfg;
  cfg.width_log2 = 12;
  cfg.block_log2 = static_cast<std::uint32_t>(std::countr_zero((*tree)->config().block_cells));
  cfg.roots_per_axis = (*tree)->config().roots_per_axis;
  cfg.edge_m = (*tree)->config().edge_m;
  auto replica = cg::StreamingReplica::create(ctx, cfg);
  if (!replica) return std::move(replica).error();
  (*replica)->push(bench::capture_tree_epoch(**tree, 0, cfg.width_log2, true));
  if (!(*replica)->wait_resident(0, std::chrono::seconds(60)))
    return deepcanvas::make_error(deepcanvas::Errc::io_error, "snapshot not resident");
  // One epoch per stroke, at the painting's pace (squeezed into 60% of the run).
  cc::DAabb box = cc::empty_box();
  std::vector<std::pair<double, cg::EpochUpload>> epochs;
  const auto& strokes = apa->strokes;
  const double t_first = strokes.empty() || strokes.front().samples.empty() ? 0 : strokes.front().samples.front().t_ms;
  const double t_last = strokes.empty() || strokes.back().samples.empty() ? 0 : strokes.back().samples.front().t_ms;
  const double squeeze = t_last - t_first > seconds * 600 ? seconds * 600 / (t_last - t_first) : 1.0;
  for (const auto& s : strokes) {
    cc::grow_by_samples(box, s.samples);
    if (!(*painter)->apply_stroke(s)) continue;
    const double at_s = s.samples.empty() ? 0 : (s.samples.front().t_ms - t_first) * squeeze / 1000;
    epochs.emplace_back(at_s, bench::capture_tree_epoch(**tree, epochs.size() + 1, cfg.width_log2, false));
  }
  if (box.min.x > box.max.x) return deepcanvas::make_error(deepcanvas::Errc::not_found, "no samples");
  const cc::PoseTrace trace = cc::generate_pose_trace(box, std::max(seconds, 10.0), 1, 90);
  cg::HeadsetOptions ho;
  ho.eyes.width = eye_w;
  ho.eyes.height = eye_h;
  ho.hz = a.hz;
  ho.render.background = {0.05, 0.06, 0.08};
  auto loop = cg::HeadsetLoop::create(**replica, ho);
  if (!loop) return std::move(loop).error();
  // The stream, on this thread's helper, while the loop renders.
  const auto t0 = Clock::now();
  std::thread pusher([&] {
    for (auto& [at, e] : epochs) {
      std::this_thread::sleep_until(t0 + std::chrono::duration_cast<Clock::duration>(
                                             std::chrono::duration<double>(at)));
      e.committed_at = Clock::now();
      (*replica)->push(std::move(e));
    }
  });
  const std::size_t epoch_count = epochs.size();
  auto frames = (*loop)->run([&](double t) { return trace.at(t).pose; },
                             [&](const std::vector<cg::HeadsetFrame>& f) {
                               return !f.empty() && f.back().start_s >= seconds;
                             });
  pusher.join();
  if (!frames) return std::move(frames).error();
  if (std::getenv("DEEPCANVAS_BENCH_TRACE")) {
    // The batches that held the GPU lock long enough to delay a frame, and growth steps.
    for (const auto& b : (*replica)->take_resident_log())
      if (b.gpu_lock_ms > 5)
        std::fprintf(
            stderr,
            "batch %llu-%llu at %.3f s: staged %.1f ms, lock %.1f ms (mirror %.1f grow %.1f%s "
            "upload %.1f links %.1f exact %.1f), rows %llu, mid-frame %d\n",
            (unsigned long long)b.first_epoch, (unsigned long long)b.last_epoch,
            std::chrono::duration<double>(b.taken_at - t0).count(), b.stage_ms, b.gpu_lock_ms,
            b.mirror_ms, b.grow_ms, b.grew ? " at once" : "", b.upload_ms, b.links_ms,
            b.content_exact_ms, (unsigned long long)b.rows, b.mid_frame ? 1 : 0);
    const auto st = (*replica)->stats();
    std::fprintf(stderr, "growths %llu, steps %llu, longest step %.1f ms, longest at once %.1f ms\n",
                 (unsigned long long)st.growths, (unsigned long long)st.growth_steps,
                 st.max_growth_step_ms, st.max_growth_ms);
  }
  Figures out;
  out.name = painting.filename().string();
  out.epochs = epoch_count;
  if (!a.frames_csv.empty()) {
    // One row a frame, appended (several paintings go in one file).
    const bool fresh = !fs::exists(a.frames_csv);
    std::FILE* csv = std::fopen(a.frames_csv.c_str(), "a");
    if (!csv) return deepcanvas::make_error(deepcanvas::Errc::io_error, "cannot write " + a.frames_csv);
    if (fresh)
      std::fprintf(csv, "painting,start_s,lock_wait_ms,render_ms,gpu_ms,render_scale,pixel_share,epoch,missed\n");
    for (const auto& f : *frames)
      if (!f.empty)
        std::fprintf(csv, "%s,%.6f,%.3f,%.3f,%.3f,%.4f,%.3f,%llu,%d\n", out.name.c_str(), f.start_s,
                     (f.pose_t_s - f.start_s) * 1000, f.render_ms, f.gpu_ms, f.render_scale,
                     f.pixel_share, static_cast<unsigned long long>(f.epoch), f.missed ? 1 : 0);
    if (std::fclose(csv) != 0)
      return deepcanvas::make_error(deepcanvas::Errc::io_error, "cannot write " + a.frames_csv);
  }
  std::vector<double> ms, scale, mtp, gpu, missed_gpu;
  const double last_push_s = epochs.empty() ? 0 : epochs.back().first;
  std::uint64_t last_epoch = 0;
  for (const auto& f : *frames) {
    if (f.empty) continue;
    if (f.missed) {
      missed_gpu.push_back(f.gpu_ms);
      out.missed_after_upload += f.epoch != last_epoch ? 1 : 0;
      out.missed_while_streaming += f.start_s <= last_push_s ? 1 : 0;
    }
    last_epoch = f.epoch;
    ms.push_back(f.render_ms);
    scale.push_back(f.render_scale);
    mtp.push_back(f.motion_to_photon_ms);
    gpu.push_back(f.gpu_ms);
    out.share_last = f.pixel_share;
    out.missed += f.missed ? 1 : 0;
  }
  out.frames = ms.size();
  out.frame_p50 = deepcanvas::base::percentile(ms, 0.5);
  out.frame_p99 = deepcanvas::base::percentile(ms, 0.99);
  out.gpu_p50 = bench::median(gpu);
  if (!missed_gpu.empty()) out.missed_gpu_p50 = bench::median(missed_gpu);
  out.scale_p50 = deepcanvas::base::percentile(scale, 0.5);
  out.scale_min = scale.empty() ? 0 : *std::min_element(scale.begin(), scale.end());
  out.mtp_p50 = deepcanvas::base::percentile(mtp, 0.5);
  out.mtp_p99 = deepcanvas::base::percentile(mtp, 0.99);
  // Stereo against mono on the finished painting at scale 1, blocks of 10 frames interleaved.
  (*replica)->wait_resident(epoch_count, std::chrono::seconds(60));
  cg::HeadsetOptions fixed = ho;
  fixed.adapt = false;
  fixed.fixed_scale = 1.0;
  fixed.hz = 1000;  // back to back: the render time is what is compared
  cg::HeadsetOptions mono = fixed, two_submissions = fixed;
  mono.mono = true;
  two_submissions.one_submission = false;
  // [0] stereo (one submission), [1] mono, [2] stereo with a submission per eye.
  std::unique_ptr<cg::HeadsetLoop> loops[3];
  std::vector<double> ms_of[3];
  for (int k = 0; k < 3; ++k) {
    auto l = cg::HeadsetLoop::create(**replica, k == 0 ? fixed : k == 1 ? mono : two_submissions);
    if (!l) return std::move(l).error();
    loops[k] = std::move(*l);
  }
  const auto pose = trace.at(2.0).pose;
  for (int block = 0; block < cost_frames / 10; ++block) {
    for (int k = 0; k < 3; ++k) {
      auto f = loops[k]->run([&](double) { return pose; },
                             [](const std::vector<cg::HeadsetFrame>& x) { return x.size() >= 10; });
      if (!f) return std::move(f).error();
      for (const auto& x : *f) ms_of[k].push_back(x.render_ms);
    }
  }
  out.stereo_ms = bench::median(ms_of[0]);
  out.mono_ms = bench::median(ms_of[1]);
  out.two_submissions_ms = bench::median(ms_of[2]);
  return out;
}

int run(const bench::Options& opt, const HeadsetArgs& a) {
  std::uint32_t eye_w = 0, eye_h = 0;
  if (std::sscanf(a.eye_size.c_str(), "%ux%u", &eye_w, &eye_h) != 2 || eye_w == 0 || eye_h == 0 ||
      eye_w > 8192 || eye_h > 8192)
    return bench::fail(opt, "--eye-size: WxH, each 1..8192");
  std::vector<fs::path> files;
  if (!a.painting.empty()) {
    files.push_back(a.painting);
  } else {
    auto dir = bench::paintings_dir();
    if (!dir) return bench::fail(opt, dir.error().message);
    files.push_back(*dir / "demo.apa");
    fs::path largest;
    std::uintmax_t size = 0;
    for (const auto& e : fs::directory_iterator(*dir))
      if (e.path().extension() == ".apa" && e.file_size() > size) size = e.file_size(), largest = e.path();
    if (!opt.quick && !largest.empty() && largest.filename() != "demo.apa") files.push_back(largest);
  }
  auto ctx = cg::ContextBuilder().app_name("deepcanvas-bench headset").device(a.device).build();
  if (!ctx) return bench::fail(opt, ctx.error().message);
  const double seconds = a.seconds > 0 ? a.seconds : opt.quick ? 8 : 20;
  const int cost_frames = opt.quick ? 30 : 60;
  auto progress = bench::progress(opt, "headset", static_cast<double>(files.size()), "paintings");
  std::vector<Figures> all;
  for (const auto& f : files) {
    auto r = measure(**ctx, f, a, eye_w, eye_h, seconds, cost_frames);
    if (!r) return bench::fail(opt, f.filename().string() + ": " + r.error().message);
    all.push_back(*r);
    progress.add(1);
  }
  progress.finish();
  if (opt.json) {
    std::string rows;
    for (const auto& x : all) {
      char b[1536];
      std::snprintf(b, sizeof b,
                    "%s{\"painting\":\"%s\",\"epochs\":%llu,\"frames\":%zu,\"frame_ms_p50\":%.3f,"
                    "\"frame_ms_p99\":%.3f,\"frame_gpu_ms_p50\":%.3f,\"missed_frames\":%zu,\"missed_pct\":%.2f,"
                    "\"missed_gpu_ms_p50\":%.3f,\"missed_after_upload\":%zu,\"missed_while_streaming\":%zu,"
                    "\"render_scale_p50\":%.3f,\"render_scale_min\":%.3f,\"pixel_share_last\":%.3f,"
                    "\"motion_to_photon_ms_p50\":%.3f,\"motion_to_photon_ms_p99\":%.3f,"
                    "\"stereo_ms_p50\":%.3f,\"mono_ms_p50\":%.3f,\"stereo_over_mono\":%.3f,"
                    "\"stereo_two_submissions_ms_p50\":%.3f,\"two_submissions_over_mono\":%.3f}",
                    rows.empty() ? "" : ",", x.name.c_str(), static_cast<unsigned long long>(x.epochs),
                    x.frames, x.frame_p50, x.frame_p99, x.gpu_p50, x.missed,
                    x.frames ? 100.0 * static_cast<double>(x.missed) / static_cast<double>(x.frames) : 0.0,
                    x.missed_gpu_p50, x.missed_after_upload, x.missed_while_streaming,
                    x.scale_p50, x.scale_min, x.share_last, x.mtp_p50, x.mtp_p99, x.stereo_ms, x.mono_ms,
                    x.mono_ms > 0 ? x.stereo_ms / x.mono_ms : 0.0, x.two_submissions_ms,
                    x.mono_ms > 0 ? x.two_submissions_ms / x.mono_ms : 0.0);
      rows += b;
    }
    std::printf("{\"suite\":\"headset\",\"device\":\"%s\",\"eye_width\":%u,\"eye_height\":%u,"
                "\"hz\":%.1f,\"seconds\":%.1f,\"targets\":{\"missed_pct_max\":1,"
                "\"stereo_over_mono_max\":1.7},\"paintings\":[%s]}\n",
                (*ctx)->info().name.c_str(), eye_w, eye_h, a.hz, seconds, rows.c_str());
    return 0;
  }
  for (const auto& x : all)
    bench::print("headset: %s on %s, 2 x %ux%u at %.0f Hz, %zu frames while %llu strokes streamed "
                 "in: frame_ms p50 %.1f p99 %.1f; missed %zu (%.1f%%; %zu while streaming, %zu on a new "
                 "epoch); render_scale p50 %.2f min "
                 "%.2f; motion_to_photon_ms p50 %.1f p99 %.1f; stereo/mono %.2fx (%.1f / %.1f ms "
                 "at scale 1; a submission per eye: %.2fx)\n",
                 x.name.c_str(), (*ctx)->info().name.c_str(), eye_w, eye_h, a.hz, x.frames,
                 static_cast<unsigned long long>(x.epochs), x.frame_p50, x.frame_p99, x.missed,
                 x.frames ? 100.0 * static_cast<double>(x.missed) / static_cast<double>(x.frames) : 0.0,
                 x.missed_while_streaming, x.missed_after_upload, x.scale_p50, x.scale_min, x.mtp_p50, x.mtp_p99,
                 x.mono_ms > 0 ? x.stereo_ms / x.mono_ms : 0.0, x.stereo_ms, x.mono_ms,
                 x.mono_ms > 0 ? x.two_submissions_ms / x.mono_ms : 0.0);
  return 0;
}

bench::SuiteRun setup(CLI::App& app) {
  auto a = std::make_shared<HeadsetArgs>();
  app.add_option("--painting", a->painting, "one painting (default demo.apa and the largest)")
      ->type_name("FILE.apa");
  app.add_option("--device", a->device, "Vulkan device (else DEEPCANVAS_VK_DEVICE / automatic)")
      ->type_name("SPEC");
  app.add_option("--eye-size", a->eye_size, "each eye at render scale 1 (default 640x576)")
      ->type_name("WxH");
  app.add_option("--hz", a->hz, "the headset's refresh rate (default 30)")
      ->type_name("HZ")
      ->transform(bench::number(1, 1000));
  app.add_option("--frames-csv", a->frames_csv,
                 "also write every frame (times, scale, epoch, missed) to FILE, appended")
      ->type_name("FILE");
  app.add_option("--seconds", a->seconds, "length of the streaming run (default 20, --quick 8)")
      ->type_name("S")
      ->transform(bench::number(1, 3600));
  return [a](const bench::Options& opt) { return run(opt, *a); };
}

}  // namespace

DEEPCANVAS_BENCH_SUITE(deepcanvas::bench::Suite{
    "headset", "stereo frames from a pose trace while a painting streams in (missed frames, scale)",
    "examples:\n"
    "  deepcanvas-bench headset --quick\n"
    "  deepcanvas-bench headset --eye-size 1680x1512 --hz 90 --json   # on a GPU\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder), DEEPCANVAS_VK_DEVICE\n",
    setup});
