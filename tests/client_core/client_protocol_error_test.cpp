// Client library vs a scripted server that breaks the stream (PROTOCOL.md 4.5 / 4.7): a block
// frame the client cannot decode, or a delta frame whose base it does not hold, must make the
// client close with 1002, report a fatal malformed error, and keep its replica at the last
// committed epoch (the frames of the open batch are never applied).
#include <gtest/gtest.h>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/websocket.hpp>
#include <future>
#include <thread>

#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::test {
namespace {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;
using server_core::Octree;
using namespace std::chrono_literals;

struct BlockBytes {
  std::vector<std::uint32_t> first_child, colour, group_parent;
  std::vector<std::uint8_t> depth_flags;
  std::vector<std::uint64_t> mask;
};

// Block 0 of `tree` (which holds fewer than one block of cells here) as a BlockView.
protocol::BlockView view_of_block0(const Octree& tree, BlockBytes& b, std::uint64_t version,
                                   std::uint64_t epoch) {
  const std::size_t n = tree.high_water_cells();
  b.first_child.assign(tree.first_child_pool().begin(), tree.first_child_pool().begin() + n);
  b.colour.assign(tree.colour_pool().begin(), tree.colour_pool().begin() + n);
  b.group_parent.assign(tree.group_parent_pool().begin(), tree.group_parent_pool().begin() + n / 8);
  b.depth_flags.assign(tree.group_depth_flags_pool().begin(),
                       tree.group_depth_flags_pool().begin() + n / 8);
  b.mask.assign((n / 8 + 63) / 64, ~std::uint64_t{0});
  protocol::BlockView v;
  v.block_id = 0;
  v.version = version;
  v.epoch = epoch;
  v.first_cell = 0;
  v.cell_count = static_cast<std::uint32_t>(n);
  v.first_child = b.first_child;
  v.colour = b.colour;
  v.group_parent = b.group_parent;
  v.depth_flags = b.depth_flags;
  v.neighbour_mask = b.mask;
  return v;
}

// One connection: welcome, a snapshot (block 0 at version 1, epoch 0), then `bad` (a binary
// frame), then waits for the client's close and returns its code (0 if none arrived).
class ScriptedServer {
 public:
  ScriptedServer(std::vector<std::uint8_t> snapshot, std::vector<std::uint8_t> bad)
      : acceptor_(ioc_, tcp::endpoint(net::ip::make_address("127.0.0.1"), 0)) {
    port_ = acceptor_.local_endpoint().port();
    result_ = std::async(std::launch::async,
                         [this, s = std::move(snapshot), b = std::move(bad)] { return run(s, b); });
  }
  std::string url() const { return "ws://127.0.0.1:" + std::to_string(port_) + "/"; }
  int close_code() { return result_.get(); }

 private:
  int run(const std::vector<std::uint8_t>& snapshot, const std::vector<std::uint8_t>& bad) {
    tcp::socket sock(ioc_);
    acceptor_.accept(sock);
    websocket::stream<tcp::socket> ws(std::move(sock));
    ws.accept();
    beast::flat_buffer buf;
    ws.read(buf);  // hello
    protocol::Welcome w;
    w.canvas = "default";
    w.role = protocol::Role::viewer;
    ws.text(true);
    ws.write(net::buffer(protocol::encode_message(w)));
    ws.binary(true);
    ws.write(net::buffer(snapshot));
    ws.text(true);
    ws.write(net::buffer(protocol::encode_message(protocol::EpochEnd{0, 1, true})));
    ws.binary(true);
    ws.write(net::buffer(bad));
    beast::error_code ec;
    for (int i = 0; i < 16 && !ec; ++i) ws.read(buf, ec);  // until the client's close arrives
    return ec == websocket::error::closed ? static_cast<int>(ws.reason().code) : 0;
  }

  net::io_context ioc_;
  tcp::acceptor acceptor_;
  unsigned short port_ = 0;
  std::future<int> result_;
};

struct Frames {
  std::vector<std::uint8_t> snapshot, delta_wrong_base, undecodable;
  std::uint64_t snapshot_hash = 0;
};

Frames make_frames() {
  server_core::OctreeConfig cfg;
  auto tree = Octree::create(cfg);
  EXPECT_TRUE(tree.ok());
  Frames f;
  protocol::BlockEncoder enc;
  BlockBytes b1, b2, b3;
  EXPECT_TRUE(enc.encode(view_of_block0(**tree, b1, 1, 0), f.snapshot).ok());
  f.snapshot_hash = (*tree)->pool_hash();
  // A delta of version 3 against version 2, which the client never received (it holds 1).
  auto v2 = view_of_block0(**tree, b2, 2, 1);
  (*tree)->set_colour(0, 0xff0000ffu);
  auto v3 = view_of_block0(**tree, b3, 3, 1);
  EXPECT_TRUE(enc.encode_delta(v3, v2, f.delta_wrong_base).ok());
  f.undecodable = f.snapshot;
  f.undecodable.resize(f.undecodable.size() / 2);  // truncated
  return f;
}

void expect_closed_with_1002(const std::vector<std::uint8_t>& bad, const Frames& f,
                             bool keep_replica = true) {
  ScriptedServer server(f.snapshot, bad);
  client_core::ClientOptions opt;
  opt.url = server.url();
  opt.role = protocol::Role::viewer;
  opt.keep_replica = keep_replica;
  auto client = client_core::Client::connect(opt);
  ASSERT_TRUE(client.ok()) << client.error().message;
  auto& c = **client;
  auto err = c.wait_for_error(10s);
  ASSERT_TRUE(err.has_value());
  EXPECT_EQ(err->code, Errc::malformed);
  EXPECT_TRUE(err->fatal);
  EXPECT_EQ(err->in_reply_to, "block_frame");
  EXPECT_TRUE(c.wait_for_close(10s));
  EXPECT_EQ(c.close_code(), 1002);
  EXPECT_EQ(server.close_code(), 1002);
  // The snapshot stays applied; nothing of the broken batch is.
  EXPECT_EQ(c.applied_epoch(), 0u);
  if (keep_replica) {
    EXPECT_EQ(c.pool_hash(), f.snapshot_hash);
  }
  EXPECT_GE(c.stats().decode_failures, 1u);
  EXPECT_FALSE(c.request_stats().ok());  // the connection is over
}

TEST(ClientProtocolError, UndecodableFrameClosesWith1002) {
  const Frames f = make_frames();
  expect_closed_with_1002(f.undecodable, f);
}

TEST(ClientProtocolError, DeltaWithoutItsBaseClosesWith1002) {
  const Frames f = make_frames();
  expect_closed_with_1002(f.delta_wrong_base, f);
}

// A client without a replica reads only headers, and still refuses a frame whose header does
// not match its bytes (here: fewer payload bytes than the header declares).
TEST(ClientProtocolError, WithoutReplicaATruncatedFrameClosesWith1002) {
  const Frames f = make_frames();
  expect_closed_with_1002(f.undecodable, f, /*keep_replica=*/false);
}

}  // namespace
}  // namespace deepcanvas::test
