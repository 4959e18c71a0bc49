// `deepcanvas-client paint` over connections that break: the real client command paints a real
// painting ($DEEPCANVAS_PAINTINGS) into a real server on loopback through a TCP proxy (Boost.Asio,
// in this test) that cuts the connection after a set number of client bytes, refuses the
// reconnect attempts that follow for a while, cuts once more, then lets the connection through.
// The painting must finish, and the canvas must equal a clean run's (canvas_hash, stroke count):
// every stroke applied exactly once, in the painting's order.
#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <boost/asio.hpp>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/server_net/server.hpp"

namespace deepcanvas::test {
namespace {

namespace net = boost::asio;
using tcp = net::ip::tcp;
namespace fs = std::filesystem;

// Forwards loopback TCP connections to `upstream_port`. The i-th accepted connection follows
// plan[i] (past the plan: passed through): kRefuse closes it at once; a positive K forwards K
// bytes from the client, then closes both sides (the rest is lost, as when a link breaks);
// kPass forwards everything. Everything runs on one io_context thread.
class CuttingProxy {
 public:
  static constexpr long kRefuse = -1, kPass = 0;

  CuttingProxy(std::uint16_t upstream_port, std::vector<long> plan)
      : upstream_(net::ip::make_address("127.0.0.1"), upstream_port), plan_(std::move(plan)) {
    acceptor_.open(tcp::v4());
    acceptor_.set_option(tcp::acceptor::reuse_address(true));
    acceptor_.bind(tcp::endpoint(net::ip::make_address("127.0.0.1"), 0));
    acceptor_.listen();
    accept();
    thread_ = std::thread([this] { ioc_.run(); });
  }
  ~CuttingProxy() {
    net::post(ioc_, [this] { ioc_.stop(); });
    thread_.join();
  }
  std::uint16_t port() const { return acceptor_.local_endpoint().port(); }
  int accepted() const { return accepted_.load(); }
  int cuts() const { return cuts_->load(); }

 private:
  struct Link : std::enable_shared_from_this<Link> {
    Link(tcp::socket c, net::io_context& ioc, long lim, std::shared_ptr<std::atomic<int>> cuts)
        : client(std::move(c)), server(ioc), limit(lim), cut_count(std::move(cuts)) {}
    tcp::socket client, server;
    long limit, forwarded = 0;
    std::shared_ptr<std::atomic<int>> cut_count;
    std::array<char, 16384> up{}, down{};

    void start(const tcp::endpoint& to) {
      server.async_connect(to, [self = shared_from_this()](boost::system::error_code ec) {
        if (ec) return self->close();
        self->pump_up();
        self->pump_down();
      });
    }
    void pump_up() {
      client.async_read_some(net::buffer(up), [self = shared_from_this()](
                                                  boost::system::error_code ec, std::size_t n) {
        if (ec) return self->close();
        bool cut = false;
        if (self->limit > 0 && self->forwarded + static_cast<long>(n) >= self->limit) {
          n = static_cast<std::size_t>(self->limit - self->forwarded);
          cut = true;
        }
        self->forwarded += static_cast<long>(n);
        net::async_write(self->server, net::buffer(self->up, n),
                         [self, cut](boost::system::error_code wec, std::size_t) {
                           if (cut) ++*self->cut_count;
                           if (wec || cut) return self->close();
                           self->pump_up();
                         });
      });
    }
    void pump_down() {
      server.async_read_some(net::buffer(down), [self = shared_from_this()](
                                                    boost::system::error_code ec, std::size_t n) {
        if (ec) return self->close();
        net::async_write(self->client, net::buffer(self->down, n),
                         [self](boost::system::error_code wec, std::size_t) {
                           if (wec) return self->close();
                           self->pump_down();
                         });
      });
    }
    void close() {
      boost::system::error_code ignored;
      client.close(ignored);
      server.close(ignored);
    }
  };

  void accept() {
    acceptor_.async_accept([this](boost::system::error_code ec, tcp::socket s) {
      if (ec) return;
      const std::size_t i = static_cast<std::size_t>(accepted_++);
      const long step = i < plan_.size() ? plan_[i] : kPass;
      if (step == kRefuse) {
        boost::system::error_code ignored;
        s.close(ignored);
      } else {
        std::make_shared<Link>(std::move(s), ioc_, step, cuts_)->start(upstream_);
      }
      accept();
    });
  }

  net::io_context ioc_;
  tcp::acceptor acceptor_{ioc_};
  tcp::endpoint upstream_;
  std::vector<long> plan_;
  std::atomic<int> accepted_{0};
  std::shared_ptr<std::atomic<int>> cuts_ = std::make_shared<std::atomic<int>>(0);
  std::thread thread_;
};

std::unique_ptr<server_net::Server> start_server() {
  server_net::ServerConfig cfg;
  cfg.listen_address = "127.0.0.1";
  cfg.port = 0;
  server_core::CanvasServiceConfig canvas;
  canvas.name = "default";
  cfg.canvases.push_back(canvas);
  auto server = server_net::Server::create(std::move(cfg));
  EXPECT_TRUE(server.ok()) << server.error().message;
  if (!server) return nullptr;
  auto started = (*server)->start();
  EXPECT_TRUE(started.ok()) << started.error().message;
  return started ? std::move(*server) : nullptr;
}

std::string read_file(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

struct PaintRun {
  int status = -1;
  std::string out, err;
};

PaintRun paint(std::uint16_t port, const std::string& painting, const std::string& name) {
  const fs::path dir = fs::path(::testing::TempDir()) / ("paint_resume_" + name);
  fs::create_directories(dir);
  const std::string cmd = std::string("'") + DEEPCANVAS_CLIENT_BIN + "' paint --connect ws://127.0.0.1:" +
                          std::to_string(port) + "/default --token t --timeout 120 " +
                          "--reconnect-for 60 '" + painting + "' >'" + (dir / "out").string() +
                          "' 2>'" + (dir / "err").string() + "'";
  PaintRun r;
  r.status = std::system(cmd.c_str());
  r.out = read_file(dir / "out");
  r.err = read_file(dir / "err");
  return r;
}

TEST(PaintResume, APaintingCutTwiceEndsAsACleanRun) {
  const char* dir = std::getenv("DEEPCANVAS_PAINTINGS");
  if (!dir || !*dir) GTEST_SKIP() << "DEEPCANVAS_PAINTINGS is not set: no real painting to paint";
  const std::string painting = (fs::path(dir) / "demo.apa").string();
  if (!fs::exists(painting)) GTEST_SKIP() << painting << " does not exist";
  base::set_log_level(base::LogLevel::warn);

  // The stroke messages' bytes, to place the cuts inside the painting.
  auto apa = paintings::read_apa_file(painting, {});
  ASSERT_TRUE(apa.ok()) << apa.error().message;
  const std::size_t strokes = apa->strokes.size();
  long total = 0;
  for (std::size_t i = 0; i < strokes; ++i)
    total += static_cast<long>(
        protocol::encode_message(protocol::StrokeMessage{i + 1, apa->strokes[i]}).size());
  ASSERT_GT(strokes, 10u);

  auto clean_server = start_server();
  ASSERT_TRUE(clean_server);
  const PaintRun clean = paint(clean_server->port(), painting, "clean");
  ASSERT_EQ(clean.status, 0) << clean.err;
  auto clean_q = clean_server->canvas("default")->quiesce();
  ASSERT_TRUE(clean_q.ok());
  EXPECT_EQ(clean_q->strokes, strokes);

  auto server = start_server();
  ASSERT_TRUE(server);
  // Cut after ~30% of the painting, refuse two reconnects, cut again ~30% further, then pass.
  CuttingProxy proxy(server->port(), {total * 3 / 10, CuttingProxy::kRefuse,
                                      CuttingProxy::kRefuse, total * 3 / 10});
  const PaintRun cut = paint(proxy.port(), painting, "cut");
  ASSERT_EQ(cut.status, 0) << cut.err;
  EXPECT_EQ(proxy.cuts(), 2);
  EXPECT_GE(proxy.accepted(), 5);
  EXPECT_NE(cut.err.find("reconnected"), std::string::npos) << cut.err;
  auto q = server->canvas("default")->quiesce();
  ASSERT_TRUE(q.ok());
  // Some strokes reached the server twice (the test exercised resends of painted strokes)...
  const auto& m = server->metrics();
  EXPECT_GT(m.messages_in.value() - m.sessions_opened.value(), strokes);
  // ... and each was applied once.
  EXPECT_EQ(q->strokes, strokes);
  EXPECT_EQ(q->canvas_hash, clean_q->canvas_hash);  // in the painting's order
  EXPECT_NE(cut.out.find("painted " + std::to_string(strokes) + " strokes"), std::string::npos)
      << cut.out;
}

}  // namespace
}  // namespace deepcanvas::test
