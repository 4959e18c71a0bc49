// The streaming server: canvases served over WebSocket (Boost.Beast), plus HTTP on the same port
// (GET /metrics in Prometheus text format, GET /healthz).
//
// Shape (as in the Beast examples): a Listener accepts TCP connections; each starts as an
// HttpSession that reads one HTTP request; a WebSocket upgrade turns it into a WsSession, any
// other request is answered and the connection kept alive or closed. A WsSession is the
// transport only (stream, strand, read loop, write queue); what the session's messages mean is
// its SessionHandler's (session_handler.hpp), which has no socket and is tested without one. One
// io_context runs on a small pool of network threads; each connection has its own strand, so its
// handlers never run concurrently. The canvases' stroke and compress threads are in
// server_core::CanvasService and never wait on the network.
//
// Per session: a hello (protocol version, role, token, canvas) must come first; then the server
// sends welcome, a snapshot (block frames + epoch_end) and live batches. Outgoing data is
// bounded: at most one batch of block frames is queued at a time (the rest stays a coalescing set
// of block ids in the subscription) and at most `max_control_queue` control messages; a client
// that lets control replies pile up past that is disconnected. One client's errors never touch
// another's state.
//
// Threading: create() and start() from one thread; stop() from any thread (also from a signal
// handling thread), idempotent; the destructor calls stop(). Accessors are thread-safe.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/base/result.hpp"
#include "deepcanvas/server_net/tokens.hpp"
#include "deepcanvas/server_core/canvas_service.hpp"

namespace deepcanvas::server_net {

// What a restored canvas's history says about its strokes' senders (storage RestoreReport).
struct RestoredStrokeNames {
  // Ended by their senders: a resend is answered with the ack (StrokeReceipts::restore).
  std::vector<server_core::StrokeName> ended;
  // Ended cut off by the restart, a client id having sent them: a resend first withdraws what
  // was stored (StrokeReceipts::restore_cut).
  std::vector<server_core::StrokeName> cut;
};

struct ServerConfig {
  std::string listen_address = "127.0.0.1";
  std::uint16_t port = 7878;  // 0: any free port (read it back with Server::port())
  std::vector<server_core::CanvasServiceConfig> canvases;
  // Makes each canvas from its config (after the session limits are applied to it): a durable
  // canvas restored from its data directory (storage/durable_canvas.hpp). Unset: a new canvas in
  // memory (CanvasService::create).
  std::function<Result<std::unique_ptr<server_core::CanvasService>>(
      const server_core::CanvasServiceConfig&)>
      make_canvas;
  // After make_canvas: the strokes its history names (RestoredStrokeNames), seeded into the
  // receipts. Unset: none.
  std::function<RestoredStrokeNames(const std::string& canvas)> restored_stroke_names;
  // Without tokens every hello is granted the role it asks for (development on loopback);
  // create() refuses a non-loopback listen address without tokens.
  std::optional<server_net::TokenTable> tokens;
  protocol::SessionLimits limits;
  // Turns an import's file into cells for a canvas (PROTOCOL.md 3.11; the server app sets the
  // export target's importer). Runs on the server's import thread, one import at a time, never
  // on a network thread. Unset: imports are refused with `unsupported`.
  std::function<Result<server_core::CellPaste>(const protocol::Import&,
                                               const server_core::OctreeConfig&)>
      import_cells;
  // Writes a canvas (a copy of its tree) as a file for an export request (PROTOCOL.md 3.12; the
  // server app sets the export target's writers), at most `max_bytes` (limit_exceeded past it,
  // with the estimate). Runs on the import thread. Unset: exports are refused (unsupported).
  std::function<Result<std::vector<std::uint8_t>>(const server_core::Octree&,
                                                  const protocol::ExportRequest&,
                                                  std::uint64_t max_bytes)>
      export_canvas;
  int network_threads = 2;
  std::size_t max_sessions = 1024;
  std::size_t max_control_queue = 4096;  // queued outgoing control messages per session
  std::size_t read_chunk_bytes = 64 * 1024;

  // Pre-authentication budget. A connection is unauthenticated from accept until its hello is
  // accepted (its plain-HTTP phase included): anyone who can reach the port can open one, so
  // what one may cost is small and the number of them is capped, per client address (IPv6: per
  // /64, what one host usually holds) and in total. A connection past a cap is answered HTTP 503
  // and closed before anything is read from it, and an authenticated painter is unaffected by
  // how many unauthenticated connections others hold.
  std::size_t max_unauthenticated = 256;
  std::size_t max_unauthenticated_per_address = 16;
  // Largest message before the hello (a hello is a few hundred bytes; its token at most 256).
  std::size_t pre_auth_frame_bytes = 16 * 1024;
  // A connection that has not sent a valid hello this long after the upgrade is closed.
  std::chrono::milliseconds hello_timeout{5000};
  // A message whose first frame has arrived must end within this, before and after the hello:
  // a partial message holds up to max_frame_bytes of the server's memory.
  std::chrono::milliseconds message_timeout{30000};
  // Non-zero: SO_SNDBUF of every client socket. The kernel's send buffer is where a slow
  // reader's data waits before the server notices it is slow; a bound here makes coalescing
  // start sooner and bounds kernel memory per session (at some cost on long fat links).
  int socket_send_buffer_bytes = 0;

  // TLS (wss://): a PEM certificate chain (the server's certificate first) and its PEM private
  // key; both or neither. With them every connection does the TLS handshake first (within
  // hello_timeout: an unauthenticated connection's budget), then the same HTTP and WebSocket
  // handling; without, plain ws://. create() loads both files and refuses (invalid_argument,
  // naming the file) one that is missing, unreadable, not PEM, or a key that does not match the
  // certificate. Only TLS 1.2 and later are accepted.
  std::string tls_cert_file;
  std::string tls_key_file;
};

// Server-wide counters (the canvases keep their own, see CanvasMetrics).
struct ServerMetrics {
  server_core::Counter connections;  // TCP connections accepted
  // Connections closed at accept: the pre-authentication caps were reached.
  server_core::Counter connections_refused;
  // Unauthenticated connections closed to admit a new one at the total cap (the oldest first).
  server_core::Counter connections_evicted;
  server_core::Counter accept_errors;  // accept() failures (e.g. out of file descriptors)
  server_core::Counter http_requests;
  server_core::Counter sessions_opened;   // hellos accepted
  server_core::Counter sessions_refused;  // hellos refused (auth, version, canvas)
  server_core::Counter messages_in;
  server_core::Counter errors_sent;
  server_core::Counter frames_sent;  // binary messages: block frames (incl. mask-only), bundles
  server_core::Counter frame_bytes_sent;
  server_core::Counter frame_raw_bytes_sent;  // raw payload bytes of the frames taken for sending
  server_core::Counter delta_frames_sent;     // of frames_sent, temporal delta frames
  server_core::Counter control_bytes_sent;
  server_core::Counter batches_sent;
  // Presence (PROTOCOL.md 3.9): updates published by painters' sessions (gone ones included),
  // painters' presences replaced by a newer one within the 50 ms interval before being relayed,
  // updates replaced or dropped in a reader's inbox before being queued (a slow reader), and
  // updates queued to clients.
  server_core::Counter presence_published;
  server_core::Counter presence_held;
  server_core::Counter presence_coalesced;
  server_core::Counter presence_sent;
  server_core::Gauge sessions;
  server_core::Gauge unauthenticated;  // connections that have not had a hello accepted yet
  server_core::Gauge send_queue_frames;                  // block frames queued in all sessions
  server_core::Histogram stroke_to_first_block_seconds;  // stroke read -> first frame written
  server_core::Histogram stroke_to_take_seconds;  // stroke read -> its batch taken by the session
  server_core::Histogram batch_write_seconds;     // batch queued -> epoch_end written
  // A stroke's answer (ack or error) given by a canvas thread -> its session's strand runs it:
  // how long answers wait behind other sessions' work on the network threads.
  server_core::Histogram answer_wait_seconds;
};

class Server {
 public:
  // Creates the canvases (each starts its threads). invalid_argument for a bad config.
  static Result<std::unique_ptr<Server>> create(ServerConfig config);
  ~Server();
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  // Binds, listens and starts the network threads. io_error when the address cannot be bound.
  Result<void> start();
  // Closes the listener and every session (close code "going away"), stops the canvases, joins
  // every thread. Idempotent.
  void stop();
  // A graceful stop (SIGTERM): closes the listener, stops the canvases (the strokes in flight
  // are finished and acked, or answered with an error; a stroke that arrives from now on is
  // answered `refused`), keeps reading and writing until the clients have been answered (no new
  // message for 300 ms and no reply waiting to be written) or `timeout` has passed, then stop().
  // Returns how long it took.
  std::chrono::milliseconds drain(std::chrono::milliseconds timeout);
  // Replaces the tokens (a reloaded tokens file) for hellos from now on; sessions already open
  // keep running. refused when the server was created without tokens.
  Result<void> reload_tokens(const TokenTable& tokens);
  // Blocks until stop() has been called and has finished.
  void wait();

  std::uint16_t port() const noexcept;
  server_core::CanvasService* canvas(std::string_view name) const noexcept;
  const ServerMetrics& metrics() const noexcept;
  std::string metrics_text() const;  // what GET /metrics answers

  struct State;  // shared with the sessions (server_net/src)

 private:
  Server() = default;
  std::shared_ptr<State> state_;
};

}  // namespace deepcanvas::server_net
