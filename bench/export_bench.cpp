// deepcanvas-bench export: a canvas leaving for other tools (issue: export, import and
// time-lapse), on demo.apa and on the largest painting (by file size) in DEEPCANVAS_PAINTINGS.
//
// Per painting, each figure the median of 3 runs (1 with --quick):
//   vdb   export_vdb at the deepest painted level: seconds (grids built + written), bytes, and
//         the anchor: OpenVDB's own write (io::File) of the same grids, and its share
//   glb   export_mesh to binary glTF with the default budget (1M triangles: the finest level
//         that fits): seconds, bytes, triangles, the level
//   png   one 1280x720 frame of the framed painting on the Vulkan device: upload, links, ray
//         cast and PNG write, seconds and bytes (what `render` and each turntable frame do)
//   import  a vdb file of the painting at 1 cm voxels (level 19) imported back (import_cells +
//         paste into an empty canvas): seconds, cells
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "bench.hpp"
#include "deepcanvas/bridge/pool_view_of_octree.hpp"
#include "deepcanvas/client_core/camera.hpp"
#include "deepcanvas/client_core/reference_renderer.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/png.hpp"
#include "deepcanvas/client_gpu/raycaster.hpp"
#include "deepcanvas/client_gpu/replica_gpu.hpp"
#include "deepcanvas/export/mesh_export.hpp"
#include "deepcanvas/export/vdb_export.hpp"
#include "deepcanvas/export/volume_import.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas::bench {
namespace {

namespace fs = std::filesystem;
namespace cc = deepcanvas::client_core;
namespace cg = deepcanvas::client_gpu;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

struct Row {
  std::string name;
  std::size_t strokes = 0;
  std::uint64_t cells = 0;
  std::vector<double> vdb_s, vdb_write_s, glb_s, png_s, import_s;
  std::uint64_t vdb_bytes = 0, vdb_voxels = 0, glb_bytes = 0, glb_triangles = 0, png_bytes = 0,
                import_cells = 0;
  int vdb_level = 0, glb_level = 0;
};

Result<std::uint64_t> render_png(const cg::Context& ctx, const server_core::Octree& tree,
                                 const std::string& path) {
  const cc::PoolView pools = bridge::pool_view_of(tree);
  cg::GpuReplicaConfig rcfg;
  rcfg.width_log2 = 12;
  rcfg.block_log2 = 12;
  auto replica = cg::GpuReplica::create(ctx, rcfg);
  if (!replica) return std::move(replica).error();
  if (auto u = (*replica)->upload_all(pools); !u) return std::move(u).error();
  if (auto l = (*replica)->compute_all_links(pools); !l) return std::move(l).error();
  auto rc = cg::GpuRaycaster::create(**replica);
  if (!rc) return std::move(rc).error();
  auto cam = cc::fit_painted(pools, 1280, 720, 45.0, {-0.45, -0.35, -0.82}, {0, 1, 0});
  if (!cam) return std::move(cam).error();
  auto origin = cc::make_ray_origin(pools, cam->position());
  if (!origin) return std::move(origin).error();
  cc::RenderOptions ro;
  ro.background = {0.05, 0.06, 0.08};
  auto box = cc::painted_bounds(pools);
  if (box && *box) ro.content_bounds = **box;
  auto pixels = (*rc)->render_rgba8(*cam, *origin, ro);
  if (!pixels) return std::move(pixels).error();
  if (auto w = cg::write_png(path, 1280, 720, *pixels); !w) return std::move(w).error();
  return static_cast<std::uint64_t>(fs::file_size(path));
}

int export_main(const Options& opt) {
  auto dir = paintings_dir();
  if (!dir) return fail(opt, dir.error().message);
  // demo.apa and the largest painting.
  std::vector<fs::path> files{*dir / "demo.apa"};
  fs::path largest;
  std::uintmax_t largest_size = 0;
  for (const auto& e : fs::directory_iterator(*dir))
    if (e.path().extension() == ".apa" && e.file_size() > largest_size) {
      largest_size = e.file_size();
      largest = e.path();
    }
  if (!largest.empty() && largest != files[0]) files.push_back(largest);
  auto ctx = cg::ContextBuilder().app_name("deepcanvas-bench export").build();
  if (!ctx) return fail(opt, "Vulkan: " + ctx.error().message);
  const int runs = opt.quick ? 1 : 3;
  const fs::path tmp = fs::temp_directory_path() / ("deepcanvas_bench_export_" + std::to_string(::getpid()));
  fs::create_directories(tmp);
  auto progress = bench::progress(opt, "export", static_cast<double>(files.size() * runs), "runs");
  std::vector<Row> rows;
  for (const auto& f : files) {
    Row row;
    row.name = f.filename().string();
    auto p = paintings::read_apa_file(f.string(), {});
    if (!p) return fail(opt, p.error().message);
    auto tree = server_core::Octree::create({});
    if (!tree) return fail(opt, tree.error().message);
    auto painter = server_core::Painter::create(**tree);
    if (!painter) return fail(opt, painter.error().message);
    for (const auto& s : p->strokes)
      if ((*painter)->apply_stroke(s)) ++row.strokes;
    row.cells = (*tree)->live_cells();
    const std::string vdb = (tmp / "canvas.vdb").string(), glb = (tmp / "canvas.glb").string(),
                      png = (tmp / "canvas.png").string();
    for (int r = 0; r < runs; ++r) {
      auto t0 = Clock::now();
      auto v = exporting::export_vdb(**tree, {}, vdb);
      if (!v) return fail(opt, row.name + ": vdb: " + v.error().message);
      row.vdb_s.push_back(seconds_since(t0));
      row.vdb_write_s.push_back(v->write_seconds);
      row.vdb_bytes = v->file_bytes;
      row.vdb_voxels = v->voxels;
      row.vdb_level = v->voxel_depth;
      t0 = Clock::now();
      auto m = exporting::export_mesh(**tree, {}, exporting::MeshFormat::glb, glb);
      if (!m) return fail(opt, row.name + ": glb: " + m.error().message);
      row.glb_s.push_back(seconds_since(t0));
      row.glb_bytes = m->file_bytes;
      row.glb_triangles = m->triangles;
      row.glb_level = m->volume.voxel_depth;
      t0 = Clock::now();
      auto g = render_png(**ctx, **tree, png);
      if (!g) return fail(opt, row.name + ": png: " + g.error().message);
      row.png_s.push_back(seconds_since(t0));
      row.png_bytes = *g;
      // The import: a 1 cm file (level 19) imported back (the deepest level's volume makes more
      // cells than one import may hold on the largest paintings).
      exporting::VdbExportOptions cm;
      cm.voxel_depth = 19;
      if (auto w = exporting::export_vdb(**tree, cm, vdb); !w)
        return fail(opt, row.name + ": vdb 1 cm: " + w.error().message);
      std::ifstream in(vdb, std::ios::binary);
      const std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)), {});
      t0 = Clock::now();
      auto cells = exporting::import_cells(bytes, (*tree)->config(), {});
      if (!cells) return fail(opt, row.name + ": import: " + cells.error().message);
      auto empty = server_core::Octree::create({});
      auto ep = server_core::Painter::create(**empty);
      if (!empty || !ep) return fail(opt, "an empty canvas");
      if (auto pasted = (*ep)->paste(*cells); !pasted)
        return fail(opt, row.name + ": paste: " + pasted.error().message);
      row.import_s.push_back(seconds_since(t0));
      row.import_cells = cells->size();
      progress.update(static_cast<double>(rows.size() * runs + r + 1));
    }
    note(opt, "%s: vdb %.2f s (%.1f MB), glb %.2f s (%llu triangles), png %.2f s, import %.2f s\n",
         row.name.c_str(), median(row.vdb_s), row.vdb_bytes / 1e6, median(row.glb_s),
         static_cast<unsigned long long>(row.glb_triangles), median(row.png_s),
         median(row.import_s));
    rows.push_back(std::move(row));
  }
  progress.finish();
  std::error_code ec;
  fs::remove_all(tmp, ec);
  if (opt.json) {
    std::printf("{\"suite\":\"export\",\"quick\":%s,\"runs\":%d,\"device\":\"%s\",\"paintings\":[",
                opt.quick ? "true" : "false", runs, (*ctx)->info().name.c_str());
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const Row& r = rows[i];
      std::printf(
          "%s{\"name\":\"%s\",\"strokes\":%zu,\"cells\":%llu,"
          "\"vdb\":{\"seconds\":%.4f,\"bytes\":%llu,\"voxels\":%llu,\"level\":%d,"
          "\"openvdb_write_seconds\":%.4f,\"openvdb_write_share\":%.4f},"
          "\"glb\":{\"seconds\":%.4f,\"bytes\":%llu,\"triangles\":%llu,\"level\":%d},"
          "\"png\":{\"seconds\":%.4f,\"bytes\":%llu,\"size\":\"1280x720\"},"
          "\"import\":{\"seconds\":%.4f,\"cells\":%llu,\"level\":19}}",
          i ? "," : "", r.name.c_str(), r.strokes, static_cast<unsigned long long>(r.cells),
          median(r.vdb_s), static_cast<unsigned long long>(r.vdb_bytes),
          static_cast<unsigned long long>(r.vdb_voxels), r.vdb_level, median(r.vdb_write_s),
          median(r.vdb_write_s) / std::max(1e-9, median(r.vdb_s)), median(r.glb_s),
          static_cast<unsigned long long>(r.glb_bytes),
          static_cast<unsigned long long>(r.glb_triangles), r.glb_level, median(r.png_s),
          static_cast<unsigned long long>(r.png_bytes), median(r.import_s),
          static_cast<unsigned long long>(r.import_cells));
    }
    std::printf("]}\n");
    return 0;
  }
  print("export: median of %d run(s) per figure; png on %s\n", runs, (*ctx)->info().name.c_str());
  print("%-14s %7s %9s | %8s %9s %8s | %8s %9s %9s | %8s %9s | %8s\n", "painting", "strokes",
        "cells", "vdb s", "vdb MB", "OpenVDB", "glb s", "glb MB", "triangles", "png s", "png KB",
        "import s");
  for (const auto& r : rows)
    print("%-14s %7zu %9llu | %8.2f %9.2f %7.0f%% | %8.2f %9.2f %9llu | %8.2f %9.0f | %8.2f\n",
          r.name.c_str(), r.strokes, static_cast<unsigned long long>(r.cells), median(r.vdb_s),
          r.vdb_bytes / 1e6, 100 * median(r.vdb_write_s) / std::max(1e-9, median(r.vdb_s)),
          median(r.glb_s), r.glb_bytes / 1e6, static_cast<unsigned long long>(r.glb_triangles),
          median(r.png_s), r.png_bytes / 1e3, median(r.import_s));
  print("OpenVDB: the share of the vdb export that is OpenVDB's own write of the same grids\n");
  return 0;
}

}  // namespace

DEEPCANVAS_BENCH_SUITE(Suite{
    "export", "a canvas to vdb, glb and png, and the vdb imported back: seconds and bytes",
    "examples:\n"
    "  deepcanvas-bench export --quick\n"
    "  deepcanvas-bench export --json\n"
    "environment: DEEPCANVAS_PAINTINGS (the paintings' folder; demo.apa and the largest)\n",
    no_options(export_main)});

}  // namespace deepcanvas::bench
