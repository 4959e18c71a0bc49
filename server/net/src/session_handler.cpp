// SessionHandler: hello, roles, limits, routing and replies of one session (session_handler.hpp);
// its strokes are in session_strokes.cpp, its presence in session_presence.cpp.
#include "deepcanvas/server_net/session_handler.hpp"

#include <algorithm>
#include <type_traits>
#include <variant>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/base/utf8.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"  // fnv1a64

namespace deepcanvas::server_net {

using server_core::Clock;
using base::log_event;
using base::LogLevel;

// Token bucket: `rate` tokens per second, at most `burst` stored (a full bucket at the start).
class SessionHandler::RateLimiter {
 public:
  RateLimiter(double rate, double burst) : rate_(rate), burst_(burst), tokens_(burst) {}
  bool try_take(Clock::time_point now) noexcept {
    if (rate_ <= 0) return true;
    if (have_last_) {
      const double dt = std::chrono::duration<double>(now - last_).count();
      tokens_ = std::min(burst_, tokens_ + dt * rate_);
    }
    last_ = now;
    have_last_ = true;
    if (tokens_ < 1.0) return false;
    tokens_ -= 1.0;
    return true;
  }

 private:
  double rate_, burst_, tokens_;
  Clock::time_point last_{};
  bool have_last_ = false;
};

SessionHandler::SessionHandler(SessionContext context, SessionOutput& out, Poster post,
                               std::uint64_t id, std::string remote)
    : ctx_(std::move(context)),
      config_(*ctx_.config),
      metrics_(*ctx_.metrics),
      out_(out),
      post_(std::move(post)),
      id_(id),
      remote_(std::move(remote)) {
  const double rate = config_.limits.max_strokes_per_second;
  limiter_ = std::make_unique<RateLimiter>(rate, std::max(1.0, rate));
  if (!ctx_.now) ctx_.now = [] { return Clock::now(); };
}

SessionHandler::~SessionHandler() {
  on_closed({});
}

// ---------------------------------------------------------------------------- from the transport

void SessionHandler::on_message(bool text, std::string_view data) {
  if (closing()) return;
  metrics_.messages_in.add();
  const bool in_hello = phase_ == Phase::hello;
  if (!text) {
    const Error e = make_error(Errc::malformed,
                               "binary frames are not accepted from clients: control messages are "
                               "JSON text frames");
    return in_hello ? fail(e, {}) : reply_error(e, {});
  }
  if (!base::valid_utf8(data)) {
    // RFC 6455 8.1: invalid UTF-8 in a text message fails the connection (close 1007); the
    // client is told why first.
    if (in_hello) metrics_.sessions_refused.add();
    return fail(make_error(Errc::malformed, "text message is not valid UTF-8"), {},
                CloseCode::bad_payload);
  }
  protocol::MessageRef about;
  auto decoded = protocol::decode_message(data, decode_options(), &about);
  if (!decoded) {
    if (!in_hello) return reply_error(decoded.error(), about);
    metrics_.sessions_refused.add();
    return fail(decoded.error(), about);
  }
  if (in_hello) {
    if (auto* h = std::get_if<protocol::Hello>(&*decoded)) return on_hello(*h);
    metrics_.sessions_refused.add();
    return fail(make_error(Errc::malformed, "the first message must be a hello"), about);
  }
  route(*decoded, about);
}

void SessionHandler::on_message_too_big() {
  const std::uint64_t max = config_.limits.max_frame_bytes;
  fail(make_error(Errc::limit_exceeded,
                  "message larger than max_frame_bytes (" + std::to_string(max) + ")"),
       {}, CloseCode::too_big);
}

void SessionHandler::on_hello_timeout() {
  if (phase_ != Phase::hello) return;
  fail(make_error(Errc::refused, "no hello within " + std::to_string(kHelloTimeout.count()) + " s"),
       {});
}

void SessionHandler::on_batch_written() {
  batch_in_flight_ = false;
  send_next_batch();
}

void SessionHandler::on_shutdown() {
  if (phase_ != Phase::closed) phase_ = Phase::closing;
}

void SessionHandler::on_closed(const TransportCounters& counters) {
  if (phase_ == Phase::closed) return;
  const bool was_open = phase_ == Phase::open || canvas_ != nullptr;
  phase_ = Phase::closed;
  // Strokes left open are ended with what came; their resends will be painted whole
  // (StrokeReceipts::mark_cut).
  for (auto& [handle, s] : open_) {
    if (s.replayed) continue;
    if (idempotent()) ctx_.receipts->mark_cut(canvas_->name(), client_id_, handle, id_);
    (void)canvas_->end_stroke(s.key, server_core::EndedBy::server);
  }
  open_.clear();
  sub_.reset();
  leave_presence();
  if (was_open)
    log_event(LogLevel::info, "session_closed",
              {{"session", id_},
               {"remote", remote_},
               {"blocks_sent", counters.frames_sent},
               {"bytes_sent", counters.frame_bytes_sent}});
}

// ---------------------------------------------------------------------------- requests

protocol::DecodeOptions SessionHandler::decode_options() const {
  protocol::DecodeOptions o;
  o.max_bytes = config_.limits.max_frame_bytes;
  if (canvas_) {
    const protocol::StrokeRules rules = canvas_->stroke_rules();
    o.bounds = rules.bounds;
    o.stroke_limits = rules.limits;
  } else {
    o.stroke_limits.max_samples = config_.limits.max_samples_per_stroke;
  }
  return o;
}

void SessionHandler::route(protocol::Message& message, const protocol::MessageRef& about) {
  std::visit(
      [&](auto& m) {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, protocol::DecodedStroke>)
          on_stroke(m);
        else if constexpr (std::is_same_v<T, protocol::DecodedStrokeBegin>)
          on_begin(m);
        else if constexpr (std::is_same_v<T, protocol::DecodedStrokeSamples>)
          on_samples(m);
        else if constexpr (std::is_same_v<T, protocol::StrokeEnd>)
          on_end(m);
        else if constexpr (std::is_same_v<T, protocol::PickUp>)
          on_pick_up(m);
        else if constexpr (std::is_same_v<T, protocol::Undo>)
          on_undo(m.request_id, false);
        else if constexpr (std::is_same_v<T, protocol::Redo>)
          on_undo(m.request_id, true);
        else if constexpr (std::is_same_v<T, protocol::Import>)
          on_import(m);
        else if constexpr (std::is_same_v<T, protocol::ExportRequest>)
          on_export(m);
        else if constexpr (std::is_same_v<T, protocol::PlaybackStep>)
          on_playback_step(m);
        else if constexpr (std::is_same_v<T, protocol::StatsRequest>)
          on_stats();
        else if constexpr (std::is_same_v<T, protocol::Presence>)
          on_presence(m);
        else if constexpr (std::is_same_v<T, protocol::PresenceUpdate>)
          reply_error(make_error(Errc::malformed,
                                 "a presence with 'artist' is the server-to-client form: a "
                                 "painter's own presence has no 'artist', 'name' or 'gone'"),
                      about);
        else if constexpr (std::is_same_v<T, protocol::Hello>)
          reply_error(make_error(Errc::refused, "hello was already accepted on this connection"),
                      about);
        else
          reply_error(
              make_error(Errc::malformed, "'" + about.type + "' is a server-to-client message"),
              about);
      },
      message);
}

void SessionHandler::on_hello(const protocol::Hello& h) {
  if (h.protocol_version != protocol::kProtocolVersion)
    return refuse_hello(
        make_error(Errc::unsupported, "protocol version " + std::to_string(h.protocol_version) +
                                          " is not supported; this server speaks " +
                                          std::to_string(protocol::kProtocolVersion)));
  server_core::CanvasService* canvas = ctx_.find_canvas(h.canvas);
  if (!canvas)
    return refuse_hello(make_error(Errc::not_found, "no canvas named '" + h.canvas + "'"));
  protocol::Role granted = h.role;
  if (config_.tokens) {
    auto r = config_.tokens->authorize(h.canvas, h.token, h.role);
    if (!r) {
      log_event(LogLevel::info, "hello_refused",
                {{"session", id_},
                 {"remote", remote_},
                 {"canvas", h.canvas},
                 {"role", protocol::role_name(h.role)},
                 {"reason", r.error().message}});
      return refuse_hello(r.error());
    }
    granted = *r;
  }
  canvas_ = canvas;
  role_ = granted;
  phase_ = Phase::open;
  if (ctx_.receipts && !h.client_id.empty()) {
    client_id_ = h.client_id;
    ctx_.receipts->touch(canvas->name(), client_id_, ctx_.now());
  }
  // The artist the canvas orders strokes by: the client id names the same painter across
  // reconnects (its resent strokes stay in order with those the last connection got through);
  // without one, this connection. Session ids are small counters, so the top bit keeps the two
  // kinds apart.
  artist_ = h.client_id.empty() ? id_ : artist_key(h.client_id);
  // The canvas's history names who painted each stroke: the granted role and the display name
  // the client chose.
  if (const auto& journal = canvas->config().journal; journal && granted != protocol::Role::viewer)
    journal->note_artist({artist_, std::string(protocol::role_name(granted)), h.client_name});
  metrics_.sessions_opened.add();
  protocol::Welcome w;
  w.role = granted;
  w.canvas = canvas->name();
  w.geometry = canvas->geometry();
  w.block_cells = canvas->config().octree.block_cells;
  w.texture_width = canvas->config().texture_width;
  w.epoch = canvas->published_epoch();
  w.limits = config_.limits;
  w.limits.stroke_receipts =
      ctx_.receipts ? static_cast<std::uint32_t>(ctx_.receipts->limits().per_client) : 0;
  const protocol::StrokeLimits stroke_limits = canvas->stroke_rules().limits;
  w.limits.max_stroke_extent_m = stroke_limits.max_extent_m;
  w.limits.max_stroke_cells = stroke_limits.max_stroke_cells;
  w.limits.undo_depth = canvas->config().undo.depth;
  w.limits.undo_max_stroke_bytes = canvas->config().undo.max_stroke_bytes;
  reply(w);
  batch_interval_ = std::chrono::milliseconds(h.batch_interval_ms);
  // A client that asked for no block frames (hello "block_frames": false, a painter that only
  // paints) gets no subscription: nothing is queued or sent for it.
  if (h.block_frames) subscribe(h.delta_frames, h.frame_bundles);
  // Before the snapshot is taken (on this strand, after this handler returns): its blocks of
  // one depth go nearest this camera first.
  if (sub_ && h.camera) sub_->set_camera(*h.camera);
  join_presence(h.client_name);
  log_event(LogLevel::info, "session_open",
            {{"session", id_},
             {"remote", remote_},
             {"canvas", canvas->name()},
             {"role", protocol::role_name(granted)},
             {"delta_frames", h.delta_frames ? "true" : "false"},
             {"frame_bundles", h.frame_bundles ? "true" : "false"},
             {"block_frames", h.block_frames ? "true" : "false"},
             {"batch_interval_ms", std::to_string(h.batch_interval_ms)},
             {"client", h.client_name},
             {"client_id", client_id_}});
}

void SessionHandler::refuse_hello(const Error& error) {
  metrics_.sessions_refused.add();
  fail(error, {"hello", {}});
}

bool SessionHandler::may_paint(std::string_view type, std::uint64_t handle) {
  if (role_ == protocol::Role::painter) return true;
  reply_error(make_error(Errc::unauthorized, "viewers may not paint"), {std::string(type), handle});
  return false;
}

bool SessionHandler::within_rate(std::string_view type, std::uint64_t handle) {
  if (limiter_->try_take(ctx_.now())) return true;
  reply_error(make_error(Errc::limit_exceeded,
                         "more than " + std::to_string(config_.limits.max_strokes_per_second) +
                             " strokes per second"),
              {std::string(type), handle});
  return false;
}

void SessionHandler::on_pick_up(const protocol::PickUp& m) {
  const std::uint64_t rid = m.request_id;
  auto r = canvas_->pick_up(m, [post = post_, this, rid](Result<protocol::PickUpReply> reply_r) {
    post([this, rid, reply_r = std::move(reply_r)] {
      if (phase_ != Phase::open) return;
      if (reply_r)
        reply(*reply_r);
      else
        reply_error(reply_r.error(), {"pick_up", rid});
    });
  });
  if (!r) reply_error(r.error(), {"pick_up", rid});
}

// Undo and redo are ordered with this artist's strokes and counted like them against the rate.
void SessionHandler::on_undo(std::uint64_t rid, bool redo) {
  const std::string type = redo ? "redo" : "undo";
  if (!may_paint(type, rid) || !within_rate(type, rid)) return;
  auto r = canvas_->undo(
      artist_, redo, Clock::now(),
      [post = post_, this, rid, type](Result<server_core::UndoDone> done) {
        post([this, rid, type, done = std::move(done)] {
          if (phase_ != Phase::open) return;
          if (done)
            reply(protocol::UndoReply{rid, done->stroke_id, done->epoch, done->redo});
          else
            reply_error(done.error(), {type, rid});
        });
      });
  if (!r) reply_error(r.error(), {type, rid});
}

// An import: converted on the import thread (the file is untrusted and the conversion is heavy),
// then pasted as one operation ordered among this artist's strokes when it is ready (strokes
// sent while it converts go first), counted like a stroke against the rate, one at a time.
void SessionHandler::on_import(protocol::Import& m) {
  const std::uint64_t rid = m.request_id;
  if (!may_paint("import", rid) || !within_rate("import", rid)) return;
  if (!ctx_.config->import_cells || !ctx_.run_import)
    return reply_error(make_error(Errc::unsupported, "this server does not import files"),
                       {"import", rid});
  if (import_converting_)
    return reply_error(make_error(Errc::limit_exceeded,
                                  "an import of this connection is still converting: one at a "
                                  "time"),
                       {"import", rid});
  import_converting_ = true;
  auto job = [convert = ctx_.config->import_cells, octree = canvas_->config().octree,
              msg = std::move(m), post = post_, this, rid]() mutable {
    auto cells = convert(msg, octree);
    post([this, rid, cells = std::move(cells)]() mutable {
      import_converting_ = false;
      if (phase_ != Phase::open) return;
      if (!cells) return reply_error(cells.error(), {"import", rid});
      auto shared = std::make_shared<const server_core::CellPaste>(std::move(*cells));
      auto r = canvas_->paste(
          artist_, std::move(shared), Clock::now(),
          [post = post_, this, rid](Result<server_core::ImportDone> done) {
            post([this, rid, done = std::move(done)] {
              if (phase_ != Phase::open) return;
              if (done)
                reply(protocol::ImportReply{rid, done->stroke_id, done->epoch, done->stats.cells});
              else
                reply_error(done.error(), {"import", rid});
            });
          });
      if (!r) reply_error(r.error(), {"import", rid});
    });
  };
  ctx_.run_import(std::move(job));
}

// An export (painters and viewers): a copy of the canvas made on the stroke thread (ordered like
// a pick-up), written on the import thread, sent back in one message. One at a time.
void SessionHandler::on_export(const protocol::ExportRequest& m) {
  const std::uint64_t rid = m.request_id;
  if (!within_rate("export", rid)) return;
  if (!ctx_.config->export_canvas || !ctx_.run_import)
    return reply_error(make_error(Errc::unsupported, "this server does not export canvases"),
                       {"export", rid});
  if (export_running_)
    return reply_error(make_error(Errc::limit_exceeded,
                                  "an export of this connection is still being made: one at a time"),
                       {"export", rid});
  // The file travels base64 in one message (4 characters a 3 bytes, a few hundred more).
  std::uint64_t limit = (config_.limits.max_frame_bytes > 1024 ? config_.limits.max_frame_bytes - 1024 : 0) / 4 * 3;
  if (m.max_bytes != 0) limit = std::min(limit, m.max_bytes);
  export_running_ = true;
  auto r = canvas_->copy_tree([post = post_, this, rid, m, limit, write = ctx_.config->export_canvas,
                               run = ctx_.run_import](
                                  Result<std::shared_ptr<const server_core::Octree>> tree) mutable {
    auto answer = [post, this, rid, format = m.format](Result<std::vector<std::uint8_t>> file) mutable {
      post([this, rid, format, file = std::move(file)]() mutable {
        export_running_ = false;
        if (phase_ != Phase::open) return;
        if (!file) return reply_error(file.error(), {"export", rid});
        reply(protocol::ExportReply{rid, format, std::move(*file)});
      });
    };
    if (!tree) return answer(std::move(tree).error());
    run([tree = std::move(*tree), m, limit, write, answer]() mutable {
      answer(write(*tree, m, limit));
    });
  });
  if (!r) {
    export_running_ = false;
    reply_error(r.error(), {"export", rid});
  }
}

void SessionHandler::on_stats() {
  const TransportCounters c = out_.counters();
  protocol::Stats s;
  s.epoch = canvas_->published_epoch();
  s.strokes = canvas_->metrics().strokes.value();
  s.live_cells = static_cast<std::uint64_t>(canvas_->metrics().live_cells.value());
  s.clients = static_cast<std::uint64_t>(canvas_->metrics().subscribers.value());
  s.blocks_sent = c.frames_sent;
  s.bytes_sent = c.frame_bytes_sent;
  s.queue_blocks = c.frames_queued + (sub_ ? sub_->pending_blocks() : 0);
  reply(s);
}

// ---------------------------------------------------------------------------- block batches

void SessionHandler::subscribe(bool delta_frames, bool bundles) {
  // The notify runs on the compress thread; a burst of publishes posts one take.
  auto notify = [post = post_, posted = batch_posted_, this] {
    if (posted->exchange(true)) return;
    post([this, posted] {
      posted->store(false);
      send_next_batch();
    });
  };
  // Composed deltas for a client that skips versions on purpose; a slow reader gets chains.
  sub_ = canvas_->subscribe(std::move(notify), delta_frames, batch_interval_.count() > 0,
                            bundles);
}

void SessionHandler::send_next_batch(FanoutGate::SlotRef slot) {
  if (phase_ != Phase::open || batch_in_flight_ || !sub_ || batch_timer_armed_ || fanout_waiting_)
    return;
  if (batch_interval_.count() > 0 && last_batch_taken_) {
    // The client asked for batches no closer than this: the next waits for the timer, and the
    // versions published meanwhile coalesce in the subscription.
    const auto since = ctx_.now() - *last_batch_taken_;
    if (since < batch_interval_) {
      batch_timer_armed_ = true;
      out_.run_after(SessionTimer::batch,
                     std::chrono::ceil<std::chrono::milliseconds>(batch_interval_ - since), [this] {
                       batch_timer_armed_ = false;
                       send_next_batch();
                     });
      return;
    }
  }
  if (ctx_.fanout && !slot) slot = ctx_.fanout->try_acquire();
  if (ctx_.fanout && !slot) {
    // Every slot is held: wait in the gate's queue. The slot comes with the resume and goes back
    // once the posted function is done with it, or is dropped (the session gone).
    fanout_waiting_ = true;
    ctx_.fanout->acquire([post = post_, this](FanoutGate::SlotRef given) {
      post([this, given = std::move(given)] {
        fanout_waiting_ = false;
        send_next_batch(given);
      });
    });
    return;
  }
  take_batch();
  // `slot` goes back here, after the take and the writes it starts.
}

// Runs while holding a slot of the fanout gate (when there is one).
void SessionHandler::take_batch() {
  auto batch = sub_->take();
  if (!batch) return;
  last_batch_taken_ = ctx_.now();
  const auto n = batch->block_frames;
  metrics_.frame_raw_bytes_sent.add(batch->raw_bytes);
  metrics_.delta_frames_sent.add(batch->delta_frames);
  const auto taken = Clock::now();
  for (const auto& t : batch->stroke_receipts)
    metrics_.stroke_to_take_seconds.observe_seconds(
        std::chrono::duration<double>(taken - t).count());
  protocol::EpochEnd end;
  end.epoch = batch->epoch;
  end.blocks = n;
  end.caught_up = batch->epoch == canvas_->published_epoch();
  batch_in_flight_ = true;
  out_.send_batch(OutgoingBatch{std::move(batch->frames), protocol::encode_message(end),
                                std::move(batch->stroke_receipts)});
}

// ---------------------------------------------------------------------------- replies

void SessionHandler::reply(const protocol::Message& message) {
  if (closing()) return;
  if (!out_.send_text(protocol::encode_message(message)))
    fail(make_error(Errc::limit_exceeded, "too many unread replies: the client does not read"), {});
}

void SessionHandler::reply_error(const Error& error, const protocol::MessageRef& about) {
  metrics_.errors_sent.add();
  log_error(error, about, false);
  reply(protocol::to_error_message(error, about, false));
}

void SessionHandler::fail(const Error& error, const protocol::MessageRef& about, CloseCode code) {
  metrics_.errors_sent.add();
  log_error(error, about, true);
  if (closing()) return;
  phase_ = Phase::closing;
  out_.close(code, errc_name(error.code),
             protocol::encode_message(protocol::to_error_message(error, about, true)));
}

void SessionHandler::log_error(const Error& error, const protocol::MessageRef& about,
                               bool fatal) const {
  log_event(fatal ? LogLevel::info : LogLevel::debug, "client_error",
            {{"session", id_},
             {"remote", remote_},
             {"code", errc_name(error.code)},
             {"in_reply_to", about.type},
             {"fatal", fatal ? "true" : "false"},
             {"message", error.message}});
}

// A playback step (painters and viewers of a playback canvas; PROTOCOL.md 3.13): answered with
// where the playback stands once the epoch holding the step is published, so the blocks of the
// step reach this client before (or with) the answer's epoch.
void SessionHandler::on_playback_step(const protocol::PlaybackStep& m) {
  const std::uint64_t rid = m.request_id;
  if (!within_rate("playback_step", rid)) return;
  auto r = canvas_->play(m.strokes, m.seconds,
                         [post = post_, this, rid, history = canvas_->config().playback](
                             Result<server_core::PlaybackDone> done) {
    post([this, rid, history, done = std::move(done)] {
      if (phase_ != Phase::open) return;
      if (!done) return reply_error(done.error(), {"playback_step", rid});
      protocol::PlaybackPosition p;
      p.request_id = rid;
      p.epoch = done->epoch;
      p.events = done->events;
      p.events_total = history->events.size();
      p.strokes = done->operations;
      p.strokes_total = history->operations;
      p.painting_seconds = done->painting_seconds;
      p.painting_seconds_total = history->seconds_total();
      p.timed = history->timed();
      p.bounds = history->bounds;
      reply(p);
    });
  });
  if (!r) reply_error(r.error(), {"playback_step", rid});
}

}  // namespace deepcanvas::server_net
