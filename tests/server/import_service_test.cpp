// Imports (PROTOCOL.md 3.11) and exports (3.12) over the wire, and imports through a durable
// canvas: a painter's import is
// pasted as one operation, streamed to a viewer whose replica converges, undone by the painter's
// undo; bad files and viewers are refused with the canvas unchanged; the history (paste events)
// replays to the same canvas after a restart.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <future>
#include <random>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/export/mesh_export.hpp"
#include "deepcanvas/export/vdb_export.hpp"
#include "deepcanvas/export/volume_import.hpp"
#include "deepcanvas/server_core/painter.hpp"
#include "deepcanvas/storage/durable_canvas.hpp"
#include "../storage/storage_test_util.hpp"
#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

using server_core::CanvasService;

// The bytes of a VDB file of a few strokes painted on a canvas shaped like small_canvas().
std::vector<std::uint8_t> vdb_of_strokes(const server_core::OctreeConfig& oc, const TempDir& dir) {
  auto tree = server_core::Octree::create(oc);
  EXPECT_TRUE(tree);
  auto painter = server_core::Painter::create(**tree);
  EXPECT_TRUE(painter);
  std::mt19937_64 rng(4);
  for (int i = 0; i < 4; ++i) EXPECT_TRUE((*painter)->apply_stroke(random_stroke(rng)));
  const std::string path = dir.path() + "/strokes.vdb";
  exporting::VdbExportOptions xo;
  xo.voxel_depth = std::min(oc.max_depth, 6);
  EXPECT_TRUE(exporting::export_vdb(**tree, xo, path));
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

void use_importer(server_net::ServerConfig& cfg) {
  cfg.import_cells = [](const protocol::Import& m, const server_core::OctreeConfig& canvas) {
    exporting::ImportOptions io;
    io.format = m.format;
    io.at = m.at;
    io.scale = m.scale;
    io.voxel_size_m = m.voxel_size_m;
    io.colour = m.colour;
    io.density_scale = m.density_scale;
    return exporting::import_cells(m.data, canvas, io);
  };
  cfg.export_canvas = [](const server_core::Octree& tree, const protocol::ExportRequest& r,
                         std::uint64_t max_bytes) {
    std::optional<server_core::Aabb> box;
    if (r.box) box = server_core::Aabb{{(*r.box)[0], (*r.box)[1], (*r.box)[2]},
                                       {(*r.box)[3], (*r.box)[4], (*r.box)[5]}};
    return exporting::export_to_bytes(tree, r.format, r.voxel_size_m, box, max_bytes);
  };
}

TEST(ImportService, APaintersImportStreamsToViewersAndUndoTakesItBack) {
  base::set_log_level(base::LogLevel::warn);
  TempDir dir;
  TestServer s = start_server({"c"}, kTokens, {}, 0, use_importer);
  ASSERT_TRUE(s.server);
  const auto bytes = vdb_of_strokes(s.canvas()->config().octree, dir);
  auto viewer = client_core::Client::connect(
      client_options(s, "c", protocol::Role::viewer, "view-token"));
  ASSERT_TRUE(viewer.ok()) << viewer.error().message;
  auto opts = client_options(s);
  opts.client_id = "importer";
  auto painter = client_core::Client::connect(opts);
  ASSERT_TRUE(painter.ok()) << painter.error().message;
  const std::uint64_t empty_hash = s.canvas()->quiesce()->canvas_hash;

  protocol::Import m;
  m.format = "vdb";
  m.data = bytes;
  auto id = (*painter)->request_import(m);
  ASSERT_TRUE(id.ok());
  auto reply = (*painter)->wait_for_import(*id, 60s);
  ASSERT_TRUE(reply.ok()) << reply.error().message;
  EXPECT_GT(reply->cells, 100u);
  const auto q = expect_converged(*s.canvas(), {viewer->get()});
  EXPECT_NE(q.canvas_hash, empty_hash);
  EXPECT_EQ(s.canvas()->metrics().imports.value(), 1u);

  // A corrupt file, a wrong format, and a viewer: errors, the canvas unchanged.
  m.data.resize(m.data.size() / 2);
  id = (*painter)->request_import(m);
  auto bad = (*painter)->wait_for_import(*id, 60s);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code, Errc::malformed);
  m.data = bytes;
  m.format = "ply";
  id = (*painter)->request_import(m);
  bad = (*painter)->wait_for_import(*id, 60s);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code, Errc::malformed);
  m.format = "vdb";
  auto vid = (*viewer)->request_import(m);
  auto refused = (*viewer)->wait_for_import(*vid, 60s);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code, Errc::unauthorized);
  EXPECT_EQ(s.canvas()->quiesce()->canvas_hash, q.canvas_hash);

  // Undo takes the import back exactly; the viewer follows.
  auto u = (*painter)->request_undo();
  auto ur = (*painter)->wait_for_undo(*u, 60s);
  ASSERT_TRUE(ur.ok()) << ur.error().message;
  EXPECT_EQ(ur->stroke_id, reply->stroke_id);
  const auto back = expect_converged(*s.canvas(), {viewer->get()});
  EXPECT_EQ(back.canvas_hash, empty_hash);
}

// Export through the running server: a viewer gets the canvas as a mesh and as a volume; past
// max_bytes the answer is limit_exceeded with the estimate; a server without an exporter says
// unsupported.
TEST(ImportService, AViewerExportsTheLiveCanvas) {
  base::set_log_level(base::LogLevel::warn);
  TestServer s = start_server({"c"}, kTokens, {}, 0, use_importer);
  ASSERT_TRUE(s.server);
  auto painter = client_core::Client::connect(client_options(s));
  ASSERT_TRUE(painter.ok());
  std::mt19937_64 rng(9);
  std::uint64_t last = 0;
  for (int i = 0; i < 5; ++i) {
    auto h = (*painter)->send_stroke(random_stroke(rng));
    ASSERT_TRUE(h.ok());
    last = *h;
  }
  ASSERT_TRUE((*painter)->wait_for_ack(last, 30s).ok());
  auto viewer = client_core::Client::connect(
      client_options(s, "c", protocol::Role::viewer, "view-token"));
  ASSERT_TRUE(viewer.ok());
  protocol::ExportRequest m;
  m.format = "glb";
  m.voxel_size_m = 0.02;
  auto id = (*viewer)->request_export(m);
  ASSERT_TRUE(id.ok());
  auto glb = (*viewer)->wait_for_export(*id, 60s);
  ASSERT_TRUE(glb.ok()) << glb.error().message;
  EXPECT_EQ(glb->format, "glb");
  auto mesh = exporting::read_mesh_bytes(glb->data, "glb");
  ASSERT_TRUE(mesh.ok()) << mesh.error().message;
  EXPECT_GT(mesh->triangles(), 20u);
  m.format = "vdb";
  id = (*viewer)->request_export(m);
  auto vdb = (*viewer)->wait_for_export(*id, 60s);
  ASSERT_TRUE(vdb.ok()) << vdb.error().message;
  auto back = exporting::import_cells(vdb->data, s.canvas()->config().octree, {});
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_GT(back->size(), 10u);
  m.voxel_size_m = 0;
  m.max_bytes = 1000;
  id = (*viewer)->request_export(m);
  auto big = (*viewer)->wait_for_export(*id, 60s);
  ASSERT_FALSE(big.ok());
  EXPECT_EQ(big.error().code, Errc::limit_exceeded);
  EXPECT_NE(big.error().message.find("would take about"), std::string::npos);

  TestServer plain = start_server({"c"}, kTokens);
  auto v2 = client_core::Client::connect(
      client_options(plain, "c", protocol::Role::viewer, "view-token"));
  ASSERT_TRUE(v2.ok());
  id = (*v2)->request_export(m);
  auto refused = (*v2)->wait_for_export(*id, 30s);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code, Errc::unsupported);
}

TEST(ImportService, AServerWithoutAnImporterRefusesImports) {
  base::set_log_level(base::LogLevel::warn);
  TestServer s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  auto painter = client_core::Client::connect(client_options(s));
  ASSERT_TRUE(painter.ok());
  protocol::Import m;
  m.format = "vdb";
  m.data = {1, 2, 3};
  auto id = (*painter)->request_import(m);
  auto r = (*painter)->wait_for_import(*id, 30s);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, Errc::unsupported);
}

// The paste is a history event: a restart restores it, the undo history keeps it, and replaying
// every event gives the same canvas.
TEST(ImportService, ImportsSurviveARestartAndReplay) {
  base::set_log_level(base::LogLevel::warn);
  TempDir dir;
  const std::uint64_t A = 7;
  const auto config = small_canvas("c");
  const auto bytes = vdb_of_strokes(config.octree, dir);
  exporting::ImportOptions io;
  io.at = {0.25, 0, 0};
  auto cells = exporting::import_cells(bytes, config.octree, io);
  ASSERT_TRUE(cells.ok()) << cells.error().message;
  auto paste = [&](CanvasService& svc) {
    std::promise<Result<server_core::ImportDone>> p;
    auto f = p.get_future();
    auto r = svc.paste(A, std::make_shared<const server_core::CellPaste>(*cells),
                       server_core::Clock::now(),
                       [&p](Result<server_core::ImportDone> d) { p.set_value(std::move(d)); });
    EXPECT_TRUE(r.ok());
    EXPECT_EQ(f.wait_for(30s), std::future_status::ready);
    return f.get();
  };
  std::uint64_t with_import = 0, empty = 0;
  {
    auto svc = storage::open_durable_canvas(dir.path(), config, {}, false, nullptr);
    ASSERT_TRUE(svc.ok()) << svc.error().message;
    empty = (*svc)->quiesce()->canvas_hash;
    auto d = paste(**svc);
    ASSERT_TRUE(d.ok()) << d.error().message;
    EXPECT_EQ(d->stats.cells, cells->size());
    with_import = (*svc)->quiesce()->canvas_hash;
    EXPECT_NE(with_import, empty);
  }
  // Every event replayed from the start (no checkpoint) gives the canvas.
  auto replayed = storage::replay_history(dir.path() + "/c.canvas", config, 0);
  ASSERT_TRUE(replayed.ok()) << replayed.error().message;
  EXPECT_EQ(replayed->totals.rejected, 0u);
  EXPECT_EQ(replayed->totals.pastes, 1u);
  EXPECT_EQ(replayed->tree->canvas_hash(), with_import);
  // Restored, the artist's undo takes the import back.
  auto svc = storage::open_durable_canvas(dir.path(), config, {}, false, nullptr);
  ASSERT_TRUE(svc.ok());
  EXPECT_EQ((*svc)->quiesce()->canvas_hash, with_import);
  std::promise<Result<server_core::UndoDone>> p;
  auto f = p.get_future();
  ASSERT_TRUE((*svc)->undo(A, false, server_core::Clock::now(),
                           [&p](Result<server_core::UndoDone> d) { p.set_value(std::move(d)); })
                  .ok());
  ASSERT_EQ(f.wait_for(30s), std::future_status::ready);
  auto u = f.get();
  ASSERT_TRUE(u.ok()) << u.error().message;
  EXPECT_EQ((*svc)->quiesce()->canvas_hash, empty);
}

}  // namespace
}  // namespace deepcanvas::test
