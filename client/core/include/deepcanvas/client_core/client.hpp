// Client: the headless deepcanvas client library (no Vulkan). Connects to a server over
// WebSocket (Boost.Beast), says hello, sends strokes and pick-ups, and keeps a CPU Replica of the
// canvas up to date from the block frames it receives. ws:// or wss:// (TLS over OpenSSL).
//
// Epochs: block frames are decoded as they arrive and staged; at epoch_end(E) the staged frames
// are committed to the replica together (and the masked links recomputed), so the replica only
// ever moves between states the server published: no reachable cell ever points at data the
// replica has not received. applied_epoch() is the last E committed.
//
// Threading contract: one internal I/O thread owns the socket; it reads, decodes, commits
// epochs and performs the writes that the public functions queue. Every public member function is
// thread-safe and may be called from any thread except from inside a callback (there are none:
// results are collected with the wait_* functions). Sending functions never block on the
// network (they queue); wait_* functions block up to their timeout. with_replica() runs its
// function under the replica's lock: keep it short, the I/O thread waits for it.
//
// Errors: connect() fails with invalid_argument (a bad URL, a CA file that does not load),
// io_error (cannot connect; the TLS handshake failed, e.g. an untrusted certificate; the
// WebSocket handshake failed), the server's error (e.g.
// unauthorized, unsupported, not_found) when the hello is refused, or malformed for a bad reply.
// After the connection ends, sends fail with io_error and waits return what had arrived.
// A block frame that does not decode, or that cannot be applied (e.g. a delta frame whose base
// this client does not hold), is a protocol error (PROTOCOL.md 4.5): the client closes with
// 1002, wait_for_error() returns a fatal `malformed` error with in_reply_to "block_frame", and
// the replica keeps the last committed epoch (the open batch is dropped). Reconnect to resync.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "deepcanvas/client_core/replica.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_core {

struct ClientOptions {
  // ws://HOST:PORT[/path], or wss://HOST:PORT[/path] for TLS (1.2 or later). With wss:// the
  // server's certificate must chain to a trusted CA (ca_file, else the system's store) and name
  // HOST (a DNS name or an IP address in its subjectAltName); HOST is also sent as SNI when it is
  // a name. A certificate that fails is an io_error saying why (e.g. "self-signed certificate").
  std::string url = "ws://127.0.0.1:7878/";
  // wss:// only: a PEM file of CA certificates to trust instead of the system's store (a private
  // CA, or a self-signed server certificate itself).
  std::string ca_file;
  std::string canvas = "default";
  protocol::Role role = protocol::Role::painter;
  std::string token = "none";
  std::string client_name = "deepcanvas-client-core";
  // hello "client_id" (PROTOCOL.md 3.3.1): names this painter across reconnects, so that a
  // stroke resent with the same handle is painted once. Empty: none.
  std::string client_id;
  // The first stroke handle (and request id) this connection takes. A client that reconnects
  // with the same client_id must go on from the last connection's next_handle(): the server
  // answers a handle it has seen with that stroke's ack, without painting what is sent now.
  std::uint64_t first_handle = 1;
  std::chrono::milliseconds connect_timeout{10000};
  // false: count frames only (load generators): each block frame's header is checked, its
  // payload is neither decompressed nor checksummed.
  bool keep_replica = true;
  // Non-zero: the socket's receive buffer (SO_RCVBUF), set before connecting. Small values make
  // a paused client push back on the server quickly (slow-consumer tests).
  int receive_buffer_bytes = 0;
  // Ask for temporal delta block frames (hello "delta_frames", PROTOCOL.md 4.7); the replica
  // resolves them. false: the server sends every block as a full frame.
  bool delta_frames = true;
  // Ask for frame bundles (hello "frame_bundles", PROTOCOL.md 4.12): a live batch's frames as one
  // message compressed together, about 0.8x the bytes of the frames sent one by one. false: every
  // block frame alone.
  bool frame_bundles = true;
  // false: ask for no canvas stream (hello "block_frames": false): no snapshot, no block frames,
  // no epochs (wait_for_epoch() then fails at once); acks, errors, pick-ups and stats still come.
  // For clients that only paint.
  bool block_frames = true;
  // hello "batch_interval_ms" (0..1000, PROTOCOL.md 3.1): the least time between two epoch
  // batches; the versions published meanwhile come coalesced. For thin links and clients that
  // show the canvas less often than epochs come. 0: every batch as soon as it can go.
  std::uint32_t batch_interval_ms = 0;
  // Progressive join (PROTOCOL.md 4.4): while the snapshot streams in, commit what has come at
  // growing intervals (Replica::commit_partial: the subtrees still missing show as their
  // parents' filtered values), so that a large canvas shows coarse within a fraction of a
  // second and refines. Each such commit reaches the epoch listener with `partial` set; the
  // snapshot's epoch_end then commits it whole. The first comes `progressive_first` after the
  // snapshot's first frame (or at its 256th frame, if sooner: a fast link), each next one once
  // at least as many frames came again and `progressive_first` passed. false: the snapshot is
  // shown only whole.
  bool progressive_join = true;
  std::chrono::milliseconds progressive_first{150};
  // hello "camera" (PROTOCOL.md 3.1, 4.4): where this client will look from when it joins; the
  // snapshot then sends the blocks of each depth in front of it and nearest it first, so a
  // progressive join refines the view before what lies far away or behind. None: block order.
  std::optional<protocol::JoinCamera> camera;
};

struct ClientStats {
  std::uint64_t frames = 0;       // block frames received (those in bundles one by one)
  std::uint64_t frame_bytes = 0;  // their bytes on the wire (frames and bundles)
  std::uint64_t bundles = 0;      // frame bundles received (PROTOCOL.md 4.12)
  // Of frame_bytes, the uncompressed headers: 64 a block frame sent alone, 32 a bundle.
  std::uint64_t header_bytes = 0;
  std::uint64_t raw_bytes = 0;    // their payload bytes after decompression
  std::uint64_t epochs = 0;       // epoch_end messages applied
  std::uint64_t acks = 0;
  std::uint64_t errors = 0;           // error messages received
  std::uint64_t decode_failures = 0;  // frames or messages this client could not decode
  std::uint64_t applied_epoch = 0;
  std::uint64_t delta_frames = 0;  // of `frames`, temporal delta frames
  // Falling behind (PROTOCOL.md 4.5): a client that reads slower than the canvas changes gets
  // batches that skip epochs, each block at its newest version (coalesced), so it stays
  // consistent and catches up as soon as it can. `epochs_skipped`: the epochs its batches
  // skipped so far; `behind_batches`: the batches in a row, up to the last one, that skipped
  // some (0: the last batch followed the one before).
  std::uint64_t epochs_skipped = 0;
  std::uint64_t behind_batches = 0;
  // Parts of the snapshot committed before its epoch_end (ClientOptions::progressive_join).
  std::uint64_t partial_commits = 0;
};

// A committed epoch, as seen by an epoch listener (Client::set_epoch_listener).
struct CommittedRange {
  std::uint64_t first_cell = 0, cell_count = 0;
};
struct EpochCommit {
  std::uint64_t epoch = 0;
  const Replica& replica;                        // the state after the commit
  std::span<const CommittedRange> ranges;        // cell ranges the epoch's frames carried
  std::span<const std::uint32_t> masked_groups;  // groups whose links were recomputed
  bool everything = false;  // the whole replica (the call made by set_epoch_listener)
  // Part of a snapshot still arriving (ClientOptions::progressive_join): `epoch` is the
  // snapshot's, not yet held whole; subtrees not received yet show as their parents.
  bool partial = false;
  // Cells whose first_child changed besides `ranges` (Replica::changed_cells()).
  std::span<const std::uint32_t> changed_cells = {};
};

class Client {
 public:
  static Result<std::unique_ptr<Client>> connect(const ClientOptions& options);
  ~Client();  // closes the connection and joins the I/O thread
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;

  const protocol::Welcome& welcome() const noexcept;

  // ---- sending (queued; returns the handle / request id the replies will carry) ----
  Result<std::uint64_t> send_stroke(const protocol::Stroke& stroke);
  Result<std::uint64_t> begin_stroke(const protocol::Brush& brush,
                                     std::vector<protocol::StrokeSample> samples = {});
  // The handle the next stroke or request takes (see ClientOptions::first_handle). Any thread.
  std::uint64_t next_handle() const;
  Result<void> add_samples(std::uint64_t handle, std::vector<protocol::StrokeSample> samples);
  Result<void> end_stroke(std::uint64_t handle);
  Result<std::uint64_t> request_pick_up(double x, double y, double z);
  // Undo (redo) this painter's latest stroke (PROTOCOL.md 3.10): the request id the answer
  // carries. The server keys the history by client id (ClientOptions::client_id), so a client
  // that reconnects with the same id undoes the strokes it sent before.
  Result<std::uint64_t> request_undo(bool redo = false);
  // Import a file into the canvas (PROTOCOL.md 3.11): `m` with its data; its request_id is set
  // here and returned. The server converts and pastes it as one operation (undo takes it back).
  Result<std::uint64_t> request_import(protocol::Import m);
  // The canvas as a file, made by the server (PROTOCOL.md 3.12; painters and viewers): `m`'s
  // request_id is set here and returned.
  Result<std::uint64_t> request_export(protocol::ExportRequest m);
  // A playback canvas's next step (PROTOCOL.md 3.13; painters and viewers): `m`'s request_id is
  // set here and returned.
  Result<std::uint64_t> request_playback_step(protocol::PlaybackStep m);
  Result<void> request_stats();
  // This painter's presence (PROTOCOL.md 3.9): where its brush and camera are, for the other
  // artists on the canvas. Send it as often as it changes (the server relays at most one per
  // 50 ms per artist, always the latest). Checked here by the rules the server applies (the
  // canvas bounds from the welcome): invalid_argument / malformed naming the field, and nothing
  // is sent. A viewer's presence is refused by the server (unauthorized, via wait_for_error).
  Result<void> send_presence(const protocol::Presence& p);
  // Raw frames, for tests of the server's input handling.
  Result<void> send_text(std::string text);
  Result<void> send_binary(std::vector<std::uint8_t> bytes);
  // Closes the connection (a normal close); waits for the I/O thread to finish.
  void close();

  // ---- waiting ----
  // Until the replica has applied epoch >= `epoch` (at least one epoch_end must have arrived,
  // so wait_for_epoch(0) waits for the snapshot). io_error on timeout or a closed connection;
  // invalid_argument at once for a client that asked for no block frames.
  Result<std::uint64_t> wait_for_epoch(std::uint64_t epoch, std::chrono::milliseconds timeout);
  Result<protocol::Ack> wait_for_ack(std::uint64_t handle, std::chrono::milliseconds timeout);
  Result<protocol::PickUpReply> wait_for_pick_up(std::uint64_t request_id,
                                                 std::chrono::milliseconds timeout);
  // The answer to an undo or redo: the stroke taken back (restored) and the epoch it is in, or
  // the server's error (not_found: nothing to undo; limit_exceeded: history bound; ...).
  Result<protocol::UndoReply> wait_for_undo(std::uint64_t request_id,
                                            std::chrono::milliseconds timeout);
  // The answer to an import: its operation id, epoch and cell count, or the server's error.
  Result<protocol::ImportReply> wait_for_import(std::uint64_t request_id,
                                                std::chrono::milliseconds timeout);
  // The file an export request asked for, or the server's error.
  Result<protocol::ExportReply> wait_for_export(std::uint64_t request_id,
                                                std::chrono::milliseconds timeout);
  // Where the playback stands after a step (its epoch: wait_for_epoch shows the step), or the
  // server's error (unsupported: not a playback canvas, or seconds for an untimed history).
  Result<protocol::PlaybackPosition> wait_for_playback(std::uint64_t request_id,
                                                       std::chrono::milliseconds timeout);
  // The reply to the latest request_stats() (kept until the next request).
  Result<protocol::Stats> wait_for_stats(std::chrono::milliseconds timeout);
  // The next error message not yet returned by this function (in arrival order).
  std::optional<protocol::ErrorMessage> wait_for_error(std::chrono::milliseconds timeout);
  // True once the connection has ended; close_code() is the WebSocket close code (0 if none).
  bool wait_for_close(std::chrono::milliseconds timeout);
  bool is_open() const;
  int close_code() const;

  // ---- slow-consumer simulation ----
  // Stops reading from the socket (the server's sends back up) until resumed.
  void pause_reading();
  void resume_reading();

  // ---- replica and counters ----
  std::uint64_t applied_epoch() const;
  std::uint64_t pool_hash() const;
  std::uint64_t links_hash() const;
  void with_replica(const std::function<void(const Replica&)>& fn) const;
  ClientStats stats() const;
  // Epoch hook for GPU replicas: `fn` runs after every commit, on the I/O thread, under the
  // replica lock (keep it short: copy what you need; never call this Client from it). Setting
  // a listener calls it once at once (on the calling thread, under the lock) with
  // everything = true and the whole replica when an epoch has been applied, so a listener set
  // after connect() misses nothing. An empty function removes the listener.
  void set_epoch_listener(std::function<void(const EpochCommit&)> fn);
  // Time of arrival of the first block frame of an epoch > `after_epoch` (benchmarks).
  std::optional<std::chrono::steady_clock::time_point> first_frame_after(
      std::uint64_t after_epoch) const;

  // ---- presence of the other artists (PROTOCOL.md 3.9) ----
  // The latest update of every other artist currently present (those gone are removed), by
  // artist id. Painters only: viewers send no presence. A snapshot: copy, never a reference
  // into the client.
  std::vector<protocol::PresenceUpdate> presence() const;
  // Presence updates received so far, gone ones included (tests, benchmarks).
  std::uint64_t presence_updates_received() const;

  struct Impl;

 private:
  Client() = default;
  std::shared_ptr<Impl> impl_;
};

}  // namespace deepcanvas::client_core
