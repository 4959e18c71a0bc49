// StreamingReplica fed by a real Client from a loopback server (label gpu): the client's epoch
// hook (stream_client_into) keeps the GPU replica equal to the client's CPU replica, links
// included, and a progressive join shows the snapshot in parts, then whole and exact.
#include <gtest/gtest.h>

#include <chrono>
#include <memory>
#include <mutex>
#include <random>
#include <thread>
#include <vector>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/server_net/server.hpp"
#include "gpu_test_support.hpp"
#include "stream_test_support.hpp"

namespace deepcanvas::render_test {
namespace {

namespace cg = client_gpu;

// A server on loopback with one small canvas "s" (8 m, depth 12, several epochs per stroke).
Result<std::unique_ptr<server_net::Server>> start_small_server(std::uint32_t block_cells = 4096) {
  base::set_log_level(base::LogLevel::warn);
  server_net::ServerConfig scfg;
  scfg.listen_address = "127.0.0.1";
  scfg.port = 0;
  server_core::CanvasServiceConfig c;
  c.name = "s";
  c.octree.edge_m = 8.0;
  c.octree.max_depth = 12;
  c.max_cells_per_step = 4096;  // several epochs per stroke
  c.octree.block_cells = block_cells;
  scfg.canvases.push_back(c);
  auto server = server_net::Server::create(std::move(scfg));
  if (!server) return std::move(server).error();
  if (auto r = (*server)->start(); !r) return std::move(r).error();
  return std::move(*server);
}

client_core::ClientOptions small_server_client(const server_net::Server& server, protocol::Role role) {
  client_core::ClientOptions o;
  o.url = "ws://127.0.0.1:" + std::to_string(server.port()) + "/";
  o.canvas = "s";
  o.role = role;
  return o;
}

cg::GpuReplicaConfig replica_config_of(const protocol::Welcome& w) {
  cg::GpuReplicaConfig cfg;
  cfg.width_log2 = static_cast<std::uint32_t>(std::countr_zero(w.texture_width));
  cfg.block_log2 = static_cast<std::uint32_t>(std::countr_zero(w.block_cells));
  cfg.roots_per_axis = w.geometry.roots_per_axis;
  cfg.edge_m = w.geometry.edge_m;
  cfg.max_depth = w.geometry.max_depth;
  return cfg;
}

// A stroke of ten samples somewhere in the small canvas, one in four erasing.
protocol::Stroke random_small_stroke(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-1.5, 1.5);
  protocol::Stroke s;
  s.brush.colour[1] = 0.7f;
  s.brush.colour[3] = 0.8f;
  if (rng() % 4 == 0) s.brush.mode = protocol::BrushMode::erase;
  const double x0 = u(rng), y0 = u(rng), z0 = u(rng);
  for (int k = 0; k < 10; ++k) {
    protocol::StrokeSample smp;
    smp.x = x0 + 0.03 * k;
    smp.y = y0;
    smp.z = z0 + 0.01 * k;
    smp.radius = 0.02f + 0.05f * static_cast<float>(rng() % 3);
    s.samples.push_back(smp);
  }
  return s;
}

// Sends `n` random small strokes, adding their handles to `handles`.
void send_small_strokes(client_core::Client& painter, std::mt19937_64& rng, int n,
                        std::vector<std::uint64_t>& handles) {
  for (int i = 0; i < n; ++i) {
    auto h = painter.send_stroke(random_small_stroke(rng));
    ASSERT_TRUE(h.ok()) << h.error().message;
    handles.push_back(*h);
  }
}

// The mirror (= the textures) equals the viewer's CPU replica and the GPU links its CPU links.
void expect_gpu_equals_cpu(cg::StreamingReplica& sr, const client_core::Client& viewer) {
  std::vector<std::uint32_t> gpu_links, fc, col, par;
  std::vector<std::uint8_t> dep;
  ASSERT_TRUE(sr.with_gpu([&](const cg::ResidentState& s) -> Result<void> {
                  fc.assign(s.pools.first_child.begin(), s.pools.first_child.end());
                  col.assign(s.pools.colour.begin(), s.pools.colour.end());
                  par.assign(s.pools.group_parent.begin(), s.pools.group_parent.end());
                  dep.assign(s.pools.group_depth_flags.begin(), s.pools.group_depth_flags.end());
                  auto l = s.replica.read_links();
                  if (!l) return std::move(l).error();
                  gpu_links = std::move(*l);
                  return {};
                })
                  .ok());
  viewer.with_replica([&](const client_core::Replica& r) {
    const PoolView v = r.view();
    ASSERT_EQ(fc.size(), v.first_child.size());
    EXPECT_TRUE(std::equal(fc.begin(), fc.end(), v.first_child.begin()));
    EXPECT_TRUE(std::equal(col.begin(), col.end(), v.colour.begin()));
    EXPECT_TRUE(std::equal(par.begin(), par.end(), v.group_parent.begin()));
    EXPECT_TRUE(std::equal(dep.begin(), dep.end(), v.group_depth_flags.begin()));
    const auto links = r.group_links();
    ASSERT_EQ(gpu_links.size(), links.size());
    EXPECT_TRUE(std::equal(gpu_links.begin(), gpu_links.end(), links.begin()));
  });
}

// The client's epoch hook end to end: a server on loopback, a viewer Client feeding a
// StreamingReplica (stream_client_into, set after the snapshot so the catch-up call is used
// too), a painter sending random strokes (some erasing). At the end the mirror (= the textures)
// equals the viewer's CPU replica and the GPU links equal its CPU links: no changed range and
// no masked group was lost between Client and GPU.
TEST(StreamingReplica, ClientEpochHookKeepsTheGpuReplicaEqualToTheCpuReplica) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  auto server = start_small_server();
  ASSERT_TRUE(server.ok()) << server.error().message;
  auto painter = client_core::Client::connect(small_server_client(**server, protocol::Role::painter));
  ASSERT_TRUE(painter.ok()) << painter.error().message;
  auto viewer = client_core::Client::connect(small_server_client(**server, protocol::Role::viewer));
  ASSERT_TRUE(viewer.ok()) << viewer.error().message;
  ASSERT_TRUE((*viewer)->wait_for_epoch(0, std::chrono::seconds(30)).ok());
  auto sr = cg::StreamingReplica::create(*ctx, replica_config_of((*viewer)->welcome()));
  ASSERT_TRUE(sr.ok()) << sr.error().message;
  // A few strokes before the hook is set, the rest after.
  std::mt19937_64 rng(31);
  std::vector<std::uint64_t> handles;
  send_small_strokes(**painter, rng, 4, handles);
  cg::stream_client_into(**viewer, **sr);
  send_small_strokes(**painter, rng, 16, handles);
  for (auto h : handles) ASSERT_TRUE((*painter)->wait_for_ack(h, std::chrono::seconds(60)).ok());
  auto q = (*server)->canvas("s")->quiesce(std::chrono::seconds(60));
  ASSERT_TRUE(q.ok());
  ASSERT_TRUE((*viewer)->wait_for_epoch(q->epoch, std::chrono::seconds(60)).ok());
  ASSERT_TRUE((*sr)->wait_resident(q->epoch, std::chrono::seconds(60)));
  (*viewer)->set_epoch_listener({});
  ASSERT_TRUE((*sr)->status().ok());
  expect_gpu_equals_cpu(**sr, **viewer);
  EXPECT_EQ((*viewer)->pool_hash(), q->pool_hash);
  (*painter)->close();
  (*viewer)->close();
  (*server)->stop();
}

// A small server painted with 40 random strokes (all acked, then quiesced) and a viewer joining
// it progressively (a part at every doubling of the frames), with an empty streaming replica.
struct PaintedJoin {
  std::unique_ptr<server_net::Server> server;
  std::unique_ptr<client_core::Client> painter, viewer;
  std::unique_ptr<cg::StreamingReplica> sr;
  server_core::CanvasService::Quiescent q;
  void close() {
    painter->close();
    viewer->close();
    server->stop();
  }
};

void join_painted_canvas(cg::Context& ctx, std::uint32_t block_cells, std::uint64_t seed,
                         PaintedJoin& out) {
  auto server = start_small_server(block_cells);
  ASSERT_TRUE(server.ok()) << server.error().message;
  out.server = std::move(*server);
  auto painter = client_core::Client::connect(small_server_client(*out.server, protocol::Role::painter));
  ASSERT_TRUE(painter.ok()) << painter.error().message;
  out.painter = std::move(*painter);
  std::mt19937_64 rng(seed);
  std::vector<std::uint64_t> handles;
  send_small_strokes(*out.painter, rng, 40, handles);
  for (auto h : handles) ASSERT_TRUE(out.painter->wait_for_ack(h, std::chrono::seconds(60)).ok());
  auto q = out.server->canvas("s")->quiesce(std::chrono::seconds(60));
  ASSERT_TRUE(q.ok());
  out.q = *q;
  auto o = small_server_client(*out.server, protocol::Role::viewer);
  o.progressive_first = std::chrono::milliseconds(0);
  auto viewer = client_core::Client::connect(o);
  ASSERT_TRUE(viewer.ok()) << viewer.error().message;
  out.viewer = std::move(*viewer);
  auto sr = cg::StreamingReplica::create(ctx, replica_config_of(out.viewer->welcome()));
  ASSERT_TRUE(sr.ok()) << sr.error().message;
  out.sr = std::move(*sr);
}

// Progressive join into the GPU replica: a viewer joins a painted canvas and shows its
// snapshot in parts (a part at every doubling of the frames); the parts are resident batches
// marked partial that neither wait_resident() nor resident_epoch() count, and once the whole
// snapshot is in, the textures and the GPU links equal the CPU replica, which equals the server.
TEST(StreamingReplica, AProgressiveJoinShowsPartsThenTheWholeSnapshot) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  PaintedJoin j;
  join_painted_canvas(*ctx, 4096, 37, j);
  if (HasFatalFailure()) return;
  cg::stream_client_into(*j.viewer, *j.sr);
  ASSERT_TRUE(j.sr->wait_resident(j.q.epoch, std::chrono::seconds(60)));
  j.viewer->set_epoch_listener({});
  ASSERT_TRUE(j.sr->status().ok());
  EXPECT_GE(j.viewer->stats().partial_commits, 2u) << "too few blocks for parts";
  const auto log = j.sr->take_resident_log();
  ASSERT_FALSE(log.empty());
  EXPECT_FALSE(log.back().partial);
  EXPECT_EQ(j.sr->resident_epoch(), j.q.epoch);
  // How many parts were resident on their own depends on the upload thread's timing (parts
  // queued behind a batch join it, and the last of them decides): counted, not required.
  std::size_t partial = 0;
  for (const auto& b : log) partial += b.partial ? 1 : 0;
  RecordProperty("partial_batches", static_cast<int>(partial));
  expect_gpu_equals_cpu(*j.sr, *j.viewer);
  EXPECT_EQ(j.viewer->pool_hash(), j.q.pool_hash);
  j.close();
}

// The content box grows part by part through a progressive join: a part's rows that no batch
// wrote before (the mirror already spans them: the snapshot's high-water mark) read as never
// used when the box's step takes them as the state before the part, so the step sees a tree
// and never falls back to an exact recompute under the GPU lock. (Read as zeros, they made
// live groups look reparented under cell 0: a fallback at some part.) The parts are captured
// from a real join, then applied one batch each, so every part is a step of its own.
TEST(StreamingReplica, AProgressiveJoinGrowsTheContentBoxPartByPart) {
  cg::Context* ctx = nullptr;
  DEEPCANVAS_REQUIRE_GPU(ctx);
  PaintedJoin j;
  join_painted_canvas(*ctx, 512, 41, j);  // many blocks: many parts
  if (HasFatalFailure()) return;
  std::mutex parts_mutex;
  std::vector<cg::EpochUpload> parts;
  const std::uint32_t width_log2 = j.sr->width_log2();
  j.viewer->set_epoch_listener([&](const client_core::EpochCommit& c) {
    cg::EpochUpload e = cg::capture_commit(c, width_log2);
    std::lock_guard l(parts_mutex);
    parts.push_back(std::move(e));
  });
  ASSERT_TRUE(j.viewer->wait_for_epoch(j.q.epoch, std::chrono::seconds(60)).ok());
  j.viewer->set_epoch_listener({});
  std::vector<cg::EpochUpload> taken;
  {
    // Taken out, not held: the listener locked parts_mutex under the client's replica lock,
    // which expect_gpu_equals_cpu takes below.
    std::lock_guard l(parts_mutex);
    taken.swap(parts);
  }
  ASSERT_GE(taken.size(), 3u) << "too few parts";
  ASSERT_TRUE(taken.front().partial);
  ASSERT_FALSE(taken.back().partial);
  std::size_t applied = 0;
  for (cg::EpochUpload& part : taken) {
    j.sr->push(std::move(part));
    ++applied;
    for (int i = 0; i < 6000 && j.sr->stats().batches < applied; ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    ASSERT_EQ(j.sr->stats().batches, applied) << "each part is a batch of its own";
  }
  ASSERT_TRUE(j.sr->wait_resident(j.q.epoch, std::chrono::seconds(60)));
  ASSERT_TRUE(j.sr->status().ok());
  const cg::StreamingStats st = j.sr->stats();
  EXPECT_EQ(st.content_fallbacks, 0u);
  EXPECT_EQ(st.content_exact, 1u);  // the first part's box only
  expect_gpu_equals_cpu(*j.sr, *j.viewer);
  j.close();
}

}  // namespace
}  // namespace deepcanvas::render_test
