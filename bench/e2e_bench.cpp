// deepcanvas-bench e2e: server (in process) + a headless painter + a headless viewer with the
// GPU replica on loopback; a real painting is sent at its recorded pace while the viewer's
// render loop renders continuously.
//
// Figures (per stroke, then p50/p99 over all strokes of all paintings run):
//   stroke_to_resident_ms  the painter sends the stroke -> the viewer's GPU replica holds the
//                          epoch the stroke's ack names (all its blocks uploaded, G3 done)
//   stroke_to_pixel_ms     the painter sends the stroke -> the end of the first frame whose
//                          every band shows that epoch or a later one
//   bytes_per_stroke       block frame bytes the viewer received / strokes
//                          (--viewer-batch-interval-ms: a viewer that asks for batches no
//                          closer than that, hello "batch_interval_ms")
//   frame_ms_p50, frame_ms_p99_while_streaming  the viewer's frames (all; those during which
//                          an upload batch became resident)
// Pace: samples are sent as the artist painted them (stroke_begin with the first sample,
// stroke_samples with those due at each wake-up, stroke_end right after the last one), by the
// .apa timestamps, steps between samples capped at --max-gap-ms (default 1000; 400 with
// --quick) so a run stays short; "sent" is the stroke_end. --whole-strokes: each stroke sent
// whole when the artist finished it ("sent" = then; the server then paints all of it at once).
// Checks: the viewer's CPU replica converges to the server's pool hash and its GPU links equal
// its CPU links (exit 1 otherwise).
// Options (`deepcanvas-bench e2e --help`): the paintings, the frame size, the render loop's and
// the upload budget's settings, the server's compress settings; --no-render shows how much the
// rendering (lavapipe, on the same CPUs as the server) slows the rest.
// DEEPCANVAS_BENCH_TRACE=1 (environment): one stderr line per stroke, where its epoch's
// commit -> resident time went (gap wait, content box, lock: mirror/growth/upload/links), and
// one per batch that held the GPU lock over 10 ms.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "bench.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/base/log.hpp"
#include "e2e_run.hpp"

namespace deepcanvas::bench {
namespace {

namespace cg = client_gpu;

struct E2eOptions {
  E2eConfig cfg;
  std::vector<std::string> paintings;
  double budget_mbps = 0;
  bool no_render = false, no_cull = false, replies_wait = false;
  const CLI::Option* max_gap = nullptr;  // given on the command line, or the default per --quick
  const CLI::Option* budget = nullptr;
};

// The run's configuration: the options, with the defaults that depend on --quick.
E2eConfig config_of(const Options& opt, const E2eOptions& eo) {
  E2eConfig cfg = eo.cfg;
  if (eo.max_gap->count() == 0) cfg.max_gap_ms = opt.quick ? 400 : 1000;
  if (eo.budget->count() > 0) cfg.budget.bytes_per_second = eo.budget_mbps * 1e6;
  cfg.render = !eo.no_render;
  cfg.content_cull = !eo.no_cull;
  cfg.replies_first = !eo.replies_wait;
  return cfg;
}

std::vector<std::string> painting_names(const Options& opt, const E2eOptions& eo) {
  if (!eo.paintings.empty()) return eo.paintings;
  return opt.quick ? std::vector<std::string>{"demo.apa"}
                   : std::vector<std::string>{"demo.apa", "mozfest.apa", "winner.apa"};
}

Result<std::vector<paintings::ApaPainting>> read_paintings(const std::vector<std::string>& names) {
  auto dir = paintings_dir();
  if (!dir) return std::move(dir).error();
  std::vector<paintings::ApaPainting> out;
  for (const auto& name : names) {
    auto p = paintings::read_apa_file((*dir / name).string(), {});
    if (!p) return std::move(p).error();
    out.push_back(std::move(*p));
  }
  return out;
}

// Every painting's samples together: the suite's p50/p99 are over all strokes of all runs.
struct E2eTotals {
  std::vector<double> res, pix, fr, frs, bps, com, cres, blk, bmir, bup, blnk, brows, bcon, bgap;
  std::uint64_t mid_frame = 0;
  bool ok = true;

  void add(const E2eRun& r) {
    auto append = [](std::vector<double>& to, const std::vector<double>& from) {
      to.insert(to.end(), from.begin(), from.end());
    };
    ok = ok && r.converged && r.links_equal && r.resident_ms.size() == r.strokes;
    append(res, r.resident_ms);
    append(pix, r.pixel_ms);
    append(fr, r.frame_ms);
    append(frs, r.frame_stream_ms);
    bps.push_back(r.bytes_per_stroke);
    append(com, r.committed_ms);
    append(cres, r.commit_resident_ms);
    append(blk, r.batch_lock_ms);
    append(bmir, r.batch_mirror_ms);
    append(bup, r.batch_upload_ms);
    append(blnk, r.batch_links_ms);
    append(bcon, r.batch_content_ms);
    append(brows, r.batch_rows);
    append(bgap, r.batch_gap_wait_ms);
    mid_frame += r.mid_frame_batches;
  }
};

void note_run(const Options& opt, const std::string& name, const E2eRun& r) {
  using base::percentile;
  note(opt,
       "e2e: %-14s %4zu strokes in %5.1f s: resident p50 %6.1f p99 %6.1f ms, pixel p50 "
       "%6.1f p99 %6.1f ms, %7.0f B/stroke, %zu frames p50 %.1f ms (streaming p99 "
       "%.1f), %llu epochs in %llu batches (max %.1f ms, %llu growths), converged %s, "
       "GPU links = CPU %s\n",
       name.c_str(), r.strokes, r.wall_s, percentile(r.resident_ms, 0.5),
       percentile(r.resident_ms, 0.99), percentile(r.pixel_ms, 0.5), percentile(r.pixel_ms, 0.99),
       r.bytes_per_stroke, r.frame_ms.size(), percentile(r.frame_ms, 0.5),
       percentile(r.frame_stream_ms, 0.99), static_cast<unsigned long long>(r.epochs),
       static_cast<unsigned long long>(r.batches), r.max_batch_ms,
       static_cast<unsigned long long>(r.growths), r.converged ? "yes" : "NO",
       r.links_equal ? "yes" : "NO");
  note(opt,
       "e2e: %-14s server: stroke_end -> painted p50 %.1f p99 %.1f ms, stroke -> first "
       "blocks published p99 %.1f ms\n",
       name.c_str(), r.server_end_to_painted_ms_p50, r.server_end_to_painted_ms_p99,
       r.server_stroke_to_publish_ms_p99);
  const double strokes = static_cast<double>(std::max<std::size_t>(r.strokes, 1));
  note(opt,
       "e2e: %-14s bytes a stroke: %.0f to the viewer; the server's epochs: %.0f painting, %.0f "
       "merging back; frame headers %.1f%%; bundles %.3fx of their frames alone; the finished "
       "painting's snapshot %.0f\n",
       name.c_str(), r.bytes_per_stroke, r.painting_bytes_per_stroke, r.merging_bytes_per_stroke,
       100.0 * r.frame_header_share, r.bundle_ratio, r.snapshot_bytes / strokes);
}

nlohmann::json run_json(const std::string& name, const E2eRun& r) {
  using base::percentile;
  return {{"painting", name},
          {"server_end_to_painted_ms_p50", r.server_end_to_painted_ms_p50},
          {"server_end_to_painted_ms_p99", r.server_end_to_painted_ms_p99},
          {"server_stroke_to_publish_ms_p99", r.server_stroke_to_publish_ms_p99},
          {"strokes", r.strokes},
          {"stroke_to_resident_ms_p50", percentile(r.resident_ms, 0.5)},
          {"stroke_to_resident_ms_p99", percentile(r.resident_ms, 0.99)},
          {"stroke_to_pixel_ms_p50", percentile(r.pixel_ms, 0.5)},
          {"stroke_to_pixel_ms_p99", percentile(r.pixel_ms, 0.99)},
          {"bytes_per_stroke", r.bytes_per_stroke},
          {"painting_bytes_per_stroke", r.painting_bytes_per_stroke},
          {"merging_bytes_per_stroke", r.merging_bytes_per_stroke},
          {"frame_header_share", r.frame_header_share},
          {"bundle_ratio", r.bundle_ratio},
          {"snapshot_bytes_per_stroke", r.snapshot_bytes / static_cast<double>(std::max<std::size_t>(r.strokes, 1))},
          {"frames", r.frame_ms.size()},
          {"batches", r.batches},
          {"epochs", r.epochs},
          {"converged", r.converged},
          {"gpu_links_equal_cpu", r.links_equal}};
}

nlohmann::json suite_json(const Options& opt, const std::string& device, const E2eConfig& cfg,
                          const E2eTotals& t, nlohmann::json runs) {
  auto q = [](const std::vector<double>& v, double p) { return base::percentile(v, p); };
  return {{"suite", "e2e"},
          {"quick", opt.quick},
          {"device", device},
          {"frame", std::to_string(cfg.width) + "x" + std::to_string(cfg.height)},
          {"upload_budget_bytes_per_s", cfg.budget.bytes_per_second},
          {"epochs_per_batch", cfg.budget.max_epochs_per_batch},
          {"batches_per_frame", cfg.budget.max_batches_per_frame},
          {"max_fps", cfg.max_fps},
          {"upload_share", cfg.upload_share},
          {"gaps_above", cfg.gaps_above},
          {"band_target_ms", cfg.band_ms},
          {"capped_band_target_ms", cfg.capped_band_ms},
          {"max_gap_ms", cfg.max_gap_ms},
          {"viewer_batch_interval_ms", cfg.viewer_batch_interval_ms},
          {"viewer_frame_bundles", cfg.viewer_bundles},
          {"strokes", t.res.size()},
          {"stroke_to_resident_ms_p50", q(t.res, 0.5)},
          {"stroke_to_resident_ms_p99", q(t.res, 0.99)},
          {"stroke_to_pixel_ms_p50", q(t.pix, 0.5)},
          {"stroke_to_pixel_ms_p99", q(t.pix, 0.99)},
          {"bytes_per_stroke", median(t.bps)},
          {"stroke_to_committed_ms_p50", q(t.com, 0.5)},
          {"stroke_to_committed_ms_p99", q(t.com, 0.99)},
          {"committed_to_resident_ms_p50", q(t.cres, 0.5)},
          {"committed_to_resident_ms_p99", q(t.cres, 0.99)},
          {"batch_gap_wait_ms_p50", q(t.bgap, 0.5)},
          {"batch_gap_wait_ms_p99", q(t.bgap, 0.99)},
          {"mid_frame_batches", t.mid_frame},
          {"batch_lock_ms_p50", q(t.blk, 0.5)},
          {"batch_lock_ms_p99", q(t.blk, 0.99)},
          {"batch_mirror_ms_p99", q(t.bmir, 0.99)},
          {"batch_upload_ms_p99", q(t.bup, 0.99)},
          {"batch_links_ms_p99", q(t.blnk, 0.99)},
          {"batch_content_ms_p99", q(t.bcon, 0.99)},
          {"batch_rows_p50", q(t.brows, 0.5)},
          {"batch_rows_p99", q(t.brows, 0.99)},
          {"render", cfg.render},
          {"content_cull", cfg.content_cull},
          {"whole_strokes", cfg.whole_strokes},
          {"replies_first", cfg.replies_first},
          {"frame_ms_p50", q(t.fr, 0.5)},
          {"frame_ms_p99_while_streaming", q(t.frs, 0.99)},
          {"targets", {{"stroke_to_resident_ms_p99_max", 20.0}}},
          {"ok", t.ok},
          {"runs", std::move(runs)}};
}

// The human summary on stdout (without --json): a line per painting, then all strokes together.
void print_summary(const std::vector<std::string>& names, const nlohmann::json& out) {
  const auto& runs = out["runs"];
  for (std::size_t k = 0; k < names.size() && k < runs.size(); ++k) {
    const auto& r = runs[k];
    print(
        "e2e %-14s %4zu strokes: stroke -> resident p50 %6.1f p99 %6.1f ms, -> pixel p50 %6.1f "
        "p99 %6.1f ms, %7.0f B/stroke, converged %s\n",
        names[k].c_str(), r["strokes"].get<std::size_t>(),
        r["stroke_to_resident_ms_p50"].get<double>(), r["stroke_to_resident_ms_p99"].get<double>(),
        r["stroke_to_pixel_ms_p50"].get<double>(), r["stroke_to_pixel_ms_p99"].get<double>(),
        r["bytes_per_stroke"].get<double>(),
        r["converged"].get<bool>() && r["gpu_links_equal_cpu"].get<bool>() ? "yes" : "NO");
  }
  const double p99 = out["stroke_to_resident_ms_p99"].get<double>();
  print(
      "e2e all %zu strokes: stroke -> resident p50 %.1f ms, p99 %.1f ms (target <= 20 ms: %s); "
      "-> committed p99 %.1f ms; -> pixel p50 %.1f ms, p99 %.1f ms\n",
      out["strokes"].get<std::size_t>(), out["stroke_to_resident_ms_p50"].get<double>(), p99,
      p99 <= 20.0 ? "met" : "not met", out["stroke_to_committed_ms_p99"].get<double>(),
      out["stroke_to_pixel_ms_p50"].get<double>(), out["stroke_to_pixel_ms_p99"].get<double>());
  print(
      "e2e frames (%s, %s): p50 %.1f ms, p99 while streaming %.1f ms; upload batches: lock "
      "p50 %.2f p99 %.2f ms, %llu mid-frame\n",
      out["device"].get<std::string>().c_str(), out["frame"].get<std::string>().c_str(),
      out["frame_ms_p50"].get<double>(), out["frame_ms_p99_while_streaming"].get<double>(),
      out["batch_lock_ms_p50"].get<double>(), out["batch_lock_ms_p99"].get<double>(),
      static_cast<unsigned long long>(out["mid_frame_batches"].get<std::uint64_t>()));
}

int e2e_main(const Options& opt, const E2eOptions& eo) {
  base::set_log_level(base::LogLevel::warn);
  const E2eConfig cfg = config_of(opt, eo);
  const std::vector<std::string> names = painting_names(opt, eo);
  auto paintings = read_paintings(names);
  if (!paintings) return fail(opt, paintings.error().message);
  std::size_t total_strokes = 0;
  for (const auto& p : *paintings) total_strokes += std::min(cfg.max_strokes, p.strokes.size());
  auto ctx = cg::ContextBuilder().app_name("deepcanvas-bench e2e").device(cfg.device).build();
  if (!ctx) return fail(opt, ctx.error().message);
  note(opt, "e2e: device %s, frames %ux%u, budget %s, max gap %.0f ms\n",
       (*ctx)->info().name.c_str(), cfg.width, cfg.height,
       cfg.budget.bytes_per_second > 0
           ? (std::to_string(cfg.budget.bytes_per_second / 1e6) + " MB/s").c_str()
           : "unlimited",
       cfg.max_gap_ms);
  auto progress = bench::progress(opt, "e2e", double(total_strokes), "strokes");
  E2eTotals totals;
  nlohmann::json runs = nlohmann::json::array();
  for (std::size_t k = 0; k < names.size(); ++k) {
    auto r = run_one(**ctx, (*paintings)[k], cfg, progress);
    if (!r) return fail(opt, names[k] + ": " + r.error().message);
    totals.add(*r);
    note_run(opt, names[k], *r);
    runs.push_back(run_json(names[k], *r));
  }
  progress.finish();
  const nlohmann::json out = suite_json(opt, (*ctx)->info().name, cfg, totals, std::move(runs));
  if (opt.json)
    print("%s\n", out.dump().c_str());
  else
    print_summary(names, out);
  if (!totals.ok)
    return fail(opt, "a viewer did not converge to the server's canvas or its GPU links");
  return 0;
}

// WxH, each 1..4096.
CLI::Validator frame_size(std::uint32_t& width, std::uint32_t& height) {
  return CLI::Validator(
      [&width, &height](std::string& v) -> std::string {
        unsigned w = 0, h = 0;
        char tail = 0;
        if (std::sscanf(v.c_str(), "%ux%u%c", &w, &h, &tail) != 2 || w == 0 || h == 0 || w > 4096 ||
            h > 4096)
          return "must be WxH, each 1..4096, not '" + v + "'";
        width = w;
        height = h;
        return {};
      },
      "", "size");
}

SuiteRun setup(CLI::App& app) {
  auto eo = std::make_shared<E2eOptions>();
  E2eConfig& c = eo->cfg;
  app.add_option("--painting", eo->paintings,
                 "a painting to send (repeatable; default demo, mozfest, winner; --quick: demo)")
      ->type_name("NAME.apa");
  app.add_option("--max-strokes", c.max_strokes, "at most N strokes of each painting")
      ->transform(number(1, 1e9, true))
      ->type_name("N");
  eo->max_gap = app.add_option("--max-gap-ms", c.max_gap_ms,
                               "cap on the pause between two samples (default 1000; --quick 400)")
                    ->transform(number(0, 1e6))
                    ->type_name("MS");
  app.add_flag("--whole-strokes", c.whole_strokes,
               "send each stroke whole when the artist finished it");
  app.add_option("--size", "the viewer's frames (default 320x180)")
      ->check(frame_size(c.width, c.height))
      ->type_name("WxH");
  app.add_flag("--no-render", eo->no_render, "no render loop (how much rendering slows the rest)");
  app.add_flag("--no-cull", eo->no_cull, "the render loop without its content cull");
  app.add_option("--fps", c.max_fps, "the render loop's pace (default 60; 0: unpaced)")
      ->transform(number(0, 10000))
      ->type_name("X");
  app.add_option("--band-ms", c.band_ms, "the render loop's band target (default 8)")
      ->transform(number(0.01, 1000))
      ->type_name("MS");
  app.add_option("--capped-band-ms", c.capped_band_ms,
                 "its band target while the fps cap sets the pace (default 2)")
      ->transform(number(0.01, 1000))
      ->type_name("MS");
  app.add_option("--upload-share", c.upload_share, "RenderLoopOptions::upload_share")
      ->transform(number(0, 0.9))
      ->type_name("F");
  app.add_option("--gaps-above", c.gaps_above,
                 "uploads wait for frame gaps once frames take X times the fps cap's interval "
                 "(RenderLoopOptions::gaps_above, default 1)")
      ->transform(number(0.01, 100))
      ->type_name("X");
  eo->budget =
      app.add_option("--budget-mbps", eo->budget_mbps, "upload budget in MB/s (default unlimited)")
          ->transform(number(0, 1e6))
          ->type_name("X");
  app.add_option("--epochs-per-batch", c.budget.max_epochs_per_batch,
                 "upload budget: epochs per batch")
      ->transform(number(0, 1e6, true))
      ->type_name("N");
  app.add_option("--batches-per-frame", c.budget.max_batches_per_frame,
                 "upload budget: batches per frame")
      ->transform(number(0, 1e6, true))
      ->type_name("N");
  app.add_option("--compress-backlog", c.compress_backlog, "the server's max_compress_backlog")
      ->transform(number(0, 1e6, true))
      ->type_name("N");
  app.add_option("--zstd-level", c.zstd_level, "the server's block compression level (default: serve's, 3)")
      ->check(CLI::Range(1, 19));
  app.add_option("--epoch-interval-ms", c.epoch_interval_ms,
                 "the server's min_epoch_interval (default 16; 0: none)")
      ->transform(number(0, 1e6, true))
      ->type_name("MS");
  app.add_option("--interior-refresh-ms", c.interior_refresh_ms,
                 "the server's interior_refresh_interval: the most an interior value lags while "
                 "strokes are open (default 250; 0: every epoch exact)")
      ->transform(number(0, 1e6, true))
      ->type_name("MS");
  app.add_option("--viewer-batch-interval-ms", c.viewer_batch_interval_ms,
                 "the viewer's hello batch_interval_ms: the least time between its batches "
                 "(default 0)")
      ->check(CLI::Range(0u, deepcanvas::protocol::kMaxBatchIntervalMs))
      ->type_name("MS");
  app.add_option("--frame-bundles", c.viewer_bundles,
                 "the viewer's hello frame_bundles: live batches as one compressed message "
                 "(default true)")
      ->type_name("BOOL");
  app.add_flag("--replies-wait", eo->replies_wait,
               "the server stages an epoch with acks only when its compress thread is free "
               "(CanvasServiceConfig::replies_first = false)");
  app.add_option("--device", c.device, "Vulkan device (else DEEPCANVAS_VK_DEVICE / automatic)")
      ->type_name("SPEC");
  return [eo](const Options& opt) { return e2e_main(opt, *eo); };
}

DEEPCANVAS_BENCH_SUITE(Suite{
    "e2e", "server + headless GPU viewer on loopback: stroke to resident / to pixel",
    "examples:\n"
    "  deepcanvas-bench e2e --quick\n"
    "  deepcanvas-bench e2e --painting winner.apa --max-strokes 50 --json\n"
    "  DEEPCANVAS_BENCH_TRACE=1 deepcanvas-bench e2e --quick   # where each stroke's time went\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder), DEEPCANVAS_VK_DEVICE,\n"
    "DEEPCANVAS_BENCH_TRACE=1 (one stderr line per stroke: where its time went)\n",
    setup});

}  // namespace
}  // namespace deepcanvas::bench
