// Private types of server_net: the shared server state, the listener and the two session kinds
// (HttpSession, and WsSession: the WebSocket transport of a SessionHandler). Both are templates
// over the stream: PlainStream, or TlsStream when the server has a certificate (one session
// code for both; each .cpp instantiates the two).
#pragma once

#include <atomic>
#include <boost/asio.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/beast.hpp>
#include <boost/beast/ssl.hpp>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <memory>
#include <list>
#include <mutex>
#include <string>
#include <thread>

#include <boost/asio/thread_pool.hpp>
#include <unordered_map>
#include <vector>

#include "deepcanvas/server_net/fanout_gate.hpp"
#include "deepcanvas/server_net/presence_relay.hpp"
#include "deepcanvas/server_net/server.hpp"
#include "deepcanvas/server_net/stroke_receipts.hpp"

namespace deepcanvas::server_net {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;

using PlainStream = beast::tcp_stream;
using TlsStream = beast::ssl_stream<beast::tcp_stream>;

// What the server needs of a WebSocket session of either stream kind (the session map).
class WsSessionBase {
 public:
  virtual ~WsSessionBase() = default;
  // Server shutdown: close with going_away now (posted to the session's strand).
  virtual void close_from_server() = 0;
};

// Counts unauthenticated connections per client address and in total (ServerConfig's
// pre-authentication caps). Thread-safe.
//
// Eviction: when the total cap is reached, a new connection does not lock everybody out (an
// unauthenticated flood from many addresses would otherwise fill the cap and keep artists from
// joining until the hello deadline frees places): the oldest unauthenticated connection that
// can be closed (one whose session registered an evictor) is closed instead and its place
// given to the newcomer. An artist's client sends its hello within milliseconds of connecting,
// so the oldest connections without one are the idle or slow ones. The per-address cap still
// refuses: an address at its cap is the one flooding.
class PreAuthTable {
 public:
  PreAuthTable(std::size_t max_total, std::size_t max_per_address, ServerMetrics& metrics)
      : max_total_(max_total), max_per_address_(max_per_address), metrics_(metrics) {}
  // The key an address is counted under: IPv4 and IPv4-mapped addresses whole, IPv6 by /64.
  static std::string key_of(const net::ip::address& address);
  // Takes a place for `key`: its id (> 0), or 0 when a cap is reached and nothing could be
  // evicted (`why` names which cap). When the total cap is reached, the oldest evictable place
  // is given up and `evicted` receives its evictor (call it outside any lock).
  std::uint64_t try_acquire(const std::string& key, const char*& why,
                            std::function<void()>& evicted);
  // What closes the connection holding place `id` (its session's executor is used by it).
  void set_evictor(std::uint64_t id, std::function<void()> evictor);
  void release(std::uint64_t id) noexcept;

 private:
  struct Place {
    std::uint64_t id = 0;
    std::string key;
    std::function<void()> evictor;
  };
  void drop_counts(const std::string& key) noexcept;  // with mutex_ held

  std::mutex mutex_;
  std::unordered_map<std::string, std::size_t> by_key_;
  std::list<Place> places_;  // oldest first
  std::unordered_map<std::uint64_t, std::list<Place>::iterator> by_id_;
  std::uint64_t next_id_ = 1;
  std::size_t total_ = 0;
  const std::size_t max_total_, max_per_address_;
  ServerMetrics& metrics_;
};

// One connection's place in the PreAuthTable, held from accept until its hello is accepted or
// the connection ends (whichever comes first). Move-only; releases on destruction.
class PreAuthSlot {
 public:
  PreAuthSlot() = default;
  PreAuthSlot(std::shared_ptr<PreAuthTable> table, std::uint64_t id)
      : table_(std::move(table)), id_(id) {}
  PreAuthSlot(PreAuthSlot&& o) noexcept : table_(std::move(o.table_)), id_(o.id_) {}
  PreAuthSlot& operator=(PreAuthSlot&& o) noexcept {
    if (this != &o) {
      release();
      table_ = std::move(o.table_);
      id_ = o.id_;
    }
    return *this;
  }
  ~PreAuthSlot() { release(); }
  void release() noexcept {
    if (table_) table_->release(id_);
    table_.reset();
  }
  bool held() const noexcept { return table_ != nullptr; }
  // Registers what closes this connection should its place be evicted (see PreAuthTable).
  void on_evict(std::function<void()> evictor) {
    if (table_) table_->set_evictor(id_, std::move(evictor));
  }

 private:
  std::shared_ptr<PreAuthTable> table_;
  std::uint64_t id_ = 0;
};

struct Server::State {
  ServerConfig config;
  // Before the canvases: their stroke threads settle receipts until they stop.
  std::unique_ptr<StrokeReceipts> receipts;
  std::vector<std::unique_ptr<server_core::CanvasService>> canvases;
  ServerMetrics metrics;
  // Presence passed between the sessions of each canvas (after `metrics`, which it counts in).
  PresenceRelay presence{{&metrics.presence_published, &metrics.presence_coalesced}};
  // The TLS server context (certificate and key from ServerConfig), or null for plain ws://.
  // Shared by all connections: OpenSSL makes each connection's SSL object from it thread-safely.
  std::unique_ptr<net::ssl::context> tls;
  net::io_context ioc;
  // Imports are converted here, one at a time (ServerConfig::import_cells).
  net::thread_pool imports{1};
  std::unique_ptr<tcp::acceptor> acceptor;
  std::vector<std::thread> threads;
  std::atomic<std::uint16_t> port{0};
  std::shared_ptr<PreAuthTable> pre_auth;
  // Batch takes on the network threads: one less at a time than there are threads (at least
  // one), so a thread stays free for replies (fanout_gate.hpp).
  std::shared_ptr<FanoutGate> fanout;
  // Control messages queued in all sessions and not yet written (drain waits for 0).
  std::atomic<std::int64_t> control_queued{0};

  std::mutex sessions_mutex;
  std::unordered_map<std::uint64_t, std::weak_ptr<WsSessionBase>> sessions;
  std::uint64_t next_session_id = 1;

  std::mutex stop_mutex;
  std::condition_variable stop_cv;
  bool started = false;
  bool stop_begun = false;
  bool stop_done = false;

  server_core::CanvasService* canvas(std::string_view name) const noexcept;
  std::string metrics_text() const;
};

// Starts the accept loop on the state's acceptor.
void start_listener(const std::shared_ptr<Server::State>& state);
// Takes over an accepted socket: with TLS, the handshake first (within hello_timeout); then reads
// HTTP requests, upgrades WebSockets. `slot`: the connection's pre-authentication place, passed
// on to its WebSocket session.
void start_http_session(tcp::socket socket, PreAuthSlot slot,
                        const std::shared_ptr<Server::State>& state);
// Takes over an upgraded connection. Stream: PlainStream or TlsStream (instantiated for both).
template <class Stream>
void start_ws_session(Stream stream, http::request<http::string_body> request, PreAuthSlot slot,
                      const std::shared_ptr<Server::State>& state);
// Asks a session to close (posted to its strand).
void close_ws_session(const std::shared_ptr<WsSessionBase>& session);

}  // namespace deepcanvas::server_net
