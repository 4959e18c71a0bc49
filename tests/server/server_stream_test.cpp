// The streaming server on loopback with headless clients: handshake, concurrent painters,
// streamed strokes, late joiners, slow consumers, pick-up privacy, several canvases, /metrics.
#include <gtest/gtest.h>

#include <atomic>
#include <thread>

#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

using client_core::Client;
using protocol::Role;

std::unique_ptr<Client> connect_ok(const client_core::ClientOptions& o) {
  auto c = Client::connect(o);
  EXPECT_TRUE(c.ok()) << (c ? "" : c.error().message);
  return c ? std::move(*c) : nullptr;
}

// Sends `n` random strokes and waits for all their acks.
void paint(Client& c, std::uint64_t seed, int n) {
  std::mt19937_64 rng(seed);
  std::vector<std::uint64_t> handles;
  for (int i = 0; i < n; ++i) {
    auto h = c.send_stroke(random_stroke(rng));
    ASSERT_TRUE(h.ok());
    handles.push_back(*h);
  }
  for (auto h : handles) {
    auto a = c.wait_for_ack(h, 30s);
    ASSERT_TRUE(a.ok()) << a.error().message;
    EXPECT_GT(a->stroke_id, 0u);
  }
}

TEST(ServerStream, WelcomeDescribesTheCanvas) {
  auto s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  auto c = connect_ok(client_options(s, "c", Role::viewer, "paint-token"));
  ASSERT_TRUE(c);
  const auto& w = c->welcome();
  EXPECT_EQ(w.canvas, "c");
  EXPECT_EQ(w.role, Role::viewer);  // a painter token may join as a viewer
  EXPECT_EQ(w.geometry.edge_m, 8.0);
  EXPECT_EQ(w.geometry.max_depth, 12);
  EXPECT_EQ(w.block_cells, 4096u);
  // The snapshot arrives: the 64 roots.
  ASSERT_TRUE(c->wait_for_epoch(0, 10s).ok());
  EXPECT_TRUE(c->wait_for_epoch(w.epoch, 10s).ok());
  c->with_replica([](const client_core::Replica& r) { EXPECT_GE(r.high_water_cells(), 64u); });
}

TEST(ServerStream, ConcurrentPaintersConverge) {
  auto s = start_server({"c"}, kTokens);
  ASSERT_TRUE(s.server);
  std::vector<std::unique_ptr<Client>> painters;
  for (int i = 0; i < 3; ++i) painters.push_back(connect_ok(client_options(s)));
  auto viewer = connect_ok(client_options(s, "c", Role::viewer, "view-token"));
  ASSERT_TRUE(viewer);
  std::vector<std::thread> threads;
  for (int i = 0; i < 3; ++i) threads.emplace_back([&, i] { paint(*painters[i], 100 + i, 6); });
  for (auto& t : threads) t.join();
  std::vector<Client*> all{viewer.get()};
  for (auto& p : painters) all.push_back(p.get());
  auto q = expect_converged(*s.canvas(), all);
  EXPECT_EQ(q.strokes, 18u);
  EXPECT_GT(q.live_cells, 64u);
}

// Both sides of hello.delta_frames: a client that asks gets delta frames for the blocks it
// holds, one that does not gets only full frames, and both replicas equal the server's pools.
TEST(ServerStream, DeltaFramesOnlyToClientsThatAskAndBothConverge) {
  auto s = start_server();
  ASSERT_TRUE(s.server);
  auto with = client_options(s);
  with.delta_frames = true;
  auto without = client_options(s, "c", Role::viewer);
  without.delta_frames = false;
  auto a = connect_ok(with);
  auto b = connect_ok(without);
  ASSERT_TRUE(a && b);
  ASSERT_TRUE(a->wait_for_epoch(0, 10s).ok());
  ASSERT_TRUE(b->wait_for_epoch(0, 10s).ok());
  paint(*a, 41, 8);
  expect_converged(*s.canvas(), {a.get(), b.get()});
  EXPECT_GT(a->stats().delta_frames, 0u);
  EXPECT_EQ(a->stats().decode_failures, 0u);
  EXPECT_EQ(b->stats().delta_frames, 0u);
  EXPECT_EQ(b->stats().decode_failures, 0u);
  // The delta client read fewer bytes for the same pools.
  EXPECT_LT(a->stats().frame_bytes, b->stats().frame_bytes);
}

// Both sides of hello.frame_bundles: a client that asks gets its live batches as bundles (its
// snapshot as frames), one that does not gets only frames, and both replicas equal the server's.
TEST(ServerStream, FrameBundlesOnlyToClientsThatAskAndBothConverge) {
  auto s = start_server();
  ASSERT_TRUE(s.server);
  auto with = client_options(s);
  auto without = client_options(s, "c", Role::viewer);
  without.frame_bundles = false;
  auto a = connect_ok(with);
  auto b = connect_ok(without);
  ASSERT_TRUE(a && b);
  ASSERT_TRUE(a->wait_for_epoch(0, 10s).ok());
  ASSERT_TRUE(b->wait_for_epoch(0, 10s).ok());
  EXPECT_EQ(a->stats().bundles, 0u);  // the snapshot
  paint(*a, 43, 8);
  expect_converged(*s.canvas(), {a.get(), b.get()});
  EXPECT_GT(a->stats().bundles, 0u);
  EXPECT_GT(a->stats().delta_frames, 0u);  // the records of its bundles, counted as frames
  EXPECT_EQ(a->stats().decode_failures, 0u);
  EXPECT_EQ(b->stats().bundles, 0u);
  EXPECT_EQ(b->stats().decode_failures, 0u);
  // A late joiner's snapshot comes as frames, then it converges too.
  auto late = connect_ok(client_options(s, "c", Role::viewer));
  ASSERT_TRUE(late);
  expect_converged(*s.canvas(), {a.get(), b.get(), late.get()});
  EXPECT_EQ(late->stats().bundles, 0u);
}

// hello.batch_interval_ms: a viewer that asks for batches at most every 150 ms gets fewer
// epochs than one that does not, skipped versions come as one delta each, and both converge.
TEST(ServerStream, ABatchIntervalCoalescesEpochsAndConverges) {
  auto s = start_server();
  ASSERT_TRUE(s.server);
  auto painter = connect_ok(client_options(s));
  auto every_o = client_options(s, "c", Role::viewer);
  auto spaced_o = every_o;
  spaced_o.batch_interval_ms = 150;
  auto every = connect_ok(every_o);
  auto spaced = connect_ok(spaced_o);
  ASSERT_TRUE(painter && every && spaced);
  ASSERT_TRUE(every->wait_for_epoch(0, 10s).ok());
  ASSERT_TRUE(spaced->wait_for_epoch(0, 10s).ok());
  // A stroke both viewers receive, then strokes one after another recolouring it: many versions
  // of the same blocks.
  std::mt19937_64 rng(77);
  const protocol::Stroke base = random_stroke(rng);
  auto first = painter->send_stroke(base);
  ASSERT_TRUE(first.ok());
  auto first_ack = painter->wait_for_ack(*first, 30s);
  ASSERT_TRUE(first_ack.ok());
  ASSERT_TRUE(spaced->wait_for_epoch(first_ack->epoch, 10s).ok());
  for (int i = 1; i <= 12; ++i) {
    protocol::Stroke st = base;
    st.brush.colour[0] = static_cast<float>(i) / 12.0f;
    auto h = painter->send_stroke(st);
    ASSERT_TRUE(h.ok());
    ASSERT_TRUE(painter->wait_for_ack(*h, 30s).ok());
  }
  expect_converged(*s.canvas(), {painter.get(), every.get(), spaced.get()});
  EXPECT_LT(spaced->stats().epochs, every->stats().epochs);
  EXPECT_GT(s.canvas()->metrics().composed_delta_frames.value(), 0u);
  EXPECT_EQ(spaced->stats().decode_failures, 0u);
  EXPECT_LT(spaced->stats().frame_bytes, every->stats().frame_bytes);
}

// Progressive join (PROTOCOL.md 4.4): a viewer joining a painted canvas commits its snapshot
// in parts as it arrives; in each part every cell reachable from the roots lies in a block it
// has received (no cell whose data has not come), and the whole snapshot converges.
TEST(ServerStream, AJoinerShowsItsSnapshotInPartsAndConverges) {
  auto s = start_server();
  ASSERT_TRUE(s.server);
  auto painter = connect_ok(client_options(s));
  ASSERT_TRUE(painter);
  paint(*painter, 91, 30);
  ASSERT_TRUE(s.canvas()->quiesce().ok());
  // Without a camera, and with one (hello "camera": the snapshot's blocks of each depth nearest
  // it first): every part is sound either way.
  for (const bool with_camera : {false, true}) {
    SCOPED_TRACE(with_camera ? "with a camera" : "without a camera");
    auto o = client_options(s, "c", Role::viewer);
    o.progressive_first = std::chrono::milliseconds(0);  // a part at every doubling of the frames
    if (with_camera) o.camera = protocol::JoinCamera{{0.5, -3, 0.2}, {0, 0, 0}};
    auto joiner = connect_ok(o);
    ASSERT_TRUE(joiner);
    std::atomic<int> partial_parts = 0, unsound = 0;
    const std::uint32_t block_cells = joiner->welcome().block_cells;
    joiner->set_epoch_listener([&](const client_core::EpochCommit& c) {
      if (!c.partial) return;
      ++partial_parts;
      const auto v = c.replica.view();
      const std::uint32_t bc = block_cells;
      std::vector<std::uint32_t> stack;
      for (std::uint32_t r = 0; r < v.root_count(); ++r) stack.push_back(r);
      while (!stack.empty()) {
        const std::uint32_t cell = stack.back();
        stack.pop_back();
        if (!c.replica.block_version(cell / bc)) {
          ++unsound;
          return;
        }
        const std::uint32_t fc = v.first_child[cell];
        if (fc != client_core::PoolView::kNoCell)
          for (std::uint32_t i = 0; i < 8; ++i) stack.push_back(fc + i);
      }
    });
    auto q = expect_converged(*s.canvas(), {joiner.get()});
    EXPECT_EQ(unsound.load(), 0);
    EXPECT_GE(joiner->stats().partial_commits, 1u);
    // The listener may come after the first parts (it is set once connected); those it saw
    // were checked.
    EXPECT_LE(static_cast<std::uint64_t>(partial_parts.load()), joiner->stats().partial_commits + 1);
    EXPECT_EQ(q.strokes, 30u);
    joiner->set_epoch_listener({});
  }
}

// hello.block_frames = false: a painter that only paints gets its acks and stats but no
// snapshot, no block frames and no epochs; a viewer beside it still converges.
TEST(ServerStream, PainterWithoutBlockFramesGetsAcksButNoCanvas) {
  auto s = start_server();
  ASSERT_TRUE(s.server);
  auto po = client_options(s);
  po.block_frames = false;
  auto painter = connect_ok(po);
  auto viewer = connect_ok(client_options(s, "c", Role::viewer));
  ASSERT_TRUE(painter && viewer);
  ASSERT_TRUE(viewer->wait_for_epoch(0, 10s).ok());
  paint(*painter, 43, 6);
  auto q = expect_converged(*s.canvas(), {viewer.get()});
  EXPECT_EQ(q.strokes, 6u);
  ASSERT_TRUE(painter->request_stats().ok());
  auto st = painter->wait_for_stats(10s);
  ASSERT_TRUE(st.ok()) << st.error().message;
  EXPECT_EQ(st->strokes, 6u);
  EXPECT_EQ(st->blocks_sent, 0u);
  EXPECT_EQ(st->clients, 1u);  // the viewer: sessions receiving the stream
  EXPECT_EQ(painter->stats().frames, 0u);
  EXPECT_EQ(painter->stats().epochs, 0u);
  auto e = painter->wait_for_epoch(0, 1s);
  ASSERT_FALSE(e.ok());
  EXPECT_EQ(e.error().code, Errc::invalid_argument);
  EXPECT_GT(viewer->stats().frames, 0u);
}

TEST(ServerStream, StreamedStrokesConverge) {
  auto s = start_server();
  ASSERT_TRUE(s.server);
  auto a = connect_ok(client_options(s));
  auto b = connect_ok(client_options(s));
  ASSERT_TRUE(a && b);
  std::mt19937_64 rng(9);
  auto st = random_stroke(rng, 12);
  auto h = a->begin_stroke(st.brush, {st.samples.begin(), st.samples.begin() + 2});
  ASSERT_TRUE(h.ok());
  for (int i = 2; i < 12; i += 5)
    ASSERT_TRUE(
        a->add_samples(*h, {st.samples.begin() + i, st.samples.begin() + std::min(i + 5, 12)})
            .ok());
  // The server has a's begin once it answers a later request on the same connection.
  ASSERT_TRUE(a->request_stats().ok());
  ASSERT_TRUE(a->wait_for_stats(10s).ok());
  // A whole stroke from b in the middle of a's streamed one takes turns with it: it is acked
  // without waiting for a's end.
  auto hb = b->send_stroke(random_stroke(rng));
  ASSERT_TRUE(hb.ok());
  auto ack_b = b->wait_for_ack(*hb, 30s);
  ASSERT_TRUE(ack_b.ok());
  ASSERT_TRUE(a->end_stroke(*h).ok());
  auto ack_a = a->wait_for_ack(*h, 30s);
  ASSERT_TRUE(ack_a.ok());
  EXPECT_LT(ack_a->stroke_id, ack_b->stroke_id);  // ids are the order of the begins
  ASSERT_TRUE(a->wait_for_epoch(std::max(ack_a->epoch, ack_b->epoch), 10s).ok());
  expect_converged(*s.canvas(), {a.get(), b.get()});
}

TEST(ServerStream, LateJoinersConverge) {
  auto s = start_server();
  ASSERT_TRUE(s.server);
  auto a = connect_ok(client_options(s));
  ASSERT_TRUE(a);
  paint(*a, 7, 5);
  // Joins after painting: the snapshot alone must give the canvas.
  auto late = connect_ok(client_options(s, "c", Role::viewer));
  ASSERT_TRUE(late);
  expect_converged(*s.canvas(), {a.get(), late.get()});
  // Joins while strokes are in flight: snapshot at some epoch, then live updates.
  std::mt19937_64 rng(8);
  std::vector<std::uint64_t> hs;
  for (int i = 0; i < 6; ++i) hs.push_back(*a->send_stroke(random_stroke(rng)));
  auto mid = connect_ok(client_options(s, "c", Role::viewer));
  ASSERT_TRUE(mid);
  for (auto h : hs) ASSERT_TRUE(a->wait_for_ack(h, 30s).ok());
  expect_converged(*s.canvas(), {a.get(), late.get(), mid.get()});
}

TEST(ServerStream, SlowConsumerCatchesUpWithoutStallingOthers) {
  // Small socket buffers on both ends so that a paused reader pushes back within a few frames.
  auto s = start_server({"c"}, "", {}, 16 * 1024);
  ASSERT_TRUE(s.server);
  auto painter = connect_ok(client_options(s));
  auto slow_options = client_options(s, "c", Role::viewer);
  slow_options.receive_buffer_bytes = 4096;
  auto slow = connect_ok(slow_options);
  ASSERT_TRUE(painter && slow);
  ASSERT_TRUE(slow->wait_for_epoch(0, 10s).ok());
  slow->pause_reading();
  // Big strokes: many blocks change, more than the socket buffers hold.
  std::mt19937_64 rng(11);
  std::uint64_t last_epoch = 0;
  for (int i = 0; i < 16; ++i) {
    auto st = random_stroke(rng, 10);
    for (auto& p : st.samples) p.radius = 0.15f;
    auto h = painter->send_stroke(st);
    ASSERT_TRUE(h.ok());
    auto a = painter->wait_for_ack(*h, 30s);  // the painter is never held up by the slow one
    ASSERT_TRUE(a.ok()) << a.error().message;
    ASSERT_TRUE(painter->wait_for_epoch(a->epoch, 30s).ok());
    last_epoch = a->epoch;
  }
  EXPECT_LT(slow->applied_epoch(), last_epoch);
  const auto pending = s.canvas()->metrics().pending_blocks.value();
  slow->resume_reading();
  auto q = expect_converged(*s.canvas(), {painter.get(), slow.get()});
  const auto fs = slow->stats(), fp = painter->stats();
  std::printf(
      "[ info ] painter got %llu frames in %llu epochs, slow consumer %llu frames in %llu "
      "epochs (pending blocks while paused: %lld)\n",
      static_cast<unsigned long long>(fp.frames), static_cast<unsigned long long>(fp.epochs),
      static_cast<unsigned long long>(fs.frames), static_cast<unsigned long long>(fs.epochs),
      static_cast<long long>(pending));
  // The slow client skipped epochs (its pending set coalesced them) and still converged; its
  // client counted them. Both joined at the same epoch and end at the same one, so each saw
  // every epoch in between either as a batch or as a skipped one.
  EXPECT_LT(fs.epochs, fp.epochs);
  EXPECT_GT(fs.epochs_skipped, 0u);
  EXPECT_EQ(fs.epochs + fs.epochs_skipped, fp.epochs + fp.epochs_skipped);
  EXPECT_GT(pending, 0);
  EXPECT_EQ(q.strokes, 16u);
}

// A reply does not wait behind a batch: a joiner's snapshot (far more than the small socket
// buffers hold) is queued, the joiner asks for stats and stops reading for a while; when it
// reads again, the stats reply comes after the frames already in the buffers, before the
// snapshot's epoch_end (PROTOCOL.md 2.1 item 4 lets control messages pass the batches).
TEST(ServerStream, RepliesGoOutAheadOfAQueuedBatch) {
  auto s = start_server({"c"}, "", {}, 16 * 1024);
  ASSERT_TRUE(s.server);
  auto painter_options = client_options(s);
  painter_options.block_frames = false;
  auto painter = connect_ok(painter_options);
  ASSERT_TRUE(painter);
  std::mt19937_64 rng(17);
  std::vector<std::uint64_t> handles;
  for (int i = 0; i < 48; ++i) {
    auto st = random_stroke(rng, 10);
    for (auto& p : st.samples) p.radius = 0.2f;
    auto h = painter->send_stroke(st);
    ASSERT_TRUE(h.ok());
    handles.push_back(*h);
  }
  for (auto h : handles) ASSERT_TRUE(painter->wait_for_ack(h, 60s).ok());
  ASSERT_TRUE(s.canvas()->quiesce(30s).ok());

  auto raw = RawWs::connect(s, "", nullptr, 4096);
  ASSERT_TRUE(raw);
  ASSERT_TRUE(raw->send_text(R"({"type":"hello","protocol_version":1,"role":"viewer",)"
                             R"("token":"any","canvas":"c","client_name":"reply-order-test"})"));
  auto welcome = raw->read_message();
  ASSERT_TRUE(welcome && welcome->text && welcome->data.find("\"welcome\"") != std::string::npos)
      << (welcome ? welcome->data.substr(0, 300) : std::string("no message"));
  ASSERT_TRUE(raw->send_text(R"({"type":"stats_request"})"));
  std::this_thread::sleep_for(500ms);  // the server's writes stop at the full buffers
  std::size_t frames = 0, frames_before_stats = 0, frame_bytes = 0;
  bool stats = false, epoch_end = false, stats_first = false;
  while (!(stats && epoch_end)) {
    auto m = raw->read_message(20s);
    ASSERT_TRUE(m) << "the connection ended after " << frames << " frames";
    if (!m->text) {
      ++frames;
      frame_bytes += m->data.size();
    } else if (m->data.find("\"type\":\"stats\"") != std::string::npos) {
      stats = true;
      frames_before_stats = frames;
      stats_first = !epoch_end;
    } else if (m->data.find("\"type\":\"epoch_end\"") != std::string::npos) {
      epoch_end = true;
    }
  }
  std::printf("[ info ] snapshot: %zu frames, %zu bytes; the stats reply came after %zu of them\n",
              frames, frame_bytes, frames_before_stats);
  ASSERT_GT(frame_bytes, 150u << 10) << "the snapshot must be far larger than the socket buffers";
  EXPECT_TRUE(stats_first) << "the reply waited for the whole snapshot";
  EXPECT_LT(frames_before_stats, frames / 2);
}

TEST(ServerStream, PickUpReplyGoesToTheAskerOnly) {
  auto s = start_server();
  ASSERT_TRUE(s.server);
  auto a = connect_ok(client_options(s));
  auto b = connect_ok(client_options(s));
  ASSERT_TRUE(a && b);
  protocol::Stroke st;
  st.brush.colour[0] = 1;
  st.brush.colour[1] = 0;
  st.brush.colour[2] = 0;
  st.brush.colour[3] = 1;
  st.brush.opacity = 1;
  st.brush.hardness = 1;
  protocol::StrokeSample p;
  p.radius = 0.2f;
  st.samples = {p};
  auto h = a->send_stroke(st);
  ASSERT_TRUE(h.ok());
  ASSERT_TRUE(a->wait_for_ack(*h, 30s).ok());
  auto id = a->request_pick_up(0.001, 0.001, 0.001);
  ASSERT_TRUE(id.ok());
  auto r = a->wait_for_pick_up(*id, 10s);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_GT(r->colour[0], 0.9f);
  EXPECT_LT(r->colour[1], 0.1f);
  EXPECT_GT(r->density, 0.0f);
  EXPECT_FALSE(b->wait_for_pick_up(*id, 300ms).ok());
}

TEST(ServerStream, CanvasesAreIndependent) {
  auto s = start_server({"c", "d"}, kTokens);
  ASSERT_TRUE(s.server);
  auto c = connect_ok(client_options(s, "c"));
  auto d = connect_ok(client_options(s, "d", Role::painter, "paint-d"));
  ASSERT_TRUE(c && d);
  // The c token does not open d.
  auto wrong = Client::connect(client_options(s, "d", Role::painter, "paint-token"));
  ASSERT_FALSE(wrong.ok());
  EXPECT_EQ(wrong.error().code, Errc::unauthorized);
  auto before = s.canvas("d")->quiesce();
  ASSERT_TRUE(before.ok());
  paint(*c, 21, 4);
  auto after = s.canvas("d")->quiesce();
  ASSERT_TRUE(after.ok());
  EXPECT_EQ(before->pool_hash, after->pool_hash);
  EXPECT_EQ(after->strokes, 0u);
  expect_converged(*s.canvas("c"), {c.get()});
  expect_converged(*s.canvas("d"), {d.get()});
}

TEST(ServerStream, MetricsEndpointReportsTheStream) {
  auto s = start_server();
  ASSERT_TRUE(s.server);
  auto a = connect_ok(client_options(s));
  ASSERT_TRUE(a);
  paint(*a, 31, 3);
  expect_converged(*s.canvas(), {a.get()});
  auto [status, body] = http_get(s, "/metrics");
  ASSERT_EQ(status, 200) << body;
  for (const char* series :
       {"deepcanvas_strokes_total{canvas=\"c\"} 3", "deepcanvas_cells_changed_total{canvas=\"c\"}",
        "deepcanvas_blocks_staged_total{canvas=\"c\"}", "deepcanvas_block_frames_sent_total",
        "deepcanvas_block_bytes_raw_total{canvas=\"c\"}",
        "deepcanvas_block_bytes_compressed_total{canvas=\"c\"}",
        "deepcanvas_stroke_queue_depth{canvas=\"c\"}", "deepcanvas_pending_blocks{canvas=\"c\"}",
        "deepcanvas_stroke_to_first_block_seconds_bucket{le=",
        "deepcanvas_step_seconds_count{canvas=\"c\"}", "deepcanvas_sessions 1"})
    EXPECT_NE(body.find(series), std::string::npos) << "missing " << series;
  EXPECT_EQ(http_get(s, "/nope").first, 404);
  EXPECT_EQ(http_get(s, "/healthz").first, 200);
}

TEST(ServerStream, StopClosesClientsCleanly) {
  auto s = start_server();
  ASSERT_TRUE(s.server);
  auto a = connect_ok(client_options(s));
  ASSERT_TRUE(a);
  ASSERT_TRUE(a->wait_for_epoch(0, 10s).ok());
  s.server->stop();
  EXPECT_TRUE(a->wait_for_close(10s));
  EXPECT_EQ(a->close_code(), 1001);  // going away
}

}  // namespace
}  // namespace deepcanvas::test
