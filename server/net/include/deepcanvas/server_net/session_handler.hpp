// SessionHandler: what one client's WebSocket session means, without the socket.
//
// The transport (WsSession in ws_session.cpp: the Beast stream, the strand, the read loop and
// the write queue) tells the handler what it read and when; the handler answers through a
// SessionOutput. The handler owns everything else: the hello (protocol version, canvas, token
// and role), what each role may do, the per-session limits (strokes per second, streamed strokes
// open at once, samples per streamed stroke, unread replies), routing requests to the canvas
// (server_core::CanvasService) and every reply (welcome, acks, pick-up replies, stats, errors,
// epoch batches). It has no Asio in it, so tests drive it with a fake output (tests/server_net).
//
// Replies: a bad request gets an error naming its type and handle and the session goes on; the
// session ends (a fatal error, then the close) for a bad first message or refused hello, no hello
// within kHelloTimeout, a message over SessionLimits::max_frame_bytes (close code 1009) and a
// client that lets more than ServerConfig::max_control_queue replies pile up unread. Block
// frames go out one epoch batch at a time: the next batch is taken from the subscription only
// when the previous one's epoch_end has been written, so a slow reader's backlog stays in the
// subscription as a coalescing set of block ids. A client that gave hello "batch_interval_ms"
// also gets the next batch no sooner than that after the previous one was taken (a timer), so
// the versions published meanwhile coalesce the same way. With a fanout gate
// (SessionContext::fanout, fanout_gate.hpp) each take also waits for one of the gate's slots, so
// that replies are not queued behind every subscriber's take.
//
// Strokes with a client id (hello "client_id", PROTOCOL.md 3.3.1): the session claims each
// stroke in the server's StrokeReceipts before it goes to the canvas; a stroke claimed before
// (a resend after a reconnect) is not painted again and is answered with the first one's ack
// or error, now or when it comes. Without a client id every stroke is painted.
//
// Presence (PROTOCOL.md 3.9, session_presence.cpp): every session joins its canvas's
// PresenceRelay after its hello. A painter's presence is relayed to the canvas's other sessions,
// at most one per kPresenceInterval: one that comes sooner is held (a newer one replaces it) and
// relayed when the interval is up, so the last one always goes out. A viewer's presence gets
// `unauthorized`. Updates for this session come from its PresenceInbox (coalesced per artist)
// and at most kPresenceInFlight of them are in the transport's queue at a time. When the session
// ends, the others get its "gone" update (if it ever published a presence).
//
// Streamed strokes: a slot (max_open_strokes) is held from stroke_begin until stroke_end, or
// until the canvas answers the stroke first (it ended it: idle timeout, an error): then the slot
// is free at once, and its later samples and its stroke_end get `refused` naming why.
//
// Untrusted input: everything given to on_message() comes from the client. The handler decodes
// it with protocol::decode_message, the boundary where bytes become a validated stroke, and
// hands strokes to the canvas as they come out of it.
//
// Threading: not thread-safe. Every member runs on the session's strand, one call at a time.
// What comes back from the canvas's threads (acks, pick-up replies, new epochs) reaches the
// handler through its Poster, which runs it on that strand later.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/server_core/canvas_service.hpp"
#include "deepcanvas/server_net/fanout_gate.hpp"
#include "deepcanvas/server_net/presence_relay.hpp"
#include "deepcanvas/server_net/server.hpp"
#include "deepcanvas/server_net/stroke_receipts.hpp"

namespace deepcanvas::server_net {

// The WebSocket close codes a session ends with (RFC 6455, 7.4.1).
enum class CloseCode : std::uint16_t {
  going_away = 1001,
  bad_payload = 1007,  // a text message that is not valid UTF-8
  policy_error = 1008,
  too_big = 1009
};

// What the transport has written for this session (the stats reply reads it).
struct TransportCounters {
  std::uint64_t frames_sent = 0;  // block frames written
  std::uint64_t frame_bytes_sent = 0;
  std::uint64_t frames_queued = 0;  // block frames queued and not yet written
};

// One epoch's batch: its block frames, then the epoch_end that closes it.
struct OutgoingBatch {
  std::vector<server_core::FramePtr> frames;
  std::string epoch_end;  // an encoded protocol::EpochEnd
  // Receive times of strokes whose first blocks are in the batch (latency metrics).
  std::vector<server_core::Clock::time_point> stroke_receipts;
};

// The handler's timers (SessionOutput::run_after): the presence interval, and the least time
// between two epoch batches a client asked for (hello "batch_interval_ms").
enum class SessionTimer { presence, batch };

// What the handler asks of its transport. Called only from the handler's members (the strand).
class SessionOutput {
 public:
  virtual ~SessionOutput() = default;
  // Queues a control message (a JSON text frame). false when ServerConfig::max_control_queue
  // control messages already wait to be written (the client does not read): nothing is queued.
  virtual bool send_text(std::string text) = 0;
  // Queues a batch behind what is queued; SessionHandler::on_batch_written() follows once its
  // epoch_end is written. The handler has at most one batch queued at a time.
  virtual void send_batch(OutgoingBatch batch) = 0;
  // Queues `last_text` (unless empty; beyond the control-queue bound) and closes the connection
  // with `code` and `reason` once everything queued has been written. Nothing more is read.
  virtual void close(CloseCode code, std::string_view reason, std::string last_text) = 0;
  virtual TransportCounters counters() const = 0;
  // Queues a presence update (an encoded "presence" message) behind what is queued, outside the
  // control messages' bound (the handler bounds these: kPresenceInFlight);
  // SessionHandler::on_presence_written() follows once it is written. Dropped when the session
  // is ending.
  virtual void send_presence(PresenceText text) = 0;
  // Runs `fn` on the session's strand once `delay` has passed, unless the session has ended by
  // then. Each SessionTimer is one timer: a new call replaces its pending one (whose fn never
  // runs); the two timers are independent.
  virtual void run_after(SessionTimer timer, std::chrono::milliseconds delay,
                         std::function<void()> fn) = 0;
};

// Runs a function on the session's strand later, if the session still exists (otherwise drops
// it). Safe to call from any thread at any time, also after the session has ended.
using Poster = std::function<void(std::function<void()>)>;

// What a handler needs of the server. The pointers outlive the handler.
struct SessionContext {
  const ServerConfig* config = nullptr;  // limits, tokens, max_control_queue
  ServerMetrics* metrics = nullptr;
  // The canvas of that name, or nullptr.
  std::function<server_core::CanvasService*(std::string_view name)> find_canvas;
  // The rate limit's clock; empty: server_core::Clock::now.
  std::function<server_core::Clock::time_point()> now;
  // The server's receipts of strokes sent with a client id (hello "client_id"): a resent stroke
  // is answered from them instead of painted again. nullptr: client ids are not remembered and
  // welcome.limits.stroke_receipts says 0.
  StrokeReceipts* receipts = nullptr;
  // The server's presence relay (presence_relay.hpp). nullptr: presence is accepted from
  // painters but relayed to nobody.
  PresenceRelay* presence = nullptr;
  // Runs an import's conversion off the network threads (the server's import thread). Empty:
  // imports are refused.
  std::function<void(std::function<void()>)> run_import;
  // Bounds the batch takes queued on the network threads at once (fanout_gate.hpp). nullptr:
  // each session takes its next batch as soon as it may.
  std::shared_ptr<FanoutGate> fanout;
};

class SessionHandler {
 public:
  // A session that sends no hello within this is refused (fatal error, close).
  static constexpr std::chrono::seconds kHelloTimeout{10};
  // At most one presence of a painter is relayed per this interval (PROTOCOL.md 3.9).
  static constexpr std::chrono::milliseconds kPresenceInterval{50};
  // Presence updates in the transport's queue at once; the rest wait, coalesced, in the inbox.
  static constexpr std::size_t kPresenceInFlight = 4;

  // `out` outlives the handler. `id` and `remote` name the session in logs.
  SessionHandler(SessionContext context, SessionOutput& out, Poster post, std::uint64_t id,
                 std::string remote);
  ~SessionHandler();  // on_closed() with no counters, if it has not run
  SessionHandler(const SessionHandler&) = delete;
  SessionHandler& operator=(const SessionHandler&) = delete;

  // ---- what the transport reports ----
  // One whole WebSocket message (`text`: a text frame, otherwise binary).
  void on_message(bool text, std::string_view data);
  // A message grew past SessionLimits::max_frame_bytes; its rest is not read.
  void on_message_too_big();
  // kHelloTimeout has passed since the connection opened (ignored once a hello was accepted).
  void on_hello_timeout();
  // The epoch_end of the last send_batch() has been written.
  void on_batch_written();
  // A presence update from send_presence() has been written.
  void on_presence_written();
  // The server is shutting down: the transport closes with going_away now; nothing more is sent.
  void on_shutdown();
  // The connection has ended: ends the session's open streamed strokes (so that they are painted
  // and nobody waits for them), unsubscribes, logs. Idempotent.
  void on_closed(const TransportCounters& counters);

  // Still waiting for the hello (the transport runs the hello timer until then).
  bool awaiting_hello() const noexcept { return phase_ == Phase::hello; }
  // A fatal error or a shutdown has begun the end of the session: read no more.
  bool closing() const noexcept { return phase_ == Phase::closing || phase_ == Phase::closed; }

 private:
  enum class Phase { hello, open, closing, closed };
  // A resend of a stroke still in flight (its first sending's connection may be gone: a resend
  // is how the server learns of it), kept until that stroke settles: painted if it settles cut
  // (StrokeReceipts::TakeOver), else dropped. Bounded like a live stroke (one message, or
  // max_samples_per_stroke).
  struct ResendBuffer {
    std::optional<protocol::ValidatedStroke> stroke;  // a whole stroke
    std::optional<protocol::ValidatedBrush> brush;    // a streamed one: brush, samples so far
    protocol::ValidatedSamples samples;
    bool ended = false;  // its stroke_end came (or the session ended it)
  };
  struct OpenStroke {
    std::uint64_t key = 0;      // the canvas's stroke key
    std::size_t samples = 0;    // received so far (max_samples_per_stroke)
    std::uint64_t serial = 0;   // which begin opened it (a handle may be reused after its end)
    bool replayed = false;      // a resend of a stroke already claimed: nothing goes to the canvas
    std::shared_ptr<ResendBuffer> waiting;  // replayed while in flight: its samples, kept
  };
  // How a stroke with this session's client id was claimed (StrokeReceipts::claim).
  enum class ClaimStep {
    submit,    // new, or no client id: submit it to the canvas
    replayed,  // claimed before: its answer has been sent, nothing is painted
    waiting,   // claimed before and in flight: kept in the ResendBuffer until it settles
    refused,   // the error has been sent
  };
  class RateLimiter;

  protocol::DecodeOptions decode_options() const;
  void route(protocol::Message& message, const protocol::MessageRef& about);
  void on_hello(const protocol::Hello& hello);
  void refuse_hello(const Error& error);
  void on_stroke(protocol::DecodedStroke& m);
  void on_begin(protocol::DecodedStrokeBegin& m);
  void on_samples(protocol::DecodedStrokeSamples& m);
  void on_end(const protocol::StrokeEnd& m);
  void on_pick_up(const protocol::PickUp& m);
  void on_undo(std::uint64_t request_id, bool redo);
  void on_stats();
  // Presence (session_presence.cpp).
  void on_presence(const protocol::Presence& p);
  void join_presence(const std::string& client_name);
  void leave_presence();
  void relay_presence(const protocol::Presence& p, server_core::Clock::time_point now);
  void on_presence_timer();
  void pump_presence();
  void on_import(protocol::Import& m);
  void on_export(const protocol::ExportRequest& m);
  void on_playback_step(const protocol::PlaybackStep& m);
  bool may_paint(std::string_view type, std::uint64_t handle);
  bool within_rate(std::string_view type, std::uint64_t handle);
  // The ack (or error) of stroke `handle`, posted to the strand. `serial`: the streamed stroke
  // whose slot in open_ the answer frees (0 for a whole stroke).
  server_core::AckFn ack_fn(std::uint64_t handle, std::uint64_t serial = 0);
  void on_answered(std::uint64_t handle, std::uint64_t serial,
                   const Result<server_core::StrokeDone>& r);
  // With a client id: claims the stroke (StrokeReceipts::claim) and answers a resend. Without
  // one: submit.
  // `resend` (may be null) is kept for the take-over when the claim is in flight.
  ClaimStep claim(std::string_view type, std::uint64_t handle, std::uint64_t serial,
                  std::shared_ptr<ResendBuffer> resend = nullptr);
  // The stroke a kept resend waited on settled cut: this session now holds its claim and paints
  // the resend (after withdrawing `withdraw`, 0: nothing).
  void on_taken_over(std::uint64_t handle, std::uint64_t serial, ResendBuffer& resend,
                     std::uint64_t withdraw);
  void withdraw_cut_stroke(std::uint64_t stroke_id, std::uint64_t handle);
  // The canvas's callback for a claimed stroke: settles the receipt, then answers as ack_fn.
  server_core::AckFn settle_fn(std::uint64_t handle, std::uint64_t serial);
  // The canvas refused a claimed stroke at once: the claim is released.
  void unclaim(std::uint64_t handle, const Error& error);
  bool idempotent() const noexcept { return ctx_.receipts != nullptr && !client_id_.empty(); }
  // The handle the canvas's history keeps with a stroke (StrokeEvent::handle): only where a
  // resend can be recognised by it (a client id), else 0.
  std::uint64_t history_handle(std::uint64_t handle) const noexcept {
    return idempotent() ? handle : 0;
  }
  // `why` completes "the server ended it ...".
  void remember_ended(std::uint64_t handle, std::string why);
  const std::string* ended_why(std::uint64_t handle) const;
  void forget_ended(std::uint64_t handle);
  Error not_open(std::uint64_t handle) const;
  void subscribe(bool delta_frames, bool bundles);
  // Takes and sends the next batch when the session may (open, none in flight, past its batch
  // interval), once it holds a slot of the fanout gate (`slot`, or one free now, or one it
  // waits for in the gate's queue).
  void send_next_batch(FanoutGate::SlotRef slot = nullptr);
  void take_batch();

  // A control message; a client that leaves too many unread is disconnected.
  void reply(const protocol::Message& message);
  // A non-fatal error about the message `about` names.
  void reply_error(const Error& error, const protocol::MessageRef& about);
  // A fatal error, then the close (the first one only).
  void fail(const Error& error, const protocol::MessageRef& about,
            CloseCode code = CloseCode::policy_error);
  void log_error(const Error& error, const protocol::MessageRef& about, bool fatal) const;

  SessionContext ctx_;
  const ServerConfig& config_;
  ServerMetrics& metrics_;
  SessionOutput& out_;
  Poster post_;
  std::uint64_t id_;
  std::string remote_;
  Phase phase_ = Phase::hello;
  server_core::CanvasService* canvas_ = nullptr;
  protocol::Role role_ = protocol::Role::viewer;
  std::unique_ptr<RateLimiter> limiter_;
  std::string client_id_;  // hello "client_id"; empty: none
  std::uint64_t artist_ = 0;  // CanvasService's artist for this session's strokes (on hello)
  bool import_converting_ = false;  // an import of this session is on the import thread
  bool export_running_ = false;     // an export of this session is being made
  std::unordered_map<std::uint64_t, OpenStroke> open_;  // by the client's handle
  std::uint64_t next_serial_ = 1;
  // Streamed strokes the server ended (idle, failed, too long) that the client has not ended:
  // their late samples and their stroke_end get `refused`. The latest kMaxEnded.
  static constexpr std::size_t kMaxEnded = 64;
  std::vector<std::pair<std::uint64_t, std::string>> ended_;  // (handle, why)
  std::shared_ptr<server_core::Subscription> sub_;
  bool batch_in_flight_ = false;
  // Set while a take is posted, so that a burst of publishes posts one (shared with the
  // subscription's notify, which runs on the compress thread).
  std::shared_ptr<std::atomic<bool>> batch_posted_ = std::make_shared<std::atomic<bool>>(false);
  // hello "batch_interval_ms": when the last batch was taken, and a take waiting on the timer.
  std::chrono::milliseconds batch_interval_{0};
  std::optional<server_core::Clock::time_point> last_batch_taken_;
  bool batch_timer_armed_ = false;
  bool fanout_waiting_ = false;  // queued in the fanout gate for a slot

  // Presence: this session's inbox (joined at hello) and what is in the transport's queue.
  std::shared_ptr<PresenceInbox> presence_inbox_;
  std::size_t presence_in_flight_ = 0;
  std::string client_name_;  // the hello's, the name others see with this painter's presence
  // A painter's own presence: when it last went out, and one held back by the interval.
  server_core::Clock::time_point presence_last_relayed_{};
  bool presence_relayed_ = false;
  std::optional<protocol::Presence> presence_held_;
  bool presence_timer_armed_ = false;
};

}  // namespace deepcanvas::server_net
